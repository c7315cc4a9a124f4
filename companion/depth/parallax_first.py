"""A frame the network alone had to judge, judged again by the parallax against a LATER frame (issue 15).

Why: the masker's parallax compares a frame with one 8-60 cm back along the telemetry's baseline. The first frame
of a pass or of a strip has none (nothing before it, or the previous frame is a strip away), so the network alone
decides its mask, and on real walls the shipped model reads the top of the wall farther than the background behind
it: that frame's mask cuts the wall top, and as the only keyframe that sees the strip's start, what it cuts is a hole
in the map (bench/mask_wall_coverage.py: most of the uncovered wall). Giving the cut back blindly keeps the
background beside the wall's start with it (``ParallaxParams.unjudged_far_cut_ratio``, off).

Motion parallax does not care which of the two frames came first: the flow of frame k against frame k+j, with the
translation between them from the telemetry, measures the same depths as against k-j. So such a frame is held until
a later frame lies far enough along the baseline, then masked again by a masker whose only reference is that later
frame: the same ``Masker`` and the same parallax rules every other frame gets (no copy of them here), so trusted near
pixels keep the wall top, trusted far ones cut the background, and a frame whose trusted pixels are all far is
dropped as any other. The onboard chain holds the keyframe for this before spooling it (``onboard/chain.py``);
the benches hold every frame in the same way (``bench/stitch_photo_passes.py``, ``bench/mask_wall_coverage.py``).
A frame no later frame reaches (the stream or the segment ends first, or the next frame is already beyond
``max_baseline_m``) keeps the network's mask.

The same hold gives a second look to a frame judged against an EARLIER frame only, beyond the 4 m standoff
(issue 27 item 4, ``ParallaxParams.telemetry_both_sides``): stills metres apart bring a strip of new wall into view
at the frame's leading side (a quarter of the frame at 5 m spacing 13 m out), which the earlier frame does not show,
so its flow trusts nothing there and the network decided it (and cut 20-25 % of such keyframes on a real-texture
validation pass). The later frame shows that strip; its parallax decides the pixels the earlier flow could not
trust (``parallax.fill_untrusted``, as ``companion mask --sequence`` does with both neighbours) and the mask there
(``parallax.second_look_in_strip``); the rest of the frame keeps the earlier answer's mask. Released as above: a
frame no later frame reaches keeps its first mask.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from companion.depth.masker import Masker
from companion.depth.parallax import ParallaxResult, SequenceParallax, with_second_reference
from companion.records import MaskedFrame, Pose, TaggedFrame


class Baseline(StrEnum):
    """How far a later frame lies from a held one, against the parallax's baseline limits."""

    SHORT = "short"  # closer than ``min_baseline_m``: wait for a later one
    USABLE = "usable"
    TOO_FAR = "too_far"  # beyond ``max_baseline_m``: the flow cannot track it, and later frames lie farther


def reference_mark(masker: Masker) -> tuple[int, int, int]:
    """The masker's counters that :func:`judged_alone` compares: frames, judged by parallax, skipped as sure."""
    st = masker.stats
    return st.frames, st.parallax_frames, st.parallax_skipped_sure


def judged_alone(masker: Masker, mark: tuple[int, int, int], tagged: TaggedFrame) -> bool:
    """Whether the one frame masked since ``mark`` (:func:`reference_mark`) was decided by the network alone for
    want of a reference frame: the masker has parallax, the frame a fresh pose, and the masker neither judged it by
    parallax nor skipped the flow because the network was sure of it (``MaskerStats``)."""
    frames, by_parallax, sure = reference_mark(masker)
    return (masker.parallax is not None and tagged.pose is not None and not tagged.pose_stale
            and frames == mark[0] + 1 and by_parallax == mark[1] and sure == mark[2])


@dataclass(frozen=True)
class FirstLook:
    """A frame masked in capture order, and what a later frame should still judge of it: everything (``alone``: the
    network alone decided it for want of a reference) or the pixels the flow against an earlier frame could not
    trust (``earlier``: that answer, beyond the 4 m standoff, ``ParallaxParams.telemetry_both_sides``)."""

    masked: MaskedFrame | None
    alone: bool
    earlier: ParallaxResult | None = None


def first_look(masker: Masker, tagged: TaggedFrame) -> FirstLook:
    """``masker(tagged)`` and what a later frame should still judge of it (:class:`FirstLook`)."""
    mark = reference_mark(masker)
    masked = masker(tagged)
    alone = judged_alone(masker, mark, tagged)
    earlier = None
    seq = masker.parallax
    if masked is not None and not alone and seq is not None and reference_mark(masker)[1] == mark[1] + 1 \
            and seq.last_wants_later and seq.last_answer is not None:
        earlier = seq.last_answer
    return FirstLook(masked, alone, earlier)


