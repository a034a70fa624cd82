"""The defaults every part of the graph shares, each defined once: the cameras' frame rate, where
the shared data lives, and how cameras' messages are gathered into sets (`sync_timeout`,
`max_skew`). Nodes, message adapters, the graph runner, launch files and the 3D stage read them
here; ROS-free."""
from __future__ import annotations

import os
from pathlib import Path

# Hz: the cameras' rate a node assumes unless its frame_rate parameter says otherwise, and the
# datasets' own (Shelf and Campus run at 25 Hz: frame f is stamped f / FRAME_RATE s in the bags).
FRAME_RATE = 25.0

DATA_ROOT_ENV = 'MVPOSE_DATA_ROOT'

SYNC_TIMEOUT_S = 0.5  # s a set waits for a camera missing from it


def default_max_skew(frame_rate: float) -> float:
    """The default max_skew, seconds: half a frame period of cameras running at frame_rate Hz."""
    return 0.5 / frame_rate


def max_skew_or_default(max_skew: float, frame_rate: float) -> float:
    """The max_skew (s) of a node whose parameter reads 0 as 'the default': half a frame period."""
    return max_skew or default_max_skew(frame_rate)


def data_root(override: str | None = None) -> Path:
    """Folder holding the shared data (`data/`, `models/`).

    An explicit `override` (CLI flag) or the MVPOSE_DATA_ROOT variable is used as given and is an
    error when missing: silently falling back to another data set would hide a typo. Without
    either, try `../shared` beside the repository checkout, then `../shared` beside the cwd.
    """
    if override is not None:
        tried = [Path(override).expanduser()]
    elif os.environ.get(DATA_ROOT_ENV):
        tried = [Path(os.environ[DATA_ROOT_ENV]).expanduser()]
    else:
        checkout = Path(__file__).resolve().parents[2]
        tried = [checkout.parent / 'shared', Path.cwd().parent / 'shared']
    for path in tried:
        if path.is_dir():
            return path
    source = ('override' if override is not None
              else DATA_ROOT_ENV if os.environ.get(DATA_ROOT_ENV) else 'default locations')
    raise FileNotFoundError(
        f'mvpose data root not found ({source}); tried: {", ".join(str(p) for p in tried)}. '
        f'Pass a data root or set {DATA_ROOT_ENV}.')
