"""Each node process imports only what it runs: a node module imported alone, in a fresh
interpreter, must not pull in a heavy library its process never uses (numba and its LLVM hold
about 125 MiB in each process that loads them, scipy's linalg / optimize / io 20-50 MiB,
onnxruntime 20, OpenCV 15)."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

NUMBA = 'numba'
ONNXRUNTIME = 'onnxruntime'
CV2 = 'cv2'
SCIPY = 'scipy.*'  # any public scipy subpackage
# what a process running compiled kernels cannot avoid: numba's CPU target binds LAPACK through
# scipy.linalg's cython_lapack when it starts
SCIPY_BEYOND_NUMBA = 'scipy.* but linalg'

# node module -> the heavy modules it must not load; the OpenPose detector runs compiled kernels
# (grouping, heatmap rendering), association and bp_solver run the 3D stage; the overlay decodes
# and draws (OpenCV) and the live view forwards, neither computes on a heatmap.
FORBIDDEN = {
    'bag_player': (NUMBA, SCIPY, ONNXRUNTIME, CV2),
    'skeleton_echo': (NUMBA, SCIPY, ONNXRUNTIME, CV2),
    'overlay': (NUMBA, SCIPY, ONNXRUNTIME),
    'foxglove_view': (NUMBA, SCIPY, ONNXRUNTIME, CV2),
    'heatmap_detector': (SCIPY_BEYOND_NUMBA, ONNXRUNTIME),
    'association': (ONNXRUNTIME, CV2),
    'bp_solver': (ONNXRUNTIME, CV2),
}

_PROBE = '''
import importlib, json, sys
importlib.import_module(sys.argv[1])
print(json.dumps(sorted(sys.modules)))
'''


def loaded_modules(module: str) -> set[str]:
    """Every module in sys.modules after importing `module` alone in a fresh interpreter."""
    done = subprocess.run([sys.executable, '-c', _PROBE, module], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return set(json.loads(done.stdout.splitlines()[-1]))


def heavy(loaded: set[str], name: str) -> list[str]:
    """The modules of `loaded` that are `name`: a package, or 'pkg.*' its public subpackages
    ('pkg.* but a': other than a)."""
    if '.*' in name:
        prefix, _, exempt = name.partition('.*')
        allowed = {'version', '__config__', exempt.removeprefix(' but ')}
        return sorted(m for m in loaded if m.startswith(prefix + '.') and not m[len(prefix) + 1:].startswith('_')
                      and m[len(prefix) + 1:].split('.')[0] not in allowed)
    return sorted(m for m in loaded if m == name or m.startswith(name + '.'))[:1]


@pytest.mark.parametrize('node', sorted(FORBIDDEN))
def test_a_node_loads_no_heavy_module_it_does_not_run(node):
    loaded = loaded_modules(f'mvpose_ros.nodes.{node}')
    pulled = {name: found[:3] for name in FORBIDDEN[node] if (found := heavy(loaded, name))}
    assert not pulled, f'mvpose_ros.nodes.{node} imports {pulled}, which its process never runs'
