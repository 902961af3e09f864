"""Measure crash isolation of `sage sim --processes` (issue #24): kill -9 groups while the robot drives.

Starts the simulator as process groups on a free loopback port, drives the robot with a
steady teleop command on /cmd_vel (over Zenoh, as the pages' joystick would), then for each
group named: kill -9 its process, and measures how long until the supervisor reports it
running again (a new pid), whether any other group's pid changed, and how fast the robot
moved meanwhile (ground truth). Killing ``motion`` (the serial bridge) must stop the robot
while teleop keeps commanding: the firmware's command watchdog. Prints one JSON line.

``--nav-goal PLACE`` first measures the nav group killed *while nav drives*: the operator's
goal goes in through the web's ``POST /api/goal`` (the web process sends it to the navigator
in the nav process, a Zenoh action), and once the robot drives the nav group is killed:
time until a zero /cmd_vel, until the robot is at rest (ground truth), until the web's goal
ends (its ``/ws/status`` ``nav`` message) and until nav is back; that the robot stays at rest
after (nobody resends the goal) and that no other group restarted.

    .venv/bin/python scripts/crash_isolation.py --groups voice,brain,nav,motion
    .venv/bin/python scripts/crash_isolation.py --nav-goal CLEAN_ROOM --groups ""
"""

from __future__ import annotations

import argparse
import contextlib
import http.cookiejar
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from pathlib import Path
from typing import Any

import yaml
import zenoh
from websockets.sync.client import connect as ws_connect

from sage_robot.core import topics
from sage_robot.core.config import default_profile_path
from sage_robot.core.msgs import Twist
from sage_robot.core.transport import wire
from sage_robot.core.transport.keys import topic_key

START_S = 300.0  # bound on the whole system coming up (s, wall)
BACK_S = 120.0  # bound on one group coming back (s, wall)
STOP_S = 30.0  # bound on the robot stopping after the motion group died (s, wall)
TELEOP_PERIOD_S = 0.1  # the teleop command's period (s)
DRIVE = Twist(0.2, 0.3)  # m/s, rad/s: a slow circle
MOVING_MPS = 0.05  # faster than this counts as moving (m/s)
CRUISING_MPS = 0.9 * DRIVE.linear_x  # teleop's kills wait for this (from rest it is still speeding up)
POLL_S = 0.02
RATE_WINDOW_S = 2.0  # the simulation's real-time factor is taken over this much wall time (s)
STOPPED_MPS = 0.01  # slower than this counts as at rest (m/s)
GOAL_S = 120.0  # bound on the navigator taking the goal and the robot driving (s, wall)
DRIVE_FIRST_S = 2.0  # the robot drives this long under nav before the kill (s, simulated)
DRIVING_MPS = 0.3  # ... and at least this fast at the kill (m/s)
AT_REST_AFTER_S = 3.0  # watch the robot this long after nav is back: it must stay at rest (s)
PASSWORD = "crash-isolation-operator"


class Watch:
    """The robot's health and ground truth as seen over Zenoh."""

    def __init__(self, endpoint: str, robot: str) -> None:
        cfg = zenoh.Config()
        cfg.insert_json5("mode", '"client"')
        cfg.insert_json5("connect/endpoints", json.dumps([endpoint]))
        cfg.insert_json5("scouting/multicast/enabled", "false")
        self.session = zenoh.open(cfg)
        self.robot = robot
        self.health: dict[str, Any] = {}
        self.truth: list[tuple[float, float, float]] = []  # (wall, sim stamp, speed)
        self.session.declare_subscriber(topic_key(robot, topics.HEALTH), self._on_health)
        self.session.declare_subscriber(topic_key(robot, topics.SIM_TRUTH), self._on_truth)
        self.cmd_vel: list[tuple[float, tuple[float, float]]] = []  # (wall, (v, w)) as the bus carries them
        self.session.declare_subscriber(topic_key(robot, topics.CMD_VEL), self._on_cmd_vel)
        self.teleop = threading.Event()

    def _on_cmd_vel(self, sample: Any) -> None:
        twist = wire.decode(sample.payload.to_bytes())
        self.cmd_vel.append((time.monotonic(), (twist.linear_x, twist.angular_z)))

    def _on_health(self, sample: Any) -> None:
        report = wire.decode(sample.payload.to_bytes())
        self.health = {n.name: n for n in report.nodes}

    def _on_truth(self, sample: Any) -> None:
        odom = wire.decode(sample.payload.to_bytes())
        self.truth.append((time.monotonic(), odom.stamp, abs(odom.twist.linear_x)))

    def processes(self) -> dict[str, Any]:
        return {k.split(":", 1)[1]: v for k, v in self.health.items() if k.startswith("process:")}

    def drive(self) -> None:
        key, frame = topic_key(self.robot, topics.CMD_VEL), wire.encode(DRIVE)
        while self.teleop.is_set():
            self.session.put(key, frame)
            time.sleep(TELEOP_PERIOD_S)

    def speed_since(self, t0: float) -> list[float]:
        return [v for w, _, v in self.truth if w >= t0]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def page_health(url: str, group: str) -> dict[str, Any]:
    """The web page's /api/health entry for ``group``'s process (what the pages show)."""
    with urllib.request.urlopen(url, timeout=10) as r:
        nodes = json.loads(r.read())["nodes"]
    entry = nodes.get(f"process:{group}", {})
    out = {"state": entry.get("state"), "restarts": entry.get("restarts")}
    members = str(entry.get("stats", {}).get("nodes", "")).split(",")
    out["nodes"] = {n: nodes.get(n, {}).get("state") for n in members if n}
    return out


