"""Which modules hold compiled kernels (core.compiled), and whether numba's caches of them on disk
are fresh: the graph runner compiles them before it starts the nodes only when one is not, and
finds out without importing numba."""
from __future__ import annotations

import re
import sys
from pathlib import Path

# Every module that defines kernels (test_compiled checks that none is missing), core.compiled
# itself aside.
KERNEL_MODULES: tuple[str, ...] = (
    'mvpose_ros.core.association.associator',
    'mvpose_ros.core.association.matching',
    'mvpose_ros.core.association.tracking',
    'mvpose_ros.core.association.view_consistency',
    'mvpose_ros.core.detection.grouping',
    'mvpose_ros.core.detection.openpose_detector',
    'mvpose_ros.core.geometry.projection',
    'mvpose_ros.core.geometry.rays',
    'mvpose_ros.core.heatmap_kernels',
    'mvpose_ros.core.inference.bp',
    'mvpose_ros.core.inference.confidence',
    'mvpose_ros.core.inference.factors',
    'mvpose_ros.core.inference.hypotheses',
    'mvpose_ros.core.inference.window',
)
COMPILED = 'mvpose_ros.core.compiled'
# a function compiled with a cache: core.compiled.kernel's decorator, then its def
KERNEL_DEF = re.compile(r'^@kernel\(.*?^def (\w+)\(', re.MULTILINE | re.DOTALL)


def import_root() -> Path:
    """The folder holding the mvpose_ros package that `python -m` in this working directory
    imports: the working directory's own checkout, else this package's."""
    here = Path.cwd()
    if (here / 'mvpose_ros' / '__init__.py').is_file():
        return here
    return Path(__file__).resolve().parents[2]


def caches_fresh(root: Path) -> bool:
    """Whether every kernel of every kernel module under root (the folder holding mvpose_ros/) has
    a numba index file for this Python beside it, written after the module was: what numba would
    load rather than compile. A cache numba keeps elsewhere (a read-only install) counts as not
    fresh."""
    tag = f'py{sys.version_info.major}{sys.version_info.minor}'
    for name in (COMPILED, *KERNEL_MODULES):
        source = root.joinpath(*name.split('.')).with_suffix('.py')
        if not source.is_file():
            return False
        written = source.stat().st_mtime
        cache = source.parent / '__pycache__'
        for kernel in KERNEL_DEF.findall(source.read_text(encoding='utf-8')):
            # numba names an index <module>.<function>-<line>.<python>.nbi; one of a moved or
            # deleted function stays behind, older
            if not any(i.stat().st_mtime >= written for i in cache.glob(f'{source.stem}.{kernel}-*.{tag}.nbi')):
                return False
    return True
