"""Where the project's shared data folder is (real facade photos, drone photos, firmware downloads).

A checkout keeps it in ../shared/data and an install has no such place, so nothing here guesses from a module's
location: the folder is given explicitly, else by ``$COMPANION_SHARED_DATA``. The benches and the tests, which
always run from a checkout, set that variable to the checkout's folder when it is unset (bench/checkout.py,
tests/conftest.py).
"""

from __future__ import annotations

import os
from pathlib import Path

from companion.errors import CompanionError

ENV_VAR = "COMPANION_SHARED_DATA"


def shared_data_root(root: str | Path | None = None) -> Path:
    """``root`` when given, else ``$COMPANION_SHARED_DATA``; an error naming both when neither is set."""
    if root is not None:
        return Path(root)
    named = os.environ.get(ENV_VAR)
    if named:
        return Path(named)
    raise CompanionError("no shared data folder given",
                         f"pass the folder that holds real-facades/ or set {ENV_VAR} (../shared/data in a checkout)")