def connect(endpoint: str, robot: str) -> Watch:
    """A Watch once the supervisor's router listens (bounded by START_S)."""
    t0 = time.monotonic()
    while True:
        try:
            return Watch(endpoint, robot)
        except zenoh.ZError:
            if time.monotonic() - t0 > START_S:
                raise SystemExit(f"no router at {endpoint} after {START_S:g} s") from None
            time.sleep(0.5)


def wait(cond: Any, bound: float, what: str) -> float:
    t0 = time.monotonic()
    while not cond():
        if time.monotonic() - t0 > bound:
            raise SystemExit(f"timed out after {bound:g} s waiting for {what}")
        time.sleep(POLL_S)
    return time.monotonic() - t0


def kill_and_measure(w: Watch, group: str) -> dict[str, Any]:
    procs = w.processes()
    pids = {g: p.stats.get("pid") for g, p in procs.items()}
    t_kill = time.monotonic()
    sim_kill = w.truth[-1][1] if w.truth else 0.0
    os.kill(int(pids[group]), signal.SIGKILL)
    out: dict[str, Any] = {"group": group}
    if group == "motion":
        wait(lambda: any(v < 0.01 for w_, _, v in w.truth if w_ > t_kill + 0.05), STOP_S, "the robot stopped")
        stopped = next(s for w_, s, v in w.truth if w_ > t_kill + 0.05 and v < 0.01)
        out["robot_stopped_after_sim_s"] = round(stopped - sim_kill, 3)

    def back() -> bool:
        p = w.processes().get(group)
        return p is not None and p.state == "running" and p.stats.get("pid") != pids[group]

    wait(back, BACK_S, f"{group} back")
    out["back_after_s"] = round(time.monotonic() - t_kill, 2)
    members = str(procs[group].stats.get("nodes", "")).split(",")
    wait(lambda: all(getattr(w.health.get(n), "state", "") == "running" for n in members), BACK_S,
         f"{group}'s nodes running")
    out["nodes_running_after_s"] = round(time.monotonic() - t_kill, 2)
    speeds = w.speed_since(t_kill)
    out["min_speed_mps_while_down"] = round(min(speeds), 3) if speeds else None
    out["max_speed_mps_while_down"] = round(max(speeds), 3) if speeds else None
    now = {g: p.stats.get("pid") for g, p in w.processes().items()}
    out["others_restarted"] = sorted(g for g in pids if g != group and now.get(g) != pids[g])
    out["restarts"] = w.processes()[group].restarts
    return out


