"""``goniofrost sessions``: the catalogue of a folder of sessions, one line each."""
from __future__ import annotations

HELP = ("list the sessions under ROOT: name, started, operator, sample, state, samples (measured/planned, and how "
        "many were not measured: too dark or saturated), predicted error, "
        "duration, then the samples of their queues not started yet, pending, in queue order (read-only)")


def add_arguments(parser) -> None:
    parser.add_argument("root", metavar="ROOT", help="a folder of session folders (a queue's root), or one session folder")
    parser.add_argument("--sample", metavar="ID", help="only the sessions of this sample id")
    parser.add_argument("--operator", metavar="NAME", help="only the sessions of this operator")
    parser.add_argument("--since", metavar="DATE", help="only sessions started on or after DATE (YYYY-MM-DD[THH:MM], UTC)")
    parser.add_argument("--json", action="store_true", help="a JSON list with every field instead of the table")


def run(args) -> int:
    import json

    from goniofrost.monitor.catalogue import catalogue, parse_since, table_text

    entries = catalogue(args.root, sample=args.sample, operator=args.operator, since=parse_since(args.since))
    if args.json:
        print(json.dumps([e.as_json() for e in entries], indent=1))
    else:
        print(table_text(entries), end="")
    return 0
