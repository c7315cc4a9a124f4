"""`companion stitch SPOOL [SPOOL...] --out DIR`: the facade map from a keyframe spool (or a simulator recording);
several spools of one wall (a main flight and its re-flies) make one map (``merge.py``)."""

from __future__ import annotations

import argparse
import json

from companion.errors import CompanionError
from companion.files import removed_on_failure
from companion.stitch import view_command
from companion.stitch.follow import follow
from companion.stitch.inputs import load_input
from companion.stitch.merge import merge_spools
from companion.stitch.unscaled import ScaleNote, area_text
from companion.stitch.worker import StitchConfig, StitchResult, stitch


def _cells(text: str) -> tuple[int, int]:
    try:
        cx, cy = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--cells {text!r}: write it as CXxCY, e.g. 16x9") from None
    if cx < 1 or cy < 1 or cx * cy > 4096:
        raise argparse.ArgumentTypeError(f"--cells {text!r}: need 1..4096 cells in all")
    return cx, cy


def register(sub) -> None:
    p = sub.add_parser(
        "stitch",
        help="stitch keyframes into the rectified facade map",
        description=__doc__,
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("spool", nargs="+",
                   help="keyframe spool directory (manifest.jsonl) or a simulator recording; several spools of one "
                        "wall (main flight first, then its re-flies) make one map")
    p.add_argument("--out", required=True, help="output directory (map, coverage, report; cache for resuming)")
    p.add_argument("--follow", action="store_true", help="keep updating the map while keyframes arrive")
    p.add_argument("--poll-s", type=float, default=2.0, help="follow mode: manifest polling period")
    p.add_argument("--idle-timeout-s", type=float, default=600.0, help="follow mode: stop after this long idle")
    add_map_arguments(p)
    p.add_argument("--stride", type=int, default=1, help="recording input: use every N-th frame")
    p.add_argument("--debug-dir", default=None, help="also dump what each stage decided here (docs/STITCH.md)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=run)
    view_command.register(sub)  # `companion view MAPDIR`: the map's viewer


def add_map_arguments(p: argparse.ArgumentParser) -> None:
    """The map's settings (scale, mesh, telemetry, tiles): shared with `companion site`, which makes the same maps."""
    defaults = StitchConfig()
    p.add_argument("--mm-per-px", type=float, default=None, help="map scale (default: keyframes' native)")
    p.add_argument("--cells", type=_cells, default=defaults.cells, help="APAP mesh Cx x Cy per keyframe")
    p.add_argument(
        "--rho-px", type=float, default=None, help="Eq. 4 scale rho in keyframe pixels (default 10%% of width)"
    )
    p.add_argument("--gamma", type=float, default=defaults.gamma,
                   help="APAP weight floor (far cells -> global homography)")
    p.add_argument("--global-only", action="store_true", help="no local mesh warps (one homography per keyframe)")
    p.add_argument("--no-poses", action="store_true", help="ignore telemetry (image-only alignment)")
    p.add_argument("--pose-gate-m", type=float, default=defaults.pose_gate_m,
                   help="reject matches this far from telemetry (default: 4 m, more for cameras far from the wall)")
    p.add_argument("--gnss-sigma-m", type=float, default=defaults.gnss_sigma_m,
                   help="how far GNSS absolute position may put the map off (1 sigma per axis; RTK: 0.03); the "
                        "wall's ends and roof line in view fix it better")
    p.add_argument("--no-measure-wall", action="store_true",
                   help="take the wall's distance (the map's scale) and the map's place from the telemetry alone, "
                        "as before the wall was measured (for comparison)")
    p.add_argument("--tile-px", type=int, default=defaults.tile_px, help="render tile size (bounds memory)")
    p.add_argument("--max-map-px", type=float, default=defaults.max_map_px,
                   help="refuse maps with more pixels than this (a guard against a wrong scale); raise it for a "
                        "gigapixel facade, e.g. 2e9: the map is rendered and written tile by tile")


def config_from_args(args) -> StitchConfig:
    """The :class:`StitchConfig` of :func:`add_map_arguments`' options, checked (errors say the fix)."""
    return _config(args)


def _config(args) -> StitchConfig:
    if args.mm_per_px is not None and args.mm_per_px <= 0:
        raise CompanionError(f"--mm-per-px {args.mm_per_px} must be positive", "e.g. --mm-per-px 5")
    if not args.gnss_sigma_m > 0:
        raise CompanionError(f"--gnss-sigma-m {args.gnss_sigma_m} must be positive",
                             "give the receiver's absolute accuracy in metres (e.g. 1.5, or 0.03 for RTK)")
    if args.tile_px < 64:
        raise CompanionError(f"--tile-px {args.tile_px} is too small",
                             f"use at least 64 (default {StitchConfig().tile_px})")
    if not args.max_map_px >= 1:
        raise CompanionError(f"--max-map-px {args.max_map_px:g} must be at least 1 pixel",
                             f"give the largest map to allow in pixels (default {StitchConfig().max_map_px:g})")
    return StitchConfig(
        mm_per_px=args.mm_per_px,
        cells=args.cells,
        rho_px=args.rho_px,
        gamma=args.gamma,
        local=not args.global_only,
        use_poses=not args.no_poses,
        pose_gate_m=args.pose_gate_m,
        gnss_sigma_m=args.gnss_sigma_m,
        measure_wall=not args.no_measure_wall,
        tile_px=args.tile_px,
        max_map_px=args.max_map_px,
    )


def _m(value: float) -> str:
    """Metres to the cm, never "-0.00" (a cell edge a hair below the wall base)."""
    return f"{round(value, 2) + 0.0:.2f}"


def _print(res: StitchResult) -> None:
    r = res.report
    for w in r.get("warnings", []):
        print(f"warning: {w}")
    print(f"map: {res.files.get('map') or res.files.get('tiles')}")
    print(f"preview (scale bar, re-fly areas in red): {res.files['preview']}")
    if res.mm_per_px:
        print(f"scale: {res.mm_per_px:.2f} mm/px, {res.grid.width}x{res.grid.height} px")
    print(
        f"keyframes used: {len(r['keyframes_used'])}/{r['keyframes_in']}, pairs {r['pairs_accepted']}/"
        f"{r['pairs_tried']} accepted ({r['pairs_affine_fallback']} affine)"
    )
    print(f"coverage: {100 * res.coverage_fraction:.1f} %, {len(res.uncovered)} uncovered area(s)")
    if r.get("scale_unknown"):
        for a in r["uncovered_areas_px"][:10]:
            print(f"  {area_text(a)}")
        print(f"warning: {ScaleNote(**r['scale_unknown']).text()}")
    else:
        for a in res.uncovered[:10]:
            print(f"  along {_m(a.along_min_m)}..{_m(a.along_max_m)} m, up {_m(a.up_min_m)}..{_m(a.up_max_m)} m")
    print(f"report: {res.files['report']}")
    print(f"viewer (open in a browser, or `companion view {res.out_dir}`): {res.files['viewer']}")


def _input(args):
    if len(args.spool) > 1:
        return merge_spools(args.spool)[0]
    return load_input(args.spool[0], **({"stride": args.stride} if args.stride != 1 else {}))


def run(args) -> int:
    cfg = _config(args)
    if args.follow and len(args.spool) > 1:
        raise CompanionError("--follow takes one spool",
                             "follow the flight in progress; stitch the finished spools together afterwards")
    if args.follow:
        res = follow(
            args.spool[0],
            args.out,
            cfg,
            poll_s=args.poll_s,
            idle_timeout_s=args.idle_timeout_s,
            progress=not args.quiet,
            debug_dir=args.debug_dir,
        )
        if res is None:
            raise CompanionError("no map was made: fewer than 2 keyframes arrived", "check that the gate is running")
    else:
        inp = _input(args)
        with removed_on_failure(args.out):  # a failed stitch leaves no empty or half-made map folder
            res = stitch(inp, args.out, cfg, progress=not args.quiet, debug_dir=args.debug_dir)
    _print(res)
    if args.quiet:
        print(json.dumps({"coverage": res.coverage_fraction, "mm_per_px": res.mm_per_px}))
    return 0
