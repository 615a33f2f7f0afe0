"""The ``goniofrost`` command line: one sub-command per module in ``goniofrost.app.commands``.

Each command module defines ``HELP`` (one line), ``add_arguments(parser)`` and
``run(args) -> int``; it imports heavy libraries inside ``run`` so that ``--help`` stays fast.
Errors derived from GoniofrostError are printed as one line and exit with status 2.
"""
from __future__ import annotations

import argparse
import difflib
import importlib
import os
import signal
import sys

from goniofrost.capture.signals import SessionInterrupted  # a small module: --help stays fast
from goniofrost.core.errors import GoniofrostError

COMMANDS = ["materials", "convert", "train", "plan", "reconstruct", "align", "capture", "sim",
            "bench", "preview", "compare", "demo", "export", "monitor", "usage", "rig", "queue", "sessions",
            "serve"]


class OneLineParser(argparse.ArgumentParser):
    """argparse's parser whose usage errors are one line, like every other error of the command
    line (argparse prints the whole usage block first); exit status 2 as before. Sub-parsers
    inherit the class."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")

    def parse_known_args(self, args=None, namespace=None):
        """A command's unknown option or extra argument is that command's error (``goniofrost capture:
        ... (see goniofrost capture --help)``, the nearest option named), not the top parser's
        ``goniofrost: error: unrecognized arguments``; and a mistyped option is named before argparse
        reports the required option it was meant to be (``--sampels 20``: not "one of the arguments
        --samples --max-error is required")."""
        leaf = not any(isinstance(a, argparse._SubParsersAction) for a in self._actions)
        if leaf and args is not None:
            self._refuse_unknown_options(list(args))
        namespace, extras = super().parse_known_args(args, namespace)
        if leaf and extras:
            self.error(f"unrecognized arguments: {' '.join(extras)}")
        return namespace, extras

    def _refuse_unknown_options(self, args: list[str]) -> None:
        known = [s for action in self._actions for s in action.option_strings if s.startswith("--")]
        for arg in args:
            if arg == "--":
                return
            name = arg.split("=", 1)[0]
            # an unambiguous or ambiguous prefix (allow_abbrev) is argparse's to read or refuse
            if not name.startswith("--") or any(s.startswith(name) for s in known):
                continue
            close = difflib.get_close_matches(name, known, n=1)
            self.error(f"unrecognized option {name}" + (f"; did you mean {close[0]}?" if close else ""))


def build_parser() -> argparse.ArgumentParser:
    """The full argument parser, with one sub-parser per available command."""
    parser = OneLineParser(
        prog="goniofrost",
        description="Measure a BRDF from a few optimal light/view pairs (FROST-BRDF) on a real or simulated gonioreflectometer.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMANDS:
        try:
            module = importlib.import_module(f"goniofrost.app.commands.{name}")
        except ModuleNotFoundError as exc:
            if exc.name != f"goniofrost.app.commands.{name}":
                raise
            continue  # a command not built yet is simply not offered
        # argparse %-formats a command's help line but prints its description as written
        command = sub.add_parser(name, help=module.HELP.replace("%", "%%"), description=module.HELP)
        module.add_arguments(command)
        command.set_defaults(_run=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the process exit status."""
    args = build_parser().parse_args(argv)
    try:
        return int(args._run(args) or 0)
    except GoniofrostError as exc:
        print(f"goniofrost {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        # the reader went away (`| head`): quiet, as a tool killed by SIGPIPE; stdout is pointed at
        # /dev/null so that the interpreter's final flush does not raise again
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 128 + signal.SIGPIPE
    except OSError as exc:
        # the last resort at the boundary: every known path has its own message, but an
        # unforeseen file problem is still one line naming the file, never a traceback
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"goniofrost {args.command}: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 2
    except SessionInterrupted as exc:  # Ctrl-C or rig stop: the message says how each axis and the lamp took it
        text = str(exc) if str(exc).startswith("interrupted") else f"interrupted ({exc})"
        print(f"goniofrost {args.command}: {text}", file=sys.stderr)
        return 130
    except KeyboardInterrupt:
        print(f"goniofrost {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
