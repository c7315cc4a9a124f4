"""`companion site SPOOL... --out DIR`: every face's map of a site (spools grouped by wall, re-flies merged), on
an embedded Dask cluster by default, an existing one with --scheduler, or in this process with --single-process."""

from __future__ import annotations

import argparse

from companion.errors import CompanionError
from companion.site.engine import EngineSpec
from companion.site.run import SiteResult, build_site
from companion.stitch.commands import add_map_arguments, config_from_args


def register(sub) -> None:
    p = sub.add_parser("site", help="stitch a site's spools: one map per facade, re-flies merged, and an index",
                       description=__doc__, formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("spools", nargs="+", help="keyframe spool directories, any walls (a face's main flight before "
                                             "its re-flies); on a cluster, on a path every worker reads")
    p.add_argument("--out", required=True, help="site folder: one folder per facade, site.json, index.html; "
                                                "rerun with the same --out to finish what is not done")
    p.add_argument("--scheduler", default=None,
                   help="an existing Dask cluster: tcp://HOST:8786 or a scheduler file (default: an embedded one)")
    p.add_argument("--workers", type=int, default=None,
                   help="embedded cluster's worker processes (default: one per core); 0: this process only")
    p.add_argument("--single-process", action="store_true", help="no cluster: every face in this process")
    add_map_arguments(p)
    p.add_argument("--no-cog", action="store_true",
                   help="no map_cog.tif (the map as a Cloud Optimized GeoTIFF in wall metres, with overviews)")
    p.add_argument("--quiet", action="store_true", help="no progress bar (the log lines stay)")
    p.set_defaults(func=run)


def engine_spec(args) -> EngineSpec:
    if args.workers is not None and args.workers < 0:
        raise CompanionError(f"--workers {args.workers} is negative", "give 0 (this process) or more workers")
    if args.scheduler and (args.single_process or args.workers is not None):
        raise CompanionError("--scheduler runs on an existing cluster: --workers/--single-process do not apply",
                             "give either --scheduler or --workers/--single-process")
    return EngineSpec(workers=0 if args.single_process else args.workers, scheduler=args.scheduler)


def _print(res: SiteResult) -> None:
    if res.dashboard:
        print(f"dask dashboard: {res.dashboard}")
    for o in res.facades:
        if o.status == "failed":
            print(f"facade {o.name}: FAILED: {o.problem}\n  fix: {o.fix}")
            continue
        holes = len(o.uncovered_areas_m)
        print(f"facade {o.name} ({o.status}): coverage {100 * (o.coverage_fraction or 0):.1f} %, {holes} re-fly "
              f"area(s), {len(o.spools)} spool(s) -> {o.out_dir}")
    print(f"site index (open in a browser): {res.files['index']}")


def run(args) -> int:
    res = build_site(args.spools, args.out, config_from_args(args), engine_spec(args), progress=not args.quiet,
                     cog=not args.no_cog)
    _print(res)
    problems = [f"spool {b.path}: {b.problem} (fix: {b.fix})" for b in res.bad_spools]
    problems += [f"facade {o.name} ({', '.join(o.spools)}): {o.problem} (fix: {o.fix})" for o in res.failed]
    if problems:
        raise CompanionError(
            f"{len(problems)} problem(s), the other facades are done: " + "; ".join(problems),
            f"fix what is named and rerun with the same --out {args.out} (facades done are skipped)",
        )
    return 0
