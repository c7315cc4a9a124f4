"""`companion view MAPDIR`: opens the inspector's viewer of a stitched map (writing it first if it is missing).

Registered with `companion stitch` (stitch/commands.py): it reads the map's spool through the stitcher's inputs, and
the stitcher writes the viewer, so the command sits above both (no stitch <-> viewer import cycle)."""

from __future__ import annotations

import argparse
import json
import webbrowser
from pathlib import Path

from companion.errors import CompanionError
from companion.stitch.inputs import load_input
from companion.viewer.page import ASSETS, PAGE, write_viewer
from companion.viewer.serve import make_server


def register(sub) -> None:
    p = sub.add_parser(
        "view",
        help="open the inspector's viewer of a stitched map (tiles, coverage, re-fly areas, photos, mm)",
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("mapdir", help="the --out folder of `companion stitch`")
    p.add_argument("--spool", default=None, help="spool (or recording) of the map: links its keyframe photos")
    p.add_argument("--rebuild", action="store_true", help="write the viewer again even if it exists")
    p.add_argument("--no-serve", action="store_true", help="only write the viewer and print the page to open")
    p.add_argument("--no-browser", action="store_true", help="serve without opening a browser")
    p.add_argument("--host", default="127.0.0.1", help="address to serve on (0.0.0.0: other computers too)")
    p.add_argument("--port", type=int, default=8000, help="port to serve on (0: any free port)")
    p.set_defaults(func=run)


def _keyframe_images(spool: str | None) -> dict[int, Path] | None:
    if spool is None:
        return None
    return {kf.index: kf.image_path for kf in load_input(spool).keyframes}


def run(args) -> int:
    mapdir = Path(args.mapdir)
    if not mapdir.is_dir():
        raise CompanionError(f"{mapdir} is not a folder", "give the --out folder of `companion stitch`")
    page = mapdir / PAGE
    if args.rebuild or args.spool or not page.exists():
        write_viewer(mapdir, _keyframe_images(args.spool))
        footprints = json.loads((mapdir / "map_georef.json").read_text()).get("keyframes", [])
        if footprints and not any((mapdir / ASSETS / "keyframes").glob("*")):
            print("note: the keyframe photos are not in the viewer: pass --spool SPOOL (the map's spool) to add them")
    if args.no_serve:
        print(f"viewer: {page.resolve().as_uri()}")
        return 0
    server = make_server(mapdir, args.host, args.port)
    host, port = server.server_address[:2]
    url = f"http://{'127.0.0.1' if host in ('0.0.0.0', '') else host}:{port}/{PAGE}"
    print(f"viewer: {url}  (also opens without a server: {page.resolve().as_uri()}); Ctrl-C stops")
    if not args.no_browser:
        webbrowser.open(url)
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        print("stopped")
    finally:
        server.server_close()
    return 0
