"""The instrument's HTTP JSON API (Starlette), with the monitor's read-only views mounted beside it.

Reading (GET: status, queue, events, the schema, the monitor's pages) needs no token. Every other
request needs ``Authorization: Bearer TOKEN`` (the token of this server start): without it 401,
with another 403. A request carrying an ``Origin`` other than this server's own is refused (403)
before anything else, and the monitor's ``Guard`` checks the Host header of every request.
Bodies are JSON objects of at most MAX_BODY bytes (413 beyond). A refused request gets
``{"error": ..., "field": ...}`` with the field that is wrong; nothing is queued or moved.
"""
from __future__ import annotations

import hmac
import json
from pathlib import Path

import anyio
from starlette.applications import Starlette
from starlette.middleware import Middleware
from starlette.requests import Request
from starlette.responses import JSONResponse, Response, StreamingResponse
from starlette.routing import Route

from goniofrost.capture.signals import SessionInterrupted
from goniofrost.core.errors import GoniofrostError
from goniofrost.monitor.app import Guard, monitor_lifespan, monitor_routes
from goniofrost.monitor.hub import Sites
from goniofrost.server.entries import ENTRY_SCHEMA, RequestError, check_entry, check_lamp, check_move, check_snap
from goniofrost.server.instrument import Busy, State

MAX_BODY = 16 * 1024       # bytes of a request body
EVENT_POLL_S = 0.1         # how often the event stream looks for new records


def error(status: int, message: str, field: str | None = None) -> JSONResponse:
    return JSONResponse({"error": message, "field": field}, status_code=status)


