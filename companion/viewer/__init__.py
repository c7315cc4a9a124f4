"""The inspector's viewer: a static web page beside a stitched map (tiles, coverage, re-fly areas, keyframe
footprints with their photos, distances in millimetres). ``page.write_viewer`` writes it; ``companion view``
serves it."""

from companion.viewer.page import write_viewer

__all__ = ["write_viewer"]
