"""Scoring 3D poses against ground truth: PCP (strict and lenient) and MPJPE, and the paper's table.

PCP counts a limb as correct when its endpoints lie within alpha times the ground-truth limb length
of their true positions: strict asks it of each endpoint (the paper's wording), lenient of the mean
of the two endpoint errors (the form many later papers used). Each ground-truth actor present in a
frame is scored against the predicted person closest to it (mean joint distance).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from mvpose_ros.core.datasets.shelf_campus import GroundTruth
from mvpose_ros.core.geometry.body import NUM_JOINTS

FORMS = ('strict', 'lenient')
GROUPS = ('Head', 'Torso', 'Upper arm', 'Forearm', 'Thigh', 'Shin', 'All')
ALPHA = 0.5

# Joint 14 is a virtual hip centre (mean of the hips), the torso's lower end.
_HIP_CENTRE = NUM_JOINTS
LIMBS = np.array([(0, 1), (1, 2), (3, 4), (4, 5), (6, 7), (7, 8), (9, 10), (10, 11), (12, 13),
                  (_HIP_CENTRE, 12)])
LIMB_GROUPS = ('Shin', 'Thigh', 'Thigh', 'Shin', 'Forearm', 'Upper arm', 'Upper arm', 'Forearm',
               'Head', 'Torso')
# (10, 7) limb -> group membership, the last column being All.
_MEMBERSHIP = np.array([[g == lg or g == 'All' for g in GROUPS] for lg in LIMB_GROUPS], dtype=int)

PAPER_SHELF_PCP: dict[str, dict[str, float]] = {
    'Actor 1': {'Head': 32.14, 'Torso': 99.64, 'Upper arm': 95.18, 'Forearm': 82.50,
                'Thigh': 99.64, 'Shin': 99.64, 'All': 88.34},
    'Actor 2': {'Head': 16.22, 'Torso': 100.00, 'Upper arm': 94.59, 'Forearm': 66.22,
                'Thigh': 100.00, 'Shin': 100.00, 'All': 85.26},
    'Actor 3': {'Head': 28.40, 'Torso': 100.00, 'Upper arm': 94.14, 'Forearm': 94.44,
                'Thigh': 100.00, 'Shin': 100.00, 'All': 91.30},
    'Average': {'All': 88.92},
}
PAPER_CAMPUS_AVERAGE = 85.15


@dataclass
class Evaluation:
    """Scores of one clip.

    actors: (A,) actorsGT actor indices scored.
    correct: (2, A, G) correct limbs per form (FORMS), actor and group (GROUPS).
    total: (A, G) limbs scored per actor and group (the same for both forms).
    frames: (A,) frames in which each actor is present.
    missed: (A,) of those, frames without any prediction (all limbs wrong, not in MPJPE).
    mpjpe: (A,) mean per-joint position error in mm over matched frames (NaN if none).
    mpjpe_all: mm, over every matched actor-frame's joints.
    """

    actors: tuple[int, ...]
    correct: np.ndarray
    total: np.ndarray
    frames: np.ndarray
    missed: np.ndarray
    mpjpe: np.ndarray
    mpjpe_all: float
    alpha: float = ALPHA

    def _rate(self, correct: np.ndarray, total: np.ndarray) -> np.ndarray:
        with np.errstate(divide='ignore', invalid='ignore'):
            return 100.0 * correct / total

    def pcp(self, form: str, actor: int, group: str = 'All') -> float:
        """Percent of correct limbs of `actor` (actorsGT index) in `group`; NaN if unseen."""
        a, g = self.actors.index(actor), GROUPS.index(group)
        return float(self._rate(self.correct[FORMS.index(form), a, g], self.total[a, g]))

    def actor_average(self, form: str, group: str = 'All') -> float:
        """Mean over actors (those present at least once) of their PCP for `group`."""
        g = GROUPS.index(group)
        rates = self._rate(self.correct[FORMS.index(form), :, g], self.total[:, g])
        seen = self.total[:, g] > 0
        return float(rates[seen].mean()) if seen.any() else float('nan')

    def frame_weighted(self, form: str, group: str = 'All') -> float:
        """Correct over scored limbs summed over actors: the paper's "Average"."""
        g = GROUPS.index(group)
        correct = self.correct[FORMS.index(form), :, g].sum()
        return float(self._rate(correct, self.total[:, g].sum()))