class Api:
    """The routes of one server: ``instrument`` (``instrument.Instrument``), its ``store``, the
    ``root`` and rig file, the ``token`` and the ``origin`` (``http://host:port``) it serves."""

    def __init__(self, instrument, store, root: Path, rig_path: Path, token: str, origin: str) -> None:
        self.instrument, self.store, self.root, self.rig_path = instrument, store, Path(root), Path(rig_path)
        self.rig, self.token, self.origin = instrument.rig, token, origin

    def routes(self) -> list:
        control = [("/api/pause", self.pause), ("/api/resume", self.resume), ("/api/stop", self.stop),
                   ("/api/move", self.move), ("/api/home", self.home), ("/api/lamp", self.lamp),
                   ("/api/snap", self.snap), ("/api/camera", self.camera),
                   ("/api/queue/{entry_id:int}/move", self.reorder)]
        return [Route("/api/status", self.status), Route("/api/queue", self.queue, methods=["GET", "POST"]),
                Route("/api/queue/{entry_id:int}", self.remove, methods=["DELETE"]),
                Route("/api/rig", self.rig_info),
                Route("/api/events", self.events), Route("/api/actions", self.actions),
                Route("/openapi.json", self.schema),
                *[Route(path, self._control(handler), methods=["POST"]) for path, handler in control]]

    # ----- the gate of every control request ------------------------------------------------------
    def _control(self, handler):
        async def guarded(request: Request):
            try:
                self._authorize(request)
                body = await read_body(request)
                who = body.get("operator") if isinstance(body, dict) and isinstance(body.get("operator"), str) else "?"
                return await handler(request, body, who)
            except RequestError as exc:
                return error(exc.status, str(exc), exc.field)
            except Busy as exc:
                return error(409, str(exc))
        return guarded

    def _authorize(self, request: Request) -> None:
        origin = request.headers.get("origin")
        if origin is not None and origin != self.origin:
            raise RequestError("origin", f"origin: requests from {origin} are refused", 403)
        scheme, _, given = request.headers.get("authorization", "").partition(" ")
        if scheme.lower() != "bearer" or not given:
            raise RequestError("authorization", "authorization: this request needs Authorization: Bearer TOKEN "
                               "(the token printed by goniofrost serve)", 401)
        if not hmac.compare_digest(given.strip().encode(), self.token.encode()):
            raise RequestError("authorization", "authorization: wrong token", 403)

    def _journal(self, request: Request, who: str, action: str, detail=None) -> None:
        peer = f"{request.client.host}:{request.client.port}" if request.client else "?"
        self.store.journal(who, peer, action, detail)

    # ----- reading ----------------------------------------------------------------------------------
    async def status(self, request: Request):
        return JSONResponse(self.instrument.status())

    async def rig_info(self, request: Request):
        """What the page's controls need of the rig file: each axis's limits, the lamp, the camera."""
        return JSONResponse(rig_summary(self.rig))

    async def actions(self, request: Request):
        return JSONResponse(await anyio.to_thread.run_sync(self.store.actions))

    async def queue(self, request: Request):
        if request.method == "POST":
            return await self._control(self.add)(request)
        return JSONResponse(await anyio.to_thread.run_sync(self.store.entries))

    async def events(self, request: Request):
        """Server-sent events: every typed record from ``?since=N`` on (``type``, ``seq``, ``t_utc``...)."""
        try:
            seq = int(request.query_params.get("since", "0"))
        except ValueError:
            return error(400, "since: expected a record number", "since")

        async def stream():
            nonlocal seq
            while not await request.is_disconnected():
                for record in self.instrument.events_since(seq):
                    seq = record["seq"] + 1
                    yield f"event: {record['type']}\nid: {record['seq']}\ndata: {json.dumps(record)}\n\n"
                await anyio.sleep(EVENT_POLL_S)
        return StreamingResponse(stream(), media_type="text/event-stream")

    async def schema(self, request: Request):
        return JSONResponse(openapi())

    # ----- control ------------------------------------------------------------------------------------
    async def add(self, request, body, who):
        entry = await anyio.to_thread.run_sync(check_entry, body, self.root, self.rig_path, self.rig)
        row = await anyio.to_thread.run_sync(self.store.add, entry)
        self._journal(request, who, "queue_add", {"id": row["id"]})
        self.instrument.queue_changed()
        return JSONResponse(row, status_code=201)

    async def remove(self, request: Request):
        async def removed(request, body, who):
            entry_id = request.path_params["entry_id"]
            if not await anyio.to_thread.run_sync(self.store.remove, entry_id):
                raise RequestError("id", f"id: no pending entry {entry_id} (a running or ended entry stays)", 404)
            self._journal(request, who, "queue_remove", {"id": entry_id})
            self.instrument.queue_changed()
            return JSONResponse({"removed": entry_id})
        return await self._control(removed)(request)

    async def reorder(self, request, body, who):
        """Move a pending entry before another pending one (``{"before": id}``; null: last)."""
        entry_id, before = request.path_params["entry_id"], body.get("before") if isinstance(body, dict) else None
        if before is not None and (not isinstance(before, int) or isinstance(before, bool)):
            raise RequestError("before", f"before: expected the id of a pending entry (or null: last), "
                               f"found {before!r}")
        order = await anyio.to_thread.run_sync(self.store.move, entry_id, before)
        if order is None:
            pending = lambda i: (self.store.entry(i) or {}).get("state") == "pending"  # noqa: E731
            if not await anyio.to_thread.run_sync(pending, entry_id):
                raise RequestError("id", f"id: no pending entry {entry_id} (a running or ended entry stays)", 404)
            raise RequestError("before", f"before: expected the id of another pending entry (or null: last), "
                               f"found {before!r}")
        self._journal(request, who, "queue_move", {"id": entry_id, "before": before})
        self.instrument.queue_changed()
        return JSONResponse({"pending": order})

    async def camera(self, request, body, who):
        """One frame at the current pose as a PNG (camera_view); what it shows in X-Info (JSON)."""
        from goniofrost.capture.snap import DEFAULT_MATERIAL
        from goniofrost.datasets import shown_material
        from goniofrost.server.camera_view import check_view, take_view, view_png

        exposure, levels = check_view(body, self.rig)
        material = shown_material(DEFAULT_MATERIAL) if self.rig.simulated else None

        def job(hw):
            if material is not None and getattr(hw.camera, "material", None) is None:
                self.instrument.held_devices(self.rig, material=material)  # a simulated stage shows something
            frame = take_view(hw, self.rig, exposure)
            return frame, view_png(frame.raw, self.rig.camera["saturation"], levels)
        frame, (png, info) = await self._command(request, who, "camera", {"exposure_s": exposure}, job)
        info |= {"exposure_s": frame.exposure_s, "lamp_relative": round(float(frame.lamp_relative), 4)}
        return Response(png, media_type="image/png", headers={"X-Info": json.dumps(info)})

    async def pause(self, request, body, who):
        self._journal(request, who, "pause")
        return JSONResponse({"state": self.instrument.pause().value})

    async def resume(self, request, body, who):
        self._journal(request, who, "resume")
        return JSONResponse({"state": self.instrument.resume().value})

    async def stop(self, request, body, who):
        self._journal(request, who, "stop")
        peer = request.client.host if request.client else "?"
        return JSONResponse({"state": self.instrument.stop(f"{who} at {peer}").value})

    async def move(self, request, body, who):
        from goniofrost.capture.console import check_referenced, move_plan, run_plan

        targets = check_move(body, self.rig)

        def job(hw):
            check_referenced(self.rig, hw.axes, targets)
            return run_plan(hw, move_plan(self.rig, targets), "serve move")
        reached = await self._command(request, who, "move", {"targets": targets}, job)
        return JSONResponse({"reached": {k: float(v) for k, v in reached.joints.items()}})

    async def home(self, request, body, who):
        from goniofrost.capture.console import home_plan, run_plan

        axes = body.get("axes") or list(self.rig.joint_names)
        if not isinstance(axes, list) or any(a not in self.rig.axes for a in axes):
            raise RequestError("axes", f"axes: expected a list of axes among {', '.join(self.rig.axes)}, found {axes!r}")
        reached = await self._command(request, who, "home", {"axes": axes},
                                      lambda hw: run_plan(hw, home_plan(axes), "serve home"))
        return JSONResponse({"reached": {k: float(v) for k, v in reached.joints.items()}})

    async def lamp(self, request, body, who):
        from goniofrost.capture.console import lamp_plan, run_plan

        on = check_lamp(body, self.rig)
        def job(hw):
            reading = run_plan(hw, lamp_plan(on), "serve lamp")
            self.instrument.lamp_switched(on)
            return reading
        reading = await self._command(request, who, "lamp", {"on": on}, job)
        return JSONResponse({"on": on, "photodiode": None if reading is None else float(reading)})

    async def snap(self, request, body, who):
        from goniofrost.capture.snap import DEFAULT_MATERIAL, snap
        from goniofrost.datasets import shown_material

        out, target, exposure = check_snap(body, self.root)
        material = shown_material(DEFAULT_MATERIAL) if self.rig.simulated else None
        result = await self._command(request, who, "snap", {"out": out.name, "target": target},
                                     lambda hw: snap(self.rig, target=target, exposure_s=exposure, out=out,
                                                     material=material, devices=self.instrument.held_devices))
        return JSONResponse({"file": str(out.relative_to(self.root)), **result.as_dict()})

    async def _command(self, request, who, what, detail, job):
        """Journal and run ``job(hardware)`` on the instrument's thread; its error as a 409."""
        future = self.instrument.command(what, job)
        self._journal(request, who, what, detail)
        try:
            return await anyio.to_thread.run_sync(future.result)
        except (GoniofrostError, SessionInterrupted) as exc:  # refused (not homed), a device fault, a stop
            raise RequestError(what, f"{what}: {exc}", 409) from None


