"""SAGE: software of an autonomous campus tour robot, with a built-in simulator."""

__version__ = "0.1.0"
