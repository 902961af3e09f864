"""Shared test helpers.

Real data for tests lives in ``../shared/data`` beside the repository (or where
``SAGE_SHARED_DATA`` points). Tests that need it use the ``shared_data`` fixture, which
skips with a clear message when the data is absent. Nothing from there is copied here.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path

import pytest
from hypothesis import HealthCheck, Phase, settings

# In CI, property tests are derandomized (the same examples every run, so a green run stays
# green) and do not shrink (a failure is reported at once instead of after minutes).
settings.register_profile(
    "ci",
    derandomize=True,
    phases=[Phase.explicit, Phase.reuse, Phase.generate],
    suppress_health_check=[HealthCheck.too_slow],
)
if os.environ.get("CI"):
    settings.load_profile("ci")

REPO = Path(__file__).resolve().parents[1]

# Tests never touch the user's real state (knowledge base, operator password, maps): every
# test and every `sage` subprocess they start writes under one temporary folder.
_SANDBOX = Path(tempfile.mkdtemp(prefix="sage-tests-"))
os.environ["SAGE_STATE_DIR"] = str(_SANDBOX / "state")
os.environ["SAGE_DATA_DIR"] = str(_SANDBOX / "data")
SHARED_DATA = Path(os.environ.get("SAGE_SHARED_DATA", REPO.parent / "shared" / "data"))


@pytest.fixture
def shared_data() -> Callable[[str], Path]:
    """``shared_data("maps/willow-full/willow-full.yaml")`` → the path, or skip the test."""

    def get(rel: str) -> Path:
        path = SHARED_DATA / rel
        if not path.exists():
            pytest.skip(f"shared test data {rel} not found under {SHARED_DATA} (set SAGE_SHARED_DATA)")
        return path

    return get
