"""How sure the solver is of each decoded joint: the product of two numbers in [0, 1].

- support: how much 2D evidence there is, the joint's detection scores (each clipped to 1)
  summed over the views that saw it, over the number of cameras of the rig.
- agreement: how concentrated the joint's BP marginal is around the decoded point,
  exp(-E[distance from the decoded point] / SPREAD_SCALE_M) under the marginal. Hypotheses are
  samples, often within centimetres of one another, so the belief of the decoded hypothesis
  alone says little; its spread in metres does.

Why this product, against the other measures tried: docs/results.md#confidence-against-error."""
from __future__ import annotations

import math

import numpy as np

from mvpose_ros.core.compiled import kernel, kernel_array, pairwise_sum

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
    lead, m = marginals.shape[:-1], marginals.shape[-1]
    n = math.prod(lead)
    support = np.asarray(support)
    if support.shape != lead:
        support = np.broadcast_to(support, lead)
    return _joint_confidence(kernel_array(marginals, np.float64).reshape(n, m),
                             kernel_array(hypotheses, np.float64).reshape(n, m, 3),
                             kernel_array(best, np.int64).reshape(n),
                             kernel_array(support, np.float64).reshape(n)).reshape(lead)


@kernel('float64[::1](float64[:, ::1], float64[:, :, ::1], int64[::1], float64[::1])')
def _joint_confidence(marginals, hypotheses, best, support):
    """joint_confidence of N joints: (N, M), (N, M, 3), (N,), (N,) -> (N,); numpy's sums to the bit."""
    n, m = marginals.shape
    out = np.empty(n)
    p = np.empty(m)
    tiny = np.finfo(np.float64).tiny
    for i in range(n):
        total = max(pairwise_sum(marginals[i]), tiny)
        decoded = hypotheses[i, best[i]]
        for k in range(m):
            dx = hypotheses[i, k, 0] - decoded[0]
            dy = hypotheses[i, k, 1] - decoded[1]
            dz = hypotheses[i, k, 2] - decoded[2]
            p[k] = marginals[i, k] / total * np.sqrt(dx * dx + dy * dy + dz * dz)
        spread = pairwise_sum(p)  # metres
        out[i] = min(max(support[i] * np.exp(-spread / SPREAD_SCALE_M), 0.0), 1.0)
    return out
