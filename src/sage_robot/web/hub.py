"""The web server's view of the bus: latest value per channel, fanned out to WebSocket clients.

Each channel (``battery``, ``ui_state``, ``pose``, ``scan``, ...) keeps only its latest
JSON message. A client is a :class:`Listener` that is told which channels changed and
sends the latest of each, no more often than the channel's minimum interval. A slow
phone therefore skips intermediate values instead of queueing them, and one slow
client never holds up another. Camera frames work the same way (latest frame only).
Events (arrivals, safety stops) are the exception: each is kept, in a short ring.

The ``captions`` channel is what the kiosk face prints of every turn: the visitor's words
(the robot's microphone on ``/sage/heard``, a ``/talk`` question), the robot's answers (the
voice pipeline's reply, a ``/talk`` reply) and announcements (``/sage/say``); its message holds
the last :data:`CAPTIONS_KEPT` lines, so latest-only delivery loses none of a turn.

The ``ui_state`` channel is the voice pipeline's ``/sage/ui_state``, except while a ``/talk``
turn (typed or recorded on a phone) is on its way and the robot's own conversation is not
running: then its phase is ``thinking`` (``"via": "talk"``), so the face shows the robot
thinking about a phone's question too (:meth:`Hub.talk_turn`).
"""

from __future__ import annotations

import asyncio
import contextlib
import struct
import time
from collections import deque
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any

from sage_robot.core import topics
from sage_robot.core.bus import Subscription
from sage_robot.core.geometry import compose, inverse
from sage_robot.core.msgs import (
    BatteryState,
    CompressedImage,
    Event,
    LaserScan,
    OccupancyGrid,
    Odometry,
    Path,
    PoseStamped,
    PoseWithCovariance,
    Text,
)
from sage_robot.core.msgs.nav import LocalizationHealth
from sage_robot.core.msgs.sim import People
from sage_robot.core.msgs.tour import TourState
from sage_robot.core.msgs.voice import AudioChunk, Doa, Phase, UiState
from sage_robot.core.node import Node
from sage_robot.web import views
from sage_robot.web.costmap_view import costmap_json
from sage_robot.web.navstate import NavTracker
from sage_robot.web.tour_api import tour_json

# Minimum seconds between two sends of a channel to one client (phones on Wi-Fi).
MIN_INTERVAL_S: dict[str, float] = {
    "battery": 0.5,
    "ui_state": 0.04,  # the mouth follows tts_viseme at up to 25 Hz
    "ui_state_seed": 0.04,  # the same for the seed's face, which knows "searching", not "navigating"
    "doa": 0.08,  # the seed's DOA server broadcast every 80 ms
    "pose": 0.1,
    "scan": 0.2,
    "plan": 0.5,
    "goal": 0.2,
    "people": 0.2,
    "loc": 0.5,
    "map": 1.0,  # SLAM grows the map; re-send at most once a second
    "costmap": 1.0,  # the navigator's local costmap (the teleop map's optional layer)
    "estop": 0.0,
    "teleop": 0.0,
    "nav": 0.2,
    "tour": 0.2,
    "captions": 0.1,
    "social": 0.0,
    "camera": 1.0 / 15.0,  # frames/s cap per client; web.camera_fps overrides
}
# channels of the page-only streams (see Hub._live_views), dropped when the last page leaves
PAGE_ONLY_CHANNELS = ("odom", "pose", "loc", "scan", "people", "doa")
EVENTS_KEPT = 50  # recent events shown on a newly opened page
# the navigator's social events (issue #20), also shown on the kiosk face ("social" channel)
SOCIAL_EVENT_KINDS = frozenset({"slowing_for_people", "pulling_over", "passing_group", "blocked_by_people"})
QUEUE_KEPT = 100  # events and audio chunks queued per client before the oldest is dropped
CAPTIONS_KEPT = 6  # caption lines in the captions channel's message
CAPTION_MAX_CHARS = 600  # of one caption line
# Voice phases of the robot's own conversation: a /talk turn never hides them.
VOICE_TURN_PHASES = frozenset({Phase.LISTENING.value, Phase.THINKING.value, Phase.SPEAKING.value})
AUDIO_HEADER = struct.Struct("<I")  # binary audio message: sample rate (Hz), then int16 LE PCM


