"""A face's keyframes as tasks of their own: decode + SIFT of each keyframe runs on any worker before the face.

Why: a face's task is one process for minutes; a site with fewer faces than workers (or one large face) would
leave workers idle. Features are the stage that is independent per keyframe, so each keyframe's decode and
extraction is a task that writes the stitcher's own content-keyed feature cache (``stitch/features.py:
cached_features``) in the face's folder; the face's task then reads them from there as a rerun would. The
result is the same file whichever worker made it, so the map is the same.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from companion.errors import CompanionError
from companion.keyframes.features import FeatureConfig
from companion.site.facade import FacadeTask
from companion.stitch.features import cached_features
from companion.stitch.inputs import KeyframeInput
from companion.stitch.merge import merge_spools

FEATURE_CACHE = Path("cache") / "features"  # under a face's folder: where Stitcher.features looks


@dataclass(frozen=True)
class KeyframeTask:
    """One keyframe's features for one face: the keyframe (index as merged), the cache to fill, the settings."""

    keyframe: KeyframeInput
    cache_dir: Path
    features: FeatureConfig
    threads: int = 1


def keyframe_tasks(task: FacadeTask) -> list[KeyframeTask]:
    """The face's keyframes as feature tasks; none when its spools cannot be merged (the face's own task then
    reports why)."""
    try:
        inp, _ = merge_spools(list(task.job.spools))
    except CompanionError:
        return []
    cache = task.out_dir / FEATURE_CACHE
    return [KeyframeTask(kf, cache, task.config.features, task.threads) for kf in inp.keyframes]


def extract_features(task: KeyframeTask) -> str | None:
    """Fill the cache with the keyframe's features. Nothing is raised: a damaged keyframe is left to the face's
    task (which names it in its report, or fails the face with the fix), so a keyframe's problem is only returned
    here, and one keyframe never fails its face by another route than the stitcher's."""
    if task.threads > 0:
        import cv2

        cv2.setNumThreads(task.threads)
    try:
        cached_features(task.keyframe, task.cache_dir, task.features)
    except Exception as exc:  # noqa: BLE001 - whatever it is, the face's task meets it again and reports it
        return f"{type(exc).__name__}: {exc}"
    return None
