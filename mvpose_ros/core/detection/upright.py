"""Upright detection: the quarter turns that stand a camera's image up, from its rotation and the
world's up direction. 2D pose models are trained on upright people; a camera mounted upside down
(a ceiling mount) or on its side (portrait) shows them turned, and MultiPose then finds few of
them. The detector turns such a camera's image before the networks see it (Letterbox.turns) and
brings every keypoint and map back to the camera's own pixels."""
from __future__ import annotations

import math

import numpy as np

UPRIGHT = True  # the detector's default: stand every camera's people up

# Below this length of the world's up direction in the image plane (the sine of the optical
# axis's angle to the vertical) a camera looks nearly straight up or down: people lie around the
# image centre in every direction, and no quarter turn is better than none.
MIN_UP_IN_IMAGE = math.sin(math.radians(20.0))


def upright_turns(R: np.ndarray, up: np.ndarray) -> int:
    """The quarter turns (0..3, counterclockwise as shown: np.rot90's) of the image of a camera of
    rotation R (3, 3) world -> optical (x right, y down, z forward) after which the world's up
    (3,) points up at the image centre; 0 for a camera looking within 20 degrees of straight up
    or down."""
    x, y, _ = np.asarray(R, dtype=np.float64) @ (np.asarray(up, dtype=np.float64) / np.linalg.norm(up))
    if math.hypot(x, y) < MIN_UP_IN_IMAGE:
        return 0
    # a quarter turn moves an image direction (dx, dy) to (dy, -dx): up (0, -1) is reached from
    # (1, 0) by one turn, from (0, 1) by two, from (-1, 0) by three
    return round(math.degrees(math.atan2(x, -y)) / 90.0) % 4
