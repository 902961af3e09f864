"""A scripted OpenAI-compatible chat-completions server on loopback, for tests and benchmarks.

It speaks the real protocol (``POST /v1/chat/completions`` with ``stream: true`` →
``text/event-stream`` of ``chat.completion.chunk`` objects, ending ``data: [DONE]``) so the
real ``openai`` client talks to it over a socket. Each request takes the next scripted
reply: a stream (text and tool-call chunks, optionally with a pause per chunk or a
connection dropped half way) or an HTTP error status. Requests are kept for inspection.
It also answers ``POST /search`` like Tavily's search API.

Needs ``aiohttp`` (the ``brain`` extra).
"""

from __future__ import annotations

import asyncio
import json
from dataclasses import dataclass, field
from typing import Any

RETRY_AFTER_MS = 20  # what error replies ask the client to wait before retrying (ms)


def chunk(delta: dict[str, Any], finish: str | None = None) -> dict[str, Any]:
    return {
        "id": "chatcmpl-scripted",
        "object": "chat.completion.chunk",
        "created": 0,
        "model": "scripted",
        "choices": [{"index": 0, "delta": delta, "finish_reason": finish}],
    }


def text_chunks(text: str, piece_chars: int = 6) -> list[dict[str, Any]]:
    """``text`` cut into pieces of ``piece_chars`` characters, as a model streams tokens."""
    out = [chunk({"role": "assistant", "content": ""})]
    out += [chunk({"content": text[i : i + piece_chars]}) for i in range(0, len(text), piece_chars)]
    return out


def tool_call_chunks(
    calls: list[tuple[str, str | dict[str, Any]]], style: str = "openai", fragment_chars: int = 5
) -> list[dict[str, Any]]:
    """Tool calls as a server streams them.

    ``openai`` (also llama.cpp): id and name first, then the argument JSON in fragments of
    ``fragment_chars``, each tagged with the call's index. ``ollama``: every call whole in
    one chunk, arguments as an object, all with index 0.
    """
    out: list[dict[str, Any]] = []
    for i, (name, args) in enumerate(calls):
        call_id = f"call_{name}_{i}"
        if style == "ollama":
            tc = {"index": 0, "id": call_id, "type": "function",
                  "function": {"name": name, "arguments": args}}  # fmt: skip
            out.append(chunk({"tool_calls": [tc]}))
            continue
        text = args if isinstance(args, str) else json.dumps(args)
        head = {"index": i, "id": call_id, "type": "function", "function": {"name": name, "arguments": ""}}
        out.append(chunk({"tool_calls": [head]}))
        for j in range(0, len(text), fragment_chars):
            frag = {"index": i, "function": {"arguments": text[j : j + fragment_chars]}}
            out.append(chunk({"tool_calls": [frag]}))
    return out


@dataclass
class Stream:
    """A streamed reply. ``drop_after``: close the connection after this many chunks."""

    chunks: list[dict[str, Any]]
    finish: str = "stop"
    delay_s: float = 0.0  # pause before each chunk
    drop_after: int | None = None


@dataclass
class Status:
    """An HTTP error reply (429, 500, ...)."""

    code: int
    message: str = "scripted error"
    headers: dict[str, str] = field(default_factory=lambda: {"retry-after-ms": str(RETRY_AFTER_MS)})


def say(text: str, **kw: Any) -> Stream:
    return Stream(text_chunks(text), "stop", **kw)


def call(*calls: tuple[str, str | dict[str, Any]], style: str = "openai", text: str = "") -> Stream:
    lead = text_chunks(text) if text else [chunk({"role": "assistant"})]
    return Stream(lead + tool_call_chunks(list(calls), style), "tool_calls")


class ScriptedServer:
    """``async with ScriptedServer([say("Hi."), ...]) as server: server.base_url``."""

    def __init__(self, script: list[Stream | Status] | None = None) -> None:
        self.script: list[Stream | Status] = list(script or [])
        self.requests: list[dict[str, Any]] = []
        self.search_requests: list[tuple[str, dict[str, Any]]] = []
        self.auth: list[str] = []  # the Authorization header of each completion request
        self.search_reply: dict[str, Any] = {"answer": "", "results": []}
        self.chunks_sent = 0  # over all streams, so a test can tell "still streaming"
        self.base_url = ""
        self._runner: Any = None

    async def __aenter__(self) -> ScriptedServer:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    async def start(self, host: str = "127.0.0.1") -> str:
        from aiohttp import web

        app = web.Application()
        app.router.add_post("/v1/chat/completions", self._completions)
        app.router.add_post("/search", self._search)
        self._runner = web.AppRunner(app, access_log=None)
        await self._runner.setup()
        site = web.TCPSite(self._runner, host, 0)
        await site.start()
        port = site._server.sockets[0].getsockname()[1]  # type: ignore[union-attr]
        self.base_url = f"http://{host}:{port}/v1"
        return self.base_url

    async def close(self) -> None:
        if self._runner is not None:
            await self._runner.cleanup()
            self._runner = None

    def add(self, *replies: Stream | Status) -> None:
        self.script.extend(replies)

    async def _completions(self, request: Any) -> Any:
        from aiohttp import web

        self.requests.append(await request.json())
        self.auth.append(request.headers.get("Authorization", ""))
        if not self.script:
            return web.json_response({"error": {"message": "script exhausted"}}, status=500)
        reply = self.script.pop(0)
        if isinstance(reply, Status):
            body = {"error": {"message": reply.message, "type": "scripted", "code": reply.code}}
            return web.json_response(body, status=reply.code, headers=reply.headers)
        resp = web.StreamResponse(headers={"Content-Type": "text/event-stream", "Cache-Control": "no-cache"})
        await resp.prepare(request)
        chunks = [*reply.chunks, chunk({}, reply.finish)]
        for n, c in enumerate(chunks):
            if reply.drop_after is not None and n >= reply.drop_after:
                request.transport.close()  # mid-stream: no final chunk, no [DONE]
                return resp
            if reply.delay_s:
                await asyncio.sleep(reply.delay_s)
            await resp.write(f"data: {json.dumps(c)}\n\n".encode())
            self.chunks_sent += 1
        await resp.write(b"data: [DONE]\n\n")
        await resp.write_eof()
        return resp

    async def _search(self, request: Any) -> Any:
        from aiohttp import web

        self.search_requests.append((request.headers.get("Authorization", ""), await request.json()))
        return web.json_response(self.search_reply)
