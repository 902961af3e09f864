"""core/log.py: the terminal's level and the in-memory records (admin page) are separate."""

from __future__ import annotations

import subprocess
import sys

RUN_TIMEOUT_S = 30.0

# Configure at WARNING, then do what a node that wants INFO records does (web's admin
# page): make sure the logger passes INFO. The terminal must still show WARNING and up.
SNIPPET = """
import logging
from sage_robot.core import log
log.configure("WARNING")
root = logging.getLogger("sage")
if root.level == logging.NOTSET or root.level > logging.INFO:
    root.setLevel(logging.INFO)
lg = log.get_logger("probe")
lg.info("quiet info")
lg.warning("loud warning")
log.configure("ERROR")
lg.warning("quiet warning")
print(sorted(r["msg"] for r in log.RECENT.records))
"""


def test_log_level_is_the_terminals_and_recent_records_keep_info() -> None:
    proc = subprocess.run(
        [sys.executable, "-c", SNIPPET], capture_output=True, text=True, timeout=RUN_TIMEOUT_S
    )
    assert proc.returncode == 0, proc.stderr
    assert "loud warning" in proc.stderr
    assert "quiet info" not in proc.stderr
    assert "quiet warning" not in proc.stderr
    assert proc.stdout.strip() == "['loud warning', 'quiet info', 'quiet warning']"
