"""The onboard chain measures the standoff from its frame pairs (issue 26): the camera renders the TRUE distance,
the telemetry carries a GNSS bias that makes it say the plan's, and the spool, the report and the warnings say the
truth."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import pytest

from companion.capture.tagging import FrameTagger
from companion.capture.telemetry import ClockMap, TelemetryBuffer
from companion.cli import main
from companion.keyframes import FeatureConfig, GateConfig, KeyframeGate
from companion.mission import load_mission
from companion.onboard.chain import ChainStats, CullChain
from companion.onboard.crosscheck import OverlapCrossCheck
from companion.onboard.scan_flight import culling_summary
from companion.onboard.setup import scan_scope
from companion.onboard.standoff_watch import StandoffWatch
from companion.spool import KeyframeSpool
from companion.spool.layout import CULL_REPORT, MANIFEST
from evaluation.keyframes.synthetic import WallCamera, WallScene, textured_wall

W, H = 320, 180
PLAN = 4.0
SMALL_WALL = Path(__file__).parent / "data" / "small-wall.yaml"


@pytest.fixture(scope="module")
def scene() -> WallScene:
    wall = textured_wall(1200, 600, seed=1)  # 12 m x 6 m at 100 px/m
    far = cv2.normalize(textured_wall(1800, 600, seed=9), None, 0, 255, cv2.NORM_MINMAX)
    return WallScene(wall, far, 12.0, 6.0, width_px=W, height_px=H)


def _fly(scene: WallScene, tmp_path, true_m: float, n: int = 24, step_m: float = 0.25, fps: float = 3.0):
    """A sideways pass at ``true_m`` from the wall whose telemetry says ``PLAN`` (a GNSS bias out of the wall)."""
    cams = [WallCamera(3.0 + step_m * i, true_m, 3.0) for i in range(n)]
    buf = TelemetryBuffer()
    for i, c in enumerate(cams):
        buf.add(scene.pose(c, i / fps, offset_m=(0.0, PLAN - true_m, 0.0)))
    check = OverlapCrossCheck(scene.frame, scene.hfov_deg, H / W, standoff_m=PLAN)
    gate = KeyframeGate(GateConfig(features=FeatureConfig(long_side_px=W, max_features=1000)))
    warnings: list[str] = []
    chain = CullChain(FrameTagger(buf, ClockMap(0.0)), None, gate, KeyframeSpool(tmp_path / "spool"),
                      crosscheck=check, on_warning=warnings.append,
                      standoff_watch=StandoffWatch(scene.frame, scene.hfov_deg, PLAN))
    for i, c in enumerate(cams):
        chain.process(scene.masked_frame(i, c, t_s=i / fps).frame)
    chain.finish()
    return chain, warnings


def _sidecars(spool_dir) -> list[dict]:
    lines = [json.loads(x) for x in (spool_dir / MANIFEST).read_text().splitlines()]
    return [{**json.loads((spool_dir / line["sidecar"]).read_text()), "line": line} for line in lines]


def test_a_biased_pass_spools_the_true_standoff_and_warns(scene, tmp_path):
    """At 2.5 m while the poses say 4.0: every keyframe after the first pairs carries 2.5 +- 0.1 m from the
    camera, the report's median says it, and the chain warned that the standoff is off the plan."""
    chain, warnings = _fly(scene, tmp_path, true_m=2.5)
    kfs = _sidecars(tmp_path / "spool")
    measured = [k for k in kfs if k["standoff_measured_m"] is not None]
    assert len(kfs) >= 4 and len(measured) >= len(kfs) - 2
    for k in measured:
        assert k["standoff_measured_m"] == pytest.approx(2.5, abs=0.1) and k["standoff_source"] == "camera"
        assert 0.0 < k["standoff_sigma_m"] < 0.1
        assert k["line"]["standoff_measured_m"] == k["standoff_measured_m"]
    assert kfs[0]["standoff_measured_m"] is None and kfs[0]["standoff_source"] is None  # nothing measured yet
    summary = chain.stats.standoff
    assert summary["measured_median_m"] == pytest.approx(2.5, abs=0.05) and summary["planned_m"] == PLAN
    assert summary["measurements"] >= 8 and summary["measured_spread_m"] < 0.1
    assert 0.0 < summary["frames_without_share"] < 0.2
    assert chain.standoff is not None and chain.standoff.distance_m == pytest.approx(2.5, abs=0.1)
    off = [w for w in warnings if "off the plan" in w]
    assert len(off) == 1 and "standoff measured 2.5" in off[0] and "(plan 4.00)" in off[0]
    assert not any(w.startswith("DANGER") for w in warnings)
    assert "standoff measured 2.5" in culling_summary(chain.stats)
    report = json.loads(json.dumps(chain.stats.as_dict()))
    assert report["standoff"]["measured_median_m"] == summary["measured_median_m"]


