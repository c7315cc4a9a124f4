"""The onboard chain (every frame tracked, frames around each decision measured) on a camera that really delivers 30 fps
at 1280x720: a scan leg along a synthetic wall (``evaluation.keyframes.synthetic.WallScene``: textured wall, far
background, exact poses and true overlap), rendered ahead of time, JPEG-encoded, and replayed in real time through the
live runner.

    python bench/chain_tracker_synthetic.py [--fps 30] [--width 1280] [--speed 1.0] [--length 24] [--speedup 1]
                                            [--busy-core] [--working 0 640]

Why beside bench/chain_tracker.py: the SITL camera renders 1280 px frames at a few per second on a loaded 2-core
machine (docs/BENCHMARKS.md, camera simulator), so in SITL the chain never sees 30 fps; here the frames arrive at
the camera's rate whatever the renderer costs, with the real depth mask and gate. Prints per chain: frames
considered per second, frames measured, CPU share of one core (chain thread), keyframes against the minimum from
truth (the paper's rule on every frame's true overlap), the lowest true overlap of a keyframe pair, warnings, gaps.
``--working``: the chain's working copy (long side px; 0 = decide on the camera's frames), one run per size, side
by side. The chain that masked and measured every frame (the "measure-all" column of the first runs) is gone from
the product: run this script at revision 2510c03 (``--chains measure-all``) to set it beside these figures.
"""

from __future__ import annotations

import argparse
import cProfile
import io
import json
import pstats
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from busy_core import busy_core  # noqa: E402

from companion.capture.sources import FrameSource  # noqa: E402
from companion.capture.tagging import FrameTagger  # noqa: E402
from companion.capture.telemetry import ClockMap, TelemetryBuffer  # noqa: E402
from companion.depth.masker import Masker  # noqa: E402
from companion.depth.parallax import SequenceParallax  # noqa: E402
from companion.keyframes.gate import GateConfig, KeyframeGate  # noqa: E402
from companion.keyframes.motion import WallMotionPredictor  # noqa: E402
from companion.onboard.chain import CullChain  # noqa: E402
from companion.onboard.runner import TRACKED_BACKLOG, LiveRunner  # noqa: E402
from companion.onboard.tracked import MeasureSchedule  # noqa: E402
from companion.onboard.working import WorkingCopy  # noqa: E402
from companion.records import EncodedFrame, Frame  # noqa: E402
from companion.spool import KeyframeSpool  # noqa: E402
from evaluation.keyframes.synthetic import WallCamera, WallScene, textured_wall  # noqa: E402

STANDOFF_M, UP_M = 4.0, 5.0


def camera_frame(i: int, data: bytes, fps: float, width: int, decode: str) -> Frame | EncodedFrame:
    """``decode`` "chain": still encoded, as the simulator camera's stream now delivers it (the chain decodes it at
    its working size); "capture": decoded in full on arrival, as before."""
    if decode == "chain":
        return EncodedFrame(i, i / fps, data, width, round(width * 9 / 16))
    return Frame(i, i / fps, cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR))


class PacedJpegSource(FrameSource):
    """Frames released at their capture times on the wall clock (a real camera), JPEG as the simulator camera's
    stream delivers them."""

    def __init__(self, jpegs: list[bytes], fps: float, speedup: float, width: int, decode: str):
        super().__init__()
        self.jpegs, self.fps, self.speedup, self.width, self.decode = jpegs, fps, speedup, width, decode

    def __iter__(self):
        t0 = time.monotonic()
        for i, data in enumerate(self.jpegs):
            delay = t0 + i / (self.fps * self.speedup) - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            self.stats.delivered += 1
            yield camera_frame(i, data, self.fps, self.width, self.decode)


def scene_and_path(args) -> tuple[WallScene, list[WallCamera]]:
    height = round(args.width * 9 / 16)
    scene = WallScene(textured_wall(6000, 2000, seed=5), textured_wall(1600, 600, seed=9), args.length + 6.0, 10.0,
                      width_px=args.width, height_px=height)  # fmt: skip
    n = int(args.length / args.speed * args.fps)
    cams = [WallCamera(3.0 + i * args.speed / args.fps, STANDOFF_M, UP_M) for i in range(n)]
    return scene, cams


