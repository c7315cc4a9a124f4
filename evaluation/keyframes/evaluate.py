"""The gate measured against simulator truth: R error, keyframe-pair overlap, keyframe count vs the minimum.

Reads a recording through a duck-typed interface (``len``, ``image(i)``, ``roi_mask(i)``, ``capture_time(i)``,
``true_overlap(i, j)``, ``width``, ``height``; ``camera_pose(i)`` for telemetry), so this module does not import
the simulator.
"""

from __future__ import annotations

import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from companion.errors import CompanionError
from companion.keyframes.gate import GateConfig, KeyframeGate
from companion.keyframes.motion import WallMotionPredictor
from companion.records import MaskedFrame, Pose, TaggedFrame
from evaluation.keyframes.synthetic import masked_frame


@dataclass
class PairError:
    p: int
    q: int
    R_est: float  # percent, the gate's estimator
    R_true: float  # percent, simulator footprint overlap
    R_displacement: float | None
    R_polygon: float | None


@dataclass
class GateEvaluation:
    frames: int
    rth: float  # fraction
    method: str
    keyframes: list[int]
    gaps: list[int]
    pairs: list[PairError]  # every R the gate computed that was known
    unknown: int  # comparisons that came back unknown
    keyframe_pair_truth: list[float]  # true overlap (percent) of consecutive keyframes
    minimum_keyframes: list[int]  # fewest keyframes from truth with every consecutive pair >= Rth
    warnings: int
    gate_seconds: float  # time inside push/flush only (no disk reads)
    curve: list[tuple[int, float | None, float]] = field(default_factory=list)  # (q, R_est, R_true) for one p
    curve_p: int = 0
    sources: dict[str, int] = field(default_factory=dict)  # comparisons by where R came from (image / telemetry)
    telemetry: bool = False  # the gate had poses and a wall-motion predictor

    @staticmethod
    def _abs_err(values: list[float | None], truth: list[float]) -> np.ndarray:
        return np.array([abs(v - t) for v, t in zip(values, truth, strict=True) if v is not None])

    def error_stats(self, which: str = "est") -> tuple[float, float, int]:
        """(median, p95, n) of |R - R_true| in percentage points for 'est', 'displacement' or 'polygon'."""
        vals = {
            "est": [e.R_est for e in self.pairs],
            "displacement": [e.R_displacement for e in self.pairs],
            "polygon": [e.R_polygon for e in self.pairs],
        }[which]
        err = self._abs_err(vals, [e.R_true for e in self.pairs])
        if err.size == 0:
            return float("nan"), float("nan"), 0
        return float(np.median(err)), float(np.percentile(err, 95)), int(err.size)

    @property
    def excess_keyframes_pct(self) -> float:
        return 100.0 * (len(self.keyframes) / max(1, len(self.minimum_keyframes)) - 1.0)

    @property
    def fps(self) -> float:
        return self.frames / self.gate_seconds if self.gate_seconds > 0 else float("nan")


def minimum_keyframes(n: int, overlap, rth: float, patience: int = 90) -> list[int]:
    """Fewest frames from 0 to n-1 with overlap(a, b) >= rth between consecutive ones (BFS over the frame DAG).

    ``overlap(i, j)`` is the true overlap fraction. From each frame the scan forward stops after ``patience``
    frames in a row below ``rth`` (far-apart frames of the same pass do not overlap again). If some frame cannot
    be reached the path is continued from the furthest reachable frame (the gap counts as one extra keyframe).
    """
    if n <= 0:
        return []
    prev = {0: None}
    queue = deque([0])
    while queue and (n - 1) not in prev:
        i = queue.popleft()
        below = 0
        for j in range(i + 1, n):
            if overlap(i, j) >= rth:
                below = 0
                if j not in prev:
                    prev[j] = i
                    queue.append(j)
            else:
                below += 1
                if below >= patience:
                    break
        if not queue and (n - 1) not in prev:  # unreachable: restart after the furthest reached frame
            far = max(prev)
            if far + 1 < n:
                prev[far + 1] = far
                queue.append(far + 1)
    path, k = [], n - 1
    while k is not None:
        path.append(k)
        k = prev[k]
    return path[::-1]


