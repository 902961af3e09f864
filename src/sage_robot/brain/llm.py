"""The conversation agent over any OpenAI-compatible chat-completions endpoint.

One visitor turn is a loop of streamed model calls: text is cut into sentences and
handed on as each completes; tool calls are assembled from the stream
(:mod:`sage_robot.brain.stream`), run through the :class:`ToolRegistry` (arguments validated
by each tool's model, errors go back to the model) and their results fed back, for at most
``llm.max_tool_rounds`` rounds. The ``openai`` client retries 429/5xx/connection errors
with exponential backoff (``llm.max_retries``, honouring ``Retry-After``). When the
endpoint still fails before anything was said or done, the robot says so in one
sentence and the offline brain answers; for ``llm.offline_retry_s`` after that the
offline brain answers directly, then the endpoint is tried again.

A turn can be cancelled at any await (barge-in): the HTTP stream is closed and only
what was already spoken is kept in the history.
"""

from __future__ import annotations

import asyncio
import json
import logging
from collections.abc import Callable
from typing import Any

from sage_robot.brain.base import DEFAULT_SESSION, Brain, Say, Speaker, TurnResult
from sage_robot.brain.offline import OfflineBrain
from sage_robot.brain.prompt import system_prompt
from sage_robot.brain.speech import SentenceSplitter
from sage_robot.brain.stream import PendingCall, StreamAssembler
from sage_robot.brain.tools import ToolRegistry
from sage_robot.core.clock import Clock
from sage_robot.core.config import Settings, read_secret

NO_KEY = "not-needed"  # Ollama, llama.cpp and vLLM accept any key; the client wants one
ENDPOINT_DOWN = "My online brain is not answering right now, so I will keep it simple."
LOST_CONNECTION = "Sorry, I lost my connection for a moment."
TANGLED = "Sorry, I got a bit tangled up there. Could you ask me again?"
MAX_CONVERSATIONS = 32  # sessions whose history is kept at once; the one idle longest goes first

_log = logging.getLogger("sage.brain.llm")

Message = dict[str, Any]


def make_client(settings: Settings) -> Any:
    """An ``openai.AsyncOpenAI`` for ``llm.base_url``; the key from the environment or key file."""
    from openai import AsyncOpenAI

    llm = settings.llm
    key = read_secret(llm.api_key_env, settings.secrets_file or None)
    return AsyncOpenAI(
        base_url=llm.base_url,
        api_key=key.get_secret_value() if key else NO_KEY,
        timeout=llm.timeout_s,
        max_retries=llm.max_retries,
    )


def _endpoint_errors() -> tuple[type[BaseException], ...]:
    import httpx
    import openai

    return (openai.APIError, httpx.HTTPError)


