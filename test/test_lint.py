"""Lint as ROS 2 packages run it among their tests (ament_flake8, ament_pep257): flake8 with the
line length set in setup.cfg, and a docstring on every public module and package."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SOURCES = ['mvpose_ros', 'msg_adapters', 'test', 'launch', 'setup.py']


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, '-m', *args], cwd=REPO, capture_output=True, text=True, check=False)


@pytest.mark.slow
def test_flake8():
    proc = _run('flake8', *SOURCES)
    assert proc.returncode == 0, f'flake8 found problems:\n{proc.stdout}{proc.stderr}'


@pytest.mark.slow
def test_pep257_public_modules_and_packages_have_docstrings():
    proc = _run('pydocstyle', 'mvpose_ros', 'msg_adapters')
    assert proc.returncode == 0, f'pydocstyle found problems:\n{proc.stdout}{proc.stderr}'
