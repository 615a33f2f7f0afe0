"""The monitor as an ASGI app (Starlette): ``monitor_app(root, ...)`` and the pieces another app
(the coming instrument server) mounts beside its own routes.

Every answer goes through ``Guard``: exactly one Host header, and on a loopback address only a
loopback name in it (against DNS rebinding: a page of another site cannot read the session);
and security headers (a strict Content-Security-Policy: the page loads nothing from anywhere
else). ``read_only`` answers every method but GET and HEAD with 405: the views cannot write.
The lifespan polls the sessions that have a page open (``hub.POLL_S``) and bounds the worker
threads that read sessions, make pictures and read files to MAX_WORKERS.
"""
from __future__ import annotations

from contextlib import asynccontextmanager

import anyio
from starlette.applications import Starlette
from starlette.middleware import Middleware
from starlette.routing import Mount

from goniofrost.monitor.hub import POLL_S, Sites
from goniofrost.monitor.views import CatalogueViews, Limits, session_views, text

MAX_WORKERS = 16           # threads reading sessions, making pictures and reading files (then they queue)
PRUNE_S = 5.0              # how often idle worker threads are looked for
LOOPBACK = ("127.0.0.1", "localhost", "::1")
CSP = ("default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' blob:; "
       "connect-src 'self'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'")
SECURITY_HEADERS = [(b"content-security-policy", CSP.encode()), (b"x-content-type-options", b"nosniff"),
                    (b"referrer-policy", b"no-referrer")]


def monitor_app(root, *, catalogue: bool = False, attached: bool = False, host: str = "127.0.0.1") -> Starlette:
    """The read-only monitor of the session folder ``root`` (``catalogue``: of the sessions under
    it) for a server listening on ``host``; ``attached``: served by the capture's own process.
    ``app.state.sites`` holds the sessions served."""
    sites = Sites(root, catalogue, attached)
    app = Starlette(routes=monitor_routes(sites), middleware=[Middleware(Guard, host=host)],
                    lifespan=monitor_lifespan(sites))
    app.state.sites = sites
    return app


def monitor_routes(sites: Sites) -> list:
    """The read-only views, mounted at the root (another app puts its own routes before them)."""
    limits = Limits()
    views = CatalogueViews(sites, limits) if sites.catalogue else session_views(sites.single, limits)
    return [Mount("", app=read_only(views))]


def monitor_lifespan(sites: Sites):
    """Poll the sessions with an open page, and bound the worker threads, while the app serves."""
    @asynccontextmanager
    async def lifespan(app):
        anyio.to_thread.current_default_thread_limiter().total_tokens = MAX_WORKERS
        await anyio.to_thread.run_sync(int)   # the one worker that always stays, there from the start
        async with anyio.create_task_group() as tasks:
            tasks.start_soon(poll, sites)
            yield
            tasks.cancel_scope.cancel()
    return lifespan


async def poll(sites: Sites) -> None:
    """Re-read every session a page is open on, every POLL_S (its streams wake on a change)."""
    handed_at = 0.0
    while True:
        await anyio.sleep(POLL_S)
        for site in sites.all():
            if site.hub.clients:
                await anyio.to_thread.run_sync(site.hub.refresh_logged)
        if anyio.current_time() - handed_at > PRUNE_S:
            # anyio ends a worker thread idle for 10 s only when it hands out the next job: hand
            # one now and then, so that after a burst the process returns to its usual threads
            await anyio.to_thread.run_sync(int)
            handed_at = anyio.current_time()


def read_only(app):
    """``app`` answering only GET and HEAD (every other method: 405, nothing can be written)."""
    async def guarded(scope, receive, send) -> None:
        if scope["type"] == "http" and scope["method"] not in ("GET", "HEAD"):
            answer = text(405, "the monitor only reads the session", {"Allow": "GET, HEAD"})
            return await answer(scope, receive, send)
        await app(scope, receive, send)
    return guarded


def host_refusal(hosts: list[bytes], loopback: bool) -> tuple[int, str] | None:
    """(status, message) refusing a request with these Host headers, or None to answer it."""
    if len(hosts) != 1:
        return 400, f"expected one Host header, found {len(hosts)}"
    name = hosts[0].decode("latin-1").rsplit(":", 1)[0].strip("[]")
    return (403, "unexpected Host header") if loopback and name not in LOOPBACK else None


class Guard:
    """The Host check and the security headers of every answer (module doc)."""

    def __init__(self, app, host: str) -> None:
        self.app, self.loopback = app, host in LOOPBACK

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] != "http":
            return await self.app(scope, receive, send)

        async def secured(message) -> None:
            if message["type"] == "http.response.start":
                headers = list(message.get("headers", []))
                if not any(k.lower() == b"cache-control" for k, _ in headers):
                    headers.append((b"cache-control", b"no-store"))
                message = {**message, "headers": headers + SECURITY_HEADERS}
            await send(message)
        refused = host_refusal([v for k, v in scope["headers"] if k.lower() == b"host"], self.loopback)
        if refused:
            return await text(*refused)(scope, receive, secured)
        await self.app(scope, receive, secured)
