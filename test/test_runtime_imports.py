"""Nothing that runs in the graph imports the evaluation room: the nodes, the message adapters, the
launch files, the view and the core outside core/evaluation take their defaults from core/defaults
and their drawing from core/drawing. Checked in the source (every import statement) and at run
time (every run-time module imported in a fresh interpreter, then sys.modules read)."""
from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EVALUATION = 'mvpose_ros.core.evaluation'
RUNTIME = ('mvpose_ros/nodes', 'msg_adapters', 'launch', 'mvpose_ros/core', 'mvpose_ros/view')


def runtime_files() -> list[Path]:
    """Every Python file of the run-time packages, core/evaluation left out."""
    files = [f for d in RUNTIME for f in sorted((ROOT / d).rglob('*.py'))]
    return [f for f in files if (ROOT / 'mvpose_ros/core/evaluation') not in f.parents]


def imported_modules(source: str) -> set[str]:
    """The modules an import statement of `source` names (for `from a import b`: a and a.b)."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            names |= {node.module, *(f'{node.module}.{alias.name}' for alias in node.names)}
    return names


def evaluation_imports(names: set[str]) -> list[str]:
    return sorted(n for n in names if n == EVALUATION or n.startswith(EVALUATION + '.'))


def test_the_scan_sees_every_form_of_import():
    for line in ('import mvpose_ros.core.evaluation.pcp', 'from mvpose_ros.core import evaluation',
                 'from mvpose_ros.core.evaluation.offline import infer',
                 'def f():\n    import mvpose_ros.core.evaluation'):
        assert evaluation_imports(imported_modules(line)), line
    assert not evaluation_imports(imported_modules('from mvpose_ros.core.evaluations_x import y'))


def test_no_runtime_source_imports_evaluation():
    files = runtime_files()
    assert any(f.name == 'overlay.py' for f in files) and any(f.name == 'rig.launch.py' for f in files)
    found = {str(f.relative_to(ROOT)): hits for f in files
             if (hits := evaluation_imports(imported_modules(f.read_text(encoding='utf-8'))))}
    assert not found, f'run-time modules import the evaluation room: {found}'


_PROBE = '''
import importlib, json, sys
for module in sys.argv[1:]:
    importlib.import_module(module)
print(json.dumps(sorted(sys.modules)))
'''


@pytest.mark.slow
def test_no_runtime_module_loads_evaluation():
    modules = ['.'.join(f.relative_to(ROOT).with_suffix('').parts) for f in runtime_files()
               if f.parent.name != 'launch']
    modules = [m.removesuffix('.__init__') for m in modules]
    done = subprocess.run([sys.executable, '-c', _PROBE, *modules], capture_output=True, text=True, timeout=300,
                          cwd=ROOT)
    assert done.returncode == 0, done.stderr
    loaded = json.loads(done.stdout.splitlines()[-1])
    assert 'mvpose_ros.nodes.overlay' in loaded
    assert not evaluation_imports(set(loaded)), evaluation_imports(set(loaded))
