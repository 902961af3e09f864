"""E-mail over SMTP from the profile's ``email`` section, with retries.

``send_mail`` never raises for a failure of the mail system (server down, login refused,
recipient rejected): it returns a :class:`MailResult` saying what happened, so a caller's
loop (the battery watchdog, the HTTP endpoint) carries on. The password comes from the
secret ``SAGE_SMTP_PASSWORD`` (environment or key file) and is never logged.
"""

from __future__ import annotations

import asyncio
import smtplib
import ssl
import time
from collections.abc import Sequence
from dataclasses import dataclass
from email.message import EmailMessage

from pydantic import SecretStr

from sage_robot.core.config import read_secret
from sage_robot.core.config.areas import EmailSettings
from sage_robot.core.log import get_logger

PASSWORD_SECRET = "SAGE_SMTP_PASSWORD"
ATTEMPTS = 3  # tries per message
RETRY_DELAY_S = 2.0  # wait before the second try; doubles each time
TIMEOUT_S = 10.0  # socket time-out of one SMTP conversation (s)
MAX_SUBJECT_CHARS = 200
MAX_BODY_CHARS = 100_000

log = get_logger("kb.mail")


@dataclass(frozen=True)
class MailResult:
    ok: bool
    recipients: tuple[str, ...] = ()
    attempts: int = 0
    error: str = ""

    def as_dict(self) -> dict[str, object]:
        return {"ok": self.ok, "recipients": list(self.recipients), "attempts": self.attempts,
                "error": self.error}


def _message(settings: EmailSettings, to: Sequence[str], subject: str, body: str) -> EmailMessage:
    msg = EmailMessage()
    msg["From"] = settings.sender
    msg["To"] = ", ".join(to)
    msg["Subject"] = subject
    msg.set_content(body)
    return msg


def _send_once(settings: EmailSettings, msg: EmailMessage, password: SecretStr | None) -> None:
    with smtplib.SMTP(settings.smtp_host, settings.smtp_port, timeout=TIMEOUT_S) as smtp:
        if settings.starttls:
            smtp.starttls(context=ssl.create_default_context())
        if settings.username:
            smtp.login(settings.username, password.get_secret_value() if password else "")
        smtp.send_message(msg)


def send_mail(
    settings: EmailSettings,
    subject: str,
    body: str,
    recipients: Sequence[str] | None = None,
    key_file: str | None = None,
    attempts: int = ATTEMPTS,
    retry_delay_s: float = RETRY_DELAY_S,
) -> MailResult:
    """Send one message (blocking). ``recipients`` default to the profile's list."""
    to = tuple(recipients if recipients is not None else settings.recipients)
    if not settings.smtp_host:
        return MailResult(False, to, 0, "e-mail is not configured (email.smtp_host is empty)")
    if not to:
        return MailResult(False, to, 0, "no recipients (email.recipients is empty)")
    bad = [r for r in to if "@" not in r or any(c in r for c in "\r\n ,")]
    if bad:
        return MailResult(False, to, 0, f"not an e-mail address: {bad[0]!r}")
    if "\n" in subject or "\r" in subject or len(subject) > MAX_SUBJECT_CHARS:
        return MailResult(
            False, to, 0, f"the subject must be one line of at most {MAX_SUBJECT_CHARS} characters"
        )
    if len(body) > MAX_BODY_CHARS:
        return MailResult(False, to, 0, f"the body is longer than {MAX_BODY_CHARS} characters")
    try:
        password = read_secret(PASSWORD_SECRET, key_file)
    except Exception as exc:  # ConfigError from a bad key file: a value, not a crash
        return MailResult(False, to, 0, str(exc))
    msg = _message(settings, to, subject, body)
    error = ""
    delay = retry_delay_s
    for attempt in range(1, attempts + 1):
        try:
            _send_once(settings, msg, password)
            log.info("mail sent", to=len(to), subject=subject, attempt=attempt)
            return MailResult(True, to, attempt)
        except smtplib.SMTPRecipientsRefused as exc:
            return MailResult(False, to, attempt, f"recipients refused: {', '.join(exc.recipients)}")
        except smtplib.SMTPAuthenticationError as exc:
            return MailResult(False, to, attempt, f"login refused by {settings.smtp_host}: {exc.smtp_code}")
        except (smtplib.SMTPException, OSError) as exc:
            error = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
            log.warning("mail failed", attempt=attempt, error=error)
        if attempt < attempts:
            time.sleep(delay)
            delay *= 2
    return MailResult(False, to, attempts, f"could not send after {attempts} attempts ({error})")


async def send_mail_async(
    settings: EmailSettings, subject: str, body: str, recipients: Sequence[str] | None = None,
    key_file: str | None = None, attempts: int = ATTEMPTS, retry_delay_s: float = RETRY_DELAY_S,
) -> MailResult:
    """:func:`send_mail` in a worker thread, for the event loop."""
    return await asyncio.to_thread(
        send_mail, settings, subject, body, recipients, key_file, attempts, retry_delay_s
    )