def test_the_gate_predicts_the_wall_at_the_measured_standoff(scene, tmp_path):
    """At 2.5 m while the poses say 4.0, the wall moves 1.6x what the plan predicts: the gate found no wall where
    the prediction looked and took 7 of 8 keyframes' overlap from the telemetry at the wrong distance (9 keyframes
    for a pass that needs 16 at 80 %). Once measured, the prediction is made at the measured distance: the image
    decides every keyframe after the second, as on plan; on plan nothing changes. (The chain measures only the
    frames around a decision, so the first measurement comes from the pairs that decide the second keyframe.)"""
    near, _ = _fly(scene, tmp_path / "near", true_m=2.5, n=30)
    on_plan, _ = _fly(scene, tmp_path / "plan", true_m=PLAN, n=30)
    sources = [k["overlap_source"] for k in _sidecars(tmp_path / "near" / "spool")[2:]]
    assert len(sources) >= 8 and all(s == "image" for s in sources), sources
    assert near.crosscheck.standoff_m == pytest.approx(2.5, abs=0.1)
    assert near.gate.predictor is near.crosscheck.predictor
    assert on_plan.crosscheck.standoff_m == PLAN
    assert near.stats.keyframes >= 1.5 * on_plan.stats.keyframes  # the smaller footprint needs more keyframes


def test_much_closer_than_planned_is_a_louder_warning(scene, tmp_path):
    chain, warnings = _fly(scene, tmp_path, true_m=2.1, n=14)
    assert chain.stats.standoff["measured_median_m"] == pytest.approx(2.1, abs=0.05)
    danger = [w for w in warnings if w.startswith("DANGER")]
    assert len(danger) == 1 and "under 60 % of the planned standoff" in danger[0]


def test_on_plan_no_warning_and_a_hover_has_no_measurement(scene, tmp_path):
    chain, warnings = _fly(scene, tmp_path / "plan", true_m=PLAN, n=16, step_m=0.3)
    assert chain.stats.standoff["measured_median_m"] == pytest.approx(PLAN, abs=0.08)
    assert not any("standoff" in w for w in warnings)
    hover, warnings = _fly(scene, tmp_path / "hover", true_m=2.5, n=10, step_m=0.0)
    assert hover.stats.standoff["measurements"] == 0 and hover.stats.standoff["frames_without_share"] == 1.0
    assert hover.standoff is None and not any("standoff" in w for w in warnings)
    assert all(k["standoff_measured_m"] is None for k in _sidecars(tmp_path / "hover" / "spool"))
    assert "standoff not measured (plan 4.00)" in culling_summary(hover.stats)


def test_no_watch_no_figures():
    assert ChainStats().standoff is None
    assert "standoff measured" not in culling_summary(ChainStats())
    assert "standoff not measured" not in culling_summary(ChainStats())


def _bias_telemetry(src: Path, dst: Path, mission: Path, out_m: float) -> None:
    """The recording's telemetry log as a receiver off by ``out_m`` out of the wall would give it."""
    frame = scan_scope(load_mission(mission)).frame
    rows = [json.loads(x) for x in src.read_text().splitlines()]
    for r in rows:
        along, out, up = frame.geodetic_to_facade(r["lat"], r["lon"], r["alt_amsl_m"])
        lat, lon, alt = frame.facade_to_geodetic(along, out + out_m, up)
        r["lat"], r["lon"], r["alt_amsl_m"] = round(float(lat), 9), round(float(lon), 9), round(float(alt), 3)
    dst.write_text("".join(json.dumps(r) + "\n" for r in rows))


def test_companion_cull_on_a_biased_simulator_recording_spools_the_true_standoff(tmp_path):
    """The simulator flies the small wall at 2.5 m and renders from there; its telemetry log is shifted 1.5 m out
    (a GNSS bias: it says 4.0, the plan). ``companion cull`` with the 4.0 m mission, the tracker on, no mask:
    the keyframes carry the camera's 2.5 m (within 0.1 m of each one's true distance) and so does the report."""
    true_mission = tmp_path / "true.yaml"
    true_mission.write_text(SMALL_WALL.read_text().replace("standoff_m: 4.0", "standoff_m: 2.5"))
    rec, spool = tmp_path / "rec", tmp_path / "spool"
    assert main(["record", str(true_mission), "--out", str(rec), "--fast", "--width", "320", "--max-frames", "40",
                 "--stride", "8"]) == 0
    _bias_telemetry(rec / "telemetry.jsonl", tmp_path / "biased.jsonl", SMALL_WALL, 1.5)
    assert main(["cull", str(rec / "frames"), "--telemetry", str(tmp_path / "biased.jsonl"), "--out", str(spool),
                 "--mission", str(SMALL_WALL), "--no-mask"]) == 0
    frame = scan_scope(load_mission(SMALL_WALL)).frame
    truth = [json.loads(x) for x in (rec / "truth.jsonl").read_text().splitlines()]
    kfs = _sidecars(spool)
    measured = [k for k in kfs if k["standoff_measured_m"] is not None]
    assert len(measured) >= 5 and len(measured) >= len(kfs) - 3
    for k in measured:
        pose = truth[k["index"]]["pose"]
        true_out = float(frame.geodetic_to_facade(pose["lat"], pose["lon"], pose["alt_amsl_m"])[1])
        told_out = float(frame.geodetic_to_facade(k["pose"]["lat"], k["pose"]["lon"], k["pose"]["alt_amsl_m"])[1])
        assert abs(true_out - 2.5) < 0.1 and abs(told_out - 4.0) < 0.1  # the camera at 2.5, the log says 4.0
        assert k["standoff_measured_m"] == pytest.approx(true_out, abs=0.1) and k["standoff_source"] == "camera"
    report = json.loads((spool / CULL_REPORT).read_text())["standoff"]
    assert report["measured_median_m"] == pytest.approx(2.5, abs=0.05) and report["planned_m"] == 4.0
    assert report["measurements"] >= 10 and report["measured_spread_m"] < 0.1
