"""Stitching speed at full camera resolution: N keyframes at 3840x2160 (the paper stitched 35 such images in
about 38 min on a Xeon E5-2630 v4), per stage in wall and CPU seconds, side by side with another checkout of the
code (``--compare-with``, e.g. main).

Every frame of the recording is a keyframe; the true overlap of consecutive frames is printed so the input can
be compared with the paper's (Rth = 80 %). Each run is its own process (its own peak memory and CPU count; the
stitcher's stages are timed from outside, by wrapping ``Stitcher``'s stage methods, so any checkout with the
staged stitcher can be timed). ``--compare-with DIR`` runs the stitcher of DIR (a checkout, e.g. ``git archive
main``) and this one alternately, each from a fresh cache, ``--rounds`` times: on a shared machine compare the
CPU seconds (user + sys, all threads) of the two, and the wall seconds only within one round. The pairs each
accepted, the local residuals and the coverage are printed with the largest and mean map difference where both
``--cache-from DIR`` starts every run from a copy of DIR's feature and pair cache (a finished run's ``--out``),
so two checkouts are compared on their render and report stages alone, from the same alignment.
``--peers scans`` first runs cv2.Stitcher SCANS on the same keyframes and ROI masks, in its own process.

    python -c "from sim.camera.recording import generate_recording; generate_recording(
        'missions/demo-facade.yaml', '/tmp/rec4k', stride=20, width_px=3840, max_frames=35)"
    python bench/stitch_speed.py --recording /tmp/rec4k --out /tmp/stitch_speed
    mkdir /tmp/main && git archive main | tar -x -C /tmp/main
    python bench/stitch_speed.py --recording /tmp/rec4k --compare-with /tmp/main --rounds 2
    python bench/stitch_speed.py --recording /tmp/rec4k --compare-with /tmp/main --peers scans
    python bench/stitch_speed.py --recording /tmp/rec4k --compare-with /tmp/main --cache-from /tmp/stitch_speed/run
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np

STAGES = ("features", "priors", "pairs", "alignment", "wall_check", "mesh", "render", "report")  # timed where present


def _cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def run_one(args) -> dict:
    """One stitch in this process, with the stitcher found on sys.path (this checkout or ``--compare-with``)."""
    from companion.stitch import StitchConfig
    from companion.stitch.inputs import load_recording_input
    from companion.stitch.worker import Stitcher
    from sim.camera.recording import load_recording

    rec = load_recording(args.recording)
    frames = list(range(len(rec)))
    ov = [rec.true_overlap(i, i + 1) for i in range(len(rec) - 1)]
    inp = load_recording_input(
        Path(args.recording), frames=frames, pose_noise_m=args.pose_noise_m, attitude_noise_deg=args.attitude_noise_deg
    )
    stitcher = Stitcher(StitchConfig(mm_per_px=args.mm_per_px), progress=False)
    wall_s: dict[str, float] = {}
    cpu_s: dict[str, float] = {}
    for name in STAGES:
        if not hasattr(stitcher, name):  # an older checkout without this stage (e.g. before the wall check)
            continue
        stage = getattr(stitcher, name)

        def timed(*a, _stage=stage, _name=name, **k):
            w, c = time.perf_counter(), _cpu_s()
            try:
                return _stage(*a, **k)
            finally:
                wall_s[_name] = round(wall_s.get(_name, 0.0) + time.perf_counter() - w, 2)
                cpu_s[_name] = round(cpu_s.get(_name, 0.0) + _cpu_s() - c, 2)

        setattr(stitcher, name, timed)
    cpu0, t0 = _cpu_s(), time.perf_counter()
    res = stitcher.stitch(inp, args.out)
    dt, cpu = time.perf_counter() - t0, _cpu_s() - cpu0
    report = res.report
    return {
        "code": str(Path(sys.modules["companion"].__file__).resolve().parents[1]),
        "machine": f"{platform.machine()} {platform.system()}, {os.cpu_count()} CPUs, python "
        f"{sys.version.split()[0]}, cv2 {cv2.__version__} ({cv2.getNumThreads()} threads)",
        "load_average_start": round(args.load0, 1),
        "load_average_end": round(os.getloadavg()[0], 1),
        "keyframes": len(frames),
        "image_size": [rec.width, rec.height],
        "true_overlap_consecutive": {"median": float(np.median(ov)), "min": float(np.min(ov))},
        "total_wall_s": round(dt, 1),
        "total_cpu_s": round(cpu, 1),
        "wall_s": wall_s,
        "cpu_s": cpu_s,
        "render": report["render"],
        "map_px": [res.grid.width, res.grid.height],
        "mm_per_px": res.mm_per_px,
        "pairs": f"{report['pairs_accepted']}/{report['pairs_tried']}",
        "accepted_pairs": sorted([p["a"], p["b"]] for p in report["pairs"]),
        "local_residual_px": report["alignment"]["local_residual_px"],
        "coverage_fraction": res.coverage_fraction,
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024),
    }


def run_scans(args) -> dict:
    """cv2.Stitcher SCANS (OpenCV's affine scan stitcher, default settings: features and seams at reduced
    resolution, the panorama composited at full resolution) on the same keyframes and ROI masks, in this process."""
    from sim.camera.recording import load_recording

    rec = load_recording(args.recording)
    frames = range(len(rec))
    cpu0, t0 = _cpu_s(), time.perf_counter()
    images = [rec.image(i) for i in frames]
    masks = [rec.roi_mask(i) for i in frames]
    stitcher = cv2.Stitcher_create(cv2.Stitcher_SCANS)
    status, pano = stitcher.stitch(images, masks)
    return {
        "method": "cv2.Stitcher SCANS",
        "machine": f"{platform.machine()}, {os.cpu_count()} CPUs, cv2 {cv2.__version__}",
        "load_average_start": round(args.load0, 1),
        "load_average_end": round(os.getloadavg()[0], 1),
        "keyframes": len(images),
        "status": int(status),
        "ok": status == cv2.Stitcher_OK,
        "pano_px": None if pano is None or status != cv2.Stitcher_OK else [pano.shape[1], pano.shape[0]],
        "total_wall_s": round(time.perf_counter() - t0, 1),
        "total_cpu_s": round(_cpu_s() - cpu0, 1),
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024),
    }


def _map_tiles(out: Path) -> dict[str, np.ndarray]:
    if (out / "map.png").exists():
        img = cv2.imread(str(out / "map.png"))
        cov = cv2.imread(str(out / "coverage.png"), cv2.IMREAD_GRAYSCALE)
        return {"map": np.dstack((img, cov))}
    return {p.name: cv2.imread(str(p), cv2.IMREAD_UNCHANGED) for p in sorted((out / "tiles").glob("*.png"))}


def _grey_and_alpha(out: Path) -> tuple[np.ndarray, np.ndarray, list[float]]:
    """A stitch output's whole map as grey and alpha (from map.png or its tiles) and its geotransform."""
    geo = json.loads((out / "map_georef.json").read_text())
    w, h = geo["size_px"]
    grey, alpha = np.zeros((h, w), np.uint8), np.zeros((h, w), np.uint8)
    for name, t in _map_tiles(out).items():
        y0, x0 = (0, 0) if name == "map" else (int(name[6:13]), int(name[15:22]))  # tile_y0000000_x0000000.png
        grey[y0 : y0 + t.shape[0], x0 : x0 + t.shape[1]] = cv2.cvtColor(t[..., :3], cv2.COLOR_BGR2GRAY)
        alpha[y0 : y0 + t.shape[0], x0 : x0 + t.shape[1]] = t[..., 3]
    return grey, alpha, geo["geotransform"]