def _with_hip_centre(poses: np.ndarray) -> np.ndarray:
    """(..., 14, 3) -> (..., 15, 3), appending the hip centre."""
    return np.concatenate([poses, poses[..., 2:4, :].mean(axis=-2, keepdims=True)], axis=-2)


def _padded(predictions: Mapping[int, np.ndarray], frames: np.ndarray) -> np.ndarray:
    """(F, P, 14, 3) predictions per frame, NaN-padded to the largest count P (>= 1)."""
    empty = np.empty((0, NUM_JOINTS, 3))
    per_frame = [np.asarray(predictions.get(int(f), empty), dtype=float).reshape(-1, NUM_JOINTS, 3)
                 for f in frames]
    counts = np.array([len(p) for p in per_frame], dtype=int)
    out = np.full((len(frames), max(int(counts.max(initial=0)), 1), NUM_JOINTS, 3), np.nan)
    if counts.sum():
        starts = np.repeat(np.cumsum(counts) - counts, counts)
        out[np.repeat(np.arange(len(frames)), counts), np.arange(counts.sum()) - starts] = \
            np.concatenate(per_frame)
    return out


@dataclass
class Matches:
    """Each ground-truth actor of each frame with the predicted person closest to it.

    truth: (F, A, 14, 3) metres (NaN where absent); present: (F, A); best: (F, A) index of the
    closest predicted person in its frame; matched: (F, A) present and with a prediction;
    chosen: (F, A, 14, 3) that person's joints (NaN where not matched); joint_err: (F, A, 14)
    metres (NaN where not matched or a predicted joint is NaN).
    """

    truth: np.ndarray
    present: np.ndarray
    best: np.ndarray
    matched: np.ndarray
    chosen: np.ndarray
    joint_err: np.ndarray


def match_actors(predictions: Mapping[int, np.ndarray], gt: GroundTruth, actors: Sequence[int]) -> Matches:
    """Match every present actor (actorsGT indices) of every gt frame to the prediction {actorsGT
    frame: (P, 14, 3) metres} of least mean joint distance."""
    truth = gt.poses[:, list(actors)]                                  # (F, A, 14, 3)
    present = np.isfinite(truth).all(axis=(-2, -1))                    # (F, A)
    pred = _padded(predictions, gt.frames)                             # (F, P, 14, 3)

    joint_err = np.linalg.norm(truth[:, :, None] - pred[:, None], axis=-1)  # (F, A, P, 14)
    valid = np.isfinite(joint_err)
    n_valid = valid.sum(axis=-1)
    mean_err = np.where(n_valid > 0, np.where(valid, joint_err, 0).sum(-1) / np.maximum(n_valid, 1),
                        np.inf)                                        # (F, A, P)
    best = mean_err.argmin(axis=-1)                                    # (F, A)
    matched = present & np.isfinite(np.take_along_axis(mean_err, best[..., None], -1)[..., 0])
    chosen = pred[np.arange(len(pred))[:, None], best]                 # (F, A, 14, 3)
    chosen = np.where(matched[..., None, None], chosen, np.nan)
    err = np.take_along_axis(joint_err, best[..., None, None], axis=2)[:, :, 0]  # (F, A, 14)
    return Matches(truth, present, best, matched, chosen, np.where(matched[..., None], err, np.nan))


def endpoint_errors(truth: np.ndarray, chosen: np.ndarray, alpha: float = ALPHA) -> tuple[np.ndarray, np.ndarray]:
    """Each limb's (LIMBS) endpoint errors (..., 10, 2) in metres (NaN where a chosen joint is NaN)
    and its tolerance (..., 10): alpha times the true limb length; truth and chosen (..., 14, 3)."""
    ends_true = _with_hip_centre(truth)[..., LIMBS, :]                 # (..., 10, 2, 3)
    ends_pred = _with_hip_centre(chosen)[..., LIMBS, :]
    end_err = np.linalg.norm(ends_pred - ends_true, axis=-1)
    return end_err, alpha * np.linalg.norm(ends_true[..., 0, :] - ends_true[..., 1, :], axis=-1)


