"""Shared test helpers.

Real data for tests lives in ``../shared/data`` beside the repository (or where
``SAGE_SHARED_DATA`` points). Tests that need it use the ``shared_data`` fixture, which
skips with a clear message when the data is absent. Nothing from there is copied here.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
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
