"""`companion mask --sequence`: the parallax of one pass of photos (no telemetry) corrects the network's masks.

The pass is the simulator's real-texture pass `ornate-entry` (held-out Strecha facade photo on the wall at 4 m, a
held-out Palma street photo 120 m behind, exact truth masks), rendered short and small so the test stays quick;
docs/DEPTH.md has the figures of the full-size passes.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np
import pytest

from companion.cli import main
from companion.depth.masker import Masker
from companion.depth.photomask import mask_photos
from companion.depth.sequence import ScaleSample, SequenceMasker, pass_motion, pass_scale
from companion.errors import CompanionError
from sim.camera.photo_passes import RECIPES, build_pass
from sim.camera.photo_scene import CameraModel, PhotoPassRenderer

FRAMES, BACKGROUND_FRAMES = 36, 6


@pytest.fixture(scope="module")
def photo_pass(tmp_path_factory) -> tuple[Path, list[np.ndarray]]:
    """The pass's photos as files in capture order, and their truth masks."""
    spec = build_pass(RECIPES["ornate-entry"], frames=FRAMES, background_frames=BACKGROUND_FRAMES)
    spec = dataclasses.replace(spec, camera=CameraModel(width=640, height=360, hfov_deg=69.0))
    renderer = PhotoPassRenderer(spec)
    folder = tmp_path_factory.mktemp("pass")
    truths = []
    for i in range(len(renderer)):
        frame = renderer.render(i)
        cv2.imwrite(str(folder / f"IMG_{i:04d}.png"), frame.image)
        truths.append(frame.roi_mask)
    return folder, truths


def _scores(mask_dir: Path, truths: list[np.ndarray]) -> dict:
    """Mean pixel error against the truth; background-only photos and photos showing wall given an all-zero mask."""
    errors, background_dropped, wall_dropped = [], 0, 0
    for i, truth in enumerate(truths):
        mask = cv2.imread(str(mask_dir / f"IMG_{i:04d}_mask.png"), cv2.IMREAD_UNCHANGED)
        errors.append(float(np.count_nonzero((mask > 127) != (truth > 127))) / mask.size)
        if truth.any():
            wall_dropped += not mask.any()
        else:
            background_dropped += not mask.any()
    return {"error": float(np.mean(errors)), "background_dropped": background_dropped, "wall_dropped": wall_dropped}


def test_sequence_drops_the_background_only_photos_and_lowers_the_error(photo_pass, tmp_path, capsys):
    folder, truths = photo_pass
    assert sum(not t.any() for t in truths) == BACKGROUND_FRAMES
    assert main(["mask", str(folder), "--out", str(tmp_path / "single")]) == 0
    assert "(parallax)" not in capsys.readouterr().out
    assert main(["mask", str(folder), "--out", str(tmp_path / "sequence"), "--sequence"]) == 0
    assert capsys.readouterr().out.count("(parallax)") == FRAMES  # every photo had a neighbour, the pass a scale
    single, sequence = _scores(tmp_path / "single", truths), _scores(tmp_path / "sequence", truths)
    # The default (simulator-trained) network reads parts of the 120 m background at 8-11 m: it keeps every
    # background-only photo; the pass's parallax sees that nothing in them moves like a wall at 4 m.
    assert single["background_dropped"] == 0, (single, sequence)
    assert sequence["background_dropped"] == BACKGROUND_FRAMES, (single, sequence)  # measured: 6 of 6
    assert sequence["wall_dropped"] == 0, (single, sequence)
    # and it gives back the windows, arches and balcony the network cut (measured: 33.7 % -> 12.0 %)
    assert sequence["error"] < single["error"] - 0.10, (single, sequence)


def test_photos_without_motion_keep_the_network_mask(photo_pass, tmp_path, capsys):
    """The same photo four times: no parallax, so the network alone decides, as without --sequence, and says so."""
    folder, _ = photo_pass
    photo = folder / "IMG_0005.png"
    copies = []
    for k in range(4):
        copies.append(tmp_path / f"same_{k}.png")
        copies[-1].write_bytes(photo.read_bytes())
    single = mask_photos(copies, tmp_path / "single", Masker())
    assert main(["mask", *map(str, copies), "--out", str(tmp_path / "sequence"), "--sequence"]) == 0
    printed = capsys.readouterr().out
    assert "(parallax)" not in printed and "the network alone decided every mask" in printed
    for m in single:
        assert np.array_equal(cv2.imread(str(m.mask_path)), cv2.imread(str(tmp_path / "sequence" / m.mask_path.name)))


def test_unreadable_photo_in_a_sequence_is_named_after_the_others_are_written(photo_pass, tmp_path):
    folder, _ = photo_pass
    photos = sorted(folder.glob("IMG_000[0-3].png"))
    broken = tmp_path / "IMG_0001b.png"
    broken.write_bytes(b"not a png")
    with pytest.raises(CompanionError, match="IMG_0001b.png") as err:
        mask_photos([*photos[:2], broken, *photos[2:]], tmp_path / "out", Masker(), sequence=True)
    assert "rerun" in err.value.fix
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [f"IMG_000{k}_mask.png" for k in range(4)]


def test_scale_free_model_is_refused_with_the_fix():
    class _Info:
        metric = False
        path = Path("kitti-mono.onnx")

    class _Session:
        info = _Info()

    class _ScaleFreeMasker:
        session = _Session()

    with pytest.raises(CompanionError, match="metric depth") as err:
        SequenceMasker(_ScaleFreeMasker())
    assert "without --sequence" in err.value.fix


def test_pass_motion_needs_a_measured_scale():
    right = np.array([1.0, 0.0])
    assert pass_motion([right, None], [None, None]) is None
    samples = [ScaleSample(100.0, 20.0), None, ScaleSample(120.0, 21.0)]
    motion = pass_motion([right, right, np.array([0.9, 0.1])], samples)
    assert motion is not None and motion.pairs == 2 and motion.scale_px_m == pytest.approx(110.0)
    assert motion.direction[0] > 0.99


def test_background_only_pairs_do_not_set_the_pass_scale():
    """Stills past the wall's end: their pairs move a few pixels and, where the network reads the far background as
    near, measure a scale far too small. With more of them than wall pairs the median was theirs (every background
    kept as near); the pairs that move with the wall set the scale."""
    wall = [ScaleSample(400.0 + k, 39.0 + k % 3) for k in range(8)]
    background = [ScaleSample(20.0 + k, 4.0) for k in range(12)]
    right = np.array([1.0, 0.0])
    before = pass_motion([right] * 20, wall + background)
    now = pass_motion([right] * 20, wall + background, scale_min_motion=0.5)
    assert before is not None and before.scale_px_m < 40.0
    assert now is not None and 400.0 <= now.scale_px_m <= 408.0
    assert pass_scale(wall, 0.5) == pytest.approx(pass_scale(wall, None))  # a pass of wall pairs: as before
