"""argparse value types shared by several commands (a bad value is argparse's one-line usage error,
before the command runs and writes anything)."""
from __future__ import annotations

import argparse


def seed(text: str) -> int:
    """``--seed``: an integer >= 0 (numpy's generators refuse a negative seed with a traceback)."""
    try:
        value = int(text)
    except ValueError:
        value = None
    if value is None or value < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, found {text!r}")
    return value


def grid_bins(text: str) -> tuple[int, int, int]:
    """``--grid``: the bins of theta_h, theta_d and phi_d, "30,30,60" (or "30x30x60"), each >= 1."""
    try:
        values = tuple(int(v) for v in text.replace("x", ",").split(","))
    except ValueError:
        values = ()
    if len(values) != 3 or min(values) < 1:
        raise argparse.ArgumentTypeError(f"expected three positive integers like 30,30,60, found {text!r}")
    return values