def baseline_between(masker: Masker, held: Pose, later: Pose) -> Baseline:
    """Where ``later`` lies from ``held`` against the masker's parallax limits (distance of the camera centres)."""
    import pymap3d

    low, high = masker.parallax.baseline_window()
    d = float(np.linalg.norm(pymap3d.geodetic2enu(later.lat, later.lon, later.alt_amsl_m,
                                                  held.lat, held.lon, held.alt_amsl_m)))
    if d < low:
        return Baseline.SHORT
    return Baseline.USABLE if d <= high else Baseline.TOO_FAR


class _LaterOnly(SequenceParallax):
    """A SequenceParallax whose one reference is a later frame (its answer kept in ``last_answer`` for whoever asks
    why). With ``earlier`` (the frame's answer against an earlier frame) its answer is that one, the pixels it could
    not trust decided by the later frame (:func:`with_second_reference`)."""

    earlier: ParallaxResult | None = None

    def update(self, image: np.ndarray, pose) -> ParallaxResult | None:
        later = super().update(image, pose)
        if self.earlier is not None:
            self.last_answer = self.earlier if later is None else with_second_reference(self.earlier, later)
        return self.last_answer


@dataclass(frozen=True)
class LaterJudgement:
    """A held frame masked again against a later frame: the mask (None: parallax found only background, the frame is
    dropped as any other would be) and the parallax answer behind it (None: the flow gave none, network alone)."""

    masked: MaskedFrame | None
    parallax: ParallaxResult | None
    later_index: int


def judge_with_later(masker: Masker, tagged: TaggedFrame, later: TaggedFrame,
                     earlier: ParallaxResult | None = None) -> LaterJudgement:
    """Mask ``tagged`` again with ``later`` as its only parallax reference (same model, ROI rules and parallax rules
    as ``masker``; its own state untouched). Costs one network run and the two flows of any judged frame.
    ``earlier``: the frame's answer against an earlier frame (:class:`FirstLook`); ``later`` then judges only the
    pixels that one could not trust. The masker's wall bound, if any, cuts the new mask as it cut the first."""
    seq = masker.parallax
    reference = _LaterOnly(seq.hfov_deg, seq.params, keep=1, standoff_m=seq.standoff_m)
    reference.earlier = earlier
    reference.remember(later.frame.image, later.pose)
    judge = Masker(session=masker.session, params=masker.params, max_roi_depth_m=None, parallax=reference,
                   bound=masker.bound)
    return LaterJudgement(judge(tagged), reference.last_answer, later.frame.index)


@dataclass(frozen=True)
class Resolved:
    """A held frame's outcome: ``judgement`` None when no later frame could judge it (the network's mask stands)."""

    tagged: TaggedFrame
    network: MaskedFrame | None  # the mask it was held with (the network's; or its earlier parallax's, FirstLook)
    item: object  # what the caller held with it (the chain: the keyframe)
    judgement: LaterJudgement | None

    @property
    def masked(self) -> MaskedFrame | None:
        return self.network if self.judgement is None else self.judgement.masked


class LaterReference:
    """Frames waiting for a later frame to judge them, in capture order: ``hold`` one the masker could not judge,
    ``offer`` every later frame (each resolves the held frames it lies far enough from, or too far from), and
    ``release`` what still waits when no later frame will come (end of stream or of a scan segment)."""

    def __init__(self, masker: Masker):
        if masker.parallax is None:
            raise ValueError("a masker without parallax has no later reference to use")
        self.masker = masker
        self._held: list[tuple[TaggedFrame, MaskedFrame | None, object, ParallaxResult | None]] = []
        self.judged = 0  # held frames masked against a later frame
        self.unjudged = 0  # held frames that kept the network's mask (no later frame in reach)

    def held_indices(self) -> list[int]:
        return [t.frame.index for t, _, _, _ in self._held]

    def hold(self, tagged: TaggedFrame, network: MaskedFrame | None, item: object = None,
             earlier: ParallaxResult | None = None) -> None:
        """Hold a frame for a later one: ``network`` the mask it has now, ``earlier`` its answer against an earlier
        frame when it had one (then the later frame judges only what that could not trust, :class:`FirstLook`)."""
        self._held.append((tagged, network, item, earlier))

    def offer(self, later: TaggedFrame) -> list[Resolved]:
        """Resolve, in capture order, the held frames ``later`` judges (or lies beyond reach of); stops at the first
        one it is still too close to, so outcomes come out in the order the frames were held."""
        out: list[Resolved] = []
        if later.pose is None or later.pose_stale:
            return out
        while self._held:
            tagged, network, item, earlier = self._held[0]
            if later.frame.index <= tagged.frame.index:
                break
            reach = baseline_between(self.masker, tagged.pose, later.pose)
            if reach == Baseline.SHORT:
                break
            self._held.pop(0)
            judgement = judge_with_later(self.masker, tagged, later, earlier) if reach == Baseline.USABLE else None
            self.judged += judgement is not None
            self.unjudged += judgement is None
            out.append(Resolved(tagged, network, item, judgement))
        return out

    def release(self) -> list[Resolved]:
        """Every held frame with the network's mask (no later frame will come)."""
        out = [Resolved(t, n, item, None) for t, n, item, _ in self._held]
        self.unjudged += len(out)
        self._held = []
        return out
