"""`companion site`: a site's spools grouped by wall into one map per face (re-flies merged), the same maps in this
process, on the embedded Dask cluster and on a `dask scheduler` + two `dask worker` processes (one killed mid-job);
a bad spool named and skipped; a rerun skips the faces done.

Two faces of one building, 12 small keyframes each (8 in the main flight, which misses the upper right; 4 in the
re-fly, which flies only that): tests/site_spools.py.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from companion.cli import main
from companion.errors import CompanionError
from companion.site.engine import EngineSpec
from companion.site.facade import MARKER
from companion.site.run import build_site
from companion.stitch.config import StitchConfig
from companion.stitch.merge import INDEX_STRIDE, merge_spools
from tests.site_spools import SiteShape, make_site

ROOT = Path(__file__).resolve().parents[1]
FACES = ("face0", "face1")


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    root = tmp_path_factory.mktemp("site")
    spools = make_site(root / "spools", faces=2)
    bad = root / "spools" / "broken"
    bad.mkdir()
    (bad / "manifest.jsonl").write_text("")
    (bad / "spool.json").write_text("{not json")  # a spool.json cut short: the spool cannot be placed on a wall
    return root, spools, bad


@pytest.fixture(scope="module")
def single(site):
    """The site made in this process (--single-process): the reference the other engines must match."""
    root, spools, bad = site
    out = root / "single"
    code = main(["site", *map(str, spools), str(bad), "--out", str(out), "--single-process", "--quiet"])
    return out, code


def _map(folder: Path) -> np.ndarray:
    img = cv2.imread(str(folder / "map.png"), cv2.IMREAD_UNCHANGED)
    assert img is not None, folder
    return img.astype(int)


def _same_maps(a: Path, b: Path) -> None:
    for face in FACES:
        ma, mb = _map(a / face), _map(b / face)
        assert ma.shape == mb.shape, face
        assert np.abs(ma - mb).max() <= 1, face
        ra, rb = (json.loads((d / face / "report.json").read_text()) for d in (a, b))
        assert ra["pairs"] == rb["pairs"] and ra["pairs_rejected"] == rb["pairs_rejected"], face  # the same pairs


def test_one_map_per_face_with_its_refly_merged_and_an_index(site, single):
    root, spools, _ = site
    out, _ = single
    record = json.loads((out / "site.json").read_text())
    assert [f["name"] for f in record["facades"]] == list(FACES)
    hole = SiteShape().hole_m
    for face, k in zip(record["facades"], range(2), strict=True):
        assert face["status"] == "done" and face["spools"] == [str(spools[k]), str(spools[2 + k])]
        report = json.loads((out / face["folder"] / "report.json").read_text())
        used = report["keyframes_used"]
        assert sum(i >= INDEX_STRIDE for i in used) == 4 and len(used) == 12  # the re-fly's keyframes are in it
        assert face["coverage_fraction"] > 0.95
        for a in face["uncovered_areas_m"]:  # nothing left uncovered where the main flight missed
            assert a["along_max_m"] < hole[0] or a["along_min_m"] > hole[1] or a["up_max_m"] < hole[2]
        assert (out / face["folder"] / face["files"]["viewer"]).is_file()
    page = (out / "index.html").read_text()
    assert all(f'href="{f}/viewer.html"' in page for f in FACES) and "Re-fly areas" in page


def test_a_bad_spool_is_named_and_skipped_the_other_faces_complete(site, single):
    _, _, bad = site
    out, code = single
    assert code == 2
    record = json.loads((out / "site.json").read_text())
    assert [b["spool"] for b in record["bad_spools"]] == [str(bad)]
    assert "not valid JSON" in record["bad_spools"][0]["problem"] and record["bad_spools"][0]["fix"]
    assert all((out / f / MARKER).is_file() for f in FACES)


def test_a_face_is_the_map_companion_stitch_makes_of_its_spools(site, single, tmp_path):
    _, spools, _ = site
    out, _ = single
    assert main(["stitch", str(spools[0]), str(spools[2]), "--out", str(tmp_path / "alone"), "--quiet"]) == 0
    assert np.abs(_map(tmp_path / "alone") - _map(out / "face0")).max() <= 1


def test_a_rerun_skips_the_faces_done_and_redoes_a_face_whose_spool_changed(site, single, caplog):
    root, spools, _ = site
    out, _ = single
    before = {f: (out / f / "map.png").stat().st_mtime_ns for f in FACES}
    with caplog.at_level(logging.INFO, logger="companion.site"):
        res = build_site(spools, out, engine=EngineSpec(workers=0), progress=False)
    assert [o.status for o in res.facades] == ["skipped", "skipped"]
    assert "facade face1 already done (skipped); 2/2 facades" in caplog.text  # the log's progress line
    assert {f: (out / f / "map.png").stat().st_mtime_ns for f in FACES} == before
    manifest = spools[3] / "manifest.jsonl"  # face1's re-fly: a keyframe more arrived
    os.utime(manifest, ns=(manifest.stat().st_atime_ns, manifest.stat().st_mtime_ns + 10**9))
    res = build_site(spools, out, engine=EngineSpec(workers=0), progress=False)
    assert [o.status for o in res.facades] == ["skipped", "done"]


def test_spools_of_two_walls_are_refused_as_one_map(site):
    _, spools, _ = site
    with pytest.raises(CompanionError, match="is not of the wall of"):
        merge_spools([spools[0], spools[1]])  # face0's and face1's main flights


def test_the_embedded_dask_cluster_makes_the_same_maps(site, single):
    root, spools, _ = site
    res = build_site(spools, root / "local", engine=EngineSpec(workers=2), progress=False)
    assert "local cluster, 2 worker(s)" in res.engine and [o.status for o in res.facades] == ["done", "done"]
    _same_maps(single[0], root / "local")


def _start(args: list[str], log: Path) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    return subprocess.Popen([sys.executable, "-m", "dask", *args], env=env, stdout=log.open("w"),
                            stderr=subprocess.STDOUT, cwd=ROOT)


def _wait_for(predicate, timeout_s: float, what: str):
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if (value := predicate()):
            return value
        time.sleep(0.1)
    raise AssertionError(f"timed out waiting for {what}")


def test_a_scheduler_and_two_workers_started_by_hand_make_the_same_maps_with_a_worker_killed(site, single):
    from dask.distributed import Client

    root, spools, _ = site
    sched_file = root / "scheduler.json"
    procs = [_start(["scheduler", "--port", "0", "--no-dashboard", "--scheduler-file", str(sched_file)],
                    root / "scheduler.log")]
    try:
        _wait_for(sched_file.is_file, 60, "the scheduler file")
        for name in ("w1", "w2"):
            procs.append(_start(["worker", "--scheduler-file", str(sched_file), "--nworkers", "1", "--nthreads", "1",
                                 "--no-nanny", "--name", name], root / f"{name}.log"))
        watcher = Client(scheduler_file=str(sched_file))
        watcher.wait_for_workers(2, timeout=60)
        result = {}
        job = threading.Thread(target=lambda: result.update(res=build_site(
            spools, root / "cluster", engine=EngineSpec(scheduler=str(sched_file)), progress=False)))
        job.start()
        # once w2 runs a face, kill it (SIGKILL: no goodbye to the scheduler); the scheduler gives the face to w1
        names = {a: w["name"] for a, w in watcher.scheduler_info()["workers"].items()}
        _wait_for(lambda: any(names.get(a) == "w2" and tasks for a, tasks in watcher.processing().items()), 60,
                  "a task on w2")
        procs[2].send_signal(signal.SIGKILL)
        job.join(timeout=600)  # seconds on an idle machine; minutes when the machine is shared and loaded
        watcher.close()
        assert not job.is_alive()
        res = result["res"]
        assert [o.status for o in res.facades] == ["done", "done"], res.facades
        assert "2 worker(s)" in res.engine
        _same_maps(single[0], root / "cluster")
    finally:
        for p in procs:
            if p.poll() is None:
                p.terminate()
        for p in procs:
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()


TILED = StitchConfig(max_in_memory_px=1e5, tile_px=128)  # a tiny in-memory limit: the map is written only as tiles


@pytest.fixture(scope="module")
def tiled_single(site, tmp_path_factory):
    """Face 0 with its map kept as tiles, made in this process (its COG too): for the COG test and as the reference
    of the cluster's render tasks, made once."""
    _, spools, _ = site
    out = tmp_path_factory.mktemp("tiled") / "single"
    res = build_site([spools[0], spools[2]], out, TILED, EngineSpec(workers=0), progress=False)
    return res, out / "face0"


