"""``goniofrost monitor``: a live, read-only web page of a capture session (running or finished)."""
from __future__ import annotations

HELP = ("serve a read-only web page of a capture session: state, N of M samples, ETA, rig poses, the "
        "plan's samples, SNR, the latest frame, the reconstruction so far, faults and what to do; on a folder "
        "of sessions, their catalogue with a link to each session's page")


def add_arguments(parser) -> None:
    from goniofrost.app.monitoring import add_server_options

    parser.add_argument("session", metavar="SESSION_DIR|ROOT",
                        help="session folder of goniofrost capture --session (it may still be running, "
                             "or not have started yet), or a folder of session folders (a queue's root, which "
                             "may not exist yet: it is watched until it does)")
    add_server_options(parser, with_flag=False)


def run(args) -> int:
    import time
    from pathlib import Path

    from goniofrost.app.monitoring import check_port
    from goniofrost.core.errors import ConfigError
    from goniofrost.monitor.server import MonitorServer

    folder = Path(args.session)
    if folder.exists() and not folder.is_dir():
        raise ConfigError("command line", "SESSION_DIR|ROOT", "a session folder (goniofrost capture --session DIR) "
                          "or a folder of session folders (a queue's root)", args.session)
    from goniofrost.monitor.catalogue import is_catalogue

    check_port(args.port)
    # a folder that does not exist yet (a queue's root before the queue starts) is watched as a
    # folder of sessions: its list fills in once it exists (a capture's own folder is listed too)
    many = not folder.exists() or is_catalogue(folder)
    server = MonitorServer(args.session, host=args.host, port=args.port, catalogue=many).start()
    what = "the sessions under " if many else ""
    later = "" if folder.exists() else " once it exists"
    print(f"goniofrost monitor: {server.url} shows {what}{args.session}{later} (read-only); Ctrl-C stops", flush=True)
    try:
        # Short sleeps: Ctrl-C's handler runs in the main thread only when it next runs Python
        # code, and a SIGINT the kernel hands to one of the server's threads does not wake a
        # long sleep (an hour, before: a suite run once saw the command outlive 60 s after it).
        while True:
            time.sleep(0.5)
    except KeyboardInterrupt:
        return 0
    finally:
        server.close()
