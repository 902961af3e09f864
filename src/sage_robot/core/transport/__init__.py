"""Transports that carry the bus beyond one process.

- :mod:`~sage_robot.core.transport.wire`: the binary encoding of a message (a JSON header for
  the fields, raw buffers for numpy arrays and bytes; no pickle).
- :mod:`~sage_robot.core.transport.keys`: Zenoh key expressions and the session config.
- :mod:`~sage_robot.core.transport.zenoh_bus`: :class:`ZenohTransport`, the bus's networked
  :class:`~sage_robot.core.bus.Transport`.
- :mod:`~sage_robot.core.transport.remote`: :class:`RemoteRobot`, what tools (`sage topic`,
  `sage status`, benchmarks) use to attach to a running robot.

Zenoh (``eclipse-zenoh``, the ``zenoh`` extra) is imported only by the last three.
"""