class LlmBrain(Brain):
    """Streamed tool-using agent with the offline brain as its fallback."""

    kind = "llm"

    def __init__(
        self,
        settings: Settings,
        tools: ToolRegistry,
        clock: Clock,
        client: Any = None,
        today: Callable[[], Any] | None = None,
    ) -> None:
        self.settings, self.llm = settings, settings.llm
        self.tools, self.robot, self.clock = tools, tools.ctx.robot, clock
        self.client = client if client is not None else make_client(settings)
        self.offline = OfflineBrain(tools, settings.robot.name, clock)
        self._histories: dict[str, list[list[Message]]] = {}  # per session, most recent last
        self._session = DEFAULT_SESSION
        self.history: list[list[Message]] = self._history_of(DEFAULT_SESSION)  # one list per turn
        self._offline_until = -1e18
        self._today = today

    def reset(self, session: str | None = None) -> None:
        for name, history in self._histories.items():
            if session is None or name == session:
                history.clear()
        self.offline.reset(session)

    def _history_of(self, session: str) -> list[list[Message]]:
        """The session's history (made when new), bounded to :data:`MAX_CONVERSATIONS`."""
        history = self._histories.pop(session, [])
        self._histories[session] = history
        while len(self._histories) > MAX_CONVERSATIONS:
            del self._histories[next(iter(self._histories))]
        return history

    async def respond(self, text: str, say: Say | None = None, session: str = DEFAULT_SESSION) -> TurnResult:
        self._session, self.history = session, self._history_of(session)
        return await self._turn({"role": "user", "content": text}, text, None, say)

    async def react(self, prompt: str, fallback: str, say: Say | None = None) -> TurnResult:
        return await self._turn({"role": "user", "content": f"[event] {prompt}"}, prompt, fallback, say)

    # ------------------------------------------------------------ one turn
    async def _turn(self, user: Message, text: str, fallback: str | None, say: Say | None) -> TurnResult:
        if self.clock.now() < self._offline_until:
            return await self._offline(text, fallback, say, announce=False, error="")
        result = TurnResult(brain=self.kind)
        speaker = Speaker(say, result)
        turn: list[Message] = [user]
        try:
            await self._converse(turn, speaker, result)
        except asyncio.CancelledError:
            self._remember_partial(turn, result)
            raise
        except _endpoint_errors() as exc:
            error = f"{type(exc).__name__}: {exc}"
            _log.warning("LLM endpoint failed: %s", error)
            if not result.sentences and not result.tool_calls:
                self._offline_until = self.clock.now() + self.llm.offline_retry_s
                return await self._offline(text, fallback, say, announce=fallback is None, error=error)
            speaker(LOST_CONNECTION)
            result.error = error
            self._remember_partial(turn, result)
            return speaker.finish()
        self._remember(turn)
        return speaker.finish()

    async def _offline(
        self, text: str, fallback: str | None, say: Say | None, announce: bool, error: str
    ) -> TurnResult:
        if fallback is not None:
            result = await self.offline.react(text, fallback, say)
        else:
            if announce and say is not None:
                say(ENDPOINT_DOWN)
            result = await self.offline.respond(text, say, self._session)
            if announce:
                result.sentences.insert(0, ENDPOINT_DOWN)
                result.reply = " ".join(result.sentences)
        result.fell_back, result.error = True, error
        return result

    async def _converse(self, turn: list[Message], speaker: Speaker, result: TurnResult) -> None:
        rounds = self.llm.max_tool_rounds
        for round_no in range(rounds + 1):
            offer_tools = round_no < rounds
            messages = [await self._system(), *self._flat_history(), *turn]
            splitter = SentenceSplitter()
            asm = await self._stream(messages, offer_tools, splitter, speaker)
            for sentence in splitter.flush():
                speaker(sentence)
            calls = asm.finished_calls() if offer_tools else []
            assistant: Message = {"role": "assistant", "content": asm.text or None}
            if calls:
                assistant["tool_calls"] = [c.as_message() for c in calls]
            turn.append(assistant)
            if not calls:
                if not asm.text.strip() and not result.sentences:
                    speaker(TANGLED)
                return
            for call in calls:
                turn.append(await self._run_tool(call, result))
        speaker(TANGLED)  # unreachable unless the last round still wanted tools

    async def _stream(
        self, messages: list[Message], offer_tools: bool, splitter: SentenceSplitter, speaker: Speaker
    ) -> StreamAssembler:
        kwargs: dict[str, Any] = {
            "model": self.llm.model,
            "messages": messages,
            "stream": True,
            "temperature": self.llm.temperature,
            "max_tokens": self.llm.max_tokens,
        }
        if offer_tools:
            kwargs["tools"] = self.tools.specs()
        stream = await self.client.chat.completions.create(**kwargs)
        asm = StreamAssembler()
        try:
            async for chunk in stream:
                piece = asm.feed(chunk)
                if piece:
                    for sentence in splitter.feed(piece):
                        speaker(sentence)
        finally:
            await stream.close()
        return asm

    async def _run_tool(self, call: PendingCall, result: TurnResult) -> Message:
        done = await self.tools.call(call.name, call.arguments)
        result.tool_calls.append(done)
        return {"role": "tool", "tool_call_id": call.id, "content": done.result.to_json()}

    # ------------------------------------------------------------ context
    async def _system(self) -> Message:
        places = await self.robot.places()
        today = self._today() if self._today else None
        return {
            "role": "system",
            "content": system_prompt(
                self.settings.robot.name, places, self.robot.motion(), today,
                safety=self.robot.readiness().describe(),
            ),
        }

    def _flat_history(self) -> list[Message]:
        return [m for turn in self.history for m in turn]

    def _remember(self, turn: list[Message]) -> None:
        self.history.append(turn)
        del self.history[: -self.llm.max_history_turns]

    def _remember_partial(self, turn: list[Message], result: TurnResult) -> None:
        """After a cancel or a broken stream: the visitor's words and what was spoken."""
        spoken = " ".join(result.sentences)
        if spoken:
            self._remember([turn[0], {"role": "assistant", "content": spoken}])

    def describe_history(self) -> str:
        return json.dumps(self._flat_history(), indent=1)
