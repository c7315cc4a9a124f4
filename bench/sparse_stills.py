"""Sparse stills 10-30 m from the wall through ``companion cull`` and ``companion stitch``, as a user runs them
(issue 27 item 4): how much of the wall the map covers.

A real-texture pass (``sim/camera/photo_passes.py``, held out; or a validation pass of training-split photos,
``bench/depth_error_regions.py``) is scaled to the standoff (the wall grows by standoff / 4 m, so the photos look
as at 4 m) and rendered as stills ``--spacing`` metres apart (``bench/mask_sequence.py``'s ``pass_spec``). They are
written as a user's flight would be: an image folder with ``times.csv`` (a still every 2 s), a telemetry log in
``companion fly``'s format sampled at 10 Hz between the stills' true poses with a GNSS error (a constant bias along
and across the wall plus small noise on every still), and a mission file whose wall and standoff are the pass's.
Then the product's own commands run on them (``companion cull`` with the default model, ``companion stitch``), and:

* **masks**: the union of the spool's keyframe masks laid on the wall with the true geometry, against the wall the
  stills saw (the labels' facade inside their footprints): what the map could cover at most;
* **map**: the stitched map registered onto the wall photo (``stitch_photo_passes.score_map``): the share of the seen
  wall it covers, and the background photo's matches in it.

    python bench/sparse_stills.py --passes val-b0309-120,val-b0169-40 --standoffs 13,20,30 --spacings 2,5
    python bench/sparse_stills.py --passes ornate-entry --standoffs 13 --spacings 3 --rules yes,window,fixed

``--rules``: ParallaxParams sets of ``SPARSE_RULES`` the cull runs with, side by side on the same stills.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))

from companion.depth.parallax import ParallaxParams  # noqa: E402
from companion.records import GimbalSource, pose_json  # noqa: E402

STILL_INTERVAL_S = 2.0
FIRST_STILL_S = 10.0
TELEMETRY_HZ = 10.0
# ParallaxParams the cull's chain runs with, by name
SPARSE_RULES: dict[str, ParallaxParams] = {
    "yes": ParallaxParams(),
    "near-1.5": ParallaxParams(max_near_standoffs=1.5),
    "near-15m": ParallaxParams(max_near_standoffs=None),  # near never beyond 15 m (the 4 m standoff's limit)
    "wall-from-flow": ParallaxParams(plane_wall_from_flow_px=1.0),  # the plane check at the flow's wall motion
    "one-side": ParallaxParams(telemetry_both_sides=False),  # keyframes judged against an earlier frame only
    "fill-all": ParallaxParams(telemetry_both_sides_strip_only=False),  # the second look feeds the whole frame
    "window": ParallaxParams(telemetry_max_share=None),  # the window scaled by the standoff alone
    "fixed": ParallaxParams(baseline_standoff_m=None, telemetry_max_share=None),  # 8-60 cm: before issue 27
    "no-bound": ParallaxParams(),  # the shipped rules without the mission's wall bound (companion/depth/pose_bound.py)
}
WITHOUT_WALL_BOUND = {"no-bound"}


def write_flight(spec, renderer, folder: Path, *, bias_m: tuple[float, float, float], noise_m: float,
                 seed: int = 0) -> tuple[Path, Path, Path, list[np.ndarray]]:
    """(frames folder, telemetry log, mission file, truth masks) of the pass's stills."""
    from evaluation.stitch.synthetic import SyntheticWall, spool_meta, wall_frame

    cam = spec.camera
    wall = SyntheticWall(length_m=spec.wall.width_m, height_m=spec.wall.height_m)
    frame = wall_frame(wall)
    frames = folder / "frames"
    frames.mkdir(parents=True)
    truths, times = [], []
    rng = np.random.default_rng(seed)
    reported = []
    for i in range(len(renderer)):
        f = renderer.render(i)
        name = f"IMG_{i:04d}.jpg"
        cv2.imwrite(str(frames / name), f.image, [cv2.IMWRITE_JPEG_QUALITY, 95])
        truths.append(f)
        t = FIRST_STILL_S + STILL_INTERVAL_S * i
        times.append(f"{name},{t:.3f}")
        na, no, nu = rng.normal(0.0, noise_m, 3) if noise_m else (0.0, 0.0, 0.0)
        reported.append((t, f.along_m + bias_m[0] + na, spec.standoff_m + bias_m[1] + no, f.up_m + bias_m[2] + nu))
    (frames / "times.csv").write_text("name,capture_time_s\n" + "\n".join(times) + "\n")
    rows = []
    ts = np.array([r[0] for r in reported])
    yaw = frame.yaw_facing_wall_deg % 360.0
    for t in np.arange(ts[0] - 1.0, ts[-1] + 1.0 + 1e-9, 1.0 / TELEMETRY_HZ):
        along, out, up = (float(np.interp(t, ts, [r[k] for r in reported])) for k in (1, 2, 3))
        lat, lon, alt = (float(v) for v in frame.facade_to_geodetic(along, out, up))
        row = pose_json(time_s=round(float(t), 3), lat=lat, lon=lon, alt_amsl_m=alt,
                        relative_alt_m=alt - frame.origin.alt_amsl_m, roll_deg=0.0, pitch_deg=0.0, yaw_deg=yaw,
                        velocity_ned_m_s=(0.0, 0.0, 0.0), gimbal_pitch_deg=0.0, gimbal_yaw_deg=0.0,
                        gimbal_source=GimbalSource.TELEMETRY)
        rows.append({"t_wall": round(1_780_000_000.0 + float(t), 4), **row, "mission_total": 0,
                     "flight_mode": "MISSION", "armed": True, "in_air": True})
    telemetry = folder / "telemetry.jsonl"
    telemetry.write_text("".join(json.dumps(r) + "\n" for r in rows))
    meta = spool_meta(frame, wall, cam.width, cam.height, cam.hfov_deg, spec.standoff_m)
    demo = yaml.safe_load((Path(__file__).resolve().parents[1] / "missions" / "demo-facade.yaml").read_text())
    facade = meta["facade"]
    top = spec.wall.height_m
    mission = {**demo, "name": f"{spec.name}-{spec.standoff_m:g}m", "facade": facade,
               "standoff_m": float(spec.standoff_m),
               "camera": {**demo["camera"], "width_px": cam.width, "height_px": cam.height, "hfov_deg": cam.hfov_deg},
               "transit_alt_m": float(top + 6.0),
               "geofence": {"max_alt_m": float(top + 60.0), "max_distance_m": float(spec.wall.width_m + 200.0)}}
    takeoff = frame.facade_to_geodetic(spec.wall.width_m / 2, spec.standoff_m + 5.0, 0.0)
    mission["takeoff"] = {"lat": float(takeoff[0]), "lon": float(takeoff[1])}
    mission_path = folder / "mission.yaml"
    mission_path.write_text(yaml.safe_dump(mission, sort_keys=False))
    return frames, telemetry, mission_path, truths


