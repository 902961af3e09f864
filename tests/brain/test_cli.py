"""`sage ask` and `sage chat` end to end (offline, and with the LLM on a loopback server)."""

from __future__ import annotations

import asyncio
import json
import subprocess
import sys
import threading
from collections.abc import Iterator

import pytest

from sage_robot.brain.scripted import ScriptedServer, call, say
from sage_robot.cli.main import main

CHAT_TIMEOUT_S = 60.0
SIM_TIMEOUT_S = 120.0  # a `--sim` run: start the simulated robot, one turn, stop


def ask(capsys, *argv: str) -> tuple[int, str, str]:
    rc = main(["ask", *argv])
    out = capsys.readouterr()
    return rc, out.out, out.err


def test_ask_json_offline_reports_reply_and_tool_calls(capsys) -> None:
    rc, out, _ = ask(capsys, "take me to the clean room", "--json")
    data = json.loads(out)
    assert rc == 0
    assert data["brain"] == "offline"
    assert data["intent"] == "navigate"
    assert data["tool_calls"][0]["name"] == "set_goal"
    assert data["tool_calls"][0]["result"] == {"error": "navigation is not running right now"}
    assert data["reply"] == " ".join(data["sentences"])


def test_ask_plain_text(capsys) -> None:
    rc, out, _ = ask(capsys, "hello")
    assert rc == 0
    assert out.startswith("Hello")
    assert "{" not in out


def test_ask_errors_are_one_line(capsys) -> None:
    assert main(["ask", "  "]) == 2
    assert "the text to say is empty" in capsys.readouterr().err
    assert main(["ask", "hi", "--with", "teleporter"]) == 2
    assert "unknown node 'teleporter'" in capsys.readouterr().err


@pytest.fixture
def threaded_server() -> Iterator[ScriptedServer]:
    """A scripted server on its own loop in a thread (the CLI runs its own asyncio.run)."""
    loop = asyncio.new_event_loop()
    server = ScriptedServer()
    ready = threading.Event()

    def serve() -> None:
        asyncio.set_event_loop(loop)
        loop.run_until_complete(server.start())
        ready.set()
        loop.run_forever()

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    assert ready.wait(10)
    yield server
    asyncio.run_coroutine_threadsafe(server.close(), loop).result(10)
    loop.call_soon_threadsafe(loop.stop)
    thread.join(10)


def test_ask_json_with_the_llm(capsys, tmp_path, threaded_server) -> None:
    threaded_server.add(call(("describe_place", {"name": "the cafe"})), say("It is the café. Yum!"))
    profile = tmp_path / "p.yaml"
    profile.write_text(f"llm:\n  base_url: {threaded_server.base_url}\n  max_retries: 0\n")
    rc = main(["--profile", str(profile), "ask", "what is the cafe", "--json"])
    data = json.loads(capsys.readouterr().out)
    assert rc == 0
    assert data["brain"] == "llm"
    assert data["sentences"] == ["It is the café.", "Yum!"]
    assert data["tool_calls"][0]["name"] == "describe_place"
    assert data["tool_calls"][0]["ok"]


def test_chat_in_a_terminal() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "sage_robot.cli.main", "--log-level", "WARNING", "chat"],
        input="hello\nwhere is the clean room\nquit\n",
        capture_output=True,
        text=True,
        timeout=CHAT_TIMEOUT_S,
    )
    assert proc.returncode == 0, proc.stderr
    lines = [ln for ln in proc.stdout.splitlines() if "sage> " in ln]
    assert lines[0].endswith("Hello! I am SAGE Jarvis, your tour guide.") or "Hi there" in lines[0]
    assert any("Clean Room" in ln for ln in lines)


def sage(*argv: str, stdin: str = "") -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "sage_robot.cli.main", *argv],
        input=stdin, capture_output=True, text=True, timeout=SIM_TIMEOUT_S,
    )  # fmt: skip


def test_ask_sim_starts_only_the_robot_navigation_and_kb() -> None:
    proc = sage("ask", "take me to the cafe", "--sim", "--json")
    assert proc.returncode == 0, proc.stderr[-2000:]
    data = json.loads(proc.stdout)
    assert data["reply"] == "Sure, follow me to the Guelly Delly café!"
    goal = data["tool_calls"][0]
    assert goal["name"] == "set_goal"
    assert goal["ok"]
    assert goal["result"]["status"] == "navigating"
    for node in ("sim_world", "mcu_sim", "serial_bridge", "map_server", "localization", "navigator", "kb"):
        assert f"node running  node={node}" in proc.stderr, node
    for node in ("voice", "web", "foxglove"):
        assert f"node={node}" not in proc.stderr, node


def test_chat_sim_log_level_warning_hides_info(tmp_path) -> None:
    """The web node keeps INFO records for its admin page; the terminal still shows WARNING+."""
    profile = tmp_path / "p.yaml"
    profile.write_text("web:\n  host: 127.0.0.1\n  port: 0\n")
    proc = sage("--profile", str(profile), "--log-level", "WARNING", "chat", "--sim", "--with", "web",
                stdin="hello\nquit\n")  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "sage> Hello! I am SAGE Jarvis" in proc.stdout
    assert not [ln for ln in proc.stderr.splitlines() if " INFO " in ln or " DEBUG " in ln], proc.stderr
