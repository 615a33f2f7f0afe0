"""``python -m goniofrost.app.warm`` (run by ``./dev setup``): nothing is compiled inside the
first command after set-up, neither a module's byte code nor a numba kernel."""
from __future__ import annotations

import importlib.util
from pathlib import Path

from goniofrost.app.warm import PACKAGES, byte_compile


def test_every_module_of_the_project_is_byte_compiled():
    assert byte_compile()
    for name in PACKAGES:
        folder = Path(importlib.util.find_spec(name).origin).parent
        sources = list(folder.rglob("*.py"))
        assert sources
        for source in sources:
            cached = Path(importlib.util.cache_from_source(str(source)))
            assert cached.is_file() and cached.stat().st_mtime >= source.stat().st_mtime, source


def test_the_kernels_are_cached_on_disk_after_warming():
    from goniofrost.app.warm import warm_kernels

    seconds = warm_kernels()
    assert set(seconds) == {"byte-compiled modules", "frost kernels", "planner.view"}
    from goniofrost.frost import bayes_kernels, somp_kernels
    from planner import view

    kernels = (bayes_kernels.init_forms, bayes_kernels.update_forms, somp_kernels.pack_atoms,
               somp_kernels.block_scores, somp_kernels.rank1_step, view._roi_counts)
    for kernel in kernels:   # numba's on-disk index of the kernel's compiled versions, and one at least
        index = Path(kernel._cache._cache_file._index_path)
        assert index.is_file() and kernel.signatures, index


def test_every_dependency_set_up_imports_is_installed_under_that_name():
    """A misspelt or dropped name would leave its byte code to the first command, unseen."""
    from goniofrost.app.warm import import_dependencies

    assert import_dependencies() == []
