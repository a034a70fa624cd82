"""Compiled kernels: loops that numpy can only run as many small calls, each with its Python cost.

Every kernel of the package is compiled the same way, by `kernel`: for the signatures it names,
at import (another type is a TypeError, never a compilation mid-frame); cached on disk beside its
module; without the GIL; with numpy's arithmetic and error model (no fast-math). Callers hand
kernels their arrays through `kernel_array`; kernels sum through `pairwise_sum` where numpy's bits
must be kept. `python -m mvpose_ros.core.compiled` imports every module that holds kernels
(core.kernel_cache), so that a graph's nodes load the cache instead of each compiling the same code.
When to delete the caches by hand: docs/development.md#compiled-kernels."""
from __future__ import annotations

import importlib
from typing import Callable

import numba
import numpy as np
from numpy.typing import ArrayLike, DTypeLike

from mvpose_ros.core.kernel_cache import KERNEL_MODULES


def kernel(*signatures: str) -> Callable[[Callable], Callable]:
    """Decorator: compile a function to machine code for `signatures` (numba's strings, e.g.
    'float64[:, ::1](float64[:, ::1], int64)')."""
    return numba.njit(list(signatures), cache=True, nogil=True, error_model='numpy')


def inline_kernel(function: Callable) -> Callable:
    """Decorator for a small scalar helper that kernels call per element (a point's projection):
    compiled into each calling kernel, as a separately compiled call cost the caller up to twice
    its time. Without a signature or a cache of its own; not callable from Python."""
    return numba.njit(inline='always', nogil=True, error_model='numpy')(function)


def kernel_array(a: ArrayLike, dtype: DTypeLike) -> np.ndarray:
    """a as the kernels' signatures take arrays: C-contiguous, writable (numba types a read-only
    array, such as a Camera's matrices or a broadcast, apart) and of dtype; copied only when it is
    not already so (as np.require(a, dtype, 'CW') does, at a seventh of its cost: kernels are
    called many times a frame)."""
    out = np.ascontiguousarray(a, dtype=dtype)
    return out if out.flags.writeable else out.copy()


@kernel('float64(float64[::1])', 'float64(float64[:])', 'float32(float32[::1])', 'float32(float32[:])')
def pairwise_sum(x):
    """x.sum() of (N,) added up in numpy's order (pairwise: eight running sums over blocks of at
    most 128 elements), so that a kernel's sums equal numpy's to the bit."""
    n = len(x)
    if n == 0:
        return x.dtype.type(0)
    if n < 8:
        s = x[0]
        for i in range(1, n):
            s += x[i]
        return s
    if n > 128:
        half = n // 2
        half -= half % 8
        return pairwise_sum(x[:half]) + pairwise_sum(x[half:])
    r0, r1, r2, r3, r4, r5, r6, r7 = x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7]
    i = 8
    while i < n - n % 8:
        r0 += x[i]
        r1 += x[i + 1]
        r2 += x[i + 2]
        r3 += x[i + 3]
        r4 += x[i + 4]
        r5 += x[i + 5]
        r6 += x[i + 6]
        r7 += x[i + 7]
        i += 8
    s = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    for k in range(i, n):
        s += x[k]
    return s


def compile_all() -> None:
    """Import every module that holds kernels: compiles them, or loads them from the cache."""
    for name in KERNEL_MODULES:
        importlib.import_module(name)


if __name__ == '__main__':
    compile_all()
