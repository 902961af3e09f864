"""The simulated MCU's pty link does not outlive its process: a ``kill -9``'d owner leaves
its link directory behind, and the next PtyMcu removes it (only dead owners', only ours)."""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
from pathlib import Path

from sage_robot.sim.firmware import FirmwareModel
from sage_robot.sim.mcu_pty import PtyMcu, remove_stale_links, runtime_dir

from ..support.waits import wait_until

WAIT_S = 20.0  # bound on the child starting (imports numpy) and dying

CHILD = """
import sys, time
from pathlib import Path
from sage_robot.sim.firmware import FirmwareModel
from sage_robot.sim.mcu_pty import PtyMcu
pty = PtyMcu(FirmwareModel(), Path(sys.argv[1]))
print(pty.port_name, flush=True)
time.sleep(600)  # a live owner, until the test kills it
"""


def _start_child(base: Path) -> tuple[subprocess.Popen[str], Path]:
    child = subprocess.Popen([sys.executable, "-c", CHILD, str(base)], stdout=subprocess.PIPE, text=True)
    assert child.stdout is not None
    ready, _, _ = select.select([child.stdout], [], [], WAIT_S)
    if not ready:
        child.kill()
        child.wait(timeout=WAIT_S)
    line = child.stdout.readline() if ready else ""
    assert line.strip(), "the child did not create its pty"
    return child, Path(line.strip())


def _kill9(child: subprocess.Popen[str]) -> None:
    child.send_signal(signal.SIGKILL)
    child.wait(timeout=WAIT_S)
    assert child.returncode == -signal.SIGKILL


def test_a_killed_owners_link_is_removed_by_the_next_start(tmp_path: Path) -> None:
    base = tmp_path / "run"
    base.mkdir(mode=0o700)
    child, link = _start_child(base)
    try:
        assert link.is_symlink()
        assert link.parent.parent == base
        assert link.parent.name.startswith(f"mcu-{child.pid}-")
    finally:
        _kill9(child)
    assert link.parent.exists()  # SIGKILL: nothing could clean up
    pty = PtyMcu(FirmwareModel(), base)
    try:
        assert not link.parent.exists()
        assert [p.name for p in base.iterdir()] == [Path(pty.port_name).parent.name]
        assert os.path.realpath(pty.port_name) == pty.slave_name
    finally:
        pty.close()
    assert list(base.iterdir()) == []  # close() removes its own


def test_live_owners_and_other_entries_are_kept(tmp_path: Path) -> None:
    base = tmp_path / "run"
    base.mkdir(mode=0o700)
    child, link = _start_child(base)
    other = base / "notes-123-x"
    other.mkdir()
    try:
        assert remove_stale_links(base) == []
        assert link.exists() or link.is_symlink()
        assert other.is_dir()
    finally:
        _kill9(child)
    # the kernel may take a moment to reap the PID
    removed = wait_until(lambda: remove_stale_links(base), "the dead owner's link to be removed", WAIT_S)
    assert removed == [link.parent]
    assert other.is_dir()


def test_the_runtime_dir_is_private(monkeypatch, tmp_path: Path) -> None:
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))
    base = runtime_dir()
    assert base == tmp_path / "sage"
    st = base.stat()
    assert st.st_uid == os.getuid()
    assert st.st_mode & 0o777 == 0o700
    base.chmod(0o777)  # someone else could put links there: not used
    assert runtime_dir() is None
    pty = PtyMcu(FirmwareModel())  # falls back to a fresh private temp dir
    try:
        assert Path(pty.port_name).is_symlink()
        assert not str(pty.port_name).startswith(str(base))
    finally:
        pty.close()
