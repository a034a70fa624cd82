"""Files the package ships (config/, launch/): found in the checkout, or where `pip install` or
`colcon build` put them (<prefix>/share/mvpose_ros)."""
from __future__ import annotations

import os
import sys
from pathlib import Path

PACKAGE = 'mvpose_ros'


def package_path(relative: str | Path) -> Path:
    """The shipped file `relative` (e.g. 'config/rigs/shelf.yaml'); FileNotFoundError naming the
    places tried."""
    tried = [Path(__file__).resolve().parents[1] / relative, Path(sys.prefix) / 'share' / PACKAGE / relative]
    tried += [Path(p) / 'share' / PACKAGE / relative for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep)
              if p]
    for path in tried:
        if path.is_file():
            return path
    raise FileNotFoundError(f'{relative}: not found in {", ".join(str(p.parent) for p in tried)}')