class Web:
    """The operator's side of the web server: logged in, sends goals, watches ``/ws/status``."""

    def __init__(self, port: int) -> None:
        self.base = f"http://127.0.0.1:{port}"
        cookies = urllib.request.HTTPCookieProcessor(http.cookiejar.CookieJar())
        self.opener = urllib.request.build_opener(cookies)
        self.nav: list[tuple[float, dict[str, Any]]] = []  # (wall, the page's "nav" message)
        self.stop = threading.Event()

    def post(self, path: str, body: dict[str, Any]) -> tuple[int, Any]:
        req = urllib.request.Request(self.base + path, json.dumps(body).encode(), method="POST",
                                     headers={"Content-Type": "application/json"})
        try:
            with self.opener.open(req, timeout=10) as r:
                return r.status, json.loads(r.read())
        except urllib.error.HTTPError as err:
            return err.code, err.read().decode("utf-8", "replace")

    def watch_status(self) -> None:
        with ws_connect(self.base.replace("http", "ws") + "/ws/status", open_timeout=10) as ws:
            while not self.stop.is_set():
                with contextlib.suppress(TimeoutError):
                    msg = json.loads(ws.recv(timeout=0.5))
                    if msg.get("type") == "nav":
                        self.nav.append((time.monotonic(), msg))


def first_after(rows: list[Any], t0: float, cond: Any, bound: float, what: str) -> tuple[float, Any]:
    """The first ``(wall, x)`` row after ``t0`` whose ``x`` meets ``cond``, waited for (bounded)."""

    def found() -> tuple[float, Any] | None:
        return next(((t, x) for t, x in list(rows) if t > t0 and cond(x)), None)

    wait(lambda: found() is not None, bound, what)
    row = found()
    assert row is not None
    return row


