"""Whether this machine's BLAS rounds as the one the arrays in ``tests/data`` were recorded on.

A product of floats depends on the order its terms are summed in, and OpenBLAS picks that order
by CPU (its kernel for the machine: AVX-512 CPUs get "SkylakeX", with kernels of their own for
small matrices) and by its thread count. The recorded arrays were made with the "Haswell" kernels
on 2 cores: there a test compares them to the bit; elsewhere within float rounding, and compares to
the bit only what one machine computes two ways.
"""
from __future__ import annotations

import os

import numpy  # noqa: F401  (threadpoolctl sees only the BLAS of a loaded numpy)
from threadpoolctl import threadpool_info

RECORDED_KERNELS = "Haswell"
RECORDED_CORES = 2


def blas_kernels() -> str:
    """The kernel family of the BLAS numpy uses ("Haswell", "SkylakeX", ...; "" if not OpenBLAS)."""
    return next((pool.get("architecture") or "" for pool in threadpool_info() if pool["user_api"] == "blas"), "")


def rounds_as_recorded() -> bool:
    """True when the recorded arrays can be expected here to the bit."""
    return os.cpu_count() == RECORDED_CORES and blas_kernels() == RECORDED_KERNELS
