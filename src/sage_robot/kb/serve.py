"""``sage kb serve``: the knowledge base's HTTP API alone, for a deployment that runs it
on another host. Writes need the operator password from ``SAGE_OPERATOR_PASSWORD`` (the
environment or the profile's key file), given as HTTP Basic (any user name) or as a
bearer token; with no password set, writes are refused.
"""

from __future__ import annotations

import secrets
from collections.abc import Callable

from fastapi import FastAPI, HTTPException, Request
from fastapi.responses import RedirectResponse
from pydantic import SecretStr

from sage_robot.core.config.areas import EmailSettings
from sage_robot.kb.api import make_router
from sage_robot.kb.service import KbService

OPERATOR_SECRET = "SAGE_OPERATOR_PASSWORD"


def password_check(password: SecretStr | None) -> Callable[[Request], None]:
    """A FastAPI dependency: 401 without the operator password, 403 when none is set."""
    import base64

    def require_operator(request: Request) -> None:
        if password is None:
            raise HTTPException(
                403, f"writes are disabled: set {OPERATOR_SECRET} to allow operator logins"
            )
        header = request.headers.get("authorization", "")
        scheme, _, value = header.partition(" ")
        given = ""
        if scheme.lower() == "bearer":
            given = value.strip()
        elif scheme.lower() == "basic":
            try:
                given = base64.b64decode(value).decode("utf-8").partition(":")[2]
            except (ValueError, UnicodeDecodeError):
                given = ""
        if not given or not secrets.compare_digest(given.encode(), password.get_secret_value().encode()):
            raise HTTPException(
                401, "operator login required", headers={"WWW-Authenticate": 'Basic realm="SAGE KB"'}
            )

    return require_operator


def create_app(
    service: KbService,
    password: SecretStr | None,
    email: EmailSettings | None = None,
    secrets_file: str | None = None,
) -> FastAPI:
    app = FastAPI(
        title="SAGE knowledge base",
        version="1.0",
        description="Ingest documents and search them (hybrid full-text + vector search).",
    )
    app.include_router(make_router(service, password_check(password), email, secrets_file))

    @app.get("/", include_in_schema=False)
    async def root() -> RedirectResponse:
        return RedirectResponse("/kb/admin")

    return app
