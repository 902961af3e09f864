"""Assemble a streamed chat completion: text pieces and tool calls across chunks.

Servers differ in how they stream tool calls:

- OpenAI and llama.cpp send each call's ``id`` and ``name`` once, then the argument JSON
  in fragments, all tagged with the call's ``index``; several calls have several indices.
- Ollama sends each call whole in one chunk (arguments complete, sometimes as an object
  rather than a string), and has been seen giving every call ``index`` 0.
- Some servers leave ``index`` out.

Fragments are joined by ``index``; a new ``id`` at an index that already holds a
different call starts a new call; a fragment with neither continues the last call.
Calls without an id get one (``call_<n>``), so results can be matched to them.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any


@dataclass
class PendingCall:
    id: str = ""
    name: str = ""
    arguments: str = ""

    def as_message(self) -> dict[str, Any]:
        return {
            "id": self.id,
            "type": "function",
            "function": {"name": self.name, "arguments": self.arguments or "{}"},
        }


class StreamAssembler:
    """Feed each chunk (an ``openai`` ``ChatCompletionChunk`` or the same shape as a dict)."""

    def __init__(self) -> None:
        self.text = ""
        self.calls: list[PendingCall] = []
        self.finish_reason: str | None = None
        self._by_index: dict[int, PendingCall] = {}
        self._by_id: dict[str, PendingCall] = {}

    def feed(self, chunk: Any) -> str:
        """Take one chunk; return its text piece ('' when it carries none)."""
        choices = _get(chunk, "choices") or []
        if not choices:
            return ""
        choice = choices[0]
        self.finish_reason = _get(choice, "finish_reason") or self.finish_reason
        delta = _get(choice, "delta")
        if delta is None:
            return ""
        for tc in _get(delta, "tool_calls") or []:
            self._add_fragment(tc)
        piece = _get(delta, "content") or ""
        self.text += piece
        return piece

    def _new(self, index: int | None) -> PendingCall:
        call = PendingCall()
        self.calls.append(call)
        if index is not None:
            self._by_index[index] = call
        return call

    def _slot(self, index: int | None, call_id: str) -> PendingCall:
        if call_id:
            if call_id in self._by_id:
                return self._by_id[call_id]
            held = self._by_index.get(index) if index is not None else None
            slot = held if held is not None and not held.id else self._new(index)
            slot.id = call_id
            self._by_id[call_id] = slot
            return slot
        if index is not None:
            return self._by_index.get(index) or self._new(index)
        return self.calls[-1] if self.calls else self._new(None)

    def _add_fragment(self, tc: Any) -> None:
        index = _get(tc, "index")
        slot = self._slot(index if isinstance(index, int) else None, _get(tc, "id") or "")
        fn = _get(tc, "function")
        if fn is None:
            return
        name = _get(fn, "name")
        if name:
            slot.name = name
        args = _get(fn, "arguments")
        if isinstance(args, (dict, list)):  # Ollama may send the object itself
            slot.arguments = json.dumps(args)
        elif isinstance(args, str):
            slot.arguments += args

    def finished_calls(self) -> list[PendingCall]:
        """The calls in the order they began, each with an id."""
        for n, call in enumerate(self.calls):
            if not call.id:
                call.id = f"call_{n}"
        return list(self.calls)


def _get(obj: Any, key: str) -> Any:
    if isinstance(obj, dict):
        return obj.get(key)
    return getattr(obj, key, None)
