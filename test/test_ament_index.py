"""The installed package as `ros2 run` / `ros2 launch` find it: the ament index resolves it under
this interpreter's prefix, every node has an executable launcher in lib/mvpose_ros, and the share
folder holds package.xml, the parameter file and the launch file."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from ament_index_python.packages import (PackageNotFoundError, get_package_prefix,
                                         get_package_share_directory)

DOMAIN_ID = 172
PACKAGE = 'mvpose_ros'
NODES = ('bag_player', 'heatmap_detector', 'association', 'bp_solver', 'overlay', 'skeleton_echo', 'composed')


@pytest.fixture
def prefix(monkeypatch) -> Path:
    paths = [sys.prefix, *filter(None, os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep))]
    monkeypatch.setenv('AMENT_PREFIX_PATH', os.pathsep.join(paths))
    if not (Path(sys.prefix) / 'share' / 'ament_index' / 'resource_index' / 'packages' / PACKAGE).is_file():
        pytest.skip(f'{PACKAGE} is not installed in {sys.prefix} (run `pip install .` first, as CI does)')
    try:
        return Path(get_package_prefix(PACKAGE))
    except PackageNotFoundError as exc:
        pytest.fail(f'installed, yet the ament index does not resolve it: {exc}')


def test_prefix_is_this_environment(prefix):
    assert prefix.resolve() == Path(sys.prefix).resolve()


def test_node_launchers_are_executable(prefix):
    for name in NODES:
        launcher = prefix / 'lib' / PACKAGE / name
        assert launcher.is_file(), launcher
        assert os.access(launcher, os.X_OK), f'{launcher} has no run bit'


def test_share_folder(prefix):
    share = Path(get_package_share_directory(PACKAGE))
    for item in ('package.xml', 'config/shelf.yaml', 'config/fastdds.xml', 'config/mvpose.rviz',
                 'launch/shelf.launch.py'):
        assert (share / item).is_file(), item
    assert f'<name>{PACKAGE}</name>' in (share / 'package.xml').read_text()


@pytest.mark.ros
def test_launcher_runs_the_node(prefix, tmp_path):
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', ROS_DOMAIN_ID=str(DOMAIN_ID))
    proc = subprocess.run([str(prefix / 'lib' / PACKAGE / 'bag_player'), '--ros-args', '-p', 'bag:=/nonexistent'],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=30)
    assert proc.returncode == 2, proc.stderr
    assert '/nonexistent' in proc.stderr + proc.stdout
    assert 'Traceback' not in proc.stderr
