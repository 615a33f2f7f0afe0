"""The monitor's read-only views: the page, its state and events, pictures and the session's files.

Routes of one session (ROUTES; ``session_views``), GET and HEAD only (``app.read_only``):

* ``/``: the page (``/static/NAME``: its script and style);
* ``/api/state``: the page state (``status.page_state``) as JSON;
* ``/api/events``: server-sent events, ``state`` each time it changes;
* ``/api/frame.png?sample=K``: the latest frame of sample K with its region of interest;
* ``/api/preview.png?done=N``: the reconstruction from the samples journaled so far;
* ``/files/NAME``: a file of the session folder (``safe_path``), in FILE_CHUNK pieces.

On a folder of sessions (``catalogue_views``) ``/`` is the catalogue and each session is served
under ``/s/NAME/`` (NAME percent-decoded once).
"""
from __future__ import annotations

import json
import mimetypes
import os
from functools import partial
from importlib import resources
from urllib.parse import quote, unquote, unquote_to_bytes

import anyio
from starlette.responses import Response, StreamingResponse
from starlette.routing import Route, Router

from goniofrost.monitor.images import frame_png, preview_png
from goniofrost.monitor.safe_path import UnsafePath, session_file, shown

HEARTBEAT_S = 15.0         # an SSE comment keeps idle connections open through proxies
MAX_EVENT_STREAMS = 32     # open pages at once (a coroutine each): the others' streams are answered 503
MAX_TRANSFERS = 64         # /files/ answers streaming at once; more wait (each holds <= ~0.6 MB, no thread)
FILE_CHUNK = 256 * 1024
STATIC = ("index.html", "monitor.js", "monitor.css")


class Limits:
    """What every session of one app shares: the file transfers and the event streams."""

    def __init__(self) -> None:
        self.transfers = anyio.Semaphore(MAX_TRANSFERS)
        self.streams = anyio.Semaphore(MAX_EVENT_STREAMS)


def text(status: int, message: str, headers: dict | None = None) -> Response:
    return Response(message, status, headers, media_type="text/plain; charset=utf-8")


async def not_found_app(scope, receive, send) -> None:
    await text(404, f"no such page: {shown(scope['path'])}")(scope, receive, send)


# ----- one session --------------------------------------------------------------------------------
def page(site, limits, request) -> Response:
    return static_file("index.html")


def static(site, limits, request) -> Response:
    return static_file(request.path_params["name"])


def static_file(name: str) -> Response:
    if name not in STATIC:
        return text(404, f"no such page: {shown(name)}")
    return packaged_file("goniofrost.monitor", name)


def packaged_file(package: str, name: str) -> Response:
    """The file ``name`` of ``package``'s ``static`` folder, with its text type."""
    data = resources.files(package).joinpath("static", name).read_bytes()
    kind = mimetypes.guess_type(name)[0] or "application/octet-stream"
    return Response(data, media_type=f"{kind}; charset=utf-8")


def favicon(site, limits, request) -> Response:
    return Response(b"", 204, media_type="image/x-icon")


def state(site, limits, request) -> Response:
    site.hub.refresh_logged()
    return Response(site.hub.payload()[1], media_type="application/json")


async def events(site, limits, request) -> Response:
    """The state now and at every change, as server-sent events (a comment every HEARTBEAT_S)."""
    try:
        limits.streams.acquire_nowait()
    except anyio.WouldBlock:
        return text(503, f"at most {MAX_EVENT_STREAMS} pages at once", {"Retry-After": "5"})
    return Held(event_stream(site.hub), limits.streams, media_type="text/event-stream")


async def event_stream(hub):
    me = object()
    hub.clients[me] = -1
    try:
        await anyio.to_thread.run_sync(hub.refresh_logged)
        sent = -1
        while True:
            version, payload = hub.payload()
            if version > sent:
                yield b"event: state\ndata: " + payload + b"\n\n"
                sent = hub.clients[me] = version   # handed to the connection
            else:
                yield b": keep-alive\n\n"
            if hub.closed:
                return
            await hub.wait_newer(sent, HEARTBEAT_S)
    finally:
        hub.clients.pop(me, None)


class Held(StreamingResponse):
    """A stream that holds one unit of ``semaphore`` (already acquired) until it ends."""

    def __init__(self, content, semaphore, **kw) -> None:
        super().__init__(content, **kw)
        self.semaphore = semaphore

    async def __call__(self, scope, receive, send) -> None:
        try:
            await super().__call__(scope, receive, send)
        finally:
            self.semaphore.release()


def frame(site, limits, request) -> Response:
    hub = site.hub
    hub.refresh_logged()   # the session as it is now, whether or not a page asked for the state
    wanted, view = query_int(request, "sample"), hub.view
    if not any(d.plan_index == wanted for d in view.done):
        return text(404, f"sample {wanted} is not in the journal", {"X-Shows": str(wanted)})

    def make():
        png, info = frame_png(view, wanted)
        return wanted, png, info
    return picture(site.frames.get(wanted, make), wanted, f"the frame of sample {wanted}")


def preview(site, limits, request) -> Response:
    hub = site.hub
    hub.refresh_logged()
    view, rig = hub.view, hub.rig
    wanted = (view.plan_key, query_int(request, "done"))

    def make():
        png, info = preview_png(view, rig)
        return (view.plan_key, len(view.done)), png, info
    return picture(site.previews.get(wanted, make), wanted, f"the preview from {wanted[1]} samples")


