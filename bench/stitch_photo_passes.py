"""Real-texture passes as stitcher input, for bench/stitch_eval.py --passes (issue 15 item 6).

A pass (``sim/camera/photo_passes.py``: a held-out real facade photo on the wall plane at 4 m, a held-out real
outdoor photo 120 m behind, the camera flying along the wall and off its end) is rendered at the bench's width,
its keyframes chosen by our gate (truth mask, exact relative telemetry, so the gate is not what is measured here),
and written as keyframe spools whose telemetry a GNSS/IMU error model spoils (``TelemetryErrors``: noise on every
keyframe, a jump in the middle of a strip). Every map is scored against the wall photo itself: SSIM after the best
homography onto it, where on the wall it lies (shift), how much of the wall the keyframes saw it covers, and
whether the background photo can be matched in it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from companion.matching import match_descriptors
from companion.ransac import ransac_homography
from companion.records import Frame, Keyframe
from companion.spool.writer import KeyframeSpool
from companion.stitch.render import MapGrid
from evaluation.stitch.evaluate import (
    EVALUATION_MATCHING,
    map_accuracy,
    register_to_truth,
    truth_homography,
    truth_on_grid,
)
from evaluation.stitch.synthetic import (
    CAPTURE_EPOCH_S,
    SyntheticWall,
    TelemetryErrors,
    reported_pose,
    spool_meta,
    wall_frame,
)


@dataclass(frozen=True)
class RenderedPass:
    """A rendered pass: its spec and renderer, the gate's keyframes and the truth the scores need."""

    name: str
    spec: object  # sim.camera.photo_scene.PhotoPass
    renderer: object  # PhotoPassRenderer
    keyframes: list[int]
    minimum: list[int]
    pair_overlap: list[float]  # true plane overlap of consecutive keyframes, %
    strip_of: list[int]  # strip number of every frame


def render_pass(name: str, frames: int, width: int) -> RenderedPass:
    """Renders the pass and runs our gate on it (truth masks, exact telemetry) for the keyframes."""
    from checkout import use_checkout_shared_data

    from sim.camera.model import CameraModel
    from sim.camera.photo_passes import RECIPES, build_pass
    from sim.camera.photo_scene import PhotoPassRenderer

    spec = build_pass(RECIPES[name], root=use_checkout_shared_data(),
                      frames=frames, background_frames=max(2, round(frames * 22 / 250)))
    cam = spec.camera
    spec = replace(spec, camera=CameraModel(width, round(cam.height * width / cam.width), cam.hfov_deg))
    renderer = PhotoPassRenderer(spec)
    ups = [p[1] for p in renderer.positions]
    strips = sorted(set(ups))
    rp = RenderedPass(name, spec, renderer, [], [], [], [strips.index(u) for u in ups])
    return gate_pass(rp, None)


def gate_pass(rp: RenderedPass, masks: dict[int, np.ndarray | None] | None) -> RenderedPass:
    """The pass with the keyframes our gate keeps (exact relative telemetry, as the onboard chain) with the truth
    mask (``masks`` None) or with a depth model's (:func:`shipped_masks`: None where the masker drops a frame), so
    the spools of a shipped mask hold the keyframes the chain keeps with that mask."""
    from gate_photo_passes import PhotoPassRecording  # beside this script

    from companion.keyframes.features import FeatureConfig
    from companion.keyframes.gate import GateConfig
    from evaluation.keyframes.evaluate import evaluate_gate, telemetry_poses
    from evaluation.keyframes.synthetic import SITE

    rec = PhotoPassRecording(rp.renderer)
    cfg = GateConfig(rth=0.80, features=FeatureConfig(long_side_px=max(640, rp.spec.camera.width)))
    ev = evaluate_gate(rec, cfg, use_masks=masks is None, predictor=rec.predictor, pose=telemetry_poses(rec, SITE),
                       curve_floor=101.0, mask_of=None if masks is None else masks.get)
    return replace(rp, keyframes=list(ev.keyframes), minimum=list(ev.minimum_keyframes),
                   pair_overlap=[float(v) for v in ev.keyframe_pair_truth])


def gate_summary(rp: RenderedPass) -> dict:
    """The judge's gate figures: keyframes against the minimum, and the true plane overlap of keyframe pairs on
    one strip (a pass's strips are flown apart by design: the pair across a strip change shares no view)."""
    same_strip = [v for a, b, v in zip(rp.keyframes, rp.keyframes[1:], rp.pair_overlap, strict=False)
                  if rp.strip_of[a] == rp.strip_of[b]]
    return {"keyframes": len(rp.keyframes), "minimum": len(rp.minimum),
            "excess": len(rp.keyframes) / max(1, len(rp.minimum)) - 1.0,
            "lowest_pair": min(same_strip, default=None), "pairs_below_77": sum(v < 77.0 for v in same_strip),
            "pairs": len(same_strip)}


