"""SMTP sending against a real local server: delivery, login, retries, failures as values."""

from __future__ import annotations

import time

import pytest

from sage_robot.core.config.areas import EmailSettings
from sage_robot.kb.mail import send_mail, send_mail_async
from tests.kb.kb_smtp import PASSWORD, USER, free_port, smtp_server

pytestmark = pytest.mark.filterwarnings("ignore:Requiring AUTH while not requiring TLS")


def settings(port: int, **kw) -> EmailSettings:
    base = {"smtp_host": "127.0.0.1", "smtp_port": port, "starttls": False, "sender": "sage@robot.test"}
    return EmailSettings(**{**base, "recipients": ("ops@campus.test",), **kw})


def test_delivers_to_the_profile_recipients():
    with smtp_server() as (port, inbox):
        result = send_mail(settings(port), "Battery low", "SAGE is at 20 %.")
    assert result.ok
    assert result.attempts == 1
    [msg] = inbox.messages
    assert msg["Subject"] == "Battery low"
    assert msg["From"] == "sage@robot.test"
    assert inbox.envelopes == [["ops@campus.test"]]
    assert "SAGE is at 20 %." in msg.get_payload()


def test_logs_in_with_the_password_from_the_environment(monkeypatch):
    monkeypatch.setenv("SAGE_SMTP_PASSWORD", PASSWORD)
    with smtp_server(require_auth=True) as (port, inbox):
        result = send_mail(settings(port, username=USER), "hi", "body", ["a@b.test", "c@d.test"])
    assert result.ok
    assert inbox.envelopes == [["a@b.test", "c@d.test"]]


def test_wrong_password_is_a_value_not_an_exception(monkeypatch):
    monkeypatch.setenv("SAGE_SMTP_PASSWORD", "wrong")
    with smtp_server(require_auth=True) as (port, inbox):
        result = send_mail(settings(port, username=USER), "hi", "body", retry_delay_s=0.01)
    assert not result.ok
    assert "login refused" in result.error
    assert inbox.messages == []


def test_dead_server_is_retried_then_reported(monkeypatch):
    slept: list[float] = []
    monkeypatch.setattr(time, "sleep", slept.append)  # the waits between attempts, not taken
    result = send_mail(settings(free_port()), "hi", "body", attempts=3, retry_delay_s=0.01)
    assert not result.ok
    assert result.attempts == 3
    assert "could not send after 3 attempts" in result.error
    assert "ConnectionRefusedError" in result.error
    assert slept == [0.01, 0.02]  # the given delay, doubled after each failure


def test_bad_requests_are_refused_before_connecting():
    s = settings(free_port())
    assert "not configured" in send_mail(EmailSettings(), "s", "b").error
    assert "no recipients" in send_mail(s, "s", "b", recipients=[]).error
    assert "not an e-mail address: 'x\\ny@z'" in send_mail(s, "s", "b", recipients=["x\ny@z"]).error
    assert "one line" in send_mail(s, "two\nlines", "b").error


async def test_async_send_does_not_block_the_loop():
    with smtp_server() as (port, inbox):
        result = await send_mail_async(settings(port), "async", "body")
    assert result.ok
    assert len(inbox.messages) == 1
