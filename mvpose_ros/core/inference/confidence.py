"""How sure the solver is of each decoded joint: the product of two numbers in [0, 1].

- support: how much 2D evidence there is, the joint's detection scores (each clipped to 1)
  summed over the views that saw it, over the number of cameras of the rig. A joint seen
  clearly by every camera has 1; one hidden from most cameras little.
- agreement: how concentrated the joint's BP marginal is around the decoded point,
  exp(-E[distance from the decoded point] / SPREAD_SCALE_M) under the marginal. Hypotheses are
  samples and several of them often lie within centimetres of one another, so the belief of the
  decoded hypothesis alone (or the marginal's entropy) says little; its spread in metres does.

Chosen on Shelf (README, "Per-joint confidence") against the belief of the decoded hypothesis,
the marginal's entropy, its mass within 5, 10, 20 cm, the number of views and the spread of the
data term, each alone: the product ranked errors and wrong limbs best.
"""
from __future__ import annotations

import numpy as np

SPREAD_SCALE_M = 0.10


def joint_support(scores: np.ndarray, n_cameras: int) -> np.ndarray:
    """Support (J,) in [0, 1] from the 2D detection scores (V, J) of a person's V views (0 or NaN
    where a view did not detect the joint) in a rig of n_cameras."""
    scores = np.clip(np.nan_to_num(np.asarray(scores, dtype=np.float64)), 0.0, 1.0)
    return np.minimum(scores.sum(axis=0) / max(n_cameras, 1), 1.0)


def joint_confidence(marginals: np.ndarray, hypotheses: np.ndarray, best: np.ndarray,
                     support: np.ndarray) -> np.ndarray:
    """Confidence (..., J) in [0, 1] of the decoded joints.

    marginals: (..., J, M) beliefs (normalised here); hypotheses: (..., J, M, 3) metres; best:
    (..., J) index of the decoded hypothesis of each joint; support: (..., J) joint_support.
    """
    p = marginals / np.maximum(marginals.sum(axis=-1, keepdims=True), np.finfo(float).tiny)
    decoded = np.take_along_axis(hypotheses, best[..., None, None], axis=-2)  # (..., J, 1, 3)
    spread = (p * np.linalg.norm(hypotheses - decoded, axis=-1)).sum(axis=-1)  # (..., J) metres
    return np.clip(support * np.exp(-spread / SPREAD_SCALE_M), 0.0, 1.0)