def jump_errors(rp: RenderedPass, frames: list[int], noise_m: float, noise_deg: float,
                jump_m: tuple[float, float]) -> TelemetryErrors:
    """Noise on every keyframe, and the jump on the keyframes from the middle of the first strip to the middle
    of its second half (a quarter of that strip's keyframes: a minority the images must outvote)."""
    strip0 = [k for k, f in enumerate(frames) if rp.strip_of[f] == rp.strip_of[frames[0]]]
    n = len(strip0)
    first = strip0[n // 2]
    stop = strip0[min(n - 1, n // 2 + max(1, n // 4))]
    return TelemetryErrors(noise_m, noise_deg, jump_m, (first, stop))


def write_spool(rp: RenderedPass, frames: list[int], out: Path, *, mask: str, errors: TelemetryErrors,
                seed: int = 0, model_masks: dict[int, np.ndarray] | None = None) -> Path:
    """A keyframe spool of ``frames`` of the pass, written by the product's spool writer: images, masks (``truth``,
    ``none``: the whole frame, as ``companion cull --no-mask`` spools it, or a depth model's: ``model_masks`` from
    :func:`pass_masks`) and telemetry as reported with ``errors``. Each keyframe's index is its frame in the pass."""
    spec = rp.spec
    cam = spec.camera
    wall = SyntheticWall(length_m=spec.wall.width_m, height_m=spec.wall.height_m)
    frame = wall_frame(wall)
    rng = np.random.default_rng(seed)
    spool = KeyframeSpool(out, meta=spool_meta(frame, wall, cam.width, cam.height, cam.hfov_deg, spec.standoff_m),
                          settings={"synthetic": True, "mask": mask})
    for k, i in enumerate(frames):
        f = rp.renderer.render(i)
        roi = f.roi_mask if mask == "truth" else (None if mask == "none" else model_masks[i])
        roi = np.full(f.image.shape[:2], 255, np.uint8) if roi is None else roi
        pose = reported_pose(rng, frame, (f.along_m, spec.standoff_m, f.up_m, 0.0, 0.0), errors, k)
        spool.append(Keyframe(Frame(i, CAPTURE_EPOCH_S + k, f.image), pose, roi))
    return out


def pass_masks(rp: RenderedPass, model: str, *, parallax: bool = True,
               masks: dict[int, np.ndarray | None] | None = None) -> dict[int, np.ndarray]:
    """Every frame's mask from the onboard Masker (:func:`shipped_masks`, or ``masks`` already made by it); a frame
    the masker drops gets an empty mask (the spool must hold one)."""
    masks = masks if masks is not None else shipped_masks(rp.spec, rp.renderer, model, parallax=parallax)
    return {i: np.zeros(rp.renderer.render(i).roi_mask.shape, np.uint8) if m is None else m
            for i, m in masks.items()}


def shipped_masks(spec, renderer, model: str, *, parallax: bool = True,
                  network_first: dict[int, np.ndarray | None] | None = None) -> dict[int, np.ndarray | None]:
    """Every frame's mask from the onboard Masker with a shipped depth model (``sim``, the default, or
    ``real-nc``, the setting docs/DEPTH.md gives for real facades), frames shown in capture order with their
    telemetry (exact: the short baselines parallax uses are relative motion, not absolute GNSS), so ``parallax``
    confirms or corrects the network as in the onboard chain. A frame the masker could judge by the network alone
    (no reference: a strip's first frame) is held and masked again against the next frame far enough along the
    baseline, as the onboard chain does with such a keyframe (``companion.depth.parallax_first``; the chain holds
    keyframes only, here every frame is held, as the gate has not chosen yet). ``network_first`` (a dict, filled):
    those frames' network-alone masks, the path before issue 15's fix, for a side-by-side. None where the masker
    drops the frame (the onboard chain never passes it on)."""
    from companion.depth.masker import Masker
    from companion.depth.parallax import SequenceParallax
    from companion.depth.parallax_first import LaterReference, first_look
    from companion.records import Frame, TaggedFrame

    wall = SyntheticWall(length_m=spec.wall.width_m, height_m=spec.wall.height_m)
    frame = wall_frame(wall)
    rng = np.random.default_rng(0)
    seq = SequenceParallax(spec.camera.hfov_deg) if parallax else None
    masker = Masker(model, parallax=seq)
    later = LaterReference(masker) if parallax else None
    masks: dict[int, np.ndarray | None] = {}

    def settle(resolved) -> None:
        for r in resolved:
            i = r.tagged.frame.index
            masks[i] = None if r.masked is None else r.masked.mask
            if network_first is not None:
                network_first[i] = None if r.network is None else r.network.mask

    for i in range(len(renderer)):
        f = renderer.render(i)
        pose = reported_pose(rng, frame, (f.along_m, spec.standoff_m, f.up_m, 0.0, 0.0), TelemetryErrors(), i,
                             time_s=i / 10.0)
        tagged = TaggedFrame(Frame(i, i / 10.0, f.image), pose)
        look = first_look(masker, tagged)
        masks[i] = None if look.masked is None else look.masked.mask
        if later is not None:
            settle(later.offer(tagged))
            if look.alone:
                later.hold(tagged, look.masked)
    if later is not None:
        settle(later.release())
    if network_first is not None:
        network_first.update({i: m for i, m in masks.items() if i not in network_first})
    return masks


def mask_error(rp: RenderedPass, frames: list[int], masks: dict[int, np.ndarray]) -> dict:
    """How the model's masks of ``frames`` differ from the truth: wall pixels cut, background pixels kept."""
    wall = bg = cut = kept = 0
    for i in frames:
        t = rp.renderer.render(i).roi_mask > 0
        m = masks[i] > 0
        wall += int(t.sum())
        bg += int((~t).sum())
        cut += int((t & ~m).sum())
        kept += int((~t & m).sum())
    return {"wall_cut": cut / max(1, wall), "background_kept": kept / max(1, bg)}


@dataclass(frozen=True)
class WallTruth:
    """The wall photo (and its labels: not-facade pixels are holes) and the part of it the frames saw, on a
    grid; ``background`` is the background photo at the frames' scale, to look for in the maps."""

    image: np.ndarray
    grid: MapGrid
    seen: np.ndarray  # 0/255: wall (labels) inside the frames' true footprints
    background: np.ndarray


def wall_truth(rp: RenderedPass, frames: list[int], grid: MapGrid) -> WallTruth:
    spec, r = rp.spec, rp.renderer
    wall = spec.wall
    tex_m = wall.width_m / wall.image.shape[1]
    image = truth_on_grid(wall.image, tex_m, wall.height_m, grid, pixel_centre=0.5)
    alpha = np.full(wall.image.shape[:2], 255, np.uint8) if wall.alpha is None else wall.alpha
    labels = truth_on_grid(alpha, tex_m, wall.height_m, grid, pixel_centre=0.5)
    seen = np.zeros((grid.height, grid.width), np.uint8)
    half_w = r.half_view_m
    half_h = half_w * spec.camera.height / spec.camera.width
    for i in frames:
        a, u = r.positions[i]
        poly = grid.to_px(np.array([[a - half_w, u + half_h], [a + half_w, u + half_h], [a + half_w, u - half_h],
                                    [a - half_w, u - half_h]]))
        cv2.fillPoly(seen, [np.round(poly).astype(np.int32)], 255)
    seen[labels < 128] = 0
    return WallTruth(image, grid, seen, r._bg_img)


def truth_grid_for(rp: RenderedPass, m_per_px: float) -> MapGrid:
    """The whole wall at ``m_per_px`` (for maps with no wall coordinates, registered onto it)."""
    w = rp.spec.wall
    return MapGrid(0.0, w.height_m, m_per_px, int(np.ceil(w.width_m / m_per_px)), int(np.ceil(w.height_m / m_per_px)))


def grid_of_report(report: dict) -> MapGrid:
    m = report["map"]
    return MapGrid(m["along_m"][0], m["up_m"][1], m["mm_per_px"] / 1000.0, m["width_px"], m["height_px"])


def score_map(image: np.ndarray | None, coverage: np.ndarray | None, truth: WallTruth, *,
              rectified: bool) -> dict:
    """After the best homography onto the wall photo (SIFT; each separate piece of the map its own): SSIM, seams
    (patch shifts left after it) and the share of the seen wall covered; for a map in wall coordinates also where
    it lies (the shift, absolute); and the background photo's matches in the map."""
    if image is None:
        return {"map": False}
    out: dict = {"map": True, "background_inliers": background_inliers(image, truth.background)}
    if rectified and image.shape[:2] == truth.image.shape[:2]:
        cov = cv2.bitwise_and(coverage, truth.seen)
        acc = map_accuracy(image, cov, truth.image, truth.grid.m_per_px)
        out.update(shift_median_mm=acc.get("median_mm"), shift_p95_mm=acc.get("p95_mm"), **_scale_and_place(
            image, truth))
    parts = _map_parts(coverage if coverage is not None else (image.max(axis=2) > 0).astype(np.uint8) * 255)
    scored, drawn_all = [], np.zeros_like(truth.seen)
    for part in parts:
        sub = cv2.bitwise_and(image, image, mask=part)
        # the gate's feature settings (CLAHE, low contrast threshold): with OpenCV's defaults a plain wall's map
        # registers on its one window frame and the extrapolated homography misplaces the far end by 10-15 px
        H = truth_homography(sub, truth.image, equalize=True)
        if H is None:
            continue
        warped, cov = register_to_truth(sub, truth.image, H=H, drawn=part)
        seen = cv2.bitwise_and(cov, truth.seen)
        acc = map_accuracy(warped, seen, truth.image, truth.grid.m_per_px)
        drawn_all |= register_to_truth(sub, truth.image, erode_px=1, H=H, drawn=part)[1]
        scored.append((np.count_nonzero(seen), acc))
    if not scored:
        out["registered"] = False
        return out
    weight = np.array([w for w, _ in scored], float) + 1e-9
    out.update(registered=True, parts=len(parts),
               ssim=float(np.average([a.get("ssim", 0.0) for _, a in scored], weights=weight)),
               seam_p95_px=max((a["rel_p95_px"] for _, a in scored if "rel_p95_px" in a), default=None),
               coverage=float(np.count_nonzero(cv2.bitwise_and(drawn_all, truth.seen)))
               / max(1, np.count_nonzero(truth.seen)))
    return out


def _scale_and_place(image: np.ndarray, truth: WallTruth) -> dict:
    """A rectified map against the wall photo on the same grid (issue 26): its scale error (the best homography's
    scale; 0 when the map's mm/px is the truth's) and where its centre lies off the truth (metres)."""
    H = truth_homography(image, truth.image, equalize=True)
    if H is None:
        return {}
    scale = float(np.sqrt(abs(np.linalg.det(H[:2, :2] / H[2, 2]))))
    centre = np.array([[truth.grid.width / 2, truth.grid.height / 2]], dtype=float)
    moved = cv2.perspectiveTransform(centre.reshape(1, 1, 2), H).reshape(2)
    return {"scale_error_percent": 100.0 * (scale - 1.0),
            "placement_error_m": float(np.linalg.norm(moved - centre[0]) * truth.grid.m_per_px)}


def _map_parts(drawn: np.ndarray, min_share: float = 0.02) -> list[np.ndarray]:
    """The map's separate pieces (0/255 masks): scan strips that no image overlap ties together (two strips far
    apart on a tall wall) are each placed on the wall by their own telemetry, so each is registered onto the
    wall photo by its own homography; what is measured is then ghosting and seams, not GNSS (that is the shift,
    and report.json's anchor). Pieces under ``min_share`` of the drawn area are specks, left out."""
    joined = cv2.dilate(drawn, np.ones((9, 9), np.uint8))
    n, labels, stats, _ = cv2.connectedComponentsWithStats((joined > 0).astype(np.uint8), connectivity=8)
    total = max(1, int(np.count_nonzero(drawn)))
    parts = []
    for k in range(1, n):
        part = ((labels == k) & (drawn > 0)).astype(np.uint8) * 255
        if np.count_nonzero(part) >= min_share * total:
            parts.append(part)
    return parts


def background_inliers(image: np.ndarray, background: np.ndarray) -> int:
    """Inliers of the best homography between SIFT matches of the map and the background photo (at the
    frames' scale): a map that draws the background has a consistent set; a wall alone gives a handful."""
    sift = cv2.SIFT_create(nfeatures=20000)
    g1 = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    g2 = cv2.cvtColor(background, cv2.COLOR_BGR2GRAY)
    k1, d1 = sift.detectAndCompute(g1, (g1 > 0).astype(np.uint8) * 255)
    k2, d2 = sift.detectAndCompute(g2, None)
    if d1 is None or d2 is None or len(k1) < 8 or len(k2) < 8:
        return 0
    found = match_descriptors(d1, d2, EVALUATION_MATCHING)
    q1, t2 = found.query, found.indexed
    if len(q1) < 8:
        return 0
    p1 = np.float32([k1[i].pt for i in q1])
    p2 = np.float32([k2[i].pt for i in t2])
    cv2.setRNGSeed(7)
    H, inl = ransac_homography(p1, p2, method=cv2.USAC_MAGSAC, threshold_px=3.0, max_iters=5000, confidence=0.999)
    return 0 if H is None else int(inl.sum())
