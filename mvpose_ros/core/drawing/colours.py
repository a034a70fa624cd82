"""How a person is drawn, the same in RViz markers, the Foxglove scene, overlays and videos: the
colour of his id, the fading of a joint with its confidence, the 3D sizes (apart from the OpenCV
drawing, so that bp_solver's markers and the view do not load OpenCV)."""
from __future__ import annotations

import colorsys

import numpy as np

GOLDEN_RATIO_CONJUGATE = (5.0 ** 0.5 - 1.0) / 2.0
# A person in 3D (RViz markers, the Foxglove scene): joint spheres, bone lines, the id label.
JOINT_DIAMETER_M = 0.06
BONE_WIDTH_M = 0.03
TEXT_HEIGHT_M = 0.12
MIN_ALPHA = 0.15  # a joint of confidence 0 stays faintly visible; confidence 1 is opaque


def person_colour(person_id: int) -> tuple[float, float, float]:
    """(r, g, b) in [0, 1] for a person id, the same in RViz markers, overlays and videos: hues
    step by the golden ratio, so consecutive ids get far-apart hues and any few ids stay distinct."""
    r, g, b = colorsys.hsv_to_rgb((int(person_id) * GOLDEN_RATIO_CONJUGATE) % 1.0, 0.85, 0.95)
    return r, g, b


def confidence_alpha(confidence: np.ndarray) -> np.ndarray:
    """Alpha (...) in [MIN_ALPHA, 1] of confidences (...) in [0, 1]."""
    return MIN_ALPHA + (1.0 - MIN_ALPHA) * np.asarray(confidence, dtype=np.float64)
