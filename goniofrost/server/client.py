"""Reach the server that holds a rig: ``server_for(rig)`` finds it through the device lock (the
holder publishes its URL and token file) and ``ServerClient.call`` speaks its JSON API."""
from __future__ import annotations

import getpass
import json
import urllib.error
import urllib.request
from pathlib import Path

from goniofrost.core.errors import GoniofrostError

TIMEOUT_S = 600.0   # a move or a home may take minutes on a real rig


class ServerClient:
    """The API of the server at ``url`` with ``token``; ``holder`` is its lock's RigHolder."""

    def __init__(self, url: str, token: str, holder) -> None:
        self.url, self.token, self.holder = url.rstrip("/"), token, holder

    def call(self, method: str, path: str, body: dict | None = None) -> dict:
        """The answer's JSON; GoniofrostError with the server's own words when it refuses."""
        data = None if body is None else json.dumps(body).encode()
        request = urllib.request.Request(self.url + path, data=data, method=method, headers={
            "Authorization": f"Bearer {self.token}", "Content-Type": "application/json"})
        try:
            with urllib.request.urlopen(request, timeout=TIMEOUT_S) as answer:
                return json.loads(answer.read() or b"{}")
        except urllib.error.HTTPError as exc:
            try:
                said = json.loads(exc.read()).get("error")
            except ValueError:
                said = exc.reason
            raise GoniofrostError(f"the server at {self.url} refused {method} {path} ({exc.code}): {said}") from None
        except OSError as exc:
            raise GoniofrostError(f"the server at {self.url} holds the rig but does not answer: {exc}") from None

    def who(self, program: str = "goniofrost rig") -> str:
        return f"{getpass.getuser()} ({program})"

    @property
    def root(self) -> Path:
        """The server's root folder (its token file lies in it)."""
        return Path(self.holder.token_file).parent


def server_for(rig) -> ServerClient | None:
    """The client of the server holding ``rig``'s devices, or None when no server holds them (a
    program that is not a server may; the caller's own lock then refuses naming it)."""
    from goniofrost.rig.lock import rig_holder

    holder = rig_holder(rig)
    if holder is None or not holder.url or not holder.token_file:
        return None
    try:
        token = Path(holder.token_file).read_text().strip()
    except OSError as exc:
        raise GoniofrostError(f"rig {rig.name!r} is held by {holder.who()} at {holder.url}, whose token file "
                              f"{holder.token_file} you cannot read ({exc.strerror}): ask its user") from None
    return ServerClient(holder.url, token, holder)
