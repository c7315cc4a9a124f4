"""The tests run from a checkout: the project's shared data folder is ../shared/data beside it, unless
``$COMPANION_SHARED_DATA`` names another (evaluation/shared_data.py)."""

from __future__ import annotations

import os
from pathlib import Path

os.environ.setdefault("COMPANION_SHARED_DATA", str(Path(__file__).resolve().parents[2] / "shared" / "data"))
