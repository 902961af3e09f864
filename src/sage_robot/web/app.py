"""The FastAPI application: pages, login, and the routers of :mod:`api`, :mod:`sockets`, :mod:`talk`.

Every request passes :class:`~sage_robot.web.guard.RequestGuard` first (Origin and
Content-Type of state-changing requests, body limits on the bytes received).

Everything the handlers need hangs on ``app.state``: ``web`` (:class:`WebState`).
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path
from urllib.parse import quote

from fastapi import FastAPI, HTTPException, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, JSONResponse, RedirectResponse, Response
from fastapi.staticfiles import StaticFiles

from sage_robot.core.log import get_logger
from sage_robot.web import admin, api, slam_api, sockets, talk, tour_api
from sage_robot.web.auth import SESSION_COOKIE
from sage_robot.web.common import WebState, client_key, is_operator, json_body, state_of
from sage_robot.web.guard import RequestGuard

UPLOAD_SLACK_BYTES = 64 * 1024  # multipart headers around an upload
KB_UPLOAD_LIMIT_BYTES = 200 * 1024 * 1024  # several documents at once (the KB checks each file)
PUBLIC_PAGES = {"/": "index.html", "/face": "face.html", "/talk": "talk.html", "/login": "login.html"}
OPERATOR_PAGES = {"/teleop": "teleop.html", "/admin": "admin.html"}

_log = get_logger("web")


def body_limit(path: str) -> int:
    """Bytes a request body may have: a KB upload batch, else one voice recording."""
    if path.startswith("/api/kb/"):
        return KB_UPLOAD_LIMIT_BYTES
    return talk.MAX_UPLOAD_BYTES + UPLOAD_SLACK_BYTES


def static_dir() -> Path:
    return Path(str(resources.files("sage_robot.web").joinpath("static")))


def create_app(state: WebState) -> FastAPI:
    app = FastAPI(title="SAGE", docs_url=None, redoc_url=None, openapi_url=None)
    app.state.web = state

    app.add_middleware(
        RequestGuard,
        routes=lambda: app.router.routes,
        allowed_origins=lambda: state.node.settings.web.allowed_origins,
        body_limit=body_limit,
    )
    _add_error_handlers(app)
    _add_pages(app)
    app.include_router(api.router)
    app.include_router(admin.router)
    app.include_router(sockets.router)
    app.include_router(talk.router)
    app.include_router(slam_api.router)
    app.include_router(tour_api.router)
    admin.mount_kb(app, state)
    app.mount("/static", StaticFiles(directory=static_dir()), name="static")
    return app


def _add_error_handlers(app: FastAPI) -> None:
    @app.exception_handler(RequestValidationError)
    async def bad_request(request: Request, exc: RequestValidationError) -> JSONResponse:
        problems = [
            f"{'.'.join(str(p) for p in e['loc'] if p != 'body') or 'body'}: {e['msg']}"
            for e in exc.errors()
        ]
        return JSONResponse({"error": "; ".join(problems)}, status_code=422)

    @app.exception_handler(HTTPException)
    async def http_error(request: Request, exc: HTTPException) -> JSONResponse:
        return JSONResponse({"error": exc.detail}, status_code=exc.status_code, headers=exc.headers)

    @app.exception_handler(Exception)
    async def internal(request: Request, exc: Exception) -> JSONResponse:
        _log.exception("request failed", path=request.url.path)
        return JSONResponse({"error": f"internal error: {type(exc).__name__}"}, status_code=500)


def _add_pages(app: FastAPI) -> None:
    def page(name: str) -> FileResponse:
        return FileResponse(static_dir() / name, headers={"Cache-Control": "no-cache"})

    for route, name in PUBLIC_PAGES.items():

        async def public(name: str = name) -> FileResponse:
            return page(name)

        app.add_api_route(route, public, methods=["GET"], include_in_schema=False)

    for route, name in OPERATOR_PAGES.items():

        async def operator(request: Request, name: str = name, route: str = route) -> Response:
            if not is_operator(request):
                return RedirectResponse(f"/login?next={quote(route)}", status_code=303)
            return page(name)

        app.add_api_route(route, operator, methods=["GET"], include_in_schema=False)

    @app.post("/api/login")
    async def login(request: Request) -> JSONResponse:
        st = state_of(request)
        key = client_key(request)
        if not st.login_limiter.allow(key):
            return JSONResponse(
                {"error": "too many login attempts; wait a minute"},
                status_code=429,
                headers={"Retry-After": str(int(st.login_limiter.retry_after_s(key)) + 1)},
            )
        body = await json_body(request)
        password = body.get("password")
        if not isinstance(password, str) or not st.sessions.check_password(password):
            _log.warning("operator login refused", client=key)
            return JSONResponse({"error": "wrong password"}, status_code=401)
        token = st.sessions.create()
        resp = JSONResponse({"ok": True})
        resp.set_cookie(SESSION_COOKIE, token, httponly=True, samesite="strict", path="/",
                        secure=request.url.scheme == "https")  # never sent back over plain http
        _log.info("operator logged in", client=key)
        return resp

    @app.post("/api/logout")
    async def logout(request: Request) -> JSONResponse:
        state_of(request).sessions.revoke(request.cookies.get(SESSION_COOKIE))
        resp = JSONResponse({"ok": True})
        resp.delete_cookie(SESSION_COOKIE, path="/")
        return resp

    @app.get("/api/whoami")
    async def whoami(request: Request) -> dict[str, bool]:
        return {"operator": is_operator(request)}