def mask_coverage(spool: Path, truths, wall_seen: np.ndarray, grid) -> tuple[float, int, float]:
    """Share of the seen wall (``wall_seen`` on ``grid``) the spool's keyframe masks cover, laid on the wall by the
    stills' true geometry (a keyframe's still from its capture time); the number of keyframes; and the share of the
    keyframes' background pixels (their stills' truth) their own masks keep, pixel-weighted."""
    entries = [json.loads(line) for line in (spool / "manifest.jsonl").read_text().splitlines() if line.strip()]
    union = np.zeros_like(wall_seen)
    background = background_kept = 0
    for entry in entries:
        f = truths[round((entry["capture_time_s"] - FIRST_STILL_S) / STILL_INTERVAL_S)]
        h, w = f.roi_mask.shape
        mask = np.full((h, w), 255, np.uint8) if not entry.get("mask") else \
            cv2.imread(str(spool / entry["mask"]), cv2.IMREAD_GRAYSCALE)
        grid_from_image = np.array([[1 / grid.m_per_px, 0, -grid.along0_m / grid.m_per_px],
                                    [0, -1 / grid.m_per_px, grid.up_top_m / grid.m_per_px],
                                    [0, 0, 1]]) @ f.wall_from_image
        warped = cv2.warpPerspective(mask, grid_from_image, (grid.width, grid.height), flags=cv2.INTER_NEAREST)
        union |= (warped > 127).astype(np.uint8) * 255
        not_wall = f.roi_mask == 0
        background += int(not_wall.sum())
        background_kept += int(np.count_nonzero(mask[not_wall] > 127))
    seen = wall_seen > 0
    return (float(np.count_nonzero(union[seen])) / max(1, int(seen.sum())), len(entries),
            background_kept / max(1, background))


