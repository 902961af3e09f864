"""Operator login, sessions, WebSocket origin checks and rate limits.

- The operator password comes from ``SAGE_OPERATOR_PASSWORD`` (environment or the
  profile's key file). When it is unset, one is generated on first run, stored mode 600
  in ``state_dir()/operator_password`` and printed once on the terminal.
- A successful login gives a random session token in an HttpOnly, SameSite=Strict
  cookie; pages, REST calls and WebSockets check it. Tokens live in memory (a restart
  logs everybody out) and expire after :data:`SESSION_TTL_S`.
- Browsers always send ``Origin`` on a WebSocket handshake: it must be this server's
  own origin or one listed in ``web.allowed_origins`` (stops cross-site WebSocket
  hijacking). Clients that are not browsers send none and still need the cookie.
- Visitors' endpoints and login attempts are rate-limited per client address
  (token bucket).
"""

from __future__ import annotations

import hmac
import os
import secrets
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import urlsplit

from sage_robot.core.config import Settings, read_secret
from sage_robot.core.log import get_logger
from sage_robot.core.paths import state_dir

PASSWORD_ENV = "SAGE_OPERATOR_PASSWORD"
PASSWORD_FILE = "operator_password"
GENERATED_PASSWORD_BYTES = 12  # ~16 URL-safe characters
SESSION_COOKIE = "sage_session"
SESSION_TTL_S = 12 * 3600.0  # an operator shift
MAX_SESSIONS = 256  # oldest sessions are forgotten beyond this

_log = get_logger("web")


def operator_password(settings: Settings, announce: bool = True) -> str:
    """The operator password: environment / key file, else the stored generated one, else a new one.

    A newly generated password is written mode 600 and printed once to stderr.
    """
    secret = read_secret(PASSWORD_ENV, settings.secrets_file or None)
    if secret is not None:
        return secret.get_secret_value()
    path = state_dir() / PASSWORD_FILE
    if path.exists():
        text = path.read_text(encoding="utf-8").strip()
        if text:
            return text
    password = secrets.token_urlsafe(GENERATED_PASSWORD_BYTES)
    _write_private(path, password + "\n")
    if announce:
        print(
            f"sage web: generated operator password (stored in {path}, shown once): {password}",
            file=sys.stderr,
        )
    return password


def _write_private(path: Path, text: str) -> None:
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(text)
    os.chmod(path, 0o600)


@dataclass
class Sessions:
    """Logged-in operators: token -> expiry (monotonic seconds)."""

    password: str
    ttl_s: float = SESSION_TTL_S
    _tokens: dict[str, float] = field(default_factory=dict)

    def check_password(self, attempt: str) -> bool:
        return hmac.compare_digest(attempt.encode("utf-8"), self.password.encode("utf-8"))

    def create(self) -> str:
        token = secrets.token_urlsafe(32)
        if len(self._tokens) >= MAX_SESSIONS:
            oldest = min(self._tokens, key=self._tokens.__getitem__)
            del self._tokens[oldest]
        self._tokens[token] = time.monotonic() + self.ttl_s
        return token

    def valid(self, token: str | None) -> bool:
        if not token:
            return False
        expiry = self._tokens.get(token)
        if expiry is None:
            return False
        if expiry < time.monotonic():
            del self._tokens[token]
            return False
        return True

    def revoke(self, token: str | None) -> None:
        if token:
            self._tokens.pop(token, None)


def origin_allowed(origin: str | None, host: str | None, extra: tuple[str, ...]) -> bool:
    """A WebSocket handshake's ``Origin`` is this server's (same host:port) or listed in ``extra``.

    No Origin header at all means a client that is not a browser: allowed (it still needs
    the session cookie for anything that controls the robot).
    """
    if origin is None:
        return True
    if origin in extra:
        return True
    parts = urlsplit(origin)
    if parts.scheme not in ("http", "https") or not parts.netloc:
        return False
    return host is not None and parts.netloc.lower() == host.lower()


class RateLimiter:
    """Token bucket per key (client address): ``rate_per_min`` sustained, ``burst`` at once."""

    def __init__(self, rate_per_min: float, burst: int, max_keys: int = 4096) -> None:
        self.rate_per_s = rate_per_min / 60.0
        self.burst = float(burst)
        self.max_keys = max_keys
        self._buckets: dict[str, tuple[float, float]] = {}  # key -> (tokens, last time)

    def allow(self, key: str) -> bool:
        now = time.monotonic()
        tokens, last = self._buckets.get(key, (self.burst, now))
        tokens = min(self.burst, tokens + (now - last) * self.rate_per_s)
        if len(self._buckets) >= self.max_keys and key not in self._buckets:
            self._buckets.clear()  # a flood of addresses: start over rather than grow
        if tokens < 1.0:
            self._buckets[key] = (tokens, now)
            return False
        self._buckets[key] = (tokens - 1.0, now)
        return True

    def retry_after_s(self, key: str) -> float:
        tokens, _ = self._buckets.get(key, (self.burst, 0.0))
        return max(0.0, (1.0 - tokens) / self.rate_per_s) if self.rate_per_s > 0 else 60.0