@dataclass(frozen=True)
class PoseNoise:
    """GNSS/IMU-like telemetry error for evaluations: a constant bias (facade axes along, out, up, metres; yaw
    degrees), which cancels in relative motion, plus independent per-frame noise (metres, degrees)."""

    bias_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    bias_yaw_deg: float = 0.0
    sigma_m: float = 0.0
    sigma_deg: float = 0.0
    seed: int = 0

    @property
    def exact(self) -> bool:
        return self.bias_m == (0.0, 0.0, 0.0) and self.bias_yaw_deg == 0.0 and self.sigma_m == 0.0 \
            and self.sigma_deg == 0.0


def telemetry_poses(recording, frame, noise: PoseNoise | None = None) -> Callable[[int], Pose]:
    """``pose(i)``: the telemetry pose of recording frame i (its true camera pose, optionally with ``noise``).

    ``frame`` is the recording's FacadeFrame; the camera is a stabilised gimbal (pitch -> gimbal_pitch_deg)."""
    noise = noise or PoseNoise()
    rng = np.random.default_rng(noise.seed)
    draws: dict[int, np.ndarray] = {}

    def pose(i: int) -> Pose:
        tp = recording.camera_pose(i)
        if i not in draws:
            draws[i] = rng.normal(0.0, 1.0, 5)
        d = draws[i]
        along, out, up = (float(v) for v in frame.geodetic_to_facade(tp.lat, tp.lon, tp.alt_amsl_m))
        along += noise.bias_m[0] + noise.sigma_m * d[0]
        out += noise.bias_m[1] + noise.sigma_m * d[1]
        up += noise.bias_m[2] + noise.sigma_m * d[2]
        lat, lon, alt = (float(v) for v in frame.facade_to_geodetic(along, out, up))
        yaw = (float(tp.yaw_deg) + noise.bias_yaw_deg + noise.sigma_deg * d[3]) % 360.0
        pitch = float(tp.pitch_deg) + noise.sigma_deg * d[4]
        return Pose(recording.capture_time(i), lat, lon, alt, up, 0.0, 0.0, yaw, gimbal_pitch_deg=pitch)

    return pose


@dataclass
class _GateTally:
    """What the gate did over a recording, accumulated frame by frame: keyframes, gaps, every known R beside
    its truth, unknown comparisons, overlap warnings, where each R came from, and the time spent in the gate."""

    keys: list[int] = field(default_factory=list)
    gaps: list[int] = field(default_factory=list)
    pairs: list[PairError] = field(default_factory=list)
    sources: Counter = field(default_factory=Counter)
    unknown: int = 0
    warnings: int = 0
    spent_s: float = 0.0

    def count_step(self, step, recording) -> None:
        """Every comparison of one gate step scored against the recording's true overlap."""
        for c in step.comparisons:
            e = c.estimate
            self.sources[e.source if e.known else "unknown"] += 1
            if e.known:
                truth = 100.0 * recording.true_overlap(c.ref_index, c.frame_index)
                pair = PairError(c.ref_index, c.frame_index, e.percent, truth, e.R_displacement, e.R_polygon)
                self.pairs.append(pair)
            else:
                self.unknown += 1
        self.warnings += int(step.overlap_warning)

    def timed(self, call, *args):
        """``call(*args)``'s result, its duration added to the gate time."""
        t0 = time.perf_counter()
        out = call(*args)
        self.spent_s += time.perf_counter() - t0
        return out


def _gate_input(
    recording,
    i: int,
    use_masks: bool,
    pose: Callable[[int], Pose | None] | None,
    mask_of: Callable[[int], np.ndarray | None] | None,
) -> MaskedFrame | None:
    """Frame ``i`` as the gate sees it: its mask (``mask_of``'s, the recording's truth, or none) and pose; None
    when ``mask_of`` finds no ROI (the onboard chain drops such a frame)."""
    if mask_of is not None:
        mask = mask_of(i)
        if mask is None:
            return None
    else:
        mask = recording.roi_mask(i) if use_masks else None
    mf = masked_frame(i, recording.image(i), mask, t_s=recording.capture_time(i))
    if pose is not None:
        mf = MaskedFrame(TaggedFrame(mf.frame, pose(i)), mf.mask)
    return mf


