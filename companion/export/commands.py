"""``companion export colmap SPOOL --out DIR``: a keyframe spool as a COLMAP workspace, reconstructed with pycolmap."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from companion.export.colmap import MISPLACED_M, REPORT, export_colmap


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("export", help="keyframes in another tool's own form (COLMAP workspace)")
    what = p.add_subparsers(dest="format", required=True)
    c = what.add_parser("colmap", help="a spool as a COLMAP workspace (images, masks, database, sparse model) and "
                                       "COLMAP's incremental mapping run on it with the EXIF camera held")
    c.add_argument("spool", type=Path, help="keyframe spool folder (e.g. out/demo/spool)")
    c.add_argument("--out", type=Path, required=True, help="workspace folder (images/, database.db, sparse/)")
    c.add_argument("--masks", action="store_true",
                   help="also give COLMAP the ROI masks (masks/<image>.png): keyframes whose ROI is a sliver "
                        "(roof edge, far wall) may then fail to register")
    c.add_argument("--no-run", action="store_true", help="only write images/ (and masks/): run COLMAP yourself")
    c.add_argument("--refine-intrinsics", action="store_true",
                   help="let bundle adjustment refine the focal (COLMAP's default; on a flat wall it drifts and "
                        "images fail to register: docs/OUTPUTS.md)")
    c.set_defaults(func=run_export_colmap)


def run_export_colmap(args: argparse.Namespace) -> int:
    workspace, result = export_colmap(args.spool, args.out, masks=args.masks, run=not args.no_run,
                                      hold_intrinsics=not args.refine_intrinsics)
    print(f"COLMAP workspace: {workspace.root} ({len(workspace.names)} keyframes in images/"
          f"{', masks in masks/' if workspace.masks else ''})")
    if workspace.left_out:
        print(f"warning: {len(workspace.left_out)} keyframe(s) left out, their image missing or damaged: "
              f"{'; '.join(workspace.left_out)}", file=sys.stderr)
    if result is None:
        return 0
    focal = f"focal {result.focal_px:.1f} px"
    if result.focal_error is not None:
        focal += f" ({100 * result.focal_error:+.2f} % of the spool's {result.true_focal_px:.1f} px)"
    print(f"registered {result.registered}/{result.keyframes} keyframes in model {result.model_dir}; {focal}; "
          f"{result.cameras} camera(s), EXIF focal prior: {'yes' if result.exif_prior_focal else 'no'}")
    if result.centre_median_m is not None:
        print(f"camera centres vs telemetry (after a similarity transform): median {100 * result.centre_median_m:.1f}"
              f" cm; {result.centres_within_m}/{result.registered} within {100 * MISPLACED_M:.0f} cm")
    if result.misplaced:
        print(f"registered but over {100 * MISPLACED_M:.0f} cm from the telemetry: {', '.join(result.misplaced)}")
    if result.unregistered:
        print(f"not registered: {', '.join(result.unregistered)}")
    print(f"report: {workspace.root / REPORT}")
    if not result.unregistered:
        return 0
    # a result, not a user's mistake (exit 1, the workspace kept), but said the way every failure is
    print(f"error: {len(result.unregistered)} of {result.keyframes} keyframes did not register in COLMAP's model: "
          f"{', '.join(result.unregistered)}\n  fix: check that they overlap their neighbours (the spool's "
          "cull_report.json names gaps); without --masks if it was given, without --refine-intrinsics if it was",
          file=sys.stderr)
    return 1
