"""The evaluation package's inputs are the product's own: synthetic spools are written by the spool writer (the
stitcher reads them exactly as a flight's), and the shared data folder is found only where it is given."""

from __future__ import annotations

import json

import numpy as np
import pytest

from companion.errors import CompanionError
from companion.records import Pose
from companion.spool.layout import MANIFEST, META, SpoolEntry
from companion.spool.reader import load_spool
from evaluation.shared_data import ENV_VAR, shared_data_root
from evaluation.stitch.synthetic import SyntheticWall, TelemetryErrors, make_spool


def test_a_synthetic_spool_is_the_writer_s_spool(tmp_path):
    truth = make_spool(tmp_path, SyntheticWall(length_m=3.0, height_m=1.5), width=320, height=180, standoff_m=1.0,
                       errors=TelemetryErrors(noise_m=0.05, noise_deg=0.5))
    lines = [json.loads(line) for line in (tmp_path / MANIFEST).read_text().splitlines()]
    assert len(lines) == len(truth["views"]) >= 4
    for k, line in enumerate(lines):
        entry = SpoolEntry.for_frame(k)
        assert (line["image"], line["mask"], line["sidecar"]) == (entry.image, entry.mask, entry.sidecar)
        sidecar = json.loads((tmp_path / entry.sidecar).read_text())
        assert sidecar["pose"] == line["pose"] and line["pose"]["t_boot_s"] == float(k)
        pose = Pose.from_json(line["pose"])  # the product's one pose form
        assert pose is not None and pose.gimbal_pitch_deg is not None
    assert json.loads((tmp_path / META).read_text())["camera"]["hfov_deg"] == 70.0
    spooled = load_spool(tmp_path)
    assert not spooled.skipped and all(kf.pose is not None for kf in spooled.keyframes)
    # the camera looks at the wall: its forward axis is the facade's inward normal, to the attitude noise
    inward = -np.array([*truth["frame"].out_enu, 0.0])
    forward = np.array([kf.pose.R_enu_from_cam[:, 2] for kf in spooled.keyframes])
    assert np.degrees(np.arccos(np.clip(forward @ inward, -1, 1))).max() < 3.0


def test_the_shared_data_folder_is_given_or_named_by_the_environment(tmp_path, monkeypatch):
    assert shared_data_root(tmp_path) == tmp_path
    monkeypatch.setenv(ENV_VAR, str(tmp_path / "shared"))
    assert shared_data_root() == tmp_path / "shared"
    monkeypatch.delenv(ENV_VAR)
    with pytest.raises(CompanionError, match="no shared data folder") as err:
        shared_data_root()
    assert ENV_VAR in err.value.fix