def _run_gate(gate: KeyframeGate, recording, frames: Callable[[int], MaskedFrame | None]) -> _GateTally:
    """Pushes every frame of ``recording`` through ``gate`` in order, then flushes it."""
    tally = _GateTally()
    for i in range(len(recording)):
        mf = frames(i)
        if mf is None:
            continue
        out = tally.timed(gate.push, mf)
        tally.count_step(gate.last_step, recording)
        for k in out:
            tally.keys.append(k.index)
            if k.gap_before:
                tally.gaps.append(tally.keys[-1])
    tally.keys += [k.index for k in tally.timed(gate.flush)]
    return tally


def evaluate_gate(
    recording,
    config: GateConfig | None = None,
    *,
    use_masks: bool = True,
    curve_p: int = 0,
    curve_floor: float = 50.0,
    predictor: WallMotionPredictor | None = None,
    pose: Callable[[int], Pose | None] | None = None,
    mask_of: Callable[[int], np.ndarray | None] | None = None,
) -> GateEvaluation:
    """Runs the gate over every frame of ``recording`` and compares what it computed with the truth.

    ``predictor`` and ``pose`` give the gate telemetry (see ``telemetry_poses``); without them it decides on the
    images alone. ``mask_of(i)`` replaces the recording's truth ROI mask (e.g. the depth model's; None: no ROI,
    the frame is dropped as the onboard chain does)."""
    n = len(recording)
    if n < 2:
        raise CompanionError(f"the recording has {n} frame(s)", "evaluate a recording with at least 2 frames")
    cfg = config or GateConfig()
    gate = KeyframeGate(cfg, predictor=predictor if pose is not None else None)
    tally = _run_gate(gate, recording, lambda i: _gate_input(recording, i, use_masks, pose, mask_of))
    keys = tally.keys
    return GateEvaluation(
        frames=n,
        rth=cfg.rth,
        method=cfg.overlap.method,
        keyframes=keys,
        gaps=tally.gaps,
        pairs=tally.pairs,
        unknown=tally.unknown,
        keyframe_pair_truth=[100.0 * recording.true_overlap(a, b) for a, b in zip(keys, keys[1:], strict=False)],
        minimum_keyframes=minimum_keyframes(n, recording.true_overlap, cfg.rth),
        warnings=tally.warnings,
        gate_seconds=tally.spent_s,
        curve=overlap_curve(recording, cfg, curve_p, use_masks=use_masks, floor=curve_floor),
        curve_p=curve_p,
        sources=dict(tally.sources),
        telemetry=gate.predictor is not None,
    )


def overlap_curve(recording, config: GateConfig, p: int, *, use_masks: bool = True, floor: float = 50.0):
    """R(Ip, Iq) and the true overlap for q = p, p+1, ... until the truth falls below ``floor`` percent (Fig. 9)."""
    from companion.keyframes.features import FeatureExtractor
    from companion.keyframes.overlap import OverlapEstimator

    ex, est = FeatureExtractor(config.features), OverlapEstimator(config.overlap)
    fp = ex.extract(recording.image(p), recording.roi_mask(p) if use_masks else None)
    out = []
    for q in range(p, len(recording)):
        truth = 100.0 * recording.true_overlap(p, q)
        if truth < floor:
            break
        fq = ex.extract(recording.image(q), recording.roi_mask(q) if use_masks else None)
        out.append((q, est.estimate(fp, fq).percent, truth))
    return out


