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
    from goniofrost.frost import bayes_kernels, check_cells, somp_kernels
    from planner import view_kernels

    kernels = (bayes_kernels.init_forms, bayes_kernels.update_forms, check_cells._farthest_points, somp_kernels.pack_atoms,
               somp_kernels.block_scores, somp_kernels.rank1_step, view_kernels.roi_counts)
    for kernel in kernels:   # numba's on-disk index of the kernel's compiled versions, and one at least
        index = Path(kernel._cache._cache_file._index_path)
        assert index.is_file() and kernel.signatures, index


def test_every_dependency_set_up_imports_is_installed_under_that_name():
    """A misspelt or dropped name would leave its byte code to the first command, unseen."""
    from goniofrost.app.warm import import_dependencies

    assert import_dependencies() == []


def test_byte_code_is_written_for_imported_modules_even_where_imports_write_none(tmp_path, monkeypatch):
    """PYTHONDONTWRITEBYTECODE (set on these machines) stops imports from writing .pyc files;
    set-up writes them for what it imported, or every command would compile them again."""
    import importlib
    import sys

    from goniofrost.app.warm import write_byte_code

    (tmp_path / "warm_probe_module.py").write_text("VALUE = 3\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(sys, "dont_write_bytecode", True)
    module = importlib.import_module("warm_probe_module")
    cached = Path(importlib.util.cache_from_source(module.__file__))
    assert not cached.exists()
    try:
        assert write_byte_code() >= 1
        assert cached.is_file() and cached.stat().st_mtime >= Path(module.__file__).stat().st_mtime
        written = cached.stat().st_mtime_ns
        write_byte_code()   # a fresh .pyc is kept, not written again
        assert cached.stat().st_mtime_ns == written
    finally:
        sys.modules.pop("warm_probe_module", None)
