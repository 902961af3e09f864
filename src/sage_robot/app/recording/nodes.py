"""Nodes: ``recorder`` (bus → MCAP), ``replay`` (MCAP → bus) and ``foxglove`` (live view)."""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from sage_robot.app.recording import ros2
from sage_robot.app.recording.gate import FoxgloveGate, foxglove_token, is_loopback_host
from sage_robot.app.recording.mcap_io import McapRecorder, _ros_name, read_mcap
from sage_robot.core.errors import ConfigError
from sage_robot.core.msgs import OccupancyGrid
from sage_robot.core.node import Node
from sage_robot.core.resources import ResourceKey

RECORD_PATH: ResourceKey[str | Path] = ResourceKey("record_path", doc="where the recorder writes")
RECORD_TOPICS: ResourceKey[Sequence[str]] = ResourceKey("record_topics")  # default: the profile's
REPLAY_PATH: ResourceKey[str | Path] = ResourceKey("replay_path", doc="what the replay node plays")
REPLAY_SPEED = ResourceKey("replay_speed", float)  # default 1
FOXGLOVE_PORT = ResourceKey("foxglove_port", int)  # where the Foxglove gate listens


class RecorderNode(Node):
    name = "recorder"

    async def setup(self) -> None:
        path = self.ctx.resources.get(RECORD_PATH)
        if not path:
            raise ValueError("recorder: no output file (ctx.resources[RECORD_PATH])")
        wanted = self.ctx.resources.get(RECORD_TOPICS)
        self.topics = set(wanted or self.settings.ops.record_topics)
        self.recorder = McapRecorder(path)
        self.errors = 0
        self._remove_tap = self.bus.add_tap(self._tap)
        for topic in sorted(self.topics):  # from other processes too
            self.bus.want(topic)
        self.log.info("recording", path=str(path), topics=len(self.topics))

    def _tap(self, topic: str, msg: Any) -> None:
        if topic not in self.topics:
            return
        try:
            self.recorder.write(topic, msg, self.clock.now())
        except Exception as exc:  # a tap must never break publishing
            self.errors += 1
            if self.errors == 1:
                self.log.error("cannot record a message", topic=topic, error=str(exc))

    async def teardown(self) -> None:
        self._remove_tap()
        self.recorder.close()
        self.log.info(
            "recording closed", path=str(self.recorder.path), messages=sum(self.recorder.counts.values())
        )

    def stats(self) -> dict[str, Any]:
        return {"messages": dict(self.recorder.counts), "errors": self.errors}


class ReplayNode(Node):
    """Publish a recording on the bus with its original timing (scaled by the speed)."""

    name = "replay"

    async def setup(self) -> None:
        self.path = Path(self.ctx.resources.require(REPLAY_PATH))
        self.speed = float(self.ctx.resources.get(REPLAY_SPEED, 1.0))
        self.published = 0
        self.messages = await asyncio.to_thread(lambda: list(read_mcap(self.path)))
        for topic, _, msg in self.messages:
            if isinstance(msg, OccupancyGrid):
                self.bus.declare(topic, OccupancyGrid, latched=True)

    async def run(self) -> None:
        if not self.messages:
            return
        t0, start = self.messages[0][1], self.clock.now()
        for topic, t, msg in self.messages:
            await self.clock.sleep_until(start + (t - t0) / self.speed)
            self.bus.publish(topic, msg)
            self.published += 1
        self.log.info("replay finished", messages=self.published)

    def stats(self) -> dict[str, Any]:
        return {"published": self.published, "total": len(getattr(self, "messages", []))}


class FoxgloveNode(Node):
    """A Foxglove WebSocket server publishing every topic live, as ROS 2 CDR messages.

    Clients reach it through :class:`~sage_robot.app.recording.gate.FoxgloveGate` (Origin
    check; the Foxglove token where ``ops.foxglove_host`` is not loopback).
    """

    name = "foxglove"

    async def setup(self) -> None:
        import foxglove

        self._fg = foxglove
        ops = self.settings.ops
        # The SDK's server has no login and no Origin check: loopback only, behind the gate.
        self.server = foxglove.start_server(name="SAGE", host="127.0.0.1", port=0)
        token = None
        if not is_loopback_host(ops.foxglove_host):
            from sage_robot.web.auth import operator_password

            token = foxglove_token(operator_password(self.settings))
        origins = (*self.settings.web.allowed_origins, *ops.foxglove_origins)
        self._release_all: Callable[[], None] | None = None
        self.gate = FoxgloveGate(self.server.port, token, origins, self.log, self._on_viewers)
        try:
            self.port = await self.gate.start(ops.foxglove_host, ops.foxglove_port)
        except OSError as exc:
            self.server.stop()
            raise ConfigError(
                f"Foxglove: cannot listen on {ops.foxglove_host}:{ops.foxglove_port} ({exc.strerror}); "
                "stop the other program or set ops.foxglove_port"
            ) from None
        self.ctx.resources[FOXGLOVE_PORT] = self.port
        self._channels: dict[str, tuple[Any, Any]] = {}
        self._last_map = -1e9
        self.sent = 0
        self.errors = 0
        self._remove_tap = self.bus.add_tap(self._tap)
        self.log.info(
            "Foxglove live view",
            url=f"ws://{ops.foxglove_host}:{self.port}",
            token="required (python -m sage_robot.app.recording.gate)" if token else "not needed (loopback)",
        )

    def _channel(self, topic: str, ros_type: str) -> tuple[Any, Any]:
        found = self._channels.get(topic)
        if found is None:
            from mcap_ros2._dynamic import serialize_dynamic

            name, text = _ros_name(ros_type), ros2.msgdef(ros_type)
            encode = serialize_dynamic(name, text)[name]
            schema = self._fg.Schema(name=name, encoding="ros2msg", data=text.encode())
            found = self._channels[topic] = (
                self._fg.Channel(topic, schema=schema, message_encoding="cdr"),
                encode,
            )
        return found

    def _on_viewers(self, viewers: int) -> None:
        """Every topic of every process comes here while someone watches, none otherwise."""
        if viewers > 0 and self._release_all is None:
            self._release_all = self.bus.want_all()
        elif viewers == 0 and self._release_all is not None:
            self._release_all()
            self._release_all = None

    def _tap(self, topic: str, msg: Any) -> None:
        known = self._channels.get(topic)
        if known is not None and not known[0].has_sinks():
            return  # advertised, but no viewer subscribes: no conversion, no encoding
        now = self.clock.now()
        if isinstance(msg, OccupancyGrid):
            if now - self._last_map < self.settings.ops.foxglove_map_period_s:
                return
            self._last_map = now
        try:
            ros_type, data = ros2.convert(msg)
            channel, encode = self._channel(topic, ros_type)
            channel.log(encode(data))
            self.sent += 1
        except Exception as exc:  # a tap must never break publishing
            self.errors += 1
            if self.errors == 1:
                self.log.error("cannot send to Foxglove", topic=topic, error=str(exc))

    async def teardown(self) -> None:
        if getattr(self, "_remove_tap", None) is None:
            return  # setup failed before the tap, and stopped what it had started
        self._remove_tap()
        self._on_viewers(0)
        await self.gate.stop()
        self.server.stop()

    def stats(self) -> dict[str, Any]:
        return {
            "port": self.port, "channels": len(self._channels), "sent": self.sent, "errors": self.errors,
            **self.gate.counts,
        }  # fmt: skip
