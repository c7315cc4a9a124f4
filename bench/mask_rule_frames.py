"""Frame by frame, which frames of a real-texture pass two parallax rule sets mask differently, and how.

    python bench/mask_rule_frames.py --passes cmp-balconies cmp-roofline-40m --rules before-speck default

Each pass (100 frames at the pass's camera, 12 past the wall's end, as bench/depth_real_passes.py) is masked in
capture order by the onboard ``Masker`` (shipped ``sim`` model + parallax) once per rule set, with exact telemetry.
Prints every frame where the two differ: the frame's true wall share, its trusted far share, and the background
kept and wall lost (shares of the frame) under each rule set. docs/DEPTH.md "A far speck" names it.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from checkout import use_checkout_shared_data

import companion.depth.parallax as parallax_module  # noqa: E402
from companion.depth.masker import Masker  # noqa: E402
from companion.depth.parallax import SequenceParallax  # noqa: E402
from companion.records import Frame, TaggedFrame  # noqa: E402
from evaluation.depth.parallax_rules import PARALLAX_RULES  # noqa: E402
from sim.camera.photo_passes import RECIPES, build_pass  # noqa: E402
from sim.camera.photo_scene import PhotoPassRenderer  # noqa: E402
from tests.test_mask_wall import _pose  # noqa: E402


def _far_share_spy() -> dict:
    """The last wall-plane-checked frame's trusted far share, read off the continuity rule as it runs."""
    seen: dict = {}
    rule = parallax_module.plain_by_continuity

    def spy(net, parallax):
        if parallax.plane_checked:
            seen["far"] = float(parallax.far.mean())
        return rule(net, parallax)

    parallax_module.plain_by_continuity = spy
    return seen


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--passes", nargs="+", default=["cmp-balconies", "cmp-roofline-40m"], choices=sorted(RECIPES))
    ap.add_argument("--rules", nargs=2, default=["before-speck", "default"], choices=sorted(PARALLAX_RULES))
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--background-frames", type=int, default=12)
    args = ap.parse_args()
    seen = _far_share_spy()
    for name in args.passes:
        spec = build_pass(RECIPES[name], root=use_checkout_shared_data(),
                          frames=args.frames, background_frames=args.background_frames)
        renderer = PhotoPassRenderer(spec)
        maskers = [Masker("sim", parallax=SequenceParallax(spec.camera.hfov_deg, PARALLAX_RULES[rule]))
                   for rule in args.rules]
        print(f"{name}: frame | true wall | trusted far | background kept {' -> '.join(args.rules)} | wall lost")
        for i in range(len(renderer)):
            f = renderer.render(i)
            truth = f.roi_mask > 0
            errors = []
            seen.clear()
            for masker in maskers:
                masked, roi = masker.mask(TaggedFrame(Frame(i, i / 10.0, f.image), _pose(f, spec.standoff_m)))
                mask = roi.mask > 0 if masked is not None and roi is not None else np.zeros_like(truth)
                errors.append(((mask & ~truth).mean(), (~mask & truth).mean()))
            (kept_a, lost_a), (kept_b, lost_b) = errors
            if abs(kept_a - kept_b) > 1e-4 or abs(lost_a - lost_b) > 1e-4:
                print(f"  {i} | {truth.mean():.3f} | {seen.get('far', float('nan')):.4f} | "
                      f"{100 * kept_a:.2f} -> {100 * kept_b:.2f} % | {100 * lost_a:.2f} -> {100 * lost_b:.2f} %")


if __name__ == "__main__":
    main()
