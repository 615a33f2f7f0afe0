"""``goniofrost monitor``: a live, read-only web page of a capture session (running or finished)."""
from __future__ import annotations

HELP = ("serve a read-only web page of a capture session: state, N of M samples, ETA, rig poses, the "
        "plan's samples, SNR, the latest frame, the reconstruction so far, faults and what to do")


def add_arguments(parser) -> None:
    from goniofrost.app.monitoring import add_server_options

    parser.add_argument("session", metavar="SESSION_DIR",
                        help="session folder of goniofrost capture --session (it may still be running, "
                             "or not have started yet)")
    add_server_options(parser, with_flag=False)


def run(args) -> int:
    import time
    from pathlib import Path

    from goniofrost.app.monitoring import check_port
    from goniofrost.core.errors import ConfigError
    from goniofrost.monitor.server import MonitorServer

    if not Path(args.session).is_dir():
        raise ConfigError("command line", "SESSION_DIR", "a session folder (goniofrost capture --session DIR)",
                          args.session)
    check_port(args.port)
    server = MonitorServer(args.session, host=args.host, port=args.port).start()
    print(f"goniofrost monitor: {server.url} shows {args.session} (read-only); Ctrl-C stops", flush=True)
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        return 0
    finally:
        server.close()
