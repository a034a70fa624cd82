"""The ROS 2 install path of docs/install.md, as written: a colcon workspace with this checkout in
src/, `colcon build`, `source install/setup.bash`; then the ament index resolves the package in
the workspace, every node has the executable `ros2 run` looks for (<prefix>/lib/mvpose_ros/<node>),
a launcher started so runs the workspace's code, and the installed launch files parse.
(`ros2` itself, ros2cli, is not on PyPI: its lookup is done here as ros2run does it.)"""
from __future__ import annotations

import ast
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGE = 'mvpose_ros'
NODES = ('bag_player', 'heatmap_detector', 'association', 'bp_solver', 'overlay', 'skeleton_echo', 'composed')


def _colcon() -> str:
    found = shutil.which('colcon', path=os.pathsep.join([str(Path(sys.executable).parent), os.environ.get('PATH', '')]))
    if found is None:
        pytest.skip('colcon is not installed (pip install colcon-common-extensions, as requirements-test.txt does)')
    return found


pytestmark = pytest.mark.slow  # a colcon build (its launcher test starts a node: ros too)


@pytest.fixture(scope='module')
def workspace(tmp_path_factory) -> Path:
    colcon = _colcon()
    ws = tmp_path_factory.mktemp('colcon_ws')
    (ws / 'src').mkdir()
    (ws / 'src' / PACKAGE).symlink_to(REPO, target_is_directory=True)
    done = subprocess.run([colcon, 'build'], cwd=ws, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout + done.stderr
    return ws


def _sourced(ws: Path, command: str, domain: int | None = None) -> subprocess.CompletedProcess:
    """`command` in bash after `source install/setup.bash`, this interpreter first on PATH (the
    python3 a ROS install's launchers run)."""
    env = {**os.environ, 'PATH': os.pathsep.join([str(Path(sys.executable).parent), os.environ['PATH']])}
    env.pop('AMENT_PREFIX_PATH', None)
    if domain is not None:
        env |= {'ROS_DOMAIN_ID': str(domain), 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}
    return subprocess.run(['bash', '-c', f'source install/setup.bash && {command}'], cwd=ws, env=env,
                          capture_output=True, text=True, timeout=120)


def test_the_ament_index_resolves_the_workspace(workspace):
    done = _sourced(workspace, 'python3 -c "from ament_index_python.packages import get_package_prefix as p; '
                               f"print(p('{PACKAGE}'))\"")
    assert done.returncode == 0, done.stderr
    assert Path(done.stdout.strip()) == workspace / 'install' / PACKAGE


def test_ros2_run_finds_every_node(workspace):
    lib = workspace / 'install' / PACKAGE / 'lib' / PACKAGE
    for node in NODES:
        assert os.access(lib / node, os.X_OK), f'{lib / node}: not an executable file'


def test_a_launcher_runs_the_workspaces_code(workspace, domain):
    """bag_player with a value out of its range: one line naming it, exit 2, from the installed module."""
    lib = workspace / 'install' / PACKAGE / 'lib' / PACKAGE
    done = _sourced(workspace, f'{lib / "bag_player"} --ros-args -p loops:=0', domain)
    assert done.returncode == 2, done.stdout + done.stderr
    assert 'parameter loops' in done.stderr
    where = _sourced(workspace, f'python3 -c "import {PACKAGE}; print({PACKAGE}.__file__)"')
    assert Path(where.stdout.strip()).is_relative_to(workspace / 'install'), where.stdout


def test_the_installed_launch_files_parse(workspace):
    launch = sorted((workspace / 'install' / PACKAGE / 'share' / PACKAGE / 'launch').glob('*.launch.py'))
    assert {p.name for p in launch} >= {'shelf.launch.py', 'rig.launch.py'}
    for path in launch:
        tree = ast.parse(path.read_text(), str(path))
        assert any(isinstance(n, ast.FunctionDef) and n.name == 'generate_launch_description' for n in tree.body), path
