#!/usr/bin/env python3
"""Regenerate the default building (src/sage_robot/data/maps/campus/) byte for byte.

Usage: python scripts/generate_building.py [OUT_DIR]
The layout lives in sage_robot.sim.building; this script only writes the files.
"""

from __future__ import annotations

import sys
from pathlib import Path

from sage_robot.sim.building import generate

DEFAULT_OUT = Path(__file__).resolve().parents[1] / "src" / "sage_robot" / "data" / "maps" / "campus"


def main(argv: list[str]) -> int:
    out = Path(argv[1]) if len(argv) > 1 else DEFAULT_OUT
    for path in generate(out):
        print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
