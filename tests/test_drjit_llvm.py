"""Mitsuba's LLVM variant is pointed at the newest LLVM on the machine, or refused in one line."""
from __future__ import annotations

import pytest

from goniofrost.brdf.drjit_llvm import ENV, major_version, name_newest_llvm


@pytest.mark.parametrize("name, major", [("libLLVM-19.so", 19), ("libLLVM-14.0.6.so.1", 14), ("libLLVM-15.so.1", 15),
                                         ("libLLVM.so.19.1", 19), ("libLLVM.so", None), ("libLLVMSupport.so", None)])
def test_the_major_version_is_read_from_each_debian_name(name, major):
    assert major_version(name) == major


def _folder(tmp_path, *names):
    for name in names:
        (tmp_path / name).write_bytes(b"")
    return [str(tmp_path)]


def test_the_newest_llvm_is_named_to_drjit_ahead_of_an_older_one_it_would_find_first(tmp_path):
    """Dr.Jit takes the first libLLVM*.so.* it finds; Debian 12 with Chromium has 14 and 15 beside 19."""
    folders = _folder(tmp_path, "libLLVM-14.0.6.so.1", "libLLVM-15.so.1", "libLLVM-19.so", "libLLVM.so.19.1")
    environ = {}
    name_newest_llvm("llvm_ad_rgb", environ, folders)
    assert environ == {ENV: str(tmp_path / "libLLVM-19.so")}


def test_a_library_the_user_named_is_kept(tmp_path):
    environ = {ENV: "/opt/llvm/lib/libLLVM.so"}
    name_newest_llvm("llvm_ad_rgb", environ, _folder(tmp_path, "libLLVM-19.so"))
    assert environ == {ENV: "/opt/llvm/lib/libLLVM.so"}


def test_only_an_llvm_too_old_is_one_line_that_says_what_to_install(tmp_path):
    folders = _folder(tmp_path, "libLLVM-15.so.1", "libLLVM-14.so")
    environ = {}
    with pytest.raises(RuntimeError) as caught:
        name_newest_llvm("llvm_ad_rgb", environ, folders)
    assert str(caught.value) == (
        f"Mitsuba's llvm_ad_rgb variant needs LLVM 16 or newer (found: {tmp_path / 'libLLVM-14.so'}, "
        f"{tmp_path / 'libLLVM-15.so.1'}); install it (Debian 12: apt-get install libllvm19) or name one with "
        f"DRJIT_LIBLLVM_PATH=/path/to/libLLVM.so")
    assert environ == {}
    with pytest.raises(RuntimeError, match=r"\(found: no libLLVM in /nowhere\)"):
        name_newest_llvm("llvm_ad_rgb", {}, ["/nowhere"])
