"""Frame sources: video files with container timestamps, image folders with corrupt files, bad specs."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from companion.capture.sources import ImageFolderSource, VideoSource, open_source
from companion.errors import CompanionError


def _image(i: int) -> np.ndarray:
    img = np.full((96, 128, 3), 40, np.uint8)
    cv2.putText(img, str(i), (20, 70), cv2.FONT_HERSHEY_SIMPLEX, 2, (255, 255, 255), 3)
    return img


def test_video_file_frames_and_times(tmp_path):
    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (128, 96))
    for i in range(12):
        writer.write(_image(i))
    writer.release()
    with open_source(str(path), start_time_s=100.0) as src:
        assert isinstance(src, VideoSource)
        frames = list(src)
    assert [f.index for f in frames] == list(range(12))
    times = np.array([f.capture_time_s for f in frames])
    assert times[0] >= 100.0 and np.allclose(np.diff(times), 0.1, atol=1e-3)
    assert src.stats.delivered == 12 and src.stats.corrupt == 0


def test_image_folder_skips_and_counts_corrupt_files(tmp_path):
    for i in range(5):
        cv2.imwrite(str(tmp_path / f"f{i:03d}.jpg"), _image(i))
    (tmp_path / "f002.jpg").write_bytes(b"\xff\xd8 not really a jpeg")
    src = open_source(str(tmp_path), fps=4.0)
    assert isinstance(src, ImageFolderSource)
    frames = list(src)
    assert [f.index for f in frames] == [0, 1, 3, 4]
    assert [f.capture_time_s for f in frames] == [0.0, 0.25, 0.75, 1.0]  # index / fps without times.csv
    assert src.stats.corrupt == 1
    (tmp_path / "times.csv").write_text("name,seconds\n" + "".join(f"f{i:03d}.jpg,{10 + i / 2}\n" for i in range(5)))
    src = open_source(str(tmp_path), fps=4.0)
    assert [f.capture_time_s for f in src] == [10.0, 10.5, 11.5, 12.0]
    assert src.time_span() == (10.0, 12.0)


def test_bad_sources_are_clear_errors(tmp_path):
    with pytest.raises(CompanionError, match="does not exist"):
        open_source(str(tmp_path / "missing.mp4"))
    (tmp_path / "empty").mkdir()
    with pytest.raises(CompanionError, match="no images"):
        open_source(str(tmp_path / "empty"))
    (tmp_path / "junk.mp4").write_bytes(b"junk" * 100)
    with pytest.raises(CompanionError, match="cannot open"):
        list(open_source(str(tmp_path / "junk.mp4")))
