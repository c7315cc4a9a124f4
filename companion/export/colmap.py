"""A keyframe spool as a COLMAP workspace, and COLMAP's incremental mapping run on it the way that works on a wall.

Why COLMAP needs one setting changed on our keyframes (measured: docs/OUTPUTS.md, "COLMAP on a wall"): a facade
scan moves a level camera parallel to a flat wall without turning it. Under pure translation the image motion of a
wall point is f * baseline / depth, so bundle adjustment can trade the focal against the depth and the baseline
freely: nothing in the images fixes the focal. COLMAP refines the focal by default; on our SITL spools it drifted
from the EXIF prior 465.6 px to 7 800-48 000 px, COLMAP then discards the camera as degenerate (its
``max_focal_length_ratio`` 10) and stops registering images (9 of 29 keyframes). Holding the intrinsics COLMAP read
from the EXIF (``ba_refine_focal_length`` / ``ba_refine_extra_params`` off) registers every keyframe. Nothing here
gives COLMAP intrinsics by hand: the camera is the one its own EXIF reader builds from our tags.

The workspace: ``images/`` (the keyframe JPEGs, hard links into the spool when possible), ``masks/`` with
``--masks`` (COLMAP's naming ``<image name>.png``), ``database.db``, ``sparse/N/`` (COLMAP's model) and
``colmap_report.json`` (what registered, the focal, the camera centres against the telemetry).
"""

from __future__ import annotations

import json
import logging
import os
import shutil
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np
import pymap3d

from companion.errors import CompanionError
from companion.files import removed_on_failure, write_atomic
from companion.image_files import read_image_file
from companion.spool.layout import MANIFEST
from companion.spool.reader import KeyframeInput, load_spool, read_spool_meta

log = logging.getLogger(__name__)

REPORT = "colmap_report.json"


@dataclass(frozen=True)
class ColmapWorkspace:
    """A folder COLMAP reads: the keyframe images (and masks), with the spool's poses and camera beside them."""

    root: Path
    images: Path
    masks: Path | None
    names: tuple[str, ...]  # image file names, in capture order
    positions_llh: tuple[tuple[float, float, float], ...]  # telemetry lat, lon, alt AMSL per image (nan: none)
    true_focal_px: float | None  # spool.json's K (the mission camera or its calibration)
    left_out: tuple[str, ...] = ()  # "NAME: why" for keyframes whose image is missing or damaged (not given COLMAP)


@dataclass(frozen=True)
class ColmapResult:
    """What COLMAP made of the keyframes (written as colmap_report.json)."""

    keyframes: int
    registered: int
    unregistered: tuple[str, ...]
    models: int  # reconstructions COLMAP returned (1 when every registered keyframe is in one model)
    cameras: int  # cameras in the largest model (1: all keyframes share the EXIF camera)
    exif_prior_focal: bool  # COLMAP took the focal from the EXIF (not its own guess)
    focal_px: float  # the largest model's focal after bundle adjustment
    true_focal_px: float | None
    focal_error: float | None  # focal_px / true_focal_px - 1
    held_intrinsics: bool
    centre_median_m: float | None  # camera centres vs telemetry after a similarity transform (centre_errors)
    centres_within_m: int  # registered keyframes within MISPLACED_M of their telemetry position
    misplaced: tuple[str, ...]  # registered, but further than MISPLACED_M from the telemetry
    model_dir: str
    left_out: tuple[str, ...] = ()  # the workspace's: keyframes not given to COLMAP (image missing or damaged)


def _link_or_copy(src: Path, dst: Path) -> None:
    dst.unlink(missing_ok=True)
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


