"""The benches run from a checkout: the project's shared data folder is ../shared/data beside it, unless
``$COMPANION_SHARED_DATA`` names another (evaluation/shared_data.py). A bench that reads real photos calls
:func:`use_checkout_shared_data` before it does."""

from __future__ import annotations

import os
from pathlib import Path

from evaluation.shared_data import ENV_VAR, shared_data_root

CHECKOUT_SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def use_checkout_shared_data() -> Path:
    """The shared data folder: ``$COMPANION_SHARED_DATA``, set to the checkout's own when it is unset."""
    os.environ.setdefault(ENV_VAR, str(CHECKOUT_SHARED_DATA))
    return shared_data_root()
