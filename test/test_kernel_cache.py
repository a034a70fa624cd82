"""Whether numba's caches of the kernels are fresh, told without importing numba: the graph runner
compiles before starting its nodes only when they are not."""
from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

from mvpose_ros.core import kernel_cache
from mvpose_ros.core.kernel_cache import caches_fresh, import_root

TAG = f'py{sys.version_info.major}{sys.version_info.minor}'
SOURCE = '"""Kernels."""\n\n\n@kernel(\'f8(f8)\')\ndef twice(x):\n    return 2 * x\n\n\n@kernel(\'f8(f8)\',\n' \
         '        \'f4(f4)\')\ndef half(x):\n    return x / 2\n'


@pytest.fixture
def tree(tmp_path, monkeypatch):
    """A package root with one kernel module (two kernels) and core.compiled (none), both cached."""
    monkeypatch.setattr(kernel_cache, 'KERNEL_MODULES', ('mvpose_ros.core.k',))
    core = tmp_path / 'mvpose_ros' / 'core'
    (core / '__pycache__').mkdir(parents=True)
    (core / 'compiled.py').write_text('"""No kernel."""\n')
    (core / 'k.py').write_text(SOURCE)
    for name in ('twice-4', 'half-9'):
        (core / '__pycache__' / f'k.{name}.{TAG}.nbi').write_bytes(b'')
        os.utime(core / '__pycache__' / f'k.{name}.{TAG}.nbi', (2000, 2000))
    os.utime(core / 'k.py', (1000, 1000))
    return tmp_path


def test_caches_written_after_their_module_are_fresh(tree):
    assert caches_fresh(tree)


def test_a_module_edited_after_its_caches_is_not(tree):
    os.utime(tree / 'mvpose_ros' / 'core' / 'k.py', (3000, 3000))
    assert not caches_fresh(tree)


def test_a_kernel_without_a_cache_is_not(tree):
    (tree / 'mvpose_ros' / 'core' / '__pycache__' / f'k.half-9.{TAG}.nbi').unlink()
    assert not caches_fresh(tree)


def test_an_index_left_by_a_moved_function_does_not_count(tree):
    cache = tree / 'mvpose_ros' / 'core' / '__pycache__'
    (cache / f'k.twice-2.{TAG}.nbi').write_bytes(b'')
    os.utime(cache / f'k.twice-2.{TAG}.nbi', (500, 500))  # older than the module
    assert caches_fresh(tree)
    (cache / f'k.half-9.{TAG}.nbi').rename(cache / 'k.half-9.py27.nbi')  # another Python's
    assert not caches_fresh(tree)


def test_a_missing_module_is_not_fresh(tree):
    (tree / 'mvpose_ros' / 'core' / 'k.py').unlink()
    assert not caches_fresh(tree)


def test_python_m_takes_the_working_directorys_checkout(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert import_root() == Path(kernel_cache.__file__).resolve().parents[2]  # no checkout here: this package's
    (tmp_path / 'mvpose_ros').mkdir()
    (tmp_path / 'mvpose_ros' / '__init__.py').write_text('')
    assert import_root() == tmp_path