def write_workspace(spool: Path, out: Path, *, masks: bool = False) -> ColmapWorkspace:
    """Put the keyframes where COLMAP looks for them (``out/images``, ``out/masks``); the spool is not touched.
    The spool is read by its reader (``companion.spool.reader.load_spool``), as the stitcher reads it."""
    spool, out = Path(spool), Path(out)
    if not (spool / MANIFEST).exists() or not (spool / MANIFEST).read_text(errors="replace").strip():
        raise CompanionError(f"{spool} holds no keyframe spool (no {MANIFEST} with keyframes)",
                             "give the --out folder of `companion fly --capture`, `companion cull` or `companion demo`"
                             " (its spool/ folder)")
    if out.resolve() == spool.resolve():
        raise CompanionError("the COLMAP workspace would be written into the spool itself",
                             "choose another --out folder")
    spooled = load_spool(spool)
    usable, left_out = _readable_keyframes(spooled.keyframes)
    left_out = [skipped.reason for skipped in spooled.skipped] + left_out
    if not usable:
        raise CompanionError(f"none of the {len(spooled.keyframes) + len(spooled.skipped)} keyframe images of "
                             f"{spool} can be read: {'; '.join(left_out[:5])}",
                             "check the spool's files (a card pulled mid-write cuts JPEGs short); cull again")
    images = out / "images"
    images.mkdir(parents=True, exist_ok=True)
    mask_dir = out / "masks" if masks else None
    if mask_dir is not None:
        mask_dir.mkdir(exist_ok=True)
    names, positions = [], []
    for keyframe in usable:
        src = keyframe.image_path
        _link_or_copy(src, images / src.name)
        if mask_dir is not None and keyframe.mask_path is not None:
            _link_or_copy(keyframe.mask_path, mask_dir / f"{src.name}.png")  # COLMAP: the image's full name + .png
        pose = keyframe.pose
        positions.append((np.nan, np.nan, np.nan) if pose is None else (pose.lat, pose.lon, pose.alt_amsl_m))
        names.append(src.name)
    camera, _, _ = read_spool_meta(spool)  # the mission's camera (or its calibration); None without spool.json
    true_focal = None if camera is None else camera.focal_px
    return ColmapWorkspace(out, images, mask_dir, tuple(names), tuple(positions), true_focal, tuple(left_out))


def _readable_keyframes(keyframes: list[KeyframeInput]) -> tuple[list[KeyframeInput], list[str]]:
    """The keyframes whose image reads through the shared decode path (companion/image_files.py), and "NAME: why"
    for the others. Why: COLMAP decodes a JPEG cut short to grey without a word, or fails to read a missing one,
    and the keyframe then shows up only as "not registered" (exit 1, no reason). Decoded at 1/8 size (libjpeg
    scales in the DCT): the check costs a few ms per keyframe."""
    usable, left_out = [], []
    for keyframe in keyframes:
        read = read_image_file(keyframe.image_path, cv2.IMREAD_REDUCED_GRAYSCALE_8)
        if read.ok:
            usable.append(keyframe)
        else:
            left_out.append(read.describe())
            log.warning("keyframe image %s left out of the COLMAP workspace", read.describe())
    return usable, left_out


def _pycolmap():
    try:
        import pycolmap
    except ImportError:
        raise CompanionError("pycolmap is not installed, so COLMAP cannot be run from here",
                             "pip install 'pycolmap>=4.2' (or run COLMAP yourself on the workspace with "
                             "--no-run: docs/OUTPUTS.md has the settings)") from None
    return pycolmap


def mapping_options(pycolmap, *, hold_intrinsics: bool, max_runtime_s: float | None = None):
    """COLMAP's incremental mapping options; ``hold_intrinsics`` keeps the EXIF camera (see the module docstring);
    ``max_runtime_s`` bounds the mapping (COLMAP's default on a wall can loop through initial pairs for long)."""
    options = pycolmap.IncrementalPipelineOptions()
    if max_runtime_s is not None:
        options.max_runtime_seconds = int(max_runtime_s)
    if hold_intrinsics:
        options.ba_refine_focal_length = False
        options.ba_refine_extra_params = False
        options.ba_refine_principal_point = False
    return options


MISPLACED_M = 0.25  # a registered keyframe whose centre is further than this from the telemetry is named


def centre_errors(centres: np.ndarray, positions_enu: np.ndarray) -> np.ndarray | None:
    """Distance (m) of each COLMAP camera centre from its telemetry position after the best similarity transform
    (Umeyama, OpenCV), refitted on those within max(3 x their median, 5 cm) until that set stops changing, so
    that a few keyframes placed wrong (e.g. seeing only the far background past the roof) do not skew the others.
    None with fewer than 3 positions or without telemetry."""
    if len(centres) < 3 or not np.isfinite(positions_enu).all():
        return None
    src, dst = centres.astype(np.float64), positions_enu.astype(np.float64)
    keep = np.ones(len(src), bool)
    for _ in range(10):
        transform, scale = cv2.estimateAffine3D(src[keep], dst[keep], force_rotation=True)
        err = np.linalg.norm(scale * src @ transform[:, :3].T + transform[:, 3] - dst, axis=1)
        new_keep = err <= max(3.0 * float(np.median(err[keep])), 0.05)
        if new_keep.sum() < 3 or (new_keep == keep).all():
            break
        keep = new_keep
    return err


