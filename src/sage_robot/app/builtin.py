"""Small nodes every profile has."""

from __future__ import annotations

from sage_robot.core.bus import Topic
from sage_robot.core.msgs import Event
from sage_robot.core.node import Node

HEARTBEAT_PERIOD_S = 1.0
HEARTBEAT = Topic("/sage/heartbeat", Event)


class HeartbeatNode(Node):
    """Publishes ``/sage/heartbeat`` once a second: proof the loop and the clock are alive."""

    name = "heartbeat"

    async def setup(self) -> None:
        self.beats = 0
        self.every(HEARTBEAT_PERIOD_S, self._beat)

    def _beat(self) -> None:
        self.beats += 1
        self.bus.publish(HEARTBEAT, Event(self.clock.now(), self.name, "heartbeat"))

    def stats(self) -> dict[str, int]:
        return {"beats": self.beats}
