"""COLMAP (pycolmap) on a keyframe spool, COLMAP's default focal refinement against the EXIF camera held, side by side.

    python bench/colmap_spool.py out/demo/spool [--masks] [--work /tmp/colmap_bench]

Both runs are ``companion export colmap`` (EXIF camera, exhaustive matching, incremental mapping); they differ only
in ``ba_refine_focal_length`` / ``ba_refine_extra_params``. Prints, per run: keyframes registered, models, the
focal against the spool's, camera centres against the telemetry, CPU seconds. Figures: docs/BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from companion.errors import CompanionError
from companion.export.colmap import MISPLACED_M, export_colmap


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("spool", type=Path)
    p.add_argument("--masks", action="store_true", help="give COLMAP the ROI masks too")
    p.add_argument("--max-minutes", type=float, default=10.0,
                   help="bound each mapping (COLMAP's default can loop through initial pairs for long)")
    p.add_argument("--work", type=Path, default=Path("/tmp/colmap_bench"), help="workspaces go here")
    a = p.parse_args()
    rows = []
    for label, hold in (("EXIF camera held", True), ("COLMAP default (focal refined)", False)):
        cpu = time.process_time()
        try:
            _, r = export_colmap(a.spool, a.work / ("held" if hold else "refined"), masks=a.masks,
                                 hold_intrinsics=hold, max_runtime_s=60 * a.max_minutes)
        except CompanionError as exc:  # COLMAP built no model at all
            rows.append((label, f"none: {exc.problem}", "0", "-", "-", f"{time.process_time() - cpu:.0f} s", "-", "-"))
            continue
        cpu = time.process_time() - cpu
        focal = f"{r.focal_px:.1f} px" + ("" if r.focal_error is None else f" ({100 * r.focal_error:+.1f} %)")
        centres = "-" if r.centre_median_m is None else (
            f"median {100 * r.centre_median_m:.1f} cm, {r.centres_within_m}/{r.registered} within "
            f"{100 * MISPLACED_M:.0f} cm")
        rows.append((label, f"{r.registered}/{r.keyframes}", str(r.models), focal, centres, f"{cpu:.0f} s",
                     ", ".join(r.unregistered) or "-", ", ".join(r.misplaced) or "-"))
    print(f"spool {a.spool} (masks: {'yes' if a.masks else 'no'})")
    heads = ("run", "registered", "models", "focal", "centres vs telemetry", "CPU", "unregistered", "misplaced")
    for row in rows:
        print("\n".join(f"  {h:>22}: {v}" for h, v in zip(heads, row, strict=True)))
        print()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