def compare_on_the_wall(a: Path, b: Path, strip: int = 1024) -> dict:
    """Two maps of different grids compared on the wall: b resampled (bilinear) onto a's grid through both
    geotransforms, then grey SSIM (Gaussian 11 px, sigma 1.5) and grey differences where both drew (b's coverage
    eroded by a pixel: resampling mixes its edge with the uncovered black), and pixels covered by only one."""
    ga, aa, ta = _grey_and_alpha(a)
    gb, ab, tb = _grey_and_alpha(b)
    to_b = np.array([[ta[1] / tb[1], 0.0, (ta[0] - tb[0]) / tb[1]], [0.0, ta[5] / tb[5], (ta[3] - tb[3]) / tb[5]]])
    h, w = ga.shape
    c1, c2 = (0.01 * 255) ** 2, (0.03 * 255) ** 2
    ssim_sum, ssim_n, only = 0.0, 0, 0
    hist = np.zeros(256, np.int64)
    for r0 in range(0, h, strip):
        r1, q0, q1 = min(h, r0 + strip), max(0, r0 - 8), min(h, r0 + strip + 8)  # 8 rows of margin for the blur
        m = to_b.copy()
        m[1, 2] += m[1, 1] * q0
        yb = cv2.warpAffine(gb, m, (w, q1 - q0), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP).astype(np.float32)
        cb = cv2.warpAffine(ab, m, (w, q1 - q0), flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP) > 0
        xa, ca = ga[q0:q1].astype(np.float32), aa[q0:q1] > 0
        both = ca & (cv2.erode(cb.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0)
        rows = slice(r0 - q0, r1 - q0)
        only += int(np.count_nonzero((ca != cb)[rows]))
        hist += np.bincount(np.abs(xa - yb)[rows][both[rows]].astype(np.int64), minlength=256)[:256]

        def blur(z):
            return cv2.GaussianBlur(z, (11, 11), 1.5)

        mx, my = blur(xa), blur(yb)
        sxx, syy, sxy = blur(xa * xa) - mx * mx, blur(yb * yb) - my * my, blur(xa * yb) - mx * my
        ssim = ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2))
        inner = (cv2.erode(both.astype(np.uint8), np.ones((11, 11), np.uint8)) > 0)[rows]
        ssim_sum, ssim_n = ssim_sum + float(ssim[rows][inner].sum()), ssim_n + int(inner.sum())
    n = int(hist.sum())
    return {
        "on_the_wall": True,
        "ssim": round(ssim_sum / max(ssim_n, 1), 5),
        "mean_diff": round(float(np.dot(np.arange(256), hist)) / max(n, 1), 3),
        "p99_diff": int(np.searchsorted(np.cumsum(hist) / max(n, 1), 0.99)),
        "max_diff": int(np.nonzero(hist)[0].max()) if n else 0,
        "compared_mp": round(n / 1e6, 1),
        "coverage_px_differing": only,
    }


