"""Every frame considered, few measured: the wall tracker decides WHEN to measure, the measured R decides WHICH frame.

Why: measuring a frame (depth mask + SIFT + match + RANSAC) costs a few hundred milliseconds, tracking it a few
(``companion.keyframes.tracker``). So every frame is tracked, and frames whose tracked overlap with the keyframe
comes near Rth are held back (full resolution, in capture order). Once the tracker puts the newest frame clearly
below Rth, the held frames are searched with the gate's measurement: start at the last one the tracker puts >= Rth,
step back while the measured R is below Rth, forward while the next one is still >= Rth. The gate then gets the last
frame whose MEASURED R is >= Rth, followed by the first one below (which makes it the keyframe, the paper's rule),
so a keyframe costs about two measurements instead of one per frame. Every measurement also re-seats the tracker
(its summed flow is replaced by the measured shift), so drift never outlives a keyframe.

Far from the decision (the telemetry's overlap with the keyframe and the tracker's both more than
``MeasureSchedule.skip_above`` points above the hold band: about half of each keyframe's frames) three frames in
four are not even decoded: ``skips`` says so before the chain decodes them, and they are counted
(``skipped_far``). Every frame in the band, and so every frame that may become a keyframe or its neighbour, is
decoded and tracked; the keyframes are those of a chain that tracks every frame (tested).

When the tracker loses the wall (no texture, no telemetry), the held frames are decided at once with the newest one
measured too, as a chain without a tracker would. Frames that arrive while a search runs wait in the runner's
queue (or are dropped there, oldest first): they cost frames, never a keyframe below Rth, because the search only
uses frames it measured.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from companion.errors import CompanionError
from companion.keyframes.gate import KeyframeGate
from companion.keyframes.motion import WallMotion, WallMotionPredictor
from companion.keyframes.overlap import OverlapEstimate
from companion.keyframes.tracker import TrackerConfig, WallTracker
from companion.records import Keyframe, MaskedFrame, OverlapSource, TaggedFrame


@dataclass(frozen=True)
class MeasureSchedule:
    """Overlap band (percentage points around Rth) in which frames are held for measurement.

    ``hold_above``: frames the tracker puts below Rth + this are held; ``resolve_below``: the search runs once the
    newest frame is below Rth - this; ``max_held``: full-resolution frames held at most (oldest dropped first).
    """

    hold_above: float = 6.0
    resolve_below: float = 1.5
    max_held: int = 45  # 1.5 s of a 30 fps camera; the band itself is about 10 frames at the planned speed
    tracker: TrackerConfig = TrackerConfig()
    # Far above the band (the telemetry AND the tracker put the overlap more than ``skip_above`` points above
    # Rth + hold_above) no frame can be the keyframe nor its neighbour, so only every ``skip_stride``-th frame is
    # decoded and tracked; the others are counted, not decoded (issue 17: decode + LK flow + the telemetry's
    # step prediction are about 10 ms of CPU per 1280 px frame). None: every frame tracked.
    skip_above: float | None = 2.0  # 2 and 4: the same keyframes on a 1280 px demo recording, 40 % of frames skipped
    skip_stride: int = 4

    def __post_init__(self) -> None:
        if self.hold_above <= 0 or self.resolve_below <= 0:
            raise CompanionError(f"hold_above={self.hold_above} and resolve_below={self.resolve_below} must be > 0",
                                 "use e.g. hold_above=6, resolve_below=1.5 (percentage points)")
        if self.max_held < 2:
            raise CompanionError(f"max_held={self.max_held} cannot hold a frame pair", "use e.g. 45")
        if (self.skip_above is not None and self.skip_above < 0) or self.skip_stride < 1:
            raise CompanionError(f"skip_above={self.skip_above}, skip_stride={self.skip_stride}",
                                 "use skip_above >= 0 points (or None: track every frame) and skip_stride >= 1")


@dataclass(frozen=True)
class TrackedCounts:
    """What the scheduler did: frames tracked, frames measured (mask + SIFT), searches, lost tracks."""

    tracked: int
    measured: int
    searches: int
    lost: int
    held_dropped: int
    skipped_far: int = 0  # far above the band: counted, not decoded nor tracked (``MeasureSchedule.skip_above``)


class TrackedSelection:
    """Feeds a ``KeyframeGate`` only the frames worth measuring. ``offer(tagged)`` per frame in capture order,
    ``finish()`` at the end of the stream (before the gate's ``flush``); both return the keyframes decided.

    ``mask``: the depth mask stage (TaggedFrame -> MaskedFrame, None when the frame holds no facade).
    ``observe``: called with every tracked frame that is not masked now (the masker's parallax keeps it as a
    reference for the next masked frame: ``Masker.remember``).
    """

    def __init__(self, gate: KeyframeGate, mask: Callable[[TaggedFrame], MaskedFrame | None],
                 predictor: WallMotionPredictor | None = None, schedule: MeasureSchedule | None = None,
                 observe: Callable[[TaggedFrame], None] | None = None):
        self.gate, self.mask, self.predictor, self.observe = gate, mask, predictor, observe
        self.schedule = schedule or MeasureSchedule()
        self.tracker = WallTracker(self.schedule.tracker)
        self._held: list[TaggedFrame] = []  # frames waiting for a decision, capture order; the last is the newest
        self._masked: dict[int, MaskedFrame | None] = {}  # frame index -> mask, for held frames measured already
        self._prev: TaggedFrame | None = None
        self._anchor_tagged: TaggedFrame | None = None
        self._tracked = self._measured = self._searches = self._lost = self._held_dropped = 0
        self._skipped = self._skip_run = 0
        self._anchor_motion: tuple | None = None  # (frame index, prediction from the anchor, (width, height))
        self._seen_pose = False  # a frame with a pose was offered: the flight has telemetry (``_posed_keyframe``)

    @property
    def counts(self) -> TrackedCounts:
        return TrackedCounts(self._tracked, self._measured, self._searches, self._lost, self._held_dropped,
                             self._skipped)

    def skips(self, tagged: TaggedFrame) -> bool:
        """True when this frame need not be decoded nor tracked: the telemetry's overlap with the keyframe and the
        tracker's on the last tracked frame are both more than ``skip_above`` points above the hold band, and
        fewer than ``skip_stride`` - 1 frames were skipped since the last tracked one. Called before ``offer``
        (``tagged.frame`` may still be encoded); a skipped frame is counted and never offered."""
        sch = self.schedule
        prev = self._prev
        if (sch.skip_above is None or sch.skip_stride < 2 or prev is None or self._anchor_tagged is None
                or self.tracker.anchor_index is None or self.gate.keyframe_index is None
                or self._skip_run + 1 >= sch.skip_stride):
            self._skip_run = 0
            return False
        floor = self.gate.rth_percent + sch.hold_above + sch.skip_above
        if self._predicted(prev, 0.0) <= floor:
            self._skip_run = 0
            return False
        h, w = prev.frame.image.shape[:2]  # the working size the tracker's frames have
        prior = self._anchor_prior(tagged, w, h)
        if prior is None or prior.overlap_percent <= floor:
            self._skip_run = 0
            return False
        self._skip_run += 1
        self._skipped += 1
        return True

    def held_indices(self) -> list[int]:
        """Frames held for a decision (capture order): any of them may still become a keyframe."""
        return [t.frame.index for t in self._held]

    def offer(self, tagged: TaggedFrame) -> list[Keyframe]:
        self._seen_pose = self._seen_pose or _posed(tagged)
        if self.tracker.anchor_index is None or self.gate.keyframe_index is None:
            return self._measure_and_push(tagged)
        h, w = tagged.frame.image.shape[:2]
        track = self.tracker.track(tagged.frame.index, tagged.frame.image,
                                   self._motion(self._prev, tagged, overlap=False), self._anchor_prior(tagged, w, h))
        self._prev = tagged
        self._tracked += 1
        if self.observe is not None:
            self.observe(tagged)
        self._hold(tagged)
        if not track.known:  # the wall is lost: decide now on what is held, the newest frame measured too
            self._lost += 1
            return self._search()
        if track.overlap_percent < self.gate.rth_percent - self.schedule.resolve_below:
            return self._search()
        return []

    def finish(self) -> list[Keyframe]:
        """End of stream: decide the held frames, then make sure the newest frame reached the gate (the wall's
        last view), so the gate's flush ends the map there."""
        if not self._held:
            return []
        newest = self._held[-1]
        out = self._search()
        if self._held and self._held[-1] is newest:
            out += self._push(newest)
        self._held.clear()
        self._masked.clear()
        return out

    # -- holding and searching ----------------------------------------------------------------------------
    def _hold(self, tagged: TaggedFrame) -> None:
        """Keep the newest frame, the frames in the band above Rth and the last frame above the band: when frames
        were dropped and the track jumped across the band in one step, that one is the frame still >= Rth."""
        limit = self.gate.rth_percent + self.schedule.hold_above
        above = [t for t in self._held if self._predicted(t, 100.0) > limit]
        last_above = above[-1] if above else None
        keep = [t for t in self._held if t is last_above or self._predicted(t, 100.0) <= limit]
        keep.append(tagged)
        while len(keep) > self.schedule.max_held:
            keep.pop(0)
            self._held_dropped += 1
        self._held = keep
        kept = {t.frame.index for t in keep}
        self._masked = {i: m for i, m in self._masked.items() if i in kept}

    def _predicted(self, tagged: TaggedFrame, unknown: float) -> float:
        """The tracker's overlap of a held frame with the keyframe; ``unknown`` where it has none."""
        value = self.tracker.predicted(tagged.frame.index)
        return unknown if value is None else value

    def _search(self) -> list[Keyframe]:
        """Find the last held frame whose measured R is >= Rth and hand it, then the next one, to the gate."""
        self._searches += 1
        held, rth = self._held, self.gate.rth_percent
        start = max((i for i, t in enumerate(held) if self._predicted(t, 0.0) >= rth), default=0)
        last_above, first_below = self._bracket(start)
        last_above = self._posed_keyframe(last_above)
        plan = [held[i] for i in (last_above, first_below) if i is not None]
        if not plan:  # nothing measurable held: the newest frame decides, as without a tracker
            plan = [held[-1]]
        out: list[Keyframe] = []
        for tagged in plan:
            out += self._push(tagged)
        pushed = plan[-1].frame.index
        self._held = [t for t in held if t.frame.index > pushed]
        return out

    def _bracket(self, start: int) -> tuple[int | None, int | None]:
        """(last held index measured >= Rth, the next measurable one after it, below Rth), searching from
        ``start``: back while below, forward while still >= Rth. Frames without ROI or features are skipped."""
        held, rth = self._held, self.gate.rth_percent
        i = start
        while i >= 0:
            est = self._measure(held[i])
            if est is not None and est.known and est.percent >= rth:
                break
            i -= 1
        if i < 0:  # even the first held frame is below Rth: the gate decides on it (low overlap or gap)
            first = next((k for k in range(len(held)) if self._measure(held[k]) is not None), None)
            return None, first
        below = None
        for k in range(i + 1, len(held)):
            est = self._measure(held[k])
            if est is None:
                continue
            if est.known and est.percent >= rth:
                i = k
                continue
            below = k
            break
        return i, below

    def _posed_keyframe(self, last_above: int | None) -> int | None:
        """The held frame to make the keyframe instead of ``last_above`` when that one has no pose (a telemetry
        gap) in a flight that has poses: the nearest earlier held frame with a pose whose measured R is >= Rth too
        (more overlap with the keyframe before, so the target still holds; the next keyframe is judged against it).
        None found: ``last_above`` as before (the stitcher places a keyframe without a pose by its images)."""
        held, rth = self._held, self.gate.rth_percent
        if last_above is None or not self._seen_pose or _posed(held[last_above]):
            return last_above
        for k in range(last_above - 1, -1, -1):
            if not _posed(held[k]):
                continue
            est = self._measure(held[k])
            if est is not None and est.known and est.percent >= rth:
                return k
        return last_above

    # -- measuring -----------------------------------------------------------------------------------------
    def _masked_frame(self, tagged: TaggedFrame) -> MaskedFrame | None:
        index = tagged.frame.index
        if index not in self._masked:
            self._masked[index] = self.mask(tagged)
            self._measured += 1
        return self._masked[index]

    def _measure(self, tagged: TaggedFrame) -> OverlapEstimate | None:
        """R(keyframe, frame) measured by the gate (None: no facade, or too few features to compare)."""
        masked = self._masked_frame(tagged)
        if masked is None:
            return None
        est = self.gate.measure(masked)
        if est is not None and est.dx is not None and est.source == OverlapSource.IMAGE:
            self.tracker.correct(tagged.frame.index, est.dx, est.dy)
        return est

    def _push(self, tagged: TaggedFrame) -> list[Keyframe]:
        masked = self._masked_frame(tagged)
        if masked is None:
            return []
        out = self.gate.push(masked)
        self.tracker.set_mask(masked.mask)
        for kf in out:
            self._follow_keyframe(kf)
        self._reseat(masked)
        return out

    def _measure_and_push(self, tagged: TaggedFrame) -> list[Keyframe]:
        self._prev = tagged
        out = self._push(tagged)
        self._masked.pop(tagged.frame.index, None)
        return out

    def _follow_keyframe(self, kf: Keyframe) -> None:
        """The gate made a keyframe: the tracker's anchor moves there (it was tracked, or it is anchored anew)."""
        tagged = TaggedFrame(kf.frame, kf.pose, kf.pose_stale)
        self._anchor_tagged = tagged
        self._anchor_motion = None
        if not self.tracker.reanchor(kf.index):
            self.tracker.anchor(kf.index, kf.image, kf.mask)
            self._prev = tagged

    def _reseat(self, masked: MaskedFrame) -> None:
        """After a push: the frame's measured shift from the (possibly new) keyframe re-seats the tracker."""
        step = self.gate.last_step
        index = masked.index
        if step is None or not step.comparisons:
            return
        last = step.comparisons[-1].estimate
        if step.comparisons[-1].frame_index != index or self.gate.keyframe_index != step.comparisons[-1].ref_index:
            return
        if last.dx is not None and last.source == OverlapSource.IMAGE:
            if self.tracker.predicted(index) is None:
                self.tracker.anchor(index, masked.image, masked.mask,
                                    keyframe_index=self.gate.keyframe_index, offset=(last.dx, last.dy))
                self._prev = masked.tagged
            else:
                self.tracker.correct(index, last.dx, last.dy)

    def _anchor_prior(self, tagged: TaggedFrame, width: int, height: int) -> WallMotion | None:
        """The telemetry's wall motion from the keyframe to this frame, computed once per frame (``skips`` asks
        for it before ``offer`` does)."""
        known = self._anchor_motion
        if known is not None and known[0] == tagged.index and known[1] is not None and known[2] == (width, height):
            return known[1]
        motion = self._motion(self._anchor_tagged, tagged, (width, height))
        self._anchor_motion = (tagged.index, motion, (width, height))
        return motion

    def _motion(self, a: TaggedFrame | None, b: TaggedFrame, size: tuple[int, int] | None = None, *,
                overlap: bool = True) -> WallMotion | None:
        if self.predictor is None or a is None or a.pose_stale or b.pose_stale:
            return None
        w, h = size or b.frame.image.shape[1::-1]
        return self.predictor.predict(a.pose, b.pose, w, h, overlap=overlap)


def _posed(tagged: TaggedFrame) -> bool:
    return tagged.pose is not None and not tagged.pose_stale