@dataclass(eq=False)
class Listener:
    """One WebSocket client's interest: changed channels and queued events."""

    channels: frozenset[str]
    dirty: set[str] = field(default_factory=set)
    events: deque[dict[str, Any] | bytes] = field(default_factory=lambda: deque(maxlen=QUEUE_KEPT))
    wake: asyncio.Event = field(default_factory=asyncio.Event)
    last_sent: dict[str, float] = field(default_factory=dict)

    def mark(self, channel: str) -> None:
        if channel in self.channels:
            self.dirty.add(channel)
            self.wake.set()


class Hub:
    """Subscribes to the bus for the web node and keeps the latest of everything."""

    def __init__(self, node: Node) -> None:
        self.node = node
        self.bus, self.clock, self.settings = node.bus, node.clock, node.settings
        self.latest: dict[str, dict[str, Any]] = {}
        self.events: deque[dict[str, Any]] = deque(maxlen=EVENTS_KEPT)
        self.listeners: set[Listener] = set()
        self.frame: bytes = b""
        self.frame_seq = 0
        self.map_version = 0
        self.map_grid: OccupancyGrid | None = None
        self._map_png: tuple[int, bytes] | None = None
        self._odom: tuple[float, float, float] | None = None
        self._map_odom: tuple[float, float, float] | None = None  # pose of odom in map
        self.robot_pose: tuple[float, float, float] | None = None
        self.robot_frame = ""
        mount = self.settings.robot.lidar
        self.lidar_mount = (mount.x_m, mount.y_m, mount.yaw_rad)
        self.estop = False
        self.intervals = dict(MIN_INTERVAL_S, camera=1.0 / self.settings.web.camera_fps)
        self.counts = {"frames_in": 0, "events_in": 0}
        self.camera_sub: Subscription[CompressedImage] | None = None  # only while someone watches
        self.camera_viewers = 0
        self._live: list[Subscription[Any]] = []  # the drawn-only streams, while a page is open
        self._started = False
        self.nav = NavTracker(self)
        self.captions: deque[dict[str, Any]] = deque(maxlen=CAPTIONS_KEPT)
        self._caption_seq = 0
        self._voice_reply = ""  # the voice pipeline's reply of the running turn (from ui_state)
        self._voice_captioned = ""  # the last one captioned (ui_state keeps it until the next turn)
        self._voice_state = views.ui_state_json(UiState())  # the pipeline's last ui_state
        self._talk_turns = 0  # /talk turns on their way (from the upload to the reply)

    def start(self) -> None:
        self._started = True
        sub = self.node.subscribe
        sub(topics.BATTERY, BatteryState, self._on_battery)
        sub(topics.UI_STATE, UiState, self._on_ui_state, maxsize=50)
        sub(topics.AMCL_POSE, PoseWithCovariance, self._on_amcl)
        sub(topics.PLAN, Path, self._on_plan)
        sub(topics.GOAL_POSE, PoseStamped, self._on_goal)
        sub(topics.MAP, OccupancyGrid, self._on_map, maxsize=2)
        self.nav.start()
        sub(topics.EVENTS, Event, self._on_event, maxsize=50)
        sub(topics.AUDIO_OUT, AudioChunk, self._on_audio, maxsize=50)
        sub(topics.HEARD, Text, lambda m: self.caption("visitor", m.data, "microphone"), maxsize=20)
        sub(topics.SAY, Text, lambda m: self.caption("robot", m.data, "announcement"), maxsize=20)
        sub(topics.TOUR_STATE, TourState, lambda m: self.set("tour", tour_json(m)))  # the visitor's tour
        self.set("estop", {"type": "estop", "engaged": False})
        self._live_views()  # pages that connected before the start

    def stop(self) -> None:
        if self.camera_sub is not None:
            self.camera_sub.close()
            self.camera_sub = None
        self.listeners.clear()
        self._live_views()

    def _live_views(self) -> None:
        """The streams only pages show (odometry at 50 Hz, the map->odom correction, the
        navigator's costmap, localization's score, the lidar's points, the simulated people,
        the speaker's direction) are subscribed while some page is open. At rest nobody
        converts them, and when the pages run in a process of their own nothing is even sent
        to it. The correction and the costmap are latched: a page that opens gets their last
        values at once, so its first odometry is placed on the map. Without a page the pose
        follows ``/amcl_pose``, and :meth:`current_pose` fetches a fresh one."""
        if self.listeners and not self._live and self._started:
            sub = self.bus.subscribe
            self._live = [
                sub(topics.MAP_ODOM, PoseStamped, self._on_map_odom),  # first: latched, before odometry
                sub(topics.COSTMAP, OccupancyGrid, lambda m: self.set("costmap", costmap_json(m)), maxsize=1),
                sub(topics.ODOM, Odometry, self._on_odom),
                sub(topics.LOC_HEALTH, LocalizationHealth, self._on_loc),
                sub(topics.SCAN, LaserScan, self._on_scan, maxsize=2),
                sub(topics.SIM_PEOPLE, People, self._on_people),  # published only by the simulator
                sub(topics.DOA, Doa, self._on_doa),
            ]
        elif not self.listeners and self._live:
            for live in self._live:
                live.close()
            self._live = []
            for channel in PAGE_ONLY_CHANNELS:  # stale by the next page
                self.latest.pop(channel, None)
            self._odom = None  # the correction is kept: the next page's latched one replaces it
            self.robot_pose, self.robot_frame = None, ""  # /amcl_pose sets it again

    async def current_pose(self, timeout_s: float) -> tuple[tuple[float, float, float] | None, str]:
        """The robot's pose now and its frame: what the pages see while one is open, else
        from one fresh odometry message (waited for at most ``timeout_s``) on the last
        map->odom correction; without odometry, the last ``/amcl_pose`` (``None`` if none)."""
        if self._live:
            return self.robot_pose, self.robot_frame
        fresh: asyncio.Future[Odometry] = asyncio.get_running_loop().create_future()

        def take(msg: Odometry) -> None:
            if not fresh.done():
                fresh.set_result(msg)

        correction: list[tuple[float, float, float]] = []  # the latched map->odom, when there is one
        def on_correction(msg: PoseStamped) -> None:
            correction.append(msg.pose.as_tuple())

        subs: list[Subscription[Any]] = [self.bus.subscribe(topics.MAP_ODOM, PoseStamped, on_correction),
                                         self.bus.subscribe(topics.ODOM, Odometry, take)]
        try:
            msg = await asyncio.wait_for(fresh, timeout_s)
        except asyncio.TimeoutError:  # no odometry: what localization said last (or nothing)
            return self.robot_pose, self.robot_frame
        finally:
            for sub in subs:
                sub.close()
        if not correction:
            return msg.pose.as_tuple(), msg.frame_id
        return compose(correction[-1], msg.pose.as_tuple()), "map"

    # ------------------------------------------------------------ fan-out
    def set(self, channel: str, message: dict[str, Any]) -> None:
        if channel == "nav" and "title" not in message:  # the destination as pages name it
            from sage_robot.web.api import place_title

            message = {**message, "title": place_title(str(message.get("place") or ""))}
        self.latest[channel] = message
        for listener in self.listeners:
            listener.mark(channel)

    def listen(self, channels: Iterable[str]) -> Listener:
        listener = Listener(frozenset(channels))
        if "camera" in listener.channels:
            self._camera_viewer(+1)
        for ch in listener.channels:
            if ch in self.latest or (ch == "camera" and self.frame):
                listener.dirty.add(ch)
        if "events" in listener.channels:
            listener.events.extend(self.events)
        listener.wake.set()
        self.listeners.add(listener)
        self._live_views()
        return listener

    def unlisten(self, listener: Listener) -> None:
        if listener in self.listeners and "camera" in listener.channels:
            self._camera_viewer(-1)
        self.listeners.discard(listener)
        self._live_views()

    def _camera_viewer(self, delta: int) -> None:
        """Subscribe to the camera only while a page shows it: the simulator renders frames
        only for a subscriber (rendering costs ~45 % of its loop)."""
        self.camera_viewers = max(0, self.camera_viewers + delta)
        if self.camera_viewers and self.camera_sub is None:
            self.camera_sub = self.bus.subscribe(topics.CAMERA, CompressedImage, self._on_camera, maxsize=2)
        elif not self.camera_viewers and self.camera_sub is not None:
            self.camera_sub.close()
            self.camera_sub = None
            self.frame = b""  # a stale frame is not shown to the next viewer

    async def next_batch(self, listener: Listener) -> tuple[list[dict[str, Any] | bytes], bool]:
        """Wait for something to send: (JSON messages and binary audio chunks, in order;
        whether a new camera frame is due)."""
        while True:
            await listener.wake.wait()
            listener.wake.clear()
            now = time.monotonic()
            out: list[dict[str, Any] | bytes] = []
            camera = False
            wait_s: float | None = None
            for ch in sorted(listener.dirty):
                due = listener.last_sent.get(ch, 0.0) + self.intervals.get(ch, 0.0)
                if due > now:
                    wait_s = min(wait_s or 1e9, due - now)
                    continue
                listener.dirty.discard(ch)
                listener.last_sent[ch] = now
                if ch == "camera":
                    camera = True
                elif ch in self.latest:
                    out.append(self.latest[ch])
            while listener.events:
                out.append(listener.events.popleft())
            if wait_s is not None:
                asyncio.get_running_loop().call_later(wait_s, listener.wake.set)
            if out or camera:
                return out, camera

    # ------------------------------------------------------------ bus callbacks
    def _on_battery(self, msg: BatteryState) -> None:
        self.set("battery", views.battery_json(msg))

    def _on_ui_state(self, msg: UiState) -> None:
        self._voice_state = views.ui_state_json(msg)
        self._send_ui_state()
        self._caption_voice_reply(self._voice_state)

    def _send_ui_state(self) -> None:
        state = self._voice_state
        if self._talk_turns and state["phase"] not in VOICE_TURN_PHASES:
            state = {**views.ui_state_json(UiState(Phase.THINKING)), "via": "talk"}
        self.set("ui_state", state)
        # Sent right after it (channels go out in name order): the seed's face page shows its
        # "searching" phase while SAGE's shows "navigating" (each ignores the other's phase).
        self.set("ui_state_seed", views.seed_ui_state(state))

    @contextlib.contextmanager
    def talk_turn(self) -> Iterator[None]:
        """While a ``/talk`` question is transcribed and answered, the face thinks (see module doc)."""
        self._talk_turns += 1
        self._send_ui_state()
        try:
            yield
        finally:
            self._talk_turns -= 1
            self._send_ui_state()

    def caption(self, who: str, text: str, via: str) -> None:
        """A line for the face: ``who`` is "visitor" or "robot"; ``via`` where it came from
        ("microphone", "talk", "voice", "announcement")."""
        text = " ".join(text.split())[:CAPTION_MAX_CHARS]
        if not text:
            return
        self._caption_seq += 1
        self.captions.append(
            {"id": self._caption_seq, "who": who, "text": text, "via": via, "t": round(self.clock.now(), 2)}
        )
        self.set("captions", {"type": "captions", "items": list(self.captions)})

    def _caption_voice_reply(self, state: dict[str, Any]) -> None:
        """The voice pipeline's reply streams into ui_state.llm_tokens; it becomes a caption
        when its turn ends (the face shows the streaming text live meanwhile)."""
        tokens = str(state.get("llm_tokens") or "")
        if not tokens:  # a new turn cleared them
            self._voice_captioned = ""
        if state.get("phase") in (Phase.THINKING.value, Phase.SPEAKING.value):
            if tokens and tokens != self._voice_captioned:  # not the last turn's, kept on show
                self._voice_reply = tokens
            return
        if self._voice_reply:
            self.caption("robot", self._voice_reply, "voice")
            self._voice_captioned, self._voice_reply = self._voice_reply, ""

    def _on_doa(self, msg: Doa) -> None:
        self.set("doa", {"type": "doa", "angle": round(msg.angle_deg, 1), "source": msg.source})

    def _on_odom(self, msg: Odometry) -> None:
        self.set("odom", {"type": "odom", "x": msg.pose.x, "y": msg.pose.y, "v": msg.twist.linear_x})
        self._odom = msg.pose.as_tuple()
        if self._map_odom is None:
            self._set_pose(self._odom, msg.frame_id)
        else:
            self._set_pose(compose(self._map_odom, self._odom), "map")

    def _on_map_odom(self, msg: PoseStamped) -> None:
        """Localization's map->odom correction: odometry then gives a fresh map pose at its rate."""
        self._map_odom = msg.pose.as_tuple()

    def _on_amcl(self, msg: PoseWithCovariance) -> None:
        if self._odom is not None:
            self._map_odom = compose(msg.pose.as_tuple(), inverse(self._odom))
        self._set_pose(msg.pose.as_tuple(), msg.frame_id or "map")

    def _set_pose(self, pose: tuple[float, float, float], frame: str) -> None:
        self.robot_pose, self.robot_frame = pose, frame
        from sage_robot.core.msgs import Pose2D

        self.set("pose", views.pose_json(Pose2D(*pose), frame))

    def _on_scan(self, msg: LaserScan) -> None:
        if self.robot_pose is None:
            return
        pts = views.scan_points(msg, self.robot_pose, self.lidar_mount)
        self.set("scan", views.scan_json(pts))

    def _on_plan(self, msg: Path) -> None:
        self.set("plan", views.path_json(msg))

    def _on_goal(self, msg: PoseStamped) -> None:
        p = msg.pose
        self.set("goal", {"type": "goal", "x": p.x, "y": p.y, "theta": p.theta, "place": ""})

    def _on_people(self, msg: People) -> None:
        self.set("people", {"type": "people", "points": views.people_points(msg)})

    def _on_loc(self, msg: LocalizationHealth) -> None:
        self.set(
            "loc",
            {"type": "loc", "score": round(msg.score, 3), "lost": msg.lost, "particles": msg.particles},
        )

    def _on_map(self, msg: OccupancyGrid) -> None:
        self.map_grid = msg
        self.map_version += 1
        self.set("map", views.map_meta_json(msg, self.map_version))

    def _on_camera(self, msg: CompressedImage) -> None:
        self.frame = msg.data
        self.frame_seq += 1
        self.counts["frames_in"] += 1
        for listener in self.listeners:
            listener.mark("camera")

    def _on_event(self, msg: Event) -> None:
        self.counts["events_in"] += 1
        item = {
            "type": "event",
            "t": msg.stamp,
            "source": msg.source,
            "kind": msg.kind,
            "message": msg.message,
        }
        self.events.append(item)
        if msg.kind in SOCIAL_EVENT_KINDS:
            self.set("social", {**item, "type": "social"})
        for listener in self.listeners:
            if "events" in listener.channels:
                listener.events.append(item)
                listener.wake.set()

    def _on_audio(self, msg: AudioChunk) -> None:
        """The robot's speech: queued in order for /ws/audio clients (the simulated kiosk)."""
        self.counts["audio_in"] = self.counts.get("audio_in", 0) + 1
        items: list[dict[str, Any] | bytes] = []
        if msg.pcm:
            items.append(AUDIO_HEADER.pack(msg.sample_rate) + msg.pcm)
        if msg.final:
            items.append({"type": "audio_end", "utterance": msg.utterance})
        for listener in self.listeners:
            if "audio" in listener.channels:
                listener.events.extend(items)
                listener.wake.set()

    # ------------------------------------------------------------ map image
    async def map_png(self) -> tuple[int, bytes] | None:
        """The current map as PNG (rendered off the event loop, cached per version)."""
        grid, version = self.map_grid, self.map_version
        if grid is None:
            return None
        if self._map_png is None or self._map_png[0] != version:
            png = await asyncio.to_thread(views.map_png, grid)
            self._map_png = (version, png)
        return self._map_png
