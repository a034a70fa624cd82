"""Compiled kernels: compiled for the types they name only, and every module holding one is
listed for `compile_all` (which the graph runs before starting its nodes)."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from mvpose_ros.core import compiled
from mvpose_ros.core.compiled import kernel
from mvpose_ros.core.kernel_cache import KERNEL_MODULES

PACKAGE = Path(compiled.__file__).parents[1]


def test_every_module_with_kernels_is_listed():
    holding = sorted(
        '.'.join(path.relative_to(PACKAGE.parent).with_suffix('').parts)
        for path in PACKAGE.rglob('*.py')
        if path.name != 'compiled.py' and re.search(r'^@kernel\(', path.read_text(), re.MULTILINE))
    assert holding == sorted(KERNEL_MODULES)
    compiled.compile_all()


def test_a_kernel_takes_its_signature_only():
    @kernel('float64(float64[::1])')
    def total(x):
        s = 0.0
        for v in x:
            s += v
        return s

    assert total(np.arange(4.0)) == 6.0
    with pytest.raises(TypeError):
        total(np.arange(4, dtype=np.float32))
    with pytest.raises(TypeError):
        total(np.arange(8.0)[::2])  # not contiguous


def test_division_by_zero_follows_numpy():
    @kernel('float64(float64)')
    def inverse(x):
        return 1.0 / x

    assert inverse(0.0) == np.inf


def test_kernel_array_copies_only_what_a_kernel_would_refuse():
    plain = np.zeros((3, 3))
    assert compiled.kernel_array(plain, np.float64) is plain
    frozen = np.zeros(3)
    frozen.flags.writeable = False
    for odd in (frozen, np.zeros((3, 3)).T, np.zeros(6)[::2], np.zeros(3, np.float32)):
        ready = compiled.kernel_array(odd, np.float64)
        assert ready.flags.c_contiguous and ready.flags.writeable and ready.dtype == np.float64
        np.testing.assert_array_equal(ready, odd)
