"""A live view of a capture session: a read-only web page the operator keeps open.

``session_view`` reads a session folder without writing to it; ``status`` turns that into what
the page shows (state, "N of M samples", ETA, poses, the fault and what to do); ``images`` renders
the latest frame and the reconstruction so far; ``safe_path`` keeps served paths inside the
session; ``hub`` holds each session's state and pictures, ``views`` the read-only routes (updates
are server-sent events), ``app`` makes the Starlette app and ``server`` runs it on uvicorn.
``goniofrost monitor`` and ``capture --monitor`` start it.
"""

# The monitor page's TCP port; here, not in server, so that building the command line's parser
# (every --port option) does not import the server and the session reader behind it.
DEFAULT_PORT = 8765
