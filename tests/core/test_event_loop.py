"""Process groups run on uvloop's loop; single-process runs keep asyncio's (core/event_loop.py)."""

from __future__ import annotations

import asyncio

import pytest

from sage_robot.core import event_loop


async def _loop_module() -> str:
    await asyncio.sleep(0.001)
    return type(asyncio.get_running_loop()).__module__


def test_a_fast_run_is_on_uvloop_and_a_plain_one_on_asyncio() -> None:
    pytest.importorskip("uvloop", reason="uvloop comes with the zenoh and web extras")
    assert event_loop.run(_loop_module(), fast=True).startswith("uvloop")
    assert event_loop.run(_loop_module(), fast=False).startswith("asyncio")


def test_without_uvloop_a_fast_run_falls_back_to_asyncio(monkeypatch: pytest.MonkeyPatch) -> None:
    import sys

    monkeypatch.setitem(sys.modules, "uvloop", None)  # `import uvloop` raises ImportError
    assert event_loop.run(_loop_module(), fast=True).startswith("asyncio")