def compare_maps(a: Path, b: Path) -> dict:
    """Largest and mean grey-level difference where both maps drew, and pixels covered by only one; maps of
    different grids are compared on the wall (``compare_on_the_wall``)."""
    ta, tb = _map_tiles(a), _map_tiles(b)
    if set(ta) != set(tb) or any(ta[k].shape != tb[k].shape for k in ta):
        del ta, tb
        return compare_on_the_wall(a, b)
    worst, total, n, cov_diff = 0, 0.0, 0, 0
    for name, x in ta.items():
        y = tb[name]
        both = (x[..., 3] > 0) & (y[..., 3] > 0)
        cov_diff += int(np.count_nonzero((x[..., 3] > 0) != (y[..., 3] > 0)))
        d = np.abs(x[..., :3].astype(np.int16) - y[..., :3].astype(np.int16)).max(axis=2)[both]
        if d.size:
            worst, total, n = max(worst, int(d.max())), total + float(d.sum()), n + d.size
    return {"max_diff": worst, "mean_diff": round(total / max(n, 1), 5), "coverage_px_differing": cov_diff}


def _pair_difference(a: dict, b: dict) -> dict:
    pa, pb = {tuple(p) for p in a["accepted_pairs"]}, {tuple(p) for p in b["accepted_pairs"]}
    return {"pairs_accepted_by_both": len(pa & pb), "only_other": sorted(pa - pb), "only_this": sorted(pb - pa)}


def _launch(args, run_out: Path, code: Path | None) -> dict:
    if args.cache_from and not (run_out / "cache").exists():
        shutil.copytree(args.cache_from / "cache", run_out / "cache")
    cmd = [sys.executable, __file__, "--recording", args.recording, "--out", str(run_out), "--one-run"]
    cmd += ["--pose-noise-m", str(args.pose_noise_m), "--attitude-noise-deg", str(args.attitude_noise_deg)]
    if args.mm_per_px:
        cmd += ["--mm-per-px", str(args.mm_per_px)]
    env = dict(os.environ)
    root = code or Path(__file__).resolve().parents[1]
    env["PYTHONPATH"] = os.pathsep.join([str(root), env.get("PYTHONPATH", "")])
    cmd += ["--load0", str(os.getloadavg()[0])]
    done = subprocess.run(cmd, check=True, capture_output=True, text=True, env=env, cwd=root)
    return json.loads(done.stdout.strip().splitlines()[-1])


