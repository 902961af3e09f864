"""Helpers shared by the tests: bounded condition waits (``waits``) and grid drawing (``grids``).

Import them relatively, e.g. ``from ..support.waits import until``.
"""
