"""The spool's file names: the one place they are spelled (writer, reader, follow mode, demo, benches, tests).

A spool directory holds (docs/STITCH.md, "Spool layout"):

  spool.json              camera, facade and standoff; written atomically with the first keyframe (the camera's
                          delivered size is known then)
  kf_NNNNNN.jpg           full-resolution keyframe (NNNNNN: the frame index), EXIF GPS/time + XMP orientation
  kf_NNNNNN_mask.png      its ROI mask (OpenDroneMap's <image>_mask.png naming)
  kf_NNNNNN.json          sidecar: pose, the gate's decision, settings
  manifest.jsonl          one line per keyframe, appended + fsynced only after its files are durable
  CLOSED                  written when the flight (or offline cull) is over
  cull_report.json        the culling run's counts and warnings (written at the end)
"""

from __future__ import annotations

from dataclasses import dataclass

MANIFEST = "manifest.jsonl"
META = "spool.json"
CLOSED = "CLOSED"  # the flight is over: a following stitcher finishes (docs/STITCH.md)
CULL_REPORT = "cull_report.json"


@dataclass(frozen=True)
class SpoolEntry:
    """One keyframe's files, relative to the spool directory (a manifest line names them)."""

    index: int  # frame index in the capture stream
    image: str
    mask: str
    sidecar: str

    @classmethod
    def for_frame(cls, index: int) -> SpoolEntry:
        stem = f"kf_{index:06d}"
        return cls(index, f"{stem}.jpg", f"{stem}_mask.png", f"{stem}.json")
