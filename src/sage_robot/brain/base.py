"""What every brain offers: one visitor turn in, speakable sentences out as they are ready."""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from sage_robot.brain.tools import ToolCall
from sage_robot.core.msgs import Utterance as Utterance  # a converse goal naming its conversation

Say = Callable[[str], None]  # called with each sentence to speak, in order
DEFAULT_SESSION = "robot"  # the robot's own conversation: its microphone, /talk, typed goals


@dataclass
class TurnResult:
    """One turn: the whole reply, its sentences, the tool calls made and which brain answered."""

    reply: str = ""
    sentences: list[str] = field(default_factory=list)
    tool_calls: list[ToolCall] = field(default_factory=list)
    brain: str = "offline"
    fell_back: bool = False  # the LLM failed and the offline brain answered
    error: str = ""  # what went wrong with the endpoint, for logs and `sage ask --json`
    intent: str = ""  # the offline brain's intent

    def as_dict(self) -> dict[str, Any]:
        return {
            "reply": self.reply,
            "sentences": self.sentences,
            "tool_calls": [c.as_dict() for c in self.tool_calls],
            "brain": self.brain,
            "fell_back": self.fell_back,
            "error": self.error,
            "intent": self.intent,
        }


class Speaker:
    """Collects sentences for a :class:`TurnResult` while passing each on at once."""

    def __init__(self, say: Say | None, result: TurnResult) -> None:
        self._say, self._result = say, result

    def __call__(self, sentence: str) -> None:
        if not sentence:
            return
        self._result.sentences.append(sentence)
        if self._say is not None:
            self._say(sentence)

    def finish(self) -> TurnResult:
        self._result.reply = " ".join(self._result.sentences)
        return self._result


class Brain(ABC):
    """A conversation partner. ``respond`` may be cancelled (barge-in) at any await."""

    kind = "brain"

    @abstractmethod
    async def respond(self, text: str, say: Say | None = None, session: str = DEFAULT_SESSION) -> TurnResult:
        """Answer one visitor utterance of conversation ``session``, calling ``say`` with
        each sentence as it is ready."""

    @abstractmethod
    async def react(self, prompt: str, fallback: str, say: Say | None = None) -> TurnResult:
        """A turn the robot starts itself (an arrival): ``prompt`` for a model, else ``fallback``."""

    @abstractmethod
    def reset(self, session: str | None = None) -> None:
        """Forget one conversation, or every one."""
