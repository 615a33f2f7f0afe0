"""The monitor page beside a running command: ``capture --monitor`` and ``demo --monitor``.

The server (goniofrost.monitor) runs in a thread of the command's own process and only reads the
session folder; the capture does not know it is watched (goniofrost.capture never imports the
monitor). When the command ends, the open pages get the final state before the server stops.
"""
from __future__ import annotations

import sys
from contextlib import contextmanager

from goniofrost.core.errors import ConfigError, GoniofrostError

HOST_HELP = ("address to listen on (default 127.0.0.1: this computer only). RISK: another address, e.g. "
             "0.0.0.0 for the lab network, lets anyone who reaches this computer on that port read the "
             "session (plan, rig file, journal, RAW frames, results) without a password or encryption; "
             "use it only on a trusted network")


def add_server_options(parser, *, with_flag: bool) -> None:
    """--port and --host (and, for a command that may serve, --monitor)."""
    from goniofrost.monitor import DEFAULT_PORT

    if with_flag:
        parser.add_argument("--monitor", action="store_true",
                            help="serve a live, read-only web page of the session while it runs (prints its address)")
    parser.add_argument("--port", type=int, default=DEFAULT_PORT,
                        help=f"monitor page's TCP port (default {DEFAULT_PORT}; 0 picks a free one)")
    parser.add_argument("--host", default="127.0.0.1", help=f"monitor page's {HOST_HELP}")


def check_port(port: int) -> None:
    if not 0 <= port <= 65535:
        raise ConfigError("command line", "--port", "a TCP port 0..65535 (0 picks a free one)", port)


@contextmanager
def monitored(session_dir, host: str, port: int, command: str):
    """Serve the monitor page of ``session_dir`` while the block runs; print its address."""
    from goniofrost.capture.engine import SessionFault
    from goniofrost.monitor.server import MonitorServer

    check_port(port)
    server = MonitorServer(session_dir, host=host, port=port, attached=True).start()
    print(f"goniofrost {command}: monitor page at {server.url} (read-only view of {session_dir})",
          file=sys.stderr, flush=True)
    ended = None
    try:
        yield server
    except GoniofrostError as exc:
        if not isinstance(exc, SessionFault):  # a session fault is in the journal, in its own words
            ended = f"goniofrost {command}: error: {exc}"
        raise
    finally:
        server.close(ended)