def limb_correct(truth: np.ndarray, chosen: np.ndarray, alpha: float = ALPHA) -> np.ndarray:
    """(2, ..., 10) whether each limb (LIMBS) of the poses chosen (..., 14, 3) is correct against
    truth (..., 14, 3), strict then lenient (FORMS); NaN joints make their limbs wrong."""
    end_err, tolerance = endpoint_errors(truth, chosen, alpha)
    return np.stack([(end_err <= tolerance[..., None]).all(axis=-1), end_err.mean(axis=-1) <= tolerance])


def evaluate(predictions: Mapping[int, np.ndarray], gt: GroundTruth, actors: Sequence[int],
             alpha: float = ALPHA) -> Evaluation:
    """Score predictions {actorsGT frame: (P, 14, 3) metres} against gt for the given actors.

    Frames of gt missing from `predictions` (or with P = 0) count every limb of every present
    actor as wrong. Predicted joints that are NaN make their limbs wrong and are left out of MPJPE.
    """
    actors = tuple(int(a) for a in actors)
    m = match_actors(predictions, gt, actors)
    ok = limb_correct(m.truth, m.chosen, alpha) & m.present[..., None]  # (2, F, A, 10)

    err = m.joint_err
    scored = np.isfinite(err)
    err_sum, err_n = np.where(scored, err, 0).sum(axis=(0, 2)), scored.sum(axis=(0, 2))
    with np.errstate(divide='ignore', invalid='ignore'):
        mpjpe = 1000.0 * err_sum / err_n
    mpjpe_all = 1000.0 * err_sum.sum() / err_n.sum() if err_n.sum() else float('nan')

    frames = m.present.sum(axis=0)
    return Evaluation(
        actors=actors,
        correct=ok.sum(axis=1) @ _MEMBERSHIP,
        total=frames[:, None] * _MEMBERSHIP.sum(axis=0),
        frames=frames,
        missed=(m.present & ~m.matched).sum(axis=0),
        mpjpe=mpjpe,
        mpjpe_all=float(mpjpe_all),
        alpha=alpha,
    )


def _row(label: str, values: Sequence[float | None], extra: str = '') -> str:
    cells = ''.join(f'{v:>10.2f}' if v is not None and np.isfinite(v) else f'{"-":>10}'
                    for v in values)
    return f'{label:<24}{cells}{extra}'


def format_table(ev: Evaluation, reference: Mapping[str, Mapping[str, float]] | None = None) -> str:
    """Fixed-width PCP table in the paper's layout, with `reference` rows (e.g. PAPER_SHELF_PCP)
    printed under ours when given. Actor k is actorsGT actor k - 1."""
    heads = ''.join(f'{g.replace(" ", "-"):>10}' for g in GROUPS)
    title = f'PCP (%), alpha={ev.alpha:g}'
    lines = [f'{title:<24}{heads}{"MPJPE mm":>10}{"frames":>8}{"missed":>8}']
    reference = reference or {}

    def reference_row(key: str) -> None:
        if key in reference:
            lines.append(_row(f'{key} reference', [reference[key].get(g) for g in GROUPS]))

    for a, actor in enumerate(ev.actors):
        name = f'Actor {actor + 1}'
        for form in FORMS:
            extra = (f'{ev.mpjpe[a]:>10.1f}{ev.frames[a]:>8d}{ev.missed[a]:>8d}'
                     if form == 'strict' else '')
            lines.append(_row(f'{name} {form}', [ev.pcp(form, actor, g) for g in GROUPS], extra))
        reference_row(name)
    for form in FORMS:
        lines.append(_row(f'Actor mean {form}', [ev.actor_average(form, g) for g in GROUPS]))
    for form in FORMS:
        extra = (f'{ev.mpjpe_all:>10.1f}{ev.frames.sum():>8d}{ev.missed.sum():>8d}'
                 if form == 'strict' else '')
        lines.append(_row(f'Average {form}', [ev.frame_weighted(form, g) for g in GROUPS], extra))
    reference_row('Average')
    return '\n'.join(lines)
