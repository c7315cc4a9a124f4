"""The onboard chain's frames still awaiting a decision, in one place: which may still become keyframes, their
full-resolution copies, and the order keyframes may leave for the spool.

Why: a frame may wait for a keyframe decision in four places at once. The tracked selection holds the frames near
Rth until its search runs (``TrackedSelection``), the gate holds its candidate (``KeyframeGate``), a keyframe the
network alone masked waits for a later frame's parallax (``LaterReference``, issue 15), and the chain keeps each
such frame's full-resolution copy, because it decides on working copies (``FullResolution``). A frame skipped far
above Rth is kept undecoded in case it is the wall's last view. Each hold answers for itself; what the chain needs
is the sum of them: the oldest frame any of them may still spool (every full-resolution copy before it can go, which
is what bounds the chain's memory), and which decided keyframes may be spooled now without overtaking one that
waits. ``PendingFrames`` asks the holds (each says ``held_indices``), owns the copies, the later-reference hold and
the skipped frame, and answers both questions; the chain only tells it what happened.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Protocol

from companion.depth.masker import Masker
from companion.depth.parallax import ParallaxResult
from companion.depth.parallax_first import LaterReference, Resolved
from companion.onboard.working import FullResolution
from companion.records import EncodedFrame, Frame, Keyframe, MaskedFrame, TaggedFrame


class Hold(Protocol):
    """A stage that keeps frames between calls that may still become keyframes."""

    def held_indices(self) -> list[int]: ...


@dataclass(frozen=True)
class LaterVerdict:
    """A held keyframe masked again against a later frame: ``background`` True when that parallax found only
    background (it is not spooled)."""

    index: int
    later_index: int
    background: bool


@dataclass(frozen=True)
class SpoolOrder:
    """The keyframes that may be spooled now, in capture order, and the verdicts later frames gave on the way."""

    keyframes: tuple[Keyframe, ...]
    judged_later: tuple[LaterVerdict, ...] = ()


@dataclass(frozen=True)
class SkippedFrame:
    """A frame skipped far above Rth, as it came (maybe still encoded), with its tags: decoded and offered only if
    the segment ends on it."""

    frame: Frame | EncodedFrame
    tagged: TaggedFrame


class PendingFrames:
    """Every frame the chain may still spool. ``holds``: the stages that hold frames for their own decisions (the
    tracked selection, the gate); ``masker``: with parallax, a keyframe the network alone masked is held here for a
    later frame (None: spooled as decided)."""

    def __init__(self, holds: Sequence[Hold], masker: Masker | None = None):
        self._later = None if masker is None or masker.parallax is None else LaterReference(masker)
        self._holds: tuple[Hold, ...] = (*holds, *([] if self._later is None else [self._later]))
        self._full = FullResolution()
        # frames a later frame should judge before they are spooled: None, masked by the network alone for want of
        # a reference; else the answer of their parallax against an earlier frame, whose untrusted pixels a later
        # frame judges (beyond the 4 m standoff, ``ParallaxParams.telemetry_both_sides``)
        self._for_later: dict[int, ParallaxResult | None] = {}
        self._skipped: SkippedFrame | None = None

    @property
    def full_resolution_held(self) -> int:
        """Full-resolution frames kept because they may still become keyframes (the chain decides on copies)."""
        return len(self._full)

    # -- what the chain tells it -------------------------------------------------------------------------------
    def keep(self, full: Frame | EncodedFrame, working: Frame) -> None:
        """A frame about to be offered, decided on ``working``: its full-resolution copy is kept until decided."""
        self._full.keep(full, working)

    def mark_alone(self, index: int) -> None:
        """The network alone masked this frame (no reference before it): if it becomes a keyframe, a later frame's
        parallax judges it before it is spooled."""
        self._for_later[index] = None

    def mark_one_sided(self, index: int, earlier: ParallaxResult) -> None:
        """This frame was judged against an earlier frame only, which left pixels untrusted (the strip that entered
        the view since): if it becomes a keyframe, a later frame's parallax judges those before it is spooled."""
        self._for_later[index] = earlier

    def skip(self, frame: Frame | EncodedFrame, tagged: TaggedFrame) -> None:
        """The newest frame was skipped far above Rth: kept as it came, the segment may end on it."""
        self._skipped = SkippedFrame(frame, tagged)

    def forget_skipped(self) -> None:
        """A frame after the skipped one was offered: the skipped one is no longer the wall's last view."""
        self._skipped = None

    def take_skipped(self) -> SkippedFrame | None:
        """The segment ends: the frame skipped last, if the segment ended on one (it is not kept any longer)."""
        skipped, self._skipped = self._skipped, None
        return skipped

    # -- what it answers ---------------------------------------------------------------------------------------
    def oldest_undecided(self, newest: int) -> int:
        """The oldest frame that may still become a keyframe: held by a stage for a decision, or ``newest``."""
        return min([newest, *(index for hold in self._holds for index in hold.held_indices())])

    def release_decided(self, newest: int | None) -> None:
        """Let go of every frame older than the oldest undecided one (``newest``: the newest frame that may still
        become a keyframe; None: all, nothing is undecided any more)."""
        oldest = None if newest is None else self.oldest_undecided(newest)
        self._full.release_below(oldest)
        self._for_later = {} if oldest is None else {i: e for i, e in self._for_later.items() if i >= oldest}

    def restore(self, kf: Keyframe) -> Keyframe:
        """The keyframe as spooled: its full-resolution image, mask and pixel displacements."""
        return self._full.restore(kf)

    def spool_order(self, keyframes: list[Keyframe], later: TaggedFrame | None) -> SpoolOrder:
        """The keyframes to spool now, in capture order (issue 15: the first keyframe of a scan judged by the
        parallax of the frames after it).

        A keyframe the network alone masked (no frame far enough back: the scan's first, the first after the scan
        was left) is held until a later frame lies far enough along the baseline, then masked again against it with
        the parallax rules every other frame gets (``companion.depth.parallax_first``) and spooled. ``later``: this
        frame, which may resolve a held keyframe; None when no later frame will come (end of stream or of the scan
        segment), so a held keyframe is spooled now with the network's mask. A newer keyframe never overtakes a held
        one: it is released first (network mask), so the spool stays in capture order. A keyframe judged against an
        earlier frame only beyond the 4 m standoff (``mark_one_sided``) is held the same way; the later frame judges
        the pixels that flow could not trust, and released unjudged it keeps the mask it has."""
        if self._later is None:
            return SpoolOrder(tuple(keyframes))
        verdicts: list[LaterVerdict] = []
        resolved = [] if later is None else self._later.offer(later)
        if keyframes or later is None:
            resolved += self._later.release()
        ready = [kf for kf in (_settled(r, verdicts) for r in resolved) if kf is not None]
        for n, kf in enumerate(keyframes):
            if later is not None and n == len(keyframes) - 1 and kf.index in self._for_later:
                tagged = TaggedFrame(kf.frame, kf.pose, kf.pose_stale)
                self._later.hold(tagged, MaskedFrame(tagged, kf.mask), kf, self._for_later[kf.index])
                ready += [k for k in (_settled(r, verdicts) for r in self._later.offer(later)) if k is not None]
            else:
                ready.append(kf)
        return SpoolOrder(tuple(ready), tuple(verdicts))


def _settled(resolved: Resolved, verdicts: list[LaterVerdict]) -> Keyframe | None:
    """A held keyframe with the mask a later frame's parallax gave it (None: all background by that parallax, not
    spooled), or as it was when no later frame could judge it; a judged one's verdict is added to ``verdicts``."""
    kf = resolved.item
    judgement = resolved.judgement
    if judgement is None:
        return kf
    background = judgement.masked is None
    verdicts.append(LaterVerdict(kf.index, judgement.later_index, background))
    return None if background else replace(kf, mask=judgement.masked.mask)