def reconstruct(workspace: ColmapWorkspace, *, hold_intrinsics: bool = True,
                max_runtime_s: float | None = None) -> ColmapResult:
    """COLMAP as a user runs it (EXIF camera, exhaustive matching, incremental mapping) on ``workspace``."""
    pycolmap = _pycolmap()
    root = workspace.root
    database = root / "database.db"
    database.unlink(missing_ok=True)  # a rerun starts clean (features of removed images would linger)
    sparse = root / "sparse"
    shutil.rmtree(sparse, ignore_errors=True)
    sparse.mkdir(parents=True)
    reader = pycolmap.ImageReaderOptions()
    if workspace.masks is not None:
        reader.mask_path = str(workspace.masks)
    pycolmap.extract_features(database, workspace.images, image_names=list(workspace.names),
                              reader_options=reader, device=pycolmap.Device.cpu)
    pycolmap.match_exhaustive(database, device=pycolmap.Device.cpu)
    models = pycolmap.incremental_mapping(database, workspace.images, sparse,
                                          options=mapping_options(pycolmap, hold_intrinsics=hold_intrinsics,
                                                                          max_runtime_s=max_runtime_s))
    if not models:
        raise CompanionError(f"COLMAP built no model from the {len(workspace.names)} keyframes",
                             "check that the keyframes overlap (the spool's cull_report.json names gaps)")
    key, best = max(models.items(), key=lambda kv: kv[1].num_reg_images())
    registered = {image.name: image for image in best.images.values() if image.has_pose}
    camera = next(iter(best.cameras.values()))
    focal = float(camera.mean_focal_length())
    names = [n for n in workspace.names if n in registered]
    errors = None
    llh = np.array([workspace.positions_llh[workspace.names.index(n)] for n in names], dtype=np.float64)
    if len(names) >= 3 and np.isfinite(llh).all():
        enu = np.column_stack(pymap3d.geodetic2enu(llh[:, 0], llh[:, 1], llh[:, 2], *llh[0]))
        centres = np.array([registered[n].projection_center() for n in names])
        errors = centre_errors(centres, enu)
    true_focal = workspace.true_focal_px
    return ColmapResult(
        keyframes=len(workspace.names),
        registered=len(registered),
        unregistered=tuple(n for n in workspace.names if n not in registered),
        models=len(models),
        cameras=len(best.cameras),
        exif_prior_focal=bool(camera.has_prior_focal_length),
        focal_px=focal,
        true_focal_px=true_focal,
        focal_error=None if not true_focal else focal / true_focal - 1.0,
        held_intrinsics=hold_intrinsics,
        centre_median_m=None if errors is None else float(np.median(errors)),
        centres_within_m=0 if errors is None else int((errors <= MISPLACED_M).sum()),
        misplaced=() if errors is None else tuple(n for n, e in zip(names, errors, strict=True) if e > MISPLACED_M),
        model_dir=str(sparse / str(key)),
        left_out=workspace.left_out,
    )


def export_colmap(spool: Path, out: Path, *, masks: bool = False, run: bool = True, hold_intrinsics: bool = True,
                  max_runtime_s: float | None = None) -> tuple[ColmapWorkspace, ColmapResult | None]:
    """``companion export colmap``: write the workspace and (``run``) reconstruct it, with ``colmap_report.json``.
    A run that fails removes what it created in ``out`` (companion.files.removed_on_failure)."""
    if run:
        _pycolmap()  # missing: said before anything is written
    with removed_on_failure(out):
        workspace = write_workspace(spool, out, masks=masks)
        if not run:
            return workspace, None
        result = reconstruct(workspace, hold_intrinsics=hold_intrinsics, max_runtime_s=max_runtime_s)
        write_atomic(workspace.root / REPORT, json.dumps(asdict(result), indent=1))
    return workspace, result
