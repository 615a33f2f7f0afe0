"""The instrument's page of ``goniofrost serve``: ``/`` (static/instrument.html, its script and
style sheet) and the monitor's catalogue of the sessions at ``/sessions``.

The page reads the API like any client. Its controls show only when it was opened with the
server's token (``/?token=T``, the URL the server prints): the script keeps the token in the
tab's sessionStorage, takes it out of the address bar, and sends it only as
``Authorization: Bearer T``. Without it the page is read-only: state, pose, lamp and queue.
"""
from __future__ import annotations

from functools import partial

from starlette.responses import Response
from starlette.routing import Route

from goniofrost.monitor.views import packaged_file

STATIC = ("instrument.html", "instrument.js", "instrument.css")


def static_file(name: str, request=None) -> Response:
    return packaged_file("goniofrost.server", name)


def sessions_page(sites, request) -> Response:
    from goniofrost.monitor.catalogue import catalogue_html

    return Response(catalogue_html(sites.root), media_type="text/html; charset=utf-8")


def page_routes(sites) -> list:
    """The page's routes (before the API's and the monitor's): GET only."""
    return [Route("/", partial(static_file, "instrument.html"), methods=["GET"]),
            Route("/sessions", partial(sessions_page, sites), methods=["GET"]),
            *[Route(f"/static/{name}", partial(static_file, name), methods=["GET"]) for name in STATIC[1:]]]
