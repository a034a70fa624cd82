"""The offline evaluator's text reports beside the PCP table: the one-line summary, the time per
frame of each stage, the paper's ablation of the CRF terms, confidence against error, and what the
remaining errors rest on."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Iterator, Sequence

from mvpose_ros.core.datasets.shelf_campus import GroundTruth
from mvpose_ros.core.evaluation.confidence import confidence_samples, format_confidence_report, plot_confidence_report
from mvpose_ros.core.evaluation.error_sources import format_error_sources, head_offsets, wrong_endpoints
from mvpose_ros.core.evaluation.offline import Prepared, as_predictions, infer
from mvpose_ros.core.evaluation.pcp import Evaluation, evaluate, match_actors
from mvpose_ros.core.stage import StageConfig
from mvpose_ros.core.timing import StageTimer
from mvpose_ros.core.types import FrameResult, Sequence2D

# The paper's ablation rows (its "all terms" is data + temporal + collision).
ABLATION = (('data only', ('data',)), ('+temporal', ('data', 'temp')), ('+collision', ('data', 'col')),
            ('all (data+temp+col)', ('data', 'temp', 'col')), ('+limb (ours)', ('data', 'temp', 'col', 'limb')))
PAPER_ABLATION = {'data only': (86.75, 84.52, 90.68), '+temporal': (88.31, 85.26, 91.30),
                  '+collision': (86.66, 84.77, 90.68), 'all (data+temp+col)': (88.34, 85.26, 91.30)}


def summary(ev: Evaluation) -> str:
    """Strict and lenient PCP, frame-weighted and actor-average, and the MPJPE, on one line."""
    return (f'strict {ev.frame_weighted("strict"):6.2f} frame-weighted / {ev.actor_average("strict"):6.2f} '
            f'actor-average | lenient {ev.frame_weighted("lenient"):6.2f} / {ev.actor_average("lenient"):6.2f}'
            f' | MPJPE {ev.mpjpe_all:5.1f} mm')


def speed_report(seq: Sequence2D, prepared: Prepared, bp_timer: StageTimer) -> str:
    """Each stage's time per frame (all cameras) and the whole stage's frame rate."""
    stages = {**seq.seconds, **prepared.timer.seconds, **bp_timer.seconds}
    n = len(seq.frames)
    total = sum(stages.values())
    lines = ['3D stage time per frame (all cameras):']
    lines += [f'  {name:24s} {1000 * sec / n:7.2f} ms' for name, sec in stages.items()]
    lines.append(f'  {"total":24s} {1000 * total / n:7.2f} ms  -> {n / total:.1f} frames/s')
    return '\n'.join(lines)


def ablation_lines(prepared: Prepared, config: StageConfig, gt: GroundTruth, actors: Sequence[int], paper: bool,
                   real_time: bool = True) -> Iterator[str]:
    """The ablation table line by line (each row is a BP run over `prepared`, so it comes when
    done): All PCP per actor with each ABLATION set of terms; paper: the paper's figures beside."""
    yield '\nAblation (All PCP per actor, strict | lenient; same hypotheses, same window):'
    header = f'{"terms":22s} ' + ' '.join(f'A{a + 1:d} str  A{a + 1:d} len' for a in actors)
    yield header + '   avg-fw str/len   avg-act str/len' + ('   paper A1/A2/A3' if paper else '')
    for name, terms in ABLATION:
        results = infer(prepared, replace(config.solver.inference, terms=terms), config.solver.head_model,
                        real_time=real_time)
        ev = evaluate(as_predictions(results), gt, actors)
        cells = ' '.join(f'{ev.pcp("strict", a):6.2f} {ev.pcp("lenient", a):6.2f}' for a in actors)
        row = (f'{name:22s} {cells}   {ev.frame_weighted("strict"):6.2f}/{ev.frame_weighted("lenient"):6.2f}'
               f'   {ev.actor_average("strict"):6.2f}/{ev.actor_average("lenient"):6.2f}')
        if paper and name in PAPER_ABLATION:
            row += '   ' + '/'.join(f'{v:.2f}' for v in PAPER_ABLATION[name])
        yield row


def confidence_report(results: Sequence[FrameResult], gt: GroundTruth, actors: Sequence[int], folder: Path) -> str:
    """Confidence against error (core.evaluation.confidence), its plots written into `folder`."""
    samples = confidence_samples(results, gt, actors)
    written = [f'wrote {path}' for path in plot_confidence_report(samples, folder)]
    return '\n'.join(['\n' + format_confidence_report(samples), *written])


def error_sources_report(results: Sequence[FrameResult], gt: GroundTruth, actors: Sequence[int],
                         seq: Sequence2D) -> str:
    """Whether the 2D detections of `seq` back each wrong limb end, and the heads against the annotation."""
    matches = match_actors(as_predictions(results), gt, actors)
    endpoints = wrong_endpoints(matches, actors, seq, gt.frames)
    return '\n' + format_error_sources(endpoints, head_offsets(matches, actors), actors)
