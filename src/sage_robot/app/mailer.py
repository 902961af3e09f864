"""E-mail over SMTP from the profile (``email:``); the password from SAGE_SMTP_PASSWORD."""

from __future__ import annotations

import asyncio
import smtplib
import ssl
from email.message import EmailMessage

from sage_robot.core.config import read_secret
from sage_robot.core.config.areas import EmailSettings

SMTP_TIMEOUT_S = 10.0


class SmtpMailer:
    def __init__(self, settings: EmailSettings, secrets_file: str = "") -> None:
        self.settings, self.secrets_file = settings, secrets_file

    def _send_blocking(self, subject: str, body: str) -> None:
        s = self.settings
        msg = EmailMessage()
        msg["From"], msg["To"], msg["Subject"] = s.sender, ", ".join(s.recipients), subject
        msg.set_content(body)
        with smtplib.SMTP(s.smtp_host, s.smtp_port, timeout=SMTP_TIMEOUT_S) as smtp:
            if s.starttls:
                smtp.starttls(context=ssl.create_default_context())
            password = read_secret("SAGE_SMTP_PASSWORD", self.secrets_file or None)
            if s.username and password:
                smtp.login(s.username, password.get_secret_value())
            smtp.send_message(msg)

    async def send(self, subject: str, body: str) -> bool:
        """Send in a worker thread; raises on failure (the caller retries)."""
        await asyncio.to_thread(self._send_blocking, subject, body)
        return True
