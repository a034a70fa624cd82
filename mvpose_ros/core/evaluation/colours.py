"""The colour of a person id, the same in RViz markers, overlays and videos (apart from the
drawing, so that bp_solver's markers do not load OpenCV)."""
from __future__ import annotations

import colorsys

GOLDEN_RATIO_CONJUGATE = (5.0 ** 0.5 - 1.0) / 2.0


def person_colour(person_id: int) -> tuple[float, float, float]:
    """(r, g, b) in [0, 1] for a person id, the same in RViz markers, overlays and videos: hues
    step by the golden ratio, so consecutive ids get far-apart hues and any few ids stay distinct."""
    r, g, b = colorsys.hsv_to_rgb((int(person_id) * GOLDEN_RATIO_CONJUGATE) % 1.0, 0.85, 0.95)
    return r, g, b