def nav_goal_then_kill(w: Watch, web: Web, place: str) -> dict[str, Any]:
    """The nav group killed while it drives the robot to ``place`` (the web's goal)."""
    out: dict[str, Any] = {"group": "nav", "while": f"navigating to {place} (goal from the web)"}
    status, _ = web.post("/api/login", {"password": PASSWORD})
    if status != 200:
        raise SystemExit(f"operator login refused: HTTP {status}")
    threading.Thread(target=web.watch_status, daemon=True).start()
    t0 = time.monotonic()
    while True:  # 503 until the web process knows the navigator (another process) serves goals
        status, body = web.post("/api/goal", {"place": place})
        if status == 200:
            break
        if time.monotonic() - t0 > GOAL_S:
            raise SystemExit(f"the goal was refused for {GOAL_S:g} s: HTTP {status} {body}")
        time.sleep(0.5)
    out["goal_accepted_after_s"] = round(time.monotonic() - t0, 2)
    wait(lambda: w.truth and w.truth[-1][2] > MOVING_MPS, GOAL_S, "nav driving the robot")
    sim_moving = w.truth[-1][1]
    wait(lambda: w.truth[-1][1] - sim_moving >= DRIVE_FIRST_S and w.truth[-1][2] >= DRIVING_MPS, GOAL_S,
         f"nav driving at {DRIVING_MPS:g} m/s")
    procs = w.processes()
    pids = {g: p.stats.get("pid") for g, p in procs.items()}
    out["speed_before_kill_mps"] = round(w.truth[-1][2], 3)
    recent = [(t, stamp) for t, stamp, _ in list(w.truth) if t > time.monotonic() - RATE_WINDOW_S]
    if len(recent) > 1:  # how fast simulated time ran just before the kill (the machine's load)
        (w0, s0), (w1, s1) = recent[0], recent[-1]
        out["sim_real_time_factor"] = round((s1 - s0) / (w1 - w0), 2)
    t_kill = time.monotonic()
    sim_kill = w.truth[-1][1]
    os.kill(int(pids["nav"]), signal.SIGKILL)
    zero = first_after(w.cmd_vel, t_kill, lambda c: c == (0.0, 0.0), STOP_S, "a zero /cmd_vel")
    out["zero_cmd_vel_after_s"] = round(zero[0] - t_kill, 3)
    wait(lambda: w.truth[-1][2] < STOPPED_MPS, STOP_S, "the robot at rest")
    truth = [(t, (stamp, v)) for t, stamp, v in list(w.truth)]
    rest = first_after(truth, t_kill, lambda x: x[1] < STOPPED_MPS, STOP_S, "the robot at rest")
    out["robot_at_rest_after_s"] = round(rest[0] - t_kill, 3)
    out["robot_at_rest_after_sim_s"] = round(rest[1][0] - sim_kill, 3)
    ended = first_after(web.nav, t_kill, lambda m: m.get("done"), BACK_S, "the web's goal ended")
    with contextlib.suppress(OSError):  # what the pages show while nav is down (one report later)
        time.sleep(max(0.0, 1.0 - (time.monotonic() - t_kill)))
        out["page_while_down"] = page_health(f"{web.base}/api/health", "nav")
        out["page_while_down"]["after_s"] = round(time.monotonic() - t_kill, 2)
    out["web_goal_ended_after_s"] = round(ended[0] - t_kill, 3)
    out["web_goal_end"] = {k: ended[1].get(k) for k in ("state", "reason")}

    def back() -> bool:
        p = w.processes().get("nav")
        return p is not None and p.state == "running" and p.stats.get("pid") != pids["nav"]

    wait(back, BACK_S, "nav back")
    t_back = time.monotonic()
    out["back_after_s"] = round(t_back - t_kill, 2)
    members = str(procs["nav"].stats.get("nodes", "")).split(",")
    wait(lambda: all(getattr(w.health.get(n), "state", "") == "running" for n in members), BACK_S,
         "nav's nodes running")
    out["nodes_running_after_s"] = round(time.monotonic() - t_kill, 2)
    time.sleep(AT_REST_AFTER_S)
    after = [v for t, _, v in list(w.truth) if t > t_back]
    out["max_speed_mps_after_back"] = round(max(after), 3) if after else None
    now = {g: p.stats.get("pid") for g, p in w.processes().items()}
    out["others_restarted"] = sorted(g for g in pids if g != "nav" and now.get(g) != pids[g])
    out["restarts"] = w.processes()["nav"].restarts
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    p.add_argument("--groups", default="voice,brain,nav,motion", help="groups to kill, in order")
    p.add_argument("--headless", action="store_true", help="no web server (fewer processes)")
    p.add_argument("--nav-goal", default="", metavar="PLACE",
                   help="first kill nav while it drives to PLACE (a goal from the web)")
    args = p.parse_args()
    if args.nav_goal and args.headless:
        p.error("--nav-goal sends its goal through the web server: not with --headless")
    robot, endpoint, web_port = f"crash{os.getpid()}", f"tcp/127.0.0.1:{free_port()}", free_port()
    data = yaml.safe_load(default_profile_path().read_text())
    data["bus"] = {"robot_id": robot, "zenoh": {"listen": [endpoint]}}
    data["web"] = {**data.get("web", {}), "host": "127.0.0.1", "port": web_port, "http_port": None}
    profile = Path(tempfile.mkdtemp()) / "sim.yaml"
    profile.write_text(yaml.safe_dump(data))
    web = None if args.headless else f"http://127.0.0.1:{web_port}/api/health"
    cmd = [sys.executable, "-m", "sage_robot.cli.main", "--profile", str(profile), "sim", "--processes"]
    env = {**os.environ, "SAGE_OPERATOR_PASSWORD": PASSWORD}
    sage = subprocess.Popen(cmd + (["--headless"] if args.headless else []), env=env)
    results: dict[str, Any] = {"kills": []}
    w: Watch | None = None
    try:
        w = connect(endpoint, robot)
        results["start_s"] = round(wait(lambda: w.processes() and all(
            x.state == "running" for x in w.processes().values()), START_S, "every group running"), 1)
        results["groups"] = {g: x.stats.get("nodes") for g, x in w.processes().items()}
        if args.nav_goal:
            web_client = Web(web_port)
            try:
                results["kills"].append(nav_goal_then_kill(w, web_client, args.nav_goal))
            finally:
                web_client.stop.set()
            time.sleep(1.5)  # one health period: the page's report is at most this old
            results["kills"][-1]["page"] = page_health(f"http://127.0.0.1:{web_port}/api/health", "nav")
        w.teleop.set()
        threading.Thread(target=w.drive, daemon=True).start()
        wait(lambda: w.truth and w.truth[-1][2] > CRUISING_MPS, START_S, "the robot at teleop's speed")
        for group in [g for g in args.groups.split(",") if g]:
            results["kills"].append(kill_and_measure(w, group))
            if web is not None:
                time.sleep(1.5)  # one health period: the page's report is at most this old
                results["kills"][-1]["page"] = page_health(web, group)
            wait(lambda: w.truth and w.truth[-1][2] > CRUISING_MPS, BACK_S, "teleop's speed again")
        w.teleop.clear()
    finally:
        sage.send_signal(signal.SIGINT)
        try:
            sage.wait(30)
        except subprocess.TimeoutExpired:
            sage.kill()
        if w is not None:
            with contextlib.suppress(Exception):
                w.session.close()  # type: ignore[no-untyped-call]
    print(json.dumps(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
