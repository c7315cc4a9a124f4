"""A site: many spools of many walls in one job (`companion site SPOOL... --out DIR`, issue 28).

The stitcher (``companion.stitch``) makes one wall's map in one process. A building has four or more faces and
every face gets re-flies; this package groups the spools by wall (``spools.py``), makes each face's map as one
task (``facade.py``: the stitcher on the face's merged spools, a completion marker written last), runs those
tasks on a Dask cluster or in this process (``engine.py``), reports progress (``progress.py``) and writes the
site's index (``index.py``: site.json and the start page linking every face's viewer). ``run.py`` ties them.

Nothing in companion imports this package but the command line: it sits on top of the stitcher.
"""
