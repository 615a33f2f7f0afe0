"""The base of every error goniofrost reports to a user as a plain message (no traceback)."""


class GoniofrostError(Exception):
    """An error with a message fit for the user: what failed, where, what was expected, what was found."""


class ConfigError(GoniofrostError, ValueError):
    """A configuration file (rig YAML, plan JSON, ...) that cannot be used.

    The message always reads ``SOURCE: KEY.PATH: expected EXPECTED, found FOUND``.
    """

    def __init__(self, source, keypath: str, expected: str, found) -> None:
        self.source, self.keypath, self.expected, self.found = str(source), keypath, expected, found
        super().__init__(f"{source}: {keypath or '(top level)'}: expected {expected}, found {found!r}")


class OutputError(GoniofrostError, OSError):
    """An output path that cannot be written: ``PATH: cannot write: REASON``.

    Raised before anything is left half-written (see ``goniofrost.core.atomic_file``).
    """

    def __init__(self, path, reason: str) -> None:
        self.path, self.reason = str(path), reason
        super().__init__(f"{path}: cannot write: {reason}")
