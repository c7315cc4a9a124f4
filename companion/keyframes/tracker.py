"""The wall's image motion on every frame, cheaply: pyramidal Lucas-Kanade flow on a small grey working copy.

Why: the overlap gate's measurement (depth mask + SIFT + match + RANSAC) costs a few hundred milliseconds per
frame, so a chain that measures every frame sees only a few of a 30 fps camera's frames and cannot pick the last
frame still above Rth. Tracking corner points from one frame to the next on a 320 px grey copy costs a few
milliseconds, so every frame is followed; the tracker's overlap with the last keyframe says WHEN to measure (only
the frames around the moment it reaches Rth), while the keyframe itself is still chosen from the measured R.

How: points are picked inside the last ROI mask (wall, not background) and followed frame to frame with
``cv2.calcOpticalFlowPyrLK``; each point's first guess is where the telemetry says the wall moved since the
previous frame (``WallMotion``), so a dropped frame or a fast leg does not lose the track. A forward-backward check
throws out points that do not come back to where they started. The median displacement of the survivors, summed
since the anchor (the last keyframe), gives the paper's Eq. 2 overlap. When too few points survive, the telemetry
prediction against the anchor stands in (``TrackSource.TELEMETRY``) and the track is picked up again on the next
frame; with neither, the track is ``lost`` and the caller measures.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

import cv2
import numpy as np

from companion.errors import CompanionError
from companion.keyframes.motion import WallMotion
from companion.keyframes.overlap import eq2_overlap


@dataclass(frozen=True)
class TrackerConfig:
    """``work_width_px``: width of the grey working copy; the flow is measured there and scaled to full pixels."""

    work_width_px: int = 320
    max_points: int = 120
    min_points: int = 12  # fewer surviving points: the flow is not trusted for this frame
    quality_level: float = 0.01
    min_distance_px: int = 6
    window_px: int = 21
    pyramid_levels: int = 3
    max_fb_error_px: float = 1.0  # forward-backward round trip (working px) a point must come back within
    # The flow says the overlap is this many points above the telemetry's: it follows something that does not
    # move (all) like the wall (roof line, far background, a reflection), and the telemetry's prediction stands in.
    # Tight, as the gate's own telemetry veto (3 points): a flow that lags makes the chain measure too late, one
    # that leads only makes it measure early.
    max_telemetry_disagreement: float = 3.0

    def __post_init__(self) -> None:
        if self.work_width_px < 64:
            raise CompanionError(f"work_width_px={self.work_width_px} is too small to track texture",
                                 "use 240-480 px (default 320)")
        if not 4 <= self.min_points <= self.max_points:
            raise CompanionError(f"min_points={self.min_points} must be in [4, max_points={self.max_points}]",
                                 "use e.g. min_points=12, max_points=120")


class TrackSource(StrEnum):
    """What placed a frame relative to the anchor (``WallTrack.source``); an enum so readers compare members."""

    FLOW = "flow"  # tracked points
    TELEMETRY = "telemetry"  # too few points: the poses' prediction
    ANCHOR = "anchor"  # the anchor itself
    LOST = "lost"  # neither: no overlap known


@dataclass(frozen=True)
class WallTrack:
    """Where the tracker puts one frame relative to the anchor (the last keyframe).

    ``dx``/``dy``: the wall's image shift from the anchor to this frame (full-resolution px, this frame minus the
    anchor, the sign of ``OverlapEstimate``); ``overlap_percent``: paper Eq. 2 of that shift, None when ``lost``;
    ``source``: what placed it (:class:`TrackSource`); ``points``: points that survived the forward-backward
    check on this frame.
    """

    frame_index: int
    anchor_index: int
    dx: float
    dy: float
    overlap_percent: float | None
    source: TrackSource
    points: int

    @property
    def known(self) -> bool:
        return self.overlap_percent is not None


class WallTracker:
    """Frame-to-frame wall tracker. ``anchor`` on a keyframe, ``track`` every later frame in capture order,
    ``reanchor`` to an already tracked frame when the gate makes it the keyframe (its offset is remembered)."""

    def __init__(self, config: TrackerConfig | None = None):
        self.config = config or TrackerConfig()
        self._prev_gray: np.ndarray | None = None
        self._prev_index: int | None = None
        self._points: np.ndarray | None = None  # N x 1 x 2 float32, working px, in the previous frame
        self._mask: np.ndarray | None = None  # working-resolution ROI mask used to (re)seed points
        self._scale = 1.0  # working px per full-resolution px
        self._size = (0, 0)  # full-resolution (width, height)
        self._anchor_index: int | None = None
        self._offsets: dict[int, tuple[float, float]] = {}  # frame index -> full-res shift since the anchor

    @property
    def anchor_index(self) -> int | None:
        return self._anchor_index

    def anchor(self, frame_index: int, image: np.ndarray, mask: np.ndarray | None = None, *,
               keyframe_index: int | None = None, offset: tuple[float, float] = (0.0, 0.0)) -> WallTrack:
        """Start a new track on this frame. On a keyframe its shift is zero; after the track was lost it restarts on
        a measured frame, whose measured shift ``offset`` from the keyframe ``keyframe_index`` it carries on."""
        gray = self._working_gray(image)
        self.set_mask(mask)
        self._prev_gray, self._prev_index = gray, frame_index
        self._points = self._seed(gray)
        self._anchor_index = frame_index if keyframe_index is None else keyframe_index
        self._offsets = {frame_index: (float(offset[0]), float(offset[1]))}
        return self._record(frame_index, float(offset[0]), float(offset[1]), TrackSource.ANCHOR, len(self._points))

    def predicted(self, frame_index: int) -> float | None:
        """Eq. 2 overlap of a tracked frame with the anchor as known now (after re-anchoring and corrections)."""
        shift = self._offsets.get(frame_index)
        return None if shift is None else eq2_overlap(shift[0], shift[1], *self._size)

    def correct(self, frame_index: int, dx: float, dy: float) -> None:
        """A measurement (SIFT + RANSAC) put this tracked frame at (dx, dy) from the anchor: it replaces the summed
        flow there and the frames tracked after it move with it, so drift never outlives a measurement."""
        old = self._offsets.get(frame_index)
        if old is None:
            return
        ex, ey = dx - old[0], dy - old[1]
        self._offsets = {i: ((x + ex, y + ey) if i >= frame_index else (x, y)) for i, (x, y) in self._offsets.items()}

    def set_mask(self, mask: np.ndarray | None) -> None:
        """The newest ROI mask (full resolution, 255 = wall): new points are picked inside it."""
        if mask is None:
            self._mask = None
            return
        w, h = self._work_size()
        self._mask = cv2.resize(mask, (w, h), interpolation=cv2.INTER_NEAREST)

    def reanchor(self, frame_index: int) -> bool:
        """Make an already tracked frame the anchor; later frames' shifts become relative to it. False when that
        frame was not tracked (the caller then anchors on the next frame it has)."""
        if frame_index not in self._offsets:
            return False
        ox, oy = self._offsets[frame_index]
        self._offsets = {i: (x - ox, y - oy) for i, (x, y) in self._offsets.items() if i >= frame_index}
        self._anchor_index = frame_index
        return True

    def track(self, frame_index: int, image: np.ndarray, step_prior: WallMotion | None = None,
              anchor_prior: WallMotion | None = None) -> WallTrack:
        """Follow the wall into this frame. ``step_prior``: the telemetry's wall motion from the previously tracked
        frame to this one (first guess for every point); ``anchor_prior``: from the anchor to this frame (stands in
        when the flow has too few points)."""
        if self._prev_gray is None or self._anchor_index is None:
            raise CompanionError("the tracker has no anchor", "call anchor() on the first keyframe before track()")
        gray = self._working_gray(image)
        shift = self._flow_shift(gray, step_prior)
        prev = self._offsets.get(self._prev_index)
        self._prev_gray, self._prev_index = gray, frame_index
        if shift is not None and prev is not None:
            (sx, sy), n = shift
            w, h = self._size
            dx, dy = prev[0] + sx, prev[1] + sy
            if anchor_prior is None or (eq2_overlap(dx, dy, w, h) - anchor_prior.overlap_percent
                                        <= self.config.max_telemetry_disagreement):
                return self._record(frame_index, dx, dy, TrackSource.FLOW, n)
        self._points = self._seed(gray)  # pick the track up again from this frame
        if anchor_prior is not None:
            return self._record(frame_index, anchor_prior.dx, anchor_prior.dy, TrackSource.TELEMETRY, 0)
        self._offsets.pop(frame_index, None)
        return WallTrack(frame_index, self._anchor_index, 0.0, 0.0, None, TrackSource.LOST, 0)

    # -- internals ----------------------------------------------------------------------------------------
    def _record(self, frame_index: int, dx: float, dy: float, source: TrackSource, points: int) -> WallTrack:
        self._offsets[frame_index] = (dx, dy)
        w, h = self._size
        return WallTrack(frame_index, self._anchor_index, dx, dy, eq2_overlap(dx, dy, w, h), source, points)

    def _work_size(self) -> tuple[int, int]:
        w, h = self._size
        return max(1, round(w * self._scale)), max(1, round(h * self._scale))

    def _working_gray(self, image: np.ndarray) -> np.ndarray:
        if image is None or image.ndim not in (2, 3) or image.size == 0:
            raise CompanionError("the tracker got an empty frame", "pass a BGR uint8 or grey image")
        h, w = image.shape[:2]
        if (w, h) != self._size:
            self._size = (w, h)
            self._scale = min(1.0, self.config.work_width_px / w)
            self._mask = None
        ww, wh = self._work_size()
        small = cv2.resize(image, (ww, wh), interpolation=cv2.INTER_AREA) if self._scale < 1.0 else image
        return cv2.cvtColor(small, cv2.COLOR_BGR2GRAY) if small.ndim == 3 else small

    def _seed(self, gray: np.ndarray) -> np.ndarray:
        cfg = self.config
        mask = self._mask if self._mask is not None and self._mask.shape == gray.shape else None
        pts = cv2.goodFeaturesToTrack(gray, cfg.max_points, cfg.quality_level, cfg.min_distance_px, mask=mask)
        return np.zeros((0, 1, 2), np.float32) if pts is None else pts.astype(np.float32)

    def _flow_shift(self, gray: np.ndarray, step_prior: WallMotion | None) -> tuple[tuple[float, float], int] | None:
        """Median full-resolution shift of the points from the previous frame to ``gray`` (and how many points
        gave it); None when too few points survive."""
        cfg = self.config
        pts = self._points
        if pts is None or len(pts) < cfg.min_points:
            pts = self._seed(self._prev_gray)
        if len(pts) < cfg.min_points:
            return None
        guess = self._guess(pts, step_prior)
        lk = {"winSize": (cfg.window_px, cfg.window_px), "maxLevel": cfg.pyramid_levels,
              "criteria": (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 20, 0.03)}
        nxt, ok, _ = cv2.calcOpticalFlowPyrLK(self._prev_gray, gray, pts, guess.copy(),
                                              flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **lk)
        back, ok_back, _ = cv2.calcOpticalFlowPyrLK(gray, self._prev_gray, nxt, pts.copy(),
                                                    flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **lk)
        h, w = gray.shape[:2]
        inside = (nxt[:, 0, 0] >= 0) & (nxt[:, 0, 0] < w) & (nxt[:, 0, 1] >= 0) & (nxt[:, 0, 1] < h)
        fb = np.linalg.norm((back - pts).reshape(-1, 2), axis=1)
        good = ok.ravel().astype(bool) & ok_back.ravel().astype(bool) & (fb < cfg.max_fb_error_px) & inside
        if int(good.sum()) < cfg.min_points:
            self._points = None
            return None
        moved = (nxt - pts).reshape(-1, 2)[good]
        self._points = nxt[good].reshape(-1, 1, 2)
        if len(self._points) < 2 * cfg.min_points:  # thin out early: re-seed on this frame next time
            self._points = None
        sx, sy = np.median(moved, axis=0) / self._scale
        return (float(sx), float(sy)), int(good.sum())

    def _guess(self, pts: np.ndarray, step_prior: WallMotion | None) -> np.ndarray:
        """Each point's first guess in the new frame: where the telemetry's wall motion puts it, else in place."""
        if step_prior is None:
            return pts.astype(np.float32)
        full = pts.reshape(-1, 2) / self._scale
        return (step_prior.map_points(full) * self._scale).astype(np.float32).reshape(-1, 1, 2)