def test_the_cog_opens_in_gdal_at_the_reports_scale_also_from_a_tiled_map(single, tiled_single):
    """The COG of an in-memory map (the site's) and of a map written only as tiles (a tiny in-memory limit): GDAL
    reads a COG layout with overviews, the report's mm/px and the map's pixels."""
    rasterio = pytest.importorskip("rasterio")

    out, _ = single
    assert shutil.which("gdalinfo"), "gdalinfo is missing: apt-get install gdal-bin (as for tests/test_outputs_map.py)"
    res, tiled_dir = tiled_single
    tiled = res.facades[0]
    assert tiled.status == "done" and "map_vrt" in tiled.files and "map" not in tiled.files
    reference = _map(out / "face0")
    for folder in (out / "face0", tiled_dir):
        mm = json.loads((folder / "report.json").read_text())["map"]["mm_per_px"]
        info = subprocess.run(["gdalinfo", str(folder / "map_cog.tif")], capture_output=True, text=True, check=True)
        assert "LAYOUT=COG" in info.stdout and "Overviews:" in info.stdout
        with rasterio.open(folder / "map_cog.tif") as cog:
            assert cog.res[0] * 1000 == pytest.approx(mm, abs=5e-5) and cog.crs is not None  # report: 4 decimals
            rgba = cog.read()
        bgra = np.dstack([rgba[2], rgba[1], rgba[0], rgba[3]]).astype(int)
        assert bgra.shape == reference.shape and np.abs(bgra - reference).max() <= 1