def _summary(label: str, r: dict) -> str:
    stages = ", ".join(f"{k} {r['wall_s'][k]:.1f}/{r['cpu_s'][k]:.1f}" for k in r["wall_s"] if r["wall_s"][k] >= 0.5)
    res = r["local_residual_px"]
    res_txt = f"{res.get('median')} (p95 {res.get('p95')})" if isinstance(res, dict) else str(res)
    return (
        f"{label}: wall {r['total_wall_s']:.1f} s, CPU {r['total_cpu_s']:.1f} s (load {r['load_average_start']}-"
        f"{r['load_average_end']}); wall/CPU per stage: {stages}; pairs {r['pairs']}, residual median {res_txt} px, "
        f"coverage {r['coverage_fraction']:.4f}, decodes {r['render'].get('keyframe_decodes')}, "
        f"peak RSS {r['peak_rss_mb']} MB"
    )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--recording", required=True)
    ap.add_argument("--out", default="/tmp/stitch_speed")
    ap.add_argument("--mm-per-px", type=float, default=None, help="map scale (default native)")
    ap.add_argument("--pose-noise-m", type=float, default=0.3)
    ap.add_argument("--attitude-noise-deg", type=float, default=0.5)
    ap.add_argument("--no-run", action="store_true", help="with --peers: the peers alone")
    ap.add_argument("--compare-with", type=Path, default=None, help="another checkout, run alternately with this")
    ap.add_argument("--rounds", type=int, default=1, help="with --compare-with: how many alternations")
    ap.add_argument("--cache-from", type=Path, default=None, help="start every run from this run folder's cache")
    ap.add_argument("--one-run", action="store_true", help=argparse.SUPPRESS)  # one run in this process
    ap.add_argument("--peers", default="", help="also run these on the same keyframes, each in its own process: scans")
    ap.add_argument("--peer-run", default=None, help=argparse.SUPPRESS)  # one peer in this process
    ap.add_argument("--load0", type=float, default=0.0, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.cache_from and not (args.cache_from / "cache").is_dir():
        ap.error(f"--cache-from {args.cache_from}: it holds no cache/ folder; give the --out folder of a finished run")
    if args.one_run:
        print(json.dumps(run_one(args), default=float))
        return 0
    if args.peer_run:
        print(json.dumps(run_scans(args), default=float))
        return 0
    out = Path(args.out)
    shutil.rmtree(out, ignore_errors=True)
    for peer in filter(None, args.peers.split(",")):
        if peer != "scans":
            ap.error(f"--peers {peer}: the only peer is scans (cv2.Stitcher SCANS)")
        cmd = [sys.executable, __file__, "--recording", args.recording, "--peer-run", peer]
        cmd += ["--load0", str(os.getloadavg()[0])]
        done = subprocess.run(cmd, capture_output=True, text=True)
        if done.returncode != 0:  # a peer that fails (memory, an OpenCV error) is a result too: say how
            print(f"{peer}: failed (exit {done.returncode}): {done.stderr.strip()[-2000:]}", flush=True)
            continue
        peer_run = json.loads(done.stdout.strip().splitlines()[-1])
        print(json.dumps(peer_run, indent=1, default=float), flush=True)
        print(f"{peer_run['method']}: wall {peer_run['total_wall_s']:.1f} s, CPU {peer_run['total_cpu_s']:.1f} s (load "
              f"{peer_run['load_average_start']}-{peer_run['load_average_end']}), status {peer_run['status']}, "
              f"panorama {peer_run['pano_px']} px, peak RSS {peer_run['peak_rss_mb']} MB", flush=True)
    if args.compare_with:
        for k in range(args.rounds):
            runs = {}
            for label, code in (("other", args.compare_with.resolve()), ("this", None)):
                runs[label] = _launch(args, out / f"round{k}" / label, code)
                print(json.dumps(runs[label], indent=1, default=float), flush=True)
            diff = compare_maps(out / f"round{k}" / "other", out / f"round{k}" / "this")
            diff |= _pair_difference(runs["other"], runs["this"])
            print(f"round {k}: " + _summary(f"other ({args.compare_with})", runs["other"]))
            print(f"round {k}: " + _summary("this", runs["this"]))
            print(f"round {k}: maps {diff}", flush=True)
        return 0
    if not args.no_run:
        run = _launch(args, out / "run", None)
        print(json.dumps(run, indent=1, default=float), flush=True)
        print(_summary("this", run), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
