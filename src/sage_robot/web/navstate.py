"""The navigation state on the operator's pages, whoever started the goal.

The navigator publishes ``/nav/state`` (:class:`NavigateFeedback`: on every change, at
1 Hz while a goal runs, IDLE when none): that is what the ``nav`` channel shows — the
brain's "take me to the cafe" as much as a click on the map. The topic does not say how
a goal ended, so the running ``navigate_to`` / ``tour`` goal's result is awaited (never
its feedback stream, which belongs to whoever sent the goal) to show succeeded / aborted
and why. For a navigator that does not publish the topic, the web's own goals fall back
to their action feedback.
"""

from __future__ import annotations

from typing import Any

from sage_robot.core import topics
from sage_robot.core.actions import GoalHandle
from sage_robot.core.log import get_logger
from sage_robot.core.msgs import to_dict
from sage_robot.core.msgs.nav import NavigateFeedback, NavigateGoal, NavState

NAV_ACTIONS = (topics.NAVIGATE_TO, topics.TOUR)

_log = get_logger("web")


def _round(value: Any, digits: int = 1) -> float | None:
    return round(float(value), digits) if isinstance(value, (int, float)) else None


class NavTracker:
    """Feeds the hub's ``nav`` channel from ``/nav/state`` and the goals' results."""

    def __init__(self, hub: Any) -> None:
        self.hub = hub
        self.topic_seen = False  # the navigator publishes /nav/state
        self._watched: set[int] = set()  # goal ids whose result is awaited
        self.labels: dict[int, str] = {}  # goal id -> what the page calls it

    def start(self) -> None:
        self.hub.node.subscribe(topics.NAV_STATE, NavigateFeedback, self._on_state, maxsize=10)

    # ------------------------------------------------------------ the topic
    def _on_state(self, fb: NavigateFeedback) -> None:
        self.topic_seen = True
        if fb.state is NavState.IDLE:
            current = self.hub.latest.get("nav")
            if current is None or not current.get("done"):  # keep "succeeded CAFE" on show
                self.hub.set("nav", {"type": "nav", "state": "idle", "place": "", "done": False})
            return
        handle = self._active()
        label = fb.place or (self.labels.get(handle.goal_id, "") if handle else "") or self._label(handle)
        self.hub.set(
            "nav",
            {
                "type": "nav",
                "state": fb.state.value,
                "place": label,
                "distance_remaining_m": _round(fb.distance_remaining_m),
                "eta_s": _round(fb.eta_s, 0),
                "done": False,
            },
        )
        if handle is not None:
            self.watch(handle, label)

    def _active(self) -> GoalHandle | None:
        actions = self.hub.bus.actions
        for action in NAV_ACTIONS:
            handle = actions.active(action)
            if handle is not None:
                return handle  # type: ignore[no-any-return]
        return None

    @staticmethod
    def _label(handle: GoalHandle | None) -> str:
        goal = handle.goal if handle is not None else None
        if isinstance(goal, NavigateGoal):
            if goal.place:
                return goal.place
            if goal.pose is not None:
                return f"({goal.pose.x:.1f}, {goal.pose.y:.1f})"
        return ""

    # ------------------------------------------------------------ goals
    def sent(self, handle: GoalHandle, label: str) -> None:
        """A goal the web itself sent: show it at once, follow it to its end."""
        self.labels[handle.goal_id] = label
        self.hub.set("nav", {"type": "nav", "state": "sent", "place": label, "done": False})
        self.watch(handle, label, own=True)

    def watch(self, handle: GoalHandle, label: str, own: bool = False) -> None:
        if handle.goal_id in self._watched:
            return
        self._watched.add(handle.goal_id)
        self.hub.node.spawn(self._follow(handle, label, own), "web.nav_goal")

    async def _follow(self, handle: GoalHandle, label: str, own: bool) -> None:
        try:
            if own:  # the web's own goal: its feedback is the web's to read
                async for fb in handle.feedback():
                    if not self.topic_seen and isinstance(fb, NavigateFeedback):
                        self._on_state_fallback(fb, label)
            result = await handle.result()
            value = to_dict(result.value) if result.value is not None else {}
            self.hub.set(
                "nav",
                {
                    "type": "nav",
                    "state": result.status.value,
                    "place": value.get("place") or label,
                    "reason": value.get("reason") or result.message,
                    "done": True,
                },
            )
            if self._active() is None:  # nothing drives there any more: clear the map's marks
                self.hub.set("goal", {"type": "goal", "x": None, "y": None, "theta": None, "place": ""})
                self.hub.set("plan", {"type": "plan", "points": []})
        except Exception:  # the pages lose a status line; the web node must not stop
            _log.exception("following a navigation goal failed")
        finally:
            self._watched.discard(handle.goal_id)
            self.labels.pop(handle.goal_id, None)

    def _on_state_fallback(self, fb: NavigateFeedback, label: str) -> None:
        self.hub.set(
            "nav",
            {
                "type": "nav",
                "state": fb.state.value,
                "place": fb.place or label,
                "distance_remaining_m": _round(fb.distance_remaining_m),
                "eta_s": _round(fb.eta_s, 0),
                "done": False,
            },
        )