def _tiles(folder: Path) -> dict[str, np.ndarray]:
    return {p.name: cv2.imread(str(p), cv2.IMREAD_UNCHANGED).astype(int)
            for p in sorted((folder / "tiles").glob("tile_y*_x*.png"))}


def test_a_tiled_map_is_drawn_by_render_tasks_on_the_cluster_and_is_the_single_process_map(site, tiled_single,
                                                                                          tmp_path):
    """A face whose map is kept as tiles (a tiny in-memory limit): on the embedded cluster its tiles are render
    tasks of their own (``canvas.render_batch``, written by the tasks), in this process they are drawn on the
    stitcher's threads; the tiles are the same within one grey level."""
    _, spools, _ = site
    single, outs = tiled_single[0], {"single": tiled_single[1]}
    assert [o.status for o in single.facades] == ["done"]
    res = build_site([spools[0], spools[2]], tmp_path / "cluster", TILED, EngineSpec(workers=2), progress=False,
                     cog=False)
    assert [o.status for o in res.facades] == ["done"]
    outs["cluster"] = tmp_path / "cluster" / "face0"
    render = {k: json.loads((v / "report.json").read_text())["render"] for k, v in outs.items()}
    assert "render_tasks" not in render["single"] and render["cluster"]["render_tasks"] > 1
    a, b = _tiles(outs["single"]), _tiles(outs["cluster"])
    assert len(a) == render["single"]["tiles"] > 8 and a.keys() == b.keys()
    assert max(np.abs(a[k] - b[k]).max() for k in a) <= 1