def format_report(ev: GateEvaluation) -> str:
    med, p95, n = ev.error_stats("est")
    dmed, dp95, _ = ev.error_stats("displacement")
    pmed, pp95, _ = ev.error_stats("polygon")
    rth_pts = 100.0 * ev.rth
    kp = ev.keyframe_pair_truth
    worst = min(kp) if kp else float("nan")
    below = sum(v < rth_pts - 3.0 for v in kp)
    lines = [
        f"frames {ev.frames}, keyframes {len(ev.keyframes)} (raw/keyframe {ev.frames / max(1, len(ev.keyframes)):.2f}),"
        f" Rth {rth_pts:.0f} %, method {ev.method}",
        f"R error vs truth over {n} gate comparisons: median {med:.2f} pts, p95 {p95:.2f} pts"
        f" (target median <= 2); unknown {ev.unknown}",
        f"  displacement (Eq. 2): median {dmed:.2f} p95 {dp95:.2f} pts; polygon: median {pmed:.2f} p95 {pp95:.2f} pts",
        f"consecutive keyframe true overlap: min {worst:.1f} %, {below} of {len(kp)} pairs below Rth - 3 pts"
        f" (target 0)",
        f"keyframes {len(ev.keyframes)} vs minimum possible {len(ev.minimum_keyframes)} at Rth from truth:"
        f" {ev.excess_keyframes_pct:+.1f} % (target <= +10 %)",
        f"gaps {len(ev.gaps)}, overlap warnings {ev.warnings}; gate time {ev.gate_seconds:.1f} s"
        f" = {ev.fps:.2f} frames/s",
        f"telemetry {'on' if ev.telemetry else 'off'}; comparisons by source of R: "
        + ", ".join(f"{k} {v}" for k, v in sorted(ev.sources.items())),
        f"keyframe indices: {ev.keyframes}",
    ]
    return "\n".join(lines)


def format_table(rows: list[tuple[str, str, GateEvaluation]], rth: float) -> str:
    """One markdown row per (mask, gate, evaluation): the side-by-side figures of bench/gate_*.py."""
    rth_pts = 100.0 * rth
    lines = [
        f"| mask | gate | raw -> keyframes | minimum at Rth | excess | keyframe pairs: min true overlap | "
        f"pairs < {rth_pts - 3:.0f} % | R error median / p95 (pts) | unknown R / gaps | R from telemetry "
        f"(fallback / veto) | gate s |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for mask, gate, ev in rows:
        kp = ev.keyframe_pair_truth
        med, p95, _ = ev.error_stats("est")
        src = ev.sources
        lines.append(
            f"| {mask} | {gate} | {ev.frames} -> {len(ev.keyframes)} | {len(ev.minimum_keyframes)} | "
            f"{ev.excess_keyframes_pct:+.1f} % | {min(kp) if kp else float('nan'):.1f} % | "
            f"{sum(v < rth_pts - 3.0 for v in kp)} of {len(kp)} | {med:.2f} / {p95:.2f} | "
            f"{ev.unknown} / {len(ev.gaps)} | {src.get('telemetry', 0)} / {src.get('telemetry_veto', 0)} | "
            f"{ev.gate_seconds:.0f} |"
        )
    return "\n".join(lines)


def plot_curve(ev: GateEvaluation, path) -> None:
    """R against q for one p (paper Figure 9): estimate, truth and the threshold."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not ev.curve:
        raise CompanionError("no R-vs-q curve was computed", "run evaluate_gate with a recording of >= 2 frames")
    q = [c[0] for c in ev.curve]
    est = [np.nan if c[1] is None else c[1] for c in ev.curve]
    truth = [c[2] for c in ev.curve]
    fig, ax = plt.subplots(figsize=(6.4, 3.6), dpi=120)
    ax.plot(q, truth, "-", color="0.5", label="true overlap (simulator)")
    ax.plot(q, est, "o", ms=4, label=f"R estimated ({ev.method})")
    ax.axhline(100 * ev.rth, color="r", ls="--", lw=1, label=f"Rth = {100 * ev.rth:.0f} %")
    chosen = [k for k in ev.keyframes if q[0] < k <= q[-1]]
    if chosen:
        ax.axvline(chosen[0], color="g", lw=1, label=f"next keyframe I{chosen[0]}")
    ax.set_xlabel(f"q (frame index), p = {ev.curve_p}")
    ax.set_ylabel("R(Ip, Iq) [%]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