def picture(got, wanted, what: str) -> Response:
    """An older picture may answer (X-Shows says which: the page asks again after
    X-Retry-After-Ms), but a message is only ever the one of the picture asked for."""
    key, data, info, error, wait = got
    shows = key[1] if isinstance(key, tuple) else key
    headers = {"X-Shows": str(shows), "X-Retry-After-Ms": str(int(wait * 1000)), "X-Info": json.dumps(info or {})}
    if data is None:
        return text(503, error if key == wanted and error else f"{what} is not made yet", headers)
    return Response(data, headers=headers, media_type="image/png")


async def files(site, limits, request) -> Response:
    """A file of the session, named by the path as sent (percent-decoded once, by ``safe_path``)."""
    raw = request.scope.get("raw_path") or request.scope["path"].encode()
    start = raw.find(b"/files/")   # not found: the route's own name was percent-encoded
    requested = raw[start + len(b"/files/"):].decode("latin-1") if start >= 0 else ""
    try:
        path = await anyio.to_thread.run_sync(session_file, site.hub.session_dir, requested)
    except UnsafePath as exc:
        return text(404, str(exc))
    kind = mimetypes.guess_type(path.name)[0] or "application/octet-stream"
    if kind.startswith("text/") or kind == "application/json":
        kind += "; charset=utf-8"
    return FileStream(path, kind, requested, limits.transfers)


class FileStream(Response):
    """A file in FILE_CHUNK pieces, once one of the transfers is free (queued until then, never
    refused); its size from the open file (a file replaced meanwhile is sent whole as it was opened)."""

    def __init__(self, path, kind: str, requested: str, transfers) -> None:
        self.path, self.kind, self.requested, self.transfers = path, kind, requested, transfers

    async def __call__(self, scope, receive, send) -> None:
        async with self.transfers:
            try:
                source = await anyio.open_file(self.path, "rb")
            except OSError as exc:
                why = f"refused path {shown(self.requested)}: {exc.strerror or exc}"
                return await text(404, why)(scope, receive, send)
            async with source:
                size = os.fstat(source.wrapped.fileno()).st_size
                body = chunks(source) if scope["method"] != "HEAD" else []
                await StreamingResponse(body, headers={"Content-Length": str(size)}, media_type=self.kind)(
                    scope, receive, send)


async def chunks(source):
    while chunk := await source.read(FILE_CHUNK):
        yield chunk


def query_int(request, name: str) -> int:
    try:
        return int(request.query_params.get(name, "-1"))
    except ValueError:
        return -1


ROUTES = (  # path, view(site, limits, request): every route of one session
    ("/", page), ("/index.html", page), ("/static/{name}", static), ("/favicon.ico", favicon),
    ("/api/state", state), ("/api/events", events), ("/api/frame.png", frame), ("/api/preview.png", preview),
    ("/files/{path:path}", files),
)


def session_views(site, limits: Limits) -> Router:
    """The read-only views of one session (``hub.Site``)."""
    return Router([Route(path, partial(view, site, limits), methods=["GET"]) for path, view in ROUTES],
                  default=not_found_app)


# ----- a folder of sessions -----------------------------------------------------------------------
def catalogue_page(sites, request) -> Response:
    from goniofrost.monitor.catalogue import catalogue_html

    return Response(catalogue_html(sites.root), media_type="text/html; charset=utf-8")


class CatalogueViews:
    """``/``: the catalogue of ``sites.root``; ``/s/NAME/...``: session NAME's own views."""

    def __init__(self, sites, limits: Limits) -> None:
        self.sites, self.limits, self._views = sites, limits, {}
        top = (("/", partial(catalogue_page, sites)), ("/index.html", partial(catalogue_page, sites)),
               ("/static/{name}", partial(static, None, limits)), ("/favicon.ico", partial(favicon, None, limits)))
        self.top = Router([Route(path, view, methods=["GET"]) for path, view in top], default=not_found_app)

    async def __call__(self, scope, receive, send) -> None:
        raw = scope.get("raw_path") or scope["path"].encode()
        if scope["type"] != "http" or not raw.startswith(b"/s/"):
            return await self.top(scope, receive, send)
        raw_name, slash, rest = raw[len(b"/s/"):].partition(b"/")
        name = session_name(raw_name)
        site = None if name is None else await anyio.to_thread.run_sync(self.sites.get, name)
        if site is None:
            return await text(404, f"no such session: {(name or raw_name.decode('latin-1'))[:64]}")(scope, receive, send)
        if not slash:  # the page's relative addresses need the slash
            return await Response(b"", 301, {"Location": f"/s/{quote(name)}/"})(scope, receive, send)
        if site not in self._views:
            self._views[site] = session_views(site, self.limits)
        rest = b"/" + rest
        inner = {**scope, "raw_path": rest, "path": unquote(rest.decode("latin-1"))}
        await self._views[site](inner, receive, send)


def session_name(raw: bytes) -> str | None:
    """A session's name as it appears in ``/s/NAME/`` (percent-encoded UTF-8), or None."""
    try:
        name = unquote_to_bytes(raw).decode("utf-8")
    except UnicodeDecodeError:
        return None
    return name if name and "/" not in name and "\x00" not in name else None