async def read_body(request: Request):
    """The JSON body (None when empty); RequestError 413 beyond MAX_BODY, 400 when not JSON."""
    declared = request.headers.get("content-length")
    if declared is not None and declared.isdigit() and int(declared) > MAX_BODY:
        raise RequestError("body", f"body: at most {MAX_BODY} bytes, found {declared}", 413)
    data = b""
    async for chunk in request.stream():
        data += chunk
        if len(data) > MAX_BODY:
            raise RequestError("body", f"body: at most {MAX_BODY} bytes", 413)
    if not data.strip():
        return {}
    try:
        return json.loads(data)
    except ValueError as exc:
        raise RequestError("body", f"body: not JSON ({exc})", 400) from None


def rig_summary(rig) -> dict:
    """The rig file's limits as the page shows them: per axis its soft limits (``limits_deg``) and
    what the geometry adds (the stage's tilt limit, the camera arm's closest approach to the lamp)."""
    from goniofrost.core.rig_spec import Role

    geometry, axes = rig.geometry, []
    for name, spec in rig.axes.items():
        note = None
        if spec.role is Role.SAMPLE_TILT:
            note = f"and within +-{geometry.tilt_limit_deg:g} deg (geometry.tilt_limit_deg)"
        elif spec.role is Role.CAMERA_ARM:
            note = (f"and at least {geometry.min_arm_separation_deg:g} deg from the lamp "
                    f"(geometry.min_arm_separation_deg)")
        axes.append({"name": name, "role": spec.role.value, "limits_deg": list(spec.limits_deg),
                     "home_deg": spec.home_deg, "note": note})
    return {"name": rig.name, "simulated": bool(rig.simulated), "axes": axes,
            "lamp": bool((rig.lamp or {}).get("driver")),
            "camera": {"exposures_s": list(rig.camera["exposures_s"]), "saturation": rig.camera["saturation"]}}


def instrument_app(api: Api, sessions: Path, host: str) -> Starlette:
    """The instrument's page and the API's routes, then the monitor's read-only views of the
    sessions under ``sessions`` (their catalogue at ``/sessions``)."""
    from goniofrost.server.page import page_routes

    sites = Sites(sessions, True, False)
    app = Starlette(routes=page_routes(sites) + api.routes() + monitor_routes(sites),
                    middleware=[Middleware(Guard, host=host)],
                    lifespan=monitor_lifespan(sites))
    app.state.sites = sites
    return app


