"""Fixtures of the MCU tests."""

from __future__ import annotations

from collections.abc import AsyncIterator

import pytest

from .rig import Rig, close_rig, make_rig


@pytest.fixture
async def rig() -> AsyncIterator[Rig]:
    r = await make_rig()
    try:
        yield r
    finally:
        await close_rig(r)
