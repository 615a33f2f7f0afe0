"""The base of every error goniofrost reports to a user as a plain message (no traceback)."""


class GoniofrostError(Exception):
    """An error with a message fit for the user: what failed, where, what was expected, what was found."""
