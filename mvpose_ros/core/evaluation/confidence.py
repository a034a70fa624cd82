"""Does the per-joint confidence mean something? Confidence against error on a scored clip.

Every joint of every ground-truth actor matched to a prediction (pcp.match_actors) gives a
(confidence, error) pair, every limb of pcp.LIMBS a (confidence, correct) pair with the limb's
confidence the smaller of its two endpoints' (the torso's hip centre: the smaller of the hips').
The report bins joints and limbs by confidence into bins of equal count, gives the Spearman rank
correlation between confidence and error, and the trade-off of dropping limbs below a threshold.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import scipy.stats

from mvpose_ros.core.datasets.shelf_campus import GroundTruth
from mvpose_ros.core.drawing.plot import Series, line_plot
from mvpose_ros.core.evaluation.pcp import FORMS, LIMBS, _padded, limb_correct, match_actors
from mvpose_ros.core.types import FrameResult

BINS = 10
THRESHOLDS = np.round(np.arange(0.0, 0.95, 0.05), 2)


@dataclass
class ConfidenceSamples:
    """joint_confidence, joint_error: (N,) of every matched joint (error in metres);
    limb_confidence: (L,) and limb_correct: (2, L) (strict, lenient) of every matched limb."""

    joint_confidence: np.ndarray
    joint_error: np.ndarray
    limb_confidence: np.ndarray
    limb_correct: np.ndarray

    def spearman(self) -> float:
        """Spearman rank correlation between a joint's confidence and its error (negative: the
        surer, the nearer)."""
        return float(scipy.stats.spearmanr(self.joint_confidence, self.joint_error)[0])

    def joint_bins(self, bins: int = BINS) -> list[dict[str, float]]:
        """Per bin of equal joint count, in rising confidence: lo, hi (its confidence range), n,
        mean and median error (mm)."""
        return [{'lo': c.min(), 'hi': c.max(), 'mean confidence': c.mean(), 'n': len(c),
                 'mean mm': 1e3 * e.mean(), 'median mm': 1e3 * np.median(e)}
                for c, e in _binned(self.joint_confidence, self.joint_error, bins)]

    def limb_bins(self, bins: int = BINS) -> list[dict[str, float]]:
        """Per bin of equal limb count, in rising confidence: lo, hi, n, percent correct (strict,
        lenient)."""
        rows = []
        for c, ok in _binned(self.limb_confidence, self.limb_correct.T, bins):
            rows.append({'lo': c.min(), 'hi': c.max(), 'mean confidence': c.mean(), 'n': len(c),
                         **{f'{form} %': 100.0 * ok[:, k].mean() for k, form in enumerate(FORMS)}})
        return rows

    def tradeoff(self, thresholds: Sequence[float] = THRESHOLDS) -> list[dict[str, float]]:
        """Dropping the limbs of confidence below each threshold (strict PCP): percent of the wrong
        limbs dropped, of the right ones kept, and PCP of the limbs kept."""
        right = self.limb_correct[0]
        rows = []
        for t in thresholds:
            kept = self.limb_confidence >= t
            rows.append({'threshold': float(t),
                         'wrong dropped %': 100.0 * (~kept[~right]).mean() if (~right).any() else float('nan'),
                         'right kept %': 100.0 * kept[right].mean() if right.any() else float('nan'),
                         'PCP kept %': 100.0 * right[kept].mean() if kept.any() else float('nan')})
        return rows


def _binned(confidence: np.ndarray, values: np.ndarray, bins: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """(confidence, values) of each of `bins` bins of equal count, in rising confidence."""
    order = np.argsort(confidence, kind='stable')
    return [(confidence[part], values[part]) for part in np.array_split(order, bins) if len(part)]


def confidence_samples(results: Sequence[FrameResult], gt: GroundTruth, actors: Sequence[int]) -> ConfidenceSamples:
    """The (confidence, error) of every joint and (confidence, correct) of every limb of the
    actors matched in results (each with its confidence)."""
    missing = [r.frame for r in results if r.confidence is None]
    if missing:
        raise ValueError(f'frame {missing[0]}: no confidence (predictions written before confidence existed?)')
    m = match_actors({r.frame: r.joints for r in results}, gt, actors)
    # the confidence of each frame's people padded as the joints are, then the matched person's
    padded = _padded({r.frame: np.repeat(np.asarray(r.confidence)[..., None], 3, axis=-1) for r in results},
                     gt.frames)[..., 0]  # (F, P, 14)
    confidence = padded[np.arange(len(padded))[:, None], m.best]  # (F, A, 14)
    joints = m.matched[..., None] & np.isfinite(m.joint_err) & np.isfinite(confidence)
    with_hip_centre = np.concatenate([confidence, confidence[..., 2:4].min(axis=-1, keepdims=True)], axis=-1)
    limb_conf = with_hip_centre[..., LIMBS].min(axis=-1)  # (F, A, 10)
    correct = limb_correct(m.truth, m.chosen)  # (2, F, A, 10)
    limbs = m.matched[..., None] & np.isfinite(limb_conf)
    return ConfidenceSamples(confidence[joints], m.joint_err[joints], limb_conf[limbs], correct[:, limbs])


def format_confidence_report(samples: ConfidenceSamples) -> str:
    """The tables: joints per confidence bin, limbs per confidence bin, the threshold trade-off."""
    lines = [f'Confidence against error: {len(samples.joint_confidence)} joints, {len(samples.limb_confidence)} '
             f'limbs of matched actors; Spearman rank correlation (confidence, joint error) '
             f'{samples.spearman():+.3f}',
             '', f'{"joints: confidence":<22}{"n":>7}{"mean mm":>10}{"median mm":>11}']
    for b in samples.joint_bins():
        lines.append(f'{b["lo"]:9.3f} .. {b["hi"]:6.3f}  {b["n"]:7d}{b["mean mm"]:10.1f}{b["median mm"]:11.1f}')
    lines += ['', f'{"limbs: confidence":<22}{"n":>7}{"strict %":>10}{"lenient %":>11}']
    for b in samples.limb_bins():
        lines.append(f'{b["lo"]:9.3f} .. {b["hi"]:6.3f}  {b["n"]:7d}{b["strict %"]:10.1f}{b["lenient %"]:11.1f}')
    right = samples.limb_correct[0]
    lines += ['', f'threshold on limb confidence ({int((~right).sum())} wrong and {int(right.sum())} right limbs, '
                  f'strict)', f'{"threshold":>9}{"wrong dropped %":>17}{"right kept %":>14}{"PCP kept %":>12}']
    for row in samples.tradeoff():
        lines.append(f'{row["threshold"]:9.2f}{row["wrong dropped %"]:17.1f}{row["right kept %"]:14.1f}'
                     f'{row["PCP kept %"]:12.2f}')
    return '\n'.join(lines)


def plot_confidence_report(samples: ConfidenceSamples, folder: str | Path) -> list[Path]:
    """Two PNGs in folder: confidence_joints.png (error per bin against the bin's mean
    confidence) and confidence_limbs.png (percent correct per bin; wrong limbs dropped and right
    kept against the threshold)."""
    folder = Path(folder)
    joints = samples.joint_bins()
    x = [b['mean confidence'] for b in joints]
    paths = [line_plot(folder / 'confidence_joints.png',
                       [Series('mean error', x, [b['mean mm'] for b in joints]),
                        Series('median error', x, [b['median mm'] for b in joints])],
                       title=f'Joint error per confidence bin (Spearman {samples.spearman():+.2f})',
                       xlabel='confidence (bin mean; bins of equal count)', ylabel='error (mm)')]
    limbs = samples.limb_bins()
    trade = samples.tradeoff()
    t = [r['threshold'] for r in trade]
    paths.append(line_plot(folder / 'confidence_limbs.png',
                           [Series('correct in bin (strict)', [b['mean confidence'] for b in limbs],
                                   [b['strict %'] for b in limbs]),
                            Series('right kept, threshold', t, [r['right kept %'] for r in trade]),
                            Series('wrong dropped, threshold', t, [r['wrong dropped %'] for r in trade])],
                           title='Limbs: PCP per confidence bin, and dropping limbs below a threshold',
                           xlabel='limb confidence (min of its endpoints)', ylabel='percent',
                           legend_width=300))
    return paths
