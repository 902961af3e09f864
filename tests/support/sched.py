"""Whether this machine lets a process take a real-time priority (``SCHED_FIFO``)."""

from __future__ import annotations

import subprocess
import sys

PROBE = "from sage_robot.core.realtime import set_fifo; print(set_fifo(1) is None)"


def fifo_permitted() -> bool:
    """Asked in a child process, so the caller's scheduling never changes."""
    out = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, timeout=60)
    return out.stdout.strip() == "True"
