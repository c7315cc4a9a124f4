"""The site's index: site.json (for programs) and index.html (the start page linking every face's viewer).

Why one page: an inspector opening a site of forty faces needs to see at once which faces are mapped, how much of
each the map covers and where each still needs a re-fly, and to open a face's viewer from there. Links are
relative, so the whole ``--out`` folder can be copied or served as it is.
"""

from __future__ import annotations

import html
import json
from pathlib import Path

from companion.files import write_atomic
from companion.site.facade import FacadeOutcome
from companion.site.spools import BadSpool

SITE_JSON = "site.json"
INDEX_HTML = "index.html"


def site_record(outcomes: list[FacadeOutcome], bad: tuple[BadSpool, ...], out: Path, engine: str) -> dict:
    """site.json's content: every face (folder relative to ``out``), the spools left out, and how it ran."""
    faces = []
    for o in outcomes:
        d = o.as_dict()
        d["folder"] = _relative(o.out_dir, out)
        faces.append(d)
    return {
        "facades": faces,
        "bad_spools": [b.as_dict() for b in bad],
        "engine": engine,
        "counts": {s: sum(o.status == s for o in outcomes) for s in ("done", "skipped", "failed")},
    }


def _relative(path: Path, out: Path) -> str:
    try:
        return str(Path(path).resolve().relative_to(out.resolve()))
    except ValueError:
        return str(path)


def _refly_cell(areas: tuple[dict, ...]) -> str:
    if not areas:
        return "none"
    total = sum(float(a.get("area_m2", 0.0)) for a in areas)
    rows = "".join(
        f"<li>along {a['along_min_m']:.2f}..{a['along_max_m']:.2f} m, up {a['up_min_m']:.2f}..{a['up_max_m']:.2f} m"
        "</li>" for a in areas[:8]
    )
    more = f"<li>... {len(areas) - 8} more</li>" if len(areas) > 8 else ""
    return f"{len(areas)} area(s), {total:.2f} m&sup2;<ul>{rows}{more}</ul>"


def _face_row(face: dict) -> str:
    name, folder = html.escape(face["name"]), html.escape(face["folder"])
    spools = "<br>".join(html.escape(s) for s in face["spools"])
    if face["status"] == "failed":
        why = html.escape(f"{face['problem']} (fix: {face['fix']})")
        return f'<tr class="failed"><td>{name}</td><td colspan="4">failed: {why}</td><td>{spools}</td></tr>'
    files = face.get("files", {})
    viewer, preview = (html.escape(f"{folder}/{files[k]}") if k in files else "" for k in ("viewer", "preview"))
    thumb = f'<a href="{viewer}"><img src="{preview}" alt="{name}" height="90"></a>' if preview else ""
    scale = f"{face['mm_per_px']:.2f} mm/px" if face.get("mm_per_px") else "scale unknown"
    size = "x".join(str(v) for v in face["size_px"]) + " px" if face.get("size_px") else ""
    if "cog" in files:
        size += f'<br><a href="{html.escape(folder + "/" + files["cog"])}">GeoTIFF (COG)</a>'

    return (f'<tr><td><a href="{viewer}">{name}</a></td><td>{thumb}</td>'
            f"<td>{100 * face['coverage_fraction']:.1f} %</td><td>{scale}<br>{size}</td>"
            f"<td>{_refly_cell(tuple(face['uncovered_areas_m']))}</td><td>{spools}</td></tr>")


def index_page(record: dict) -> str:
    """index.html: a table of the faces (coverage, scale, re-fly areas, spools), links to each face's viewer."""
    rows = "\n".join(_face_row(f) for f in record["facades"])
    bad = "".join(
        f"<li>{html.escape(b['spool'])}: {html.escape(b['problem'])} (fix: {html.escape(b['fix'])})</li>"
        for b in record["bad_spools"]
    )
    bad_block = f"<h2>Spools left out</h2><ul>{bad}</ul>" if bad else ""
    return f"""<!doctype html>
<html><head><meta charset="utf-8"><title>Site: {len(record['facades'])} facades</title>
<style>body{{font-family:sans-serif;margin:1.5em}}table{{border-collapse:collapse}}
td,th{{border:1px solid #bbb;padding:.4em;vertical-align:top}}tr.failed{{background:#fdd}}ul{{margin:0}}</style>
</head><body>
<h1>Site: {len(record['facades'])} facades</h1>
<p>Engine: {html.escape(record['engine'])}. Re-fly areas: wall no keyframe showed (plan them with
<code>companion plan MISSION --refly FACE_FOLDER</code>).</p>
<table><tr><th>Facade</th><th>Map</th><th>Coverage</th><th>Scale</th><th>Re-fly areas</th><th>Spools</th></tr>
{rows}
</table>
{bad_block}
</body></html>
"""


def write_index(out: Path, record: dict) -> dict[str, str]:
    """site.json and index.html in ``out``, each written atomically (index.html first: site.json last says the
    site's job ended)."""
    page = write_atomic(out / INDEX_HTML, index_page(record))
    data = write_atomic(out / SITE_JSON, json.dumps(record, indent=1), durable=True)
    return {"index": str(page), "site": str(data)}