def run_one(name: str, standoff: float, spacing: float, args, rule: str, work: Path) -> dict:
    from mask_sequence import pass_spec
    from stitch_photo_passes import RenderedPass, grid_of_report, score_map, truth_grid_for, wall_truth

    from companion.cli import main as cli
    from sim.camera.photo_scene import PhotoPassRenderer

    spec = pass_spec(name, 80, args.background_frames, args.width, standoff, spacing)
    renderer = PhotoPassRenderer(spec)
    folder = work / f"{name}-{standoff:g}-{spacing:g}-{rule}"
    frames, telemetry, mission, truths = write_flight(spec, renderer, folder, bias_m=tuple(args.bias),
                                                      noise_m=args.noise, seed=args.seed)
    spool, out = folder / "spool", folder / "map"
    ups = [p[1] for p in renderer.positions]
    strips = sorted(set(ups))
    rp = RenderedPass(name, spec, renderer, [], [], [], [strips.index(u) for u in ups])
    row = {"pass": name, "standoff_m": standoff, "spacing_m": spacing, "rules": rule, "stills": len(renderer)}
    t0 = time.perf_counter()
    import companion.depth.parallax as parallax_module

    shipped = parallax_module.SequenceParallax
    params = SPARSE_RULES[rule]

    class WithRules(shipped):  # the cull's chain builds its SequenceParallax from this module (onboard/setup.py)
        def __init__(self, hfov_deg, p=None, keep=12, standoff_m=None):
            super().__init__(hfov_deg, p or params, keep, standoff_m)

    parallax_module.SequenceParallax = WithRules
    import companion.depth.pose_bound as pose_bound

    shipped_bound = pose_bound.TelemetryWallBound.for_mission
    if rule in WITHOUT_WALL_BOUND:
        pose_bound.TelemetryWallBound.for_mission = classmethod(lambda cls, mission, beyond_standoff_m=4.0: None)
    try:
        with contextlib.redirect_stdout(io.StringIO()) as log:
            rc = cli(["cull", str(frames), "--telemetry", str(telemetry), "--out", str(spool),
                      "--mission", str(mission), *(["--model", args.model] if args.model else [])])
    finally:
        parallax_module.SequenceParallax = shipped
        pose_bound.TelemetryWallBound.for_mission = shipped_bound
    row["cull_s"] = round(time.perf_counter() - t0, 1)
    if rc != 0:
        row["error"] = f"cull exit {rc}: {log.getvalue()[-300:]}"
        return row
    cull = json.loads((spool / "cull_report.json").read_text()) if (spool / "cull_report.json").exists() else {}
    row["parallax_frames"] = cull.get("parallax_frames")
    row["bound_cut"] = cull.get("bound_cut")
    seen_grid = truth_grid_for(rp, args.mm_per_px / 1000.0)
    seen = wall_truth(rp, list(range(len(renderer))), seen_grid)
    row["mask_cover"], row["keyframes"], row["background_kept"] = mask_coverage(spool, truths, seen.seen, seen_grid)
    t1 = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()) as log:
        rc = cli(["stitch", str(spool), "--out", str(out), "--quiet"])
    row["stitch_s"] = round(time.perf_counter() - t1, 1)
    if rc != 0 or not (out / "report.json").exists():
        row["error"] = f"stitch exit {rc}: {log.getvalue()[-300:]}"
        return row
    report = json.loads((out / "report.json").read_text())
    image = cv2.imread(str(out / "map.png"))
    cov = cv2.imread(str(out / "coverage.png"), cv2.IMREAD_GRAYSCALE)
    score = score_map(image, cov, wall_truth(rp, list(range(len(renderer))), grid_of_report(report)), rectified=True)
    row.update(map_cover=score.get("coverage"), background_inliers=score.get("background_inliers"),
               used=len(report.get("keyframes_used", [])), ssim=score.get("ssim"))
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--passes", default="val-b0309-120,val-b0169-40")
    ap.add_argument("--standoffs", default="13,20,30")
    ap.add_argument("--spacings", default="2,5")
    ap.add_argument("--background-frames", type=int, default=4)
    ap.add_argument("--width", type=int, default=960, help="still width in px (16:9, 69 deg hfov)")
    ap.add_argument("--bias", type=float, nargs=3, default=(1.0, 1.0, 0.3),
                    help="GNSS bias along, out from, up the wall (m); positive out: reported farther from the wall")
    ap.add_argument("--noise", type=float, default=0.1, help="GNSS noise on every still (m, 1 sigma)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--model", default=None, help="depth model; default: the shipped default")
    ap.add_argument("--mm-per-px", type=float, default=40.0, help="grid of the masks' wall coverage")
    ap.add_argument("--rules", default="yes", help=f"comma list of {', '.join(SPARSE_RULES)}")
    ap.add_argument("--keep", default=None, help="keep the flights, spools and maps under this folder")
    args = ap.parse_args()
    print(f"machine: {platform.platform()}, {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}; "
          f"bias {tuple(args.bias)} m, noise {args.noise} m, {args.width} px")
    print("\n| pass | standoff | spacing | rules | stills | keyframes | parallax frames | bound cut | masks cover | "
          "keyframes keep background | map covers | used | background inliers | cull s | stitch s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(args.keep) if args.keep else Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        for name in [p for p in args.passes.split(",") if p]:
            for standoff in [float(s) for s in args.standoffs.split(",")]:
                for spacing in [float(s) for s in args.spacings.split(",")]:
                    for rule in [r for r in args.rules.split(",") if r]:
                        row = run_one(name, standoff, spacing, args, rule, work)
                        rows.append(row)

                        def pct(v):
                            return "-" if v is None else f"{100 * v:.1f} %"
                        print(f"| {name} | {standoff:g} m | {spacing:g} m | {rule} | {row['stills']} | "
                              f"{row.get('keyframes', '-')} | {row.get('parallax_frames', '-')} | "
                              f"{row.get('bound_cut', '-')} | {pct(row.get('mask_cover'))} | "
                              f"{pct(row.get('background_kept'))} | {pct(row.get('map_cover'))} | "
                              f"{row.get('used', '-')} | "
                              f"{row.get('background_inliers', '-')} | {row.get('cull_s', '-')} | "
                              f"{row.get('stitch_s', '-')} |" + (f" {row['error']}" if "error" in row else ""),
                              flush=True)


if __name__ == "__main__":
    main()
