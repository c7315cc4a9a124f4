"""Every test keeps the parameter journal (companion/flight/param_journal.py) in a temporary directory, never in
the state directory of the user running the suite: a flight test that ends with its link dead leaves a journal
there, and the next `companion fly` of that user would restore it onto a real vehicle with the same system id."""

from __future__ import annotations

import atexit
import os
import shutil
import tempfile

import pytest

from companion.flight.param_journal import STATE_DIR_ENV

# Set at import, before any test module builds a subprocess environment from os.environ at its own import.
_SESSION_STATE = tempfile.mkdtemp(prefix="companion-test-state-")
os.environ[STATE_DIR_ENV] = _SESSION_STATE
atexit.register(shutil.rmtree, _SESSION_STATE, True)


@pytest.fixture(autouse=True)
def _own_state_dir(tmp_path_factory, monkeypatch):
    """Each test its own journal directory (in-process flights and subprocesses started with os.environ)."""
    monkeypatch.setenv(STATE_DIR_ENV, str(tmp_path_factory.mktemp("state")))
