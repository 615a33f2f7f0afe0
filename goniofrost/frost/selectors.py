"""The selection methods by name: the one table ``plan --selector`` and ``bench --methods`` read.

A selector is ``select(model, m=None, *, max_error=None, candidates=None, **options) ->
Selection`` (``candidates``: bool (n_valid,)). To add one: docs/how-to/extend.md.
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass


@dataclass(frozen=True)
class Selector:
    """Where a selection function lives and how its picks are used.

    ``nested``: its first m picks are its best m, so one run of max(m) gives every m (with
    ``pick_seconds``); ``posterior``: its cells are reconstructed by the posterior mean (else ridge).
    """

    module: str
    function: str
    nested: bool
    posterior: bool

    def select(self, model, m=None, **options):
        """Run the selection (the function imported on first use)."""
        return getattr(importlib.import_module(self.module), self.function)(model, m, **options)


SELECTORS = {
    "bayes": Selector("goniofrost.frost.bayes_selection", "select_bayes", nested=True, posterior=True),
    "frost": Selector("goniofrost.frost.selection", "select_cells", nested=False, posterior=False),
}
