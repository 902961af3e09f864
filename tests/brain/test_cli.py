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


def ask(capsys, *argv: str) -> tuple[int, str, str]:
    rc = main(["ask", *argv])
    out = capsys.readouterr()
    return rc, out.out, out.err


def test_ask_json_offline_reports_reply_and_tool_calls(capsys) -> None:
    rc, out, _ = ask(capsys, "take me to the clean room", "--json")
    data = json.loads(out)
    assert rc == 0 and data["brain"] == "offline" and data["intent"] == "navigate"
    assert data["tool_calls"][0]["name"] == "set_goal"
    assert data["tool_calls"][0]["result"] == {"error": "navigation is not running right now"}
    assert data["reply"] == " ".join(data["sentences"])


def test_ask_plain_text(capsys) -> None:
    rc, out, _ = ask(capsys, "hello")
    assert rc == 0 and out.startswith("Hello") and "{" not in out


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
    assert rc == 0 and data["brain"] == "llm" and data["sentences"] == ["It is the café.", "Yum!"]
    assert data["tool_calls"][0]["name"] == "describe_place" and data["tool_calls"][0]["ok"]


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