def run_chain(name: str, scene: WallScene, cams, jpegs, args, out: Path, working: int, decode: str) -> dict:
    buffer = TelemetryBuffer()
    for i, cam in enumerate(cams):
        buffer.add(scene.pose(cam, i / args.fps))
    predictor = WallMotionPredictor(scene.frame, scene.hfov_deg, standoff_m=STANDOFF_M)
    gate = KeyframeGate(GateConfig(), predictor)
    spool = out / f"{name}-{working}-{decode}"
    parallax = SequenceParallax(scene.hfov_deg, standoff_m=STANDOFF_M) if args.parallax else None
    chain = CullChain(FrameTagger(buffer, ClockMap(fixed_offset_s=0.0)), Masker(parallax=parallax), gate,
                      KeyframeSpool(spool), track=MeasureSchedule(),
                      working=WorkingCopy(working))  # fmt: skip
    source = PacedJpegSource(jpegs, args.fps, args.speedup or 1.0, args.width, decode)
    capture_cpu_s = 0.0  # unpaced only: the decode on arrival, outside the chain (0 when the chain decodes)
    wall0 = time.monotonic()
    if args.speedup > 0:
        runner = LiveRunner(source, chain, TRACKED_BACKLOG)
        runner.run_until_done(poll_s=0.05)
    else:  # unpaced: every frame through the chain, none dropped (the chain's CPU per frame, whatever the load)
        profile = cProfile.Profile(time.thread_time) if args.profile else None
        for i, data in enumerate(jpegs):
            cpu0 = time.thread_time()
            frame = camera_frame(i, data, args.fps, args.width, decode)
            capture_cpu_s += time.thread_time() - cpu0
            if profile is not None:
                profile.enable()
            chain.process(frame)
            if profile is not None:
                profile.disable()
        chain.finish()
        if profile is not None:
            print_profile(profile, f"{name}, working copy {working or 'none'}, decoded by the {decode}")
    wall = time.monotonic() - wall0
    st = chain.stats
    kept = [json.loads(x)["index"] for x in (spool / "manifest.jsonl").read_text().splitlines()]
    pairs = [100.0 * scene.true_overlap(cams[a], cams[b]) for a, b in zip(kept, kept[1:], strict=False)]
    span = len(cams) / args.fps
    return {
        "chain": name,
        "working_copy_px": working or "camera's frames",
        "decoded_by": decode,
        "speedup": args.speedup,
        "frames_offered": len(cams),
        "frames_considered_per_s": round((st.frames_in - st.skipped_backlog) / span, 2),
        "frames_skipped_for_cpu": st.skipped_backlog,
        "frames_measured": st.frames_measured,
        "frames_skipped_far_from_decision": getattr(st, "skipped_far", 0),  # not decoded (issue 17, tracked.py)
        "chain_thread_cpu_share_of_one_core": round(st.cpu_s / wall, 3),
        "chain_cpu_s_per_simulated_s": round(st.cpu_s / span, 3),
        "decode_on_arrival_plus_chain_cpu_s_per_simulated_s": (round((capture_cpu_s + st.cpu_s) / span, 3)
                                                                if args.speedup == 0 else None),
        "keyframes": st.keyframes,
        "minimum_from_truth": minimum_keyframes(scene, cams, 100.0 * chain.gate.config.rth),
        "lowest_true_overlap_of_a_pair_percent": round(min(pairs), 1) if pairs else None,
        "pairs_true_below_rth": sum(p < 100.0 * chain.gate.config.rth for p in pairs),
        "overlap_warnings": st.overlap_warnings,
        "low_overlap_keyframes": st.low_overlap_keyframes,
        "gaps": st.gaps,
        "wall_s": round(wall, 1),
    }


def print_profile(profile: cProfile.Profile, label: str) -> None:
    """Where the chain thread's CPU went (``CullChain.process`` only; cProfile's own overhead inflates the
    Python-heavy rows): the calls that cost most, by own time."""
    text = io.StringIO()
    pstats.Stats(profile, stream=text).sort_stats("tottime").print_stats(14)
    print(f"-- CPU profile of the chain thread: {label}\n{text.getvalue()}", flush=True)


def minimum_keyframes(scene: WallScene, cams, rth: float) -> int:
    """The paper's rule on every frame's true overlap: the next keyframe is the last frame still >= Rth."""
    count, key = 1, 0
    for i in range(1, len(cams)):
        if 100.0 * scene.true_overlap(cams[key], cams[i]) < rth:
            key, count = i - 1, count + 1
    return count + (key != len(cams) - 1)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--fps", type=float, default=30.0)
    p.add_argument("--width", type=int, default=1280)
    p.add_argument("--speed", type=float, default=1.0, help="scan speed along the wall, m/s")
    p.add_argument("--length", type=float, default=24.0, help="length of the scan leg, m")
    p.add_argument("--speedup", type=float, default=1.0,
                   help="replay rate (simulated s per wall s); below 1 gives a starved chain more CPU per frame; "
                        "0: unpaced, every frame processed in turn (CPU per frame, no drops)")
    p.add_argument("--profile", action="store_true", help="with --speedup 0: print the chain thread's CPU profile")
    p.add_argument("--parallax", action="store_true", help="the depth mask with motion parallax (the demo's chain)")
    p.add_argument("--busy-core", action="store_true", help="keep one core busy with another process")
    p.add_argument("--working", type=int, nargs="+", default=[640],
                   help="working copy long side(s), px (0: the camera's frames, as before the working copy)")
    p.add_argument("--decode", nargs="+", default=["chain"], choices=["capture", "chain"],
                   help="where frames are decoded: on arrival in full (capture, as before) or by the chain at its "
                        "working size (chain, the simulator camera's stream today)")
    p.add_argument("--out", type=Path)
    args = p.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="chain-tracker-syn-"))
    scene, cams = scene_and_path(args)
    jpegs = [cv2.imencode(".jpg", scene.render(c)[0], [cv2.IMWRITE_JPEG_QUALITY, 90])[1].tobytes() for c in cams]
    print(f"{len(cams)} frames {args.width} px rendered; leg {args.length:g} m at {args.speed:g} m/s, "
          f"{args.fps:g} fps", flush=True)
    with busy_core(args.busy_core):
        for working in args.working:
            for decode in args.decode:
                result = run_chain("tracker", scene, cams, jpegs, args, out, working, decode)
                print(json.dumps(result, indent=1), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
