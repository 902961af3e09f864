"""A real SMTP server on loopback (aiosmtpd) that keeps what it receives."""

from __future__ import annotations

import socket
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from email import message_from_bytes
from email.message import Message
from typing import Any

from aiosmtpd.controller import Controller
from aiosmtpd.smtp import AuthResult, LoginPassword

USER, PASSWORD = "robot", "s3cret-smtp"


@dataclass
class Inbox:
    messages: list[Message] = field(default_factory=list)
    envelopes: list[list[str]] = field(default_factory=list)

    async def handle_DATA(self, server, session, envelope):
        self.messages.append(message_from_bytes(envelope.content))
        self.envelopes.append(list(envelope.rcpt_tos))
        return "250 OK"


def _authenticator(server, session, envelope, mechanism, auth_data):
    ok = isinstance(auth_data, LoginPassword) and (auth_data.login, auth_data.password) == (
        USER.encode(),
        PASSWORD.encode(),
    )
    return AuthResult(success=ok, handled=False)  # handled=False: the server answers 535


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextmanager
def smtp_server(require_auth: bool = False) -> Iterator[tuple[int, Inbox]]:
    inbox, port = Inbox(), free_port()
    kwargs: dict[str, Any] = {
        "authenticator": _authenticator,
        "auth_require_tls": False,  # loopback only
        "auth_required": True,
        "auth_exclude_mechanism": ["LOGIN"],  # smtplib then uses PLAIN, which fails fast
    }
    controller = Controller(inbox, hostname="127.0.0.1", port=port, **(kwargs if require_auth else {}))
    controller.start()
    try:
        yield port, inbox
    finally:
        controller.stop()