def openapi() -> dict:
    """The OpenAPI 3.1 description of the API (the queue entry's fields from ENTRY_SCHEMA)."""
    entry = {"type": "object", "additionalProperties": False,
             "required": [k for k, (_, required, _) in ENTRY_SCHEMA.items() if required],
             "properties": {k: {"type": [kind, "null"] if not required else kind, "description": text}
                            for k, (kind, required, text) in ENTRY_SCHEMA.items()}}
    refused = {"description": "refused; nothing queued or moved", "content": {"application/json": {
        "schema": {"$ref": "#/components/schemas/Error"}}}}
    control = {"security": [{"token": []}], "responses": {"200": {"description": "done"}, "401": refused,
                                                          "403": refused, "409": refused, "413": refused,
                                                          "422": refused}}
    body = lambda schema: {"requestBody": {"content": {"application/json": {"schema": schema}}}}  # noqa: E731
    operator = {"type": "object", "properties": {"operator": {"type": "string"}}}
    return {
        "openapi": "3.1.0", "info": {"title": "goniofrost serve", "version": "1"},
        "components": {
            "securitySchemes": {"token": {"type": "http", "scheme": "bearer"}},
            "schemas": {"Entry": entry,
                        "State": {"type": "string", "enum": [s.value for s in State]},
                        "Error": {"type": "object", "properties": {"error": {"type": "string"},
                                                                   "field": {"type": ["string", "null"]}}}}},
        "paths": {
            "/api/status": {"get": {"summary": "state (State), current entry, pose, lamp",
                                    "responses": {"200": {"description": "the status"}}}},
            "/api/queue": {"get": {"summary": "the queue", "responses": {"200": {"description": "entries"}}},
                           "post": {"summary": "add an entry", **body({"$ref": "#/components/schemas/Entry"}),
                                    **control}},
            "/api/queue/{id}": {"delete": {"summary": "remove a pending entry", **control,
                                           "parameters": [{"name": "id", "in": "path", "required": True,
                                                           "schema": {"type": "integer"}}]}},
            "/api/queue/{id}/move": {"post": {
                "summary": "move a pending entry before another pending one (before: null puts it last)", **control,
                "parameters": [{"name": "id", "in": "path", "required": True, "schema": {"type": "integer"}}],
                **body({"type": "object", "properties": {"before": {"type": ["integer", "null"]},
                                                         "operator": {"type": "string"}}})}},
            "/api/rig": {"get": {"summary": "the rig: each axis's limits, the lamp, the camera's exposures",
                                 "responses": {"200": {"description": "the rig"}}}},
            "/api/events": {"get": {"summary": "server-sent events of typed records (?since=N)",
                                    "responses": {"200": {"description": "text/event-stream"}}}},
            "/api/actions": {"get": {"summary": "the journal of control actions",
                                     "responses": {"200": {"description": "actions"}}}},
            "/api/pause": {"post": {"summary": "pause at the next safe point", **body(operator), **control}},
            "/api/resume": {"post": {"summary": "resume, or release a held queue", **body(operator), **control}},
            "/api/stop": {"post": {"summary": "stop the run and hold the queue", **body(operator), **control}},
            "/api/move": {"post": {"summary": "move axes", **control, **body(
                {"type": "object", "properties": {"targets": {"type": "object",
                                                              "additionalProperties": {"type": "number"}}}})}},
            "/api/home": {"post": {"summary": "home axes", **control, **body(
                {"type": "object", "properties": {"axes": {"type": "array", "items": {"type": "string"}}}})}},
            "/api/lamp": {"post": {"summary": "switch the lamp", **control, **body(
                {"type": "object", "properties": {"on": {"type": "boolean"}}})}},
            "/api/snap": {"post": {"summary": "one picture at the current pose, into ROOT/snaps", **control, **body(
                {"type": "object", "properties": {"name": {"type": "string"}, "target": {"type": "string"},
                                                  "exposure_s": {"type": "number"}}})}},
            "/api/camera": {"post": {
                "summary": "one frame at the current pose, lamp as it is: a small PNG, saturated pixels red; "
                           "X-Info: its size, levels, saturated fraction, exposure", **control, **body(
                    {"type": "object", "properties": {"exposure_s": {"type": "number"},
                                                      "black": {"type": "number"}, "white": {"type": "number"}}})}},
        }}
