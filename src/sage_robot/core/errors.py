"""Typed errors shared by every layer.

Expected failures (a place that does not exist, a goal that was aborted) are values;
these exceptions are for misuse, bad input at the edges and broken devices.
"""

from __future__ import annotations


class SageError(Exception):
    """Base of every error SAGE raises on purpose. Its message is meant for a person."""


class ConfigError(SageError):
    """A profile, map, waypoint or key file is wrong. The message names file, key and fix."""


class DeviceNotConnectedError(SageError):
    """A device (serial port, lidar, camera, microphone) is absent or went away."""


class ServiceError(SageError):
    """A bus service handler failed; carries the handler's message back to the caller."""


class ServiceUnavailable(ServiceError):
    """No node offers the service that was called."""


class ServiceTimeout(ServiceError):
    """A service did not answer in time."""
