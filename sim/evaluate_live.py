"""Ground-truth checks of a live-culled spool: tagging error against the vehicle's true pose, and the true
overlap of consecutive keyframes from the camera recording's geometry. Used by tests and bench/ alike."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pymap3d

from companion.files import read_jsonl
from sim.camera.recording import load_recording


class TruthTrack:
    """The vehicle's true pose over time (``python -m sim vehicle --truth-log``), interpolated."""

    def __init__(self, truth_log: Path):
        self.rows = read_jsonl(truth_log)
        self.t = np.array([r["t_s"] for r in self.rows])

    def at(self, t: float) -> tuple[float, float, float, float, float, float]:
        k = int(np.searchsorted(self.t, t))
        a, b = self.rows[max(k - 1, 0)], self.rows[min(k, len(self.rows) - 1)]
        s = 0.0 if b["t_s"] == a["t_s"] else min(1.0, max(0.0, (t - a["t_s"]) / (b["t_s"] - a["t_s"])))

        def lerp(key: str) -> float:
            return a[key] + s * (b[key] - a[key])

        yaw = a["yaw_deg"] + s * ((b["yaw_deg"] - a["yaw_deg"] + 180.0) % 360.0 - 180.0)
        return lerp("lat"), lerp("lon"), lerp("alt_amsl_m"), lerp("roll_deg"), lerp("pitch_deg"), yaw


@dataclass(frozen=True)
class TagError:
    index: int
    position_m: float
    attitude_deg: float  # worst of roll, pitch, yaw


def tagging_errors(manifest: list[dict], truth: TruthTrack) -> list[TagError]:
    """Per keyframe with a pose: distance and worst attitude difference to the truth at its capture time."""
    out = []
    for kf in manifest:
        pose = kf.get("pose")
        if pose is None:
            continue
        lat, lon, alt, roll, pitch, yaw = truth.at(kf["capture_time_s"])
        e, n, u = pymap3d.geodetic2enu(pose["lat"], pose["lon"], pose["alt_amsl_m"], lat, lon, alt)
        dyaw = abs((pose["yaw_deg"] - yaw + 180.0) % 360.0 - 180.0)
        att = max(dyaw, abs(pose["roll_deg"] - roll), abs(pose["pitch_deg"] - pitch))
        out.append(TagError(kf["index"], math.sqrt(e * e + n * n + u * u), att))
    return out


@dataclass(frozen=True)
class PairOverlap:
    prev: int
    cur: int
    true_overlap: float  # 0..1, from the geometry
    estimated_percent: float | None  # what the gate measured
    flagged: bool  # the chain reported low overlap, a gap, or an overlap the telemetry contradicts


def keyframe_overlaps(manifest: list[dict], recording_dir: Path, rth_percent: float = 80.0) -> list[PairOverlap]:
    """Consecutive keyframe pairs whose frames are both in the recording (the scan)."""
    rec = load_recording(recording_dir)
    truth_lines = read_jsonl(Path(recording_dir) / "truth.jsonl")
    by_frame = {int(t["source_frame"]): i for i, t in enumerate(truth_lines)}
    out = []
    for prev, cur in zip(manifest, manifest[1:], strict=False):
        if prev["index"] not in by_frame or cur["index"] not in by_frame:
            continue
        est = cur.get("overlap_to_previous")
        flagged = bool(cur.get("gap_before")) or bool(cur.get("overlap_suspect")) or est is None or est < rth_percent
        true = rec.true_overlap(by_frame[prev["index"]], by_frame[cur["index"]])
        out.append(PairOverlap(prev["index"], cur["index"], true, est, flagged))
    return out
