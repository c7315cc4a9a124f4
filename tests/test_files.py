"""companion.files: the one atomic-write helper and the one JSON-lines reader."""

from __future__ import annotations

import json

import numpy as np
import pytest

from companion.files import TEMP_GLOB, append_durable, atomic_path, read_jsonl, write_atomic


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path):
    target = tmp_path / "report.json"
    write_atomic(target, '{"ok": 1}', durable=True)
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text('{"half')
        raise RuntimeError("crash mid-write")
    assert json.loads(target.read_text()) == {"ok": 1}
    assert not list(tmp_path.glob(TEMP_GLOB))


def test_writers_that_pick_the_format_by_extension_get_it(tmp_path):
    target = tmp_path / "cache.npz"
    with atomic_path(target) as tmp:
        np.savez(tmp, a=np.arange(3))  # np.savez appends .npz to a name without it
    assert np.load(target)["a"].tolist() == [0, 1, 2] and sorted(p.name for p in tmp_path.iterdir()) == ["cache.npz"]


def test_jsonl_reader_skips_a_torn_line_or_refuses_it(tmp_path):
    path = tmp_path / "log.jsonl"
    append_durable(path, json.dumps({"a": 1}))
    append_durable(path, "")
    with open(path, "a") as fh:
        fh.write('{"a": 2}\n{"a": 3, "b"')  # a crash mid-append
    assert read_jsonl(path) == [{"a": 1}, {"a": 2}]
    with pytest.raises(json.JSONDecodeError):
        read_jsonl(path, skip_bad=False)
