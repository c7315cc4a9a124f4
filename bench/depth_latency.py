"""Latency of depth + ROI mask per frame (model input 192x640) with onnxruntime on this machine.

Usage: python bench/depth_latency.py [--model M.onnx ...] [--threads 1 2] [--frames 40] [--image-size 640x360]
       [--int8-calib RECORDING]
Prints one line per (model, threads): median and p90 of depth (preprocess + inference) and of the mask
(ROI extraction + resize to the frame), and their sum. Frames are the real photos if present (resized to
--image-size, the pipeline's working width), otherwise random images: latency does not depend on content much.
"""

from __future__ import annotations

import argparse
import platform
import time
from pathlib import Path

import cv2
import numpy as np

from companion.depth.masker import Masker
from companion.depth.session import DEFAULT_MODEL, DepthSession
from companion.records import Frame, TaggedFrame

REAL = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real-uav-facade"


def frames(size: tuple[int, int], n: int) -> list[np.ndarray]:
    w, h = size
    imgs = [cv2.imread(str(p)) for p in sorted(REAL.glob("*.JPG"))] if REAL.is_dir() else []
    imgs = [cv2.resize(i, (w, h), interpolation=cv2.INTER_AREA) for i in imgs if i is not None]
    rng = np.random.default_rng(0)
    while len(imgs) < 2:
        imgs.append(rng.integers(0, 255, (h, w, 3), dtype=np.uint8))
    return [imgs[i % len(imgs)] for i in range(n)]


def bench(model: Path, threads: int, images: list[np.ndarray]) -> dict:
    masker = Masker(session=DepthSession(model, threads=threads))
    for img in images[:3]:  # warm-up
        masker.mask(TaggedFrame(Frame(0, 0.0, img), None))
    masker.stats.depth_ms.clear()
    masker.stats.mask_ms.clear()
    t0 = time.perf_counter()
    for i, img in enumerate(images):
        masker.mask(TaggedFrame(Frame(i, 0.0, img), None))
    wall = (time.perf_counter() - t0) / len(images) * 1e3
    d, m = np.array(masker.stats.depth_ms), np.array(masker.stats.mask_ms)
    return {
        "depth_med": np.median(d), "depth_p90": np.percentile(d, 90), "mask_med": np.median(m),
        "mask_p90": np.percentile(m, 90), "total_med": np.median(d + m), "total_p90": np.percentile(d + m, 90),
        "wall_per_frame": wall, "input": f"{masker.session.info.height}x{masker.session.info.width}",
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", nargs="+", default=[str(DEFAULT_MODEL)])
    ap.add_argument("--threads", nargs="+", type=int, default=[1, 2])
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--image-size", default="640x360", help="frame WIDTHxHEIGHT fed to the masker")
    ap.add_argument("--int8-calib", default=None, help="recording: also quantise the first model to int8 (QDQ), "
                    "calibrated on 24 of its frames, written to --int8-out, and time it (needs the onnx package)")
    ap.add_argument("--int8-out", default="/tmp/companion-depth-int8.onnx")
    args = ap.parse_args()
    if args.int8_calib:
        from companion.depth.training.quantise import quantise_int8
        from sim.camera.recording import load_recording

        rec = load_recording(args.int8_calib)
        calib = [rec.image(i) for i in np.linspace(0, len(rec) - 1, 24).astype(int)]
        quantise_int8(args.model[0], args.int8_out, calib)
        args.model.append(args.int8_out)
    size = tuple(int(v) for v in args.image_size.split("x"))
    images = frames(size, args.frames)
    print(f"machine: {platform.machine()} {platform.processor() or ''} cores={__import__('os').cpu_count()}; "
          f"frames {args.frames} at {size[0]}x{size[1]}")
    for model in args.model:
        for t in args.threads:
            r = bench(Path(model), t, images)
            print(f"{Path(model).name:40s} in {r['input']} threads {t}: depth {r['depth_med']:.1f} ms "
                  f"(p90 {r['depth_p90']:.1f}) + mask {r['mask_med']:.1f} ms (p90 {r['mask_p90']:.1f}) = "
                  f"{r['total_med']:.1f} ms median, p90 {r['total_p90']:.1f} ms")


if __name__ == "__main__":
    main()
