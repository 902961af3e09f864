"""The simulator's time on a shared page (process groups on one machine): the page itself,
read while another process writes it, and a follower clock that takes its time from it."""

from __future__ import annotations

import asyncio
import subprocess
import sys
import time
from pathlib import Path

import pytest

from sage_robot.core.clock_board import BOARD_BYTES, ClockBoard, decode, encode
from sage_robot.core.clock_follow import BOARD_AHEAD_LIMIT_S, FollowerClock

STEP_S = 0.01  # the writers below step like the simulator's physics (s)
WRITES = 20000  # the writer process's pages


def test_a_page_decodes_only_when_whole() -> None:
    page = encode(7, 12.5, 1000.25, 1.0)
    assert len(page) == BOARD_BYTES
    reading = decode(page)
    assert reading is not None
    assert (reading.seq, reading.t, reading.wall, reading.speed) == (7, 12.5, 1000.25, 1.0)
    newer = encode(8, 12.51, 1000.26, 1.0)
    torn = newer[:16] + page[16:]  # the first half of a write over the old page
    assert decode(torn) is None
    assert decode(bytes(BOARD_BYTES)) is None  # never written


def test_a_reader_never_sees_a_half_written_page_from_another_process(tmp_path: Path) -> None:
    path = tmp_path / "clock.board"
    board = ClockBoard.create(path)
    assert board.read() is None
    code = (
        "import sys, time\n"
        "from sage_robot.core.clock_board import ClockBoard\n"
        "b = ClockBoard(sys.argv[1])\n"
        f"for k in range(1, {WRITES} + 1):\n"
        f"    b.write(k * {STEP_S}, 100.0 + k * {STEP_S}, 1.0)\n"
    )
    writer = subprocess.Popen([sys.executable, "-c", code, str(path)])
    seqs = []
    try:
        while writer.poll() is None:
            r = board.read()
            if r is not None:
                seqs.append(r.seq)
                assert r.t == pytest.approx(r.seq * STEP_S)
                assert r.wall == pytest.approx(100.0 + r.t)
    finally:
        writer.wait(60)
    assert writer.returncode == 0
    last = board.read()
    assert last is not None
    assert last.seq == WRITES
    assert seqs == sorted(seqs), "the sequence went backwards"
    # A simulator started again on the same page goes on counting (readers look for a new count).
    again = ClockBoard(path)
    again.write(500.0, 600.0, 1.0)
    newest = board.read()
    assert newest is not None
    assert newest.seq == WRITES + 1
    assert newest.t == 500.0


async def _write_paced(board: ClockBoard, t0: float, until: float, speed: float = 1.0) -> float:
    """Write the page as a simulator paced at ``speed`` does, from ``t0`` to ``until``."""
    wall0, t = time.monotonic(), t0
    while t < until - 1e-9:
        board.write(t, time.monotonic(), speed)
        await asyncio.sleep(STEP_S / speed)
        t = t0 + (time.monotonic() - wall0) * speed
    board.write(until, time.monotonic(), speed)
    return until


def test_a_follower_wakes_sleepers_when_the_simulator_on_the_page_reaches_them(tmp_path: Path) -> None:
    async def body() -> None:
        board = ClockBoard.create(tmp_path / "clock.board")
        clock = FollowerClock(0.0, ClockBoard(board.path))
        assert clock.reads_board
        woke: list[tuple[float, float]] = []  # (follower time, page time) at the wake-up

        async def sleeper(t: float) -> None:
            await clock.sleep_until(t)
            reading = board.read()
            assert reading is not None
            woke.append((clock.now(), reading.t))

        tasks = [asyncio.get_running_loop().create_task(sleeper(t)) for t in (0.1, 0.25, 0.4)]
        await asyncio.sleep(0.05)
        assert woke == [], "nothing on the page yet: nobody wakes"
        await _write_paced(board, 0.0, 0.5)
        await asyncio.wait_for(asyncio.gather(*tasks), 5.0)
        for due, (follower_t, page_t) in zip((0.1, 0.25, 0.4), woke, strict=True):
            assert follower_t >= due - 1e-9, "woken early"
            # never further ahead of the simulator than the limit (how much later than its time
            # a sleeper runs depends on the machine's load, and is not checked here)
            assert follower_t <= page_t + BOARD_AHEAD_LIMIT_S + 1e-9
        # the page is read when a sleeper is due (and when asked the time), not at every write
        assert len(woke) <= clock.ticks < board.read().seq  # type: ignore[union-attr]

    asyncio.run(body())


def test_a_stalled_simulator_holds_its_followers_within_the_limit(tmp_path: Path) -> None:
    async def body() -> None:
        board = ClockBoard.create(tmp_path / "clock.board")
        clock = FollowerClock(0.0, ClockBoard(board.path))
        await _write_paced(board, 0.0, 1.0)  # then the simulator stops writing (paused, stalled)
        late = asyncio.get_running_loop().create_task(clock.sleep_until(1.3))
        await asyncio.sleep(0.5)  # half a second of wall time: the pace alone would pass 1.3
        assert 1.0 <= clock.now() <= 1.0 + BOARD_AHEAD_LIMIT_S + 1e-9
        assert not late.done()
        await _write_paced(board, 1.0, 1.35)  # it goes on: the sleeper wakes
        await asyncio.wait_for(late, 2.0)
        assert clock.now() >= 1.3

    asyncio.run(body())
