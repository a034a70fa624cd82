"""`mvpose-eval`: run the 3D stage offline on Shelf (or Campus) and print the PCP tables.

    mvpose-eval shelf [--data-root DIR] [--terms data,temp,col,limb] [--window N --lag L]
                      [--predictions FILE]
    mvpose-eval shelf --drop-every 2    # uneven frames: every second set dropped, scored on the rest
    mvpose-eval shelf --drop-fraction 0.3 --drop-seed 1 [--evenly-spaced]
    mvpose-eval shelf --score FILE      # score a predictions file (e.g. from the ROS graph)
    mvpose-eval shelf --confidence-report out/confidence [--score FILE]   # confidence against error
    mvpose-eval shelf --error-sources [--score FILE]   # do the 2D detections back the wrong joints?
    mvpose-eval campus [--campus-dir CampusSeq1]
    mvpose-eval ring [--ring-cameras N] [--ring-noise PX]   # N synthetic cameras around Shelf's actors
"""
from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any, Sequence, TextIO

import numpy as np

from mvpose_ros.core.datasets.campus import campus_sequence
from mvpose_ros.core.datasets.shelf_campus import (CAMPUS_ACTORS, SHELF_ACTORS, SHELF_TEST_FRAMES, GroundTruth,
                                                   dataset_dir, load_actors_gt)
from mvpose_ros.core.detection.openpose_detector import OpenPoseDetectorConfig
from mvpose_ros.core.evaluation.confidence import confidence_samples, format_confidence_report, plot_confidence_report
from mvpose_ros.core.evaluation.error_sources import format_error_sources, head_offsets, wrong_endpoints
from mvpose_ros.core.evaluation.identities import identity_report
from mvpose_ros.core.evaluation.offline import Prepared, as_predictions, drop_frames, infer, prepare, shelf_openpose
from mvpose_ros.core.evaluation.pcp import PAPER_CAMPUS_AVERAGE, PAPER_SHELF_PCP, evaluate, format_table, match_actors
from mvpose_ros.core.evaluation.predictions import read_results, write_predictions
from mvpose_ros.core.geometry.body import HEAD_MODELS
from mvpose_ros.core.inference.hypotheses import SINGLE_VIEW_DEPTHS, UNSEEN_JOINTS
from mvpose_ros.core.inference.window import TERMS
from mvpose_ros.core.scenarios.frame_drops import FrameDrop
from mvpose_ros.core.scenarios.ring import RingConfig, ring_sequence
from mvpose_ros.core.stage import ASSOCIATION_PARAMETERS, SOLVER_PARAMETERS, StageConfig
from mvpose_ros.core.timing import StageTimer
from mvpose_ros.core.types import Sequence2D

# The paper's ablation rows (its "all terms" is data + temporal + collision).
ABLATION = (('data only', ('data',)), ('+temporal', ('data', 'temp')), ('+collision', ('data', 'col')),
            ('all (data+temp+col)', ('data', 'temp', 'col')), ('+limb (ours)', ('data', 'temp', 'col', 'limb')))
PAPER_ABLATION = {'data only': (86.75, 84.52, 90.68), '+temporal': (88.31, 85.26, 91.30),
                  '+collision': (86.66, 84.77, 90.68), 'all (data+temp+col)': (88.34, 85.26, 91.30)}


def _terms(text: str) -> tuple[str, ...]:
    terms = tuple(t.strip() for t in text.split(',') if t.strip())
    bad = [t for t in terms if t not in TERMS]
    if bad or 'data' not in terms:
        raise argparse.ArgumentTypeError(f'terms must include data and come from {",".join(TERMS)}; got {text!r}')
    return terms


def _heights(text: str) -> tuple[float, ...]:
    try:
        return tuple(float(h) for h in text.split(','))
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected metres, comma separated, got {text!r}') from None


# `mvpose-eval ring` options -> (RingConfig field, type, help)
RING_OPTIONS: dict[str, tuple[str, Any, str]] = {
    '--ring-cameras': ('cameras', int, 'cameras on the circle around the actors (core.scenarios.ring)'),
    '--ring-noise': ('noise_px', float, "std of every projected keypoint's noise, px"),
    '--ring-radius': ('radius', float, "the cameras' distance from the actors' centre, horizontally, m"),
    '--ring-heights': ('heights', _heights, "the cameras' heights above the actors' centre, m, comma separated, "
                       'camera after camera in turn (negative: below; give it as --ring-heights=-0.6,-0.3)'),
    '--ring-fov': ('fov_deg', float, "every camera's horizontal field of view, degrees"),
    '--ring-miss': ('miss_share', float, 'the share of keypoints each view misses, each on its own (0 to below 1)'),
    '--ring-walk': ('walk_speed', float, 'm/s at which the whole scene walks round a circle of 1 m (people crossing '
                    'the views)'),
}


def build_parser() -> argparse.ArgumentParser:
    d = StageConfig().to_params()
    p = argparse.ArgumentParser(prog='mvpose-eval', description=__doc__.split('\n')[0])
    p.add_argument('dataset', choices=('shelf', 'campus', 'ring'))
    p.add_argument('--data-root', help='folder holding data/ and models/ (default: $MVPOSE_DATA_ROOT or ../shared)')
    p.add_argument('--terms', type=_terms, default=tuple(d['terms']),
                   help=f'CRF terms, comma separated from {",".join(TERMS)} (default: {",".join(d["terms"])})')
    p.add_argument('--window', type=int, default=0,
                   help='sliding window length in frames (default: 0, the whole clip at once, as the paper)')
    p.add_argument('--lag', type=int, default=d['lag'], help=f'{SOLVER_PARAMETERS["lag"]}, with --window')
    p.add_argument('--iterations', type=int, default=d['iterations'], help=SOLVER_PARAMETERS['iterations'])
    p.add_argument('--slide-iterations', type=int, default=d['slide_iterations'],
                   help=f'with --window: {SOLVER_PARAMETERS["slide_iterations"]}')
    p.add_argument('--hypotheses', type=int, default=d['hypotheses'], help=SOLVER_PARAMETERS['hypotheses'])
    p.add_argument('--bp-hypotheses', type=int, default=d['bp_hypotheses'], help=SOLVER_PARAMETERS['bp_hypotheses'])
    p.add_argument('--single-view-depth', choices=SINGLE_VIEW_DEPTHS, default=d['single_view_depth'],
                   help=SOLVER_PARAMETERS['single_view_depth'])
    p.add_argument('--hanging-legs', action=argparse.BooleanOptionalAction, default=d['hanging_legs'],
                   help=SOLVER_PARAMETERS['hanging_legs'])
    p.add_argument('--unseen-joints', choices=UNSEEN_JOINTS, default=d['unseen_joints'],
                   help=SOLVER_PARAMETERS['unseen_joints'])
    p.add_argument('--head-model', choices=HEAD_MODELS, default=d['head_model'])
    p.add_argument('--heatmap-stride', type=float, default=OpenPoseDetectorConfig.stride,
                   help='heatmap cell size in pixels (the ROS graph config uses 8)')
    p.add_argument('--secondary-radius', type=float, default=OpenPoseDetectorConfig.secondary_radius,
                   help='other candidates of a joint within this fraction of the person\'s box diagonal also go '
                        'into its heatmap (the heatmap_detector parameter)')
    p.add_argument('--match-distance', type=float, default=d['match_distance'],
                   help='cross-view matching threshold, metres of mean ray distance')
    p.add_argument('--max-view-residual', type=float, default=d['max_view_residual'],
                   help=ASSOCIATION_PARAMETERS['max_view_residual'])
    p.add_argument('--single-view-people', action=argparse.BooleanOptionalAction, default=d['single_view_people'],
                   help=ASSOCIATION_PARAMETERS['single_view_people'])
    p.add_argument('--collision-centre', type=float, default=d['collision_centre'])
    p.add_argument('--collision-width', type=float, default=d['collision_width'])
    p.add_argument('--seed', type=int, default=d['seed'])
    p.add_argument('--max-gap', type=float, default=d['max_gap'], help=SOLVER_PARAMETERS['max_gap'])
    p.add_argument('--threads', type=int, default=d['threads'], help=SOLVER_PARAMETERS['threads'])
    p.add_argument('--drop-every', type=int, default=0, metavar='N',
                   help='leave out every N-th frame (as sets dropped upstream) and score the frames left')
    p.add_argument('--drop-fraction', type=float, default=0.0, metavar='F',
                   help='leave out this fraction of the (remaining) frames at random and score the frames left')
    p.add_argument('--drop-seed', type=int, default=0, metavar='S', help='seed of --drop-fraction')
    p.add_argument('--evenly-spaced', action='store_true',
                   help='treat the frames left as evenly spaced, blind to the real times (for comparison)')
    p.add_argument('--predictions', type=Path, help='write the predictions here (JSON lines)')
    p.add_argument('--score', type=Path, help='only score this predictions file')
    p.add_argument('--no-ablation', action='store_true', help='skip the ablation table')
    p.add_argument('--confidence-report', type=Path, metavar='DIR',
                   help='shelf: bin every joint and limb by its confidence, print error, PCP and the threshold '
                        'trade-off, and write the plots confidence_joints.png and confidence_limbs.png into DIR')
    p.add_argument('--error-sources', action='store_true',
                   help='for each wrong limb end, whether the 2D detections back the estimate or the annotation; '
                        'where the annotated heads sit against ours (shelf)')
    p.add_argument('--campus-dir', type=Path, help='a full CampusSeq1 folder (campus only)')
    for option, (name, kind, help_text) in RING_OPTIONS.items():
        p.add_argument(option, type=kind, default=getattr(RingConfig, name), help=f'ring: {help_text}')
    return p


def _summary(ev) -> str:
    return (f'strict {ev.frame_weighted("strict"):6.2f} frame-weighted / {ev.actor_average("strict"):6.2f} '
            f'actor-average | lenient {ev.frame_weighted("lenient"):6.2f} / {ev.actor_average("lenient"):6.2f}'
            f' | MPJPE {ev.mpjpe_all:5.1f} mm')


def run(args: argparse.Namespace, out: TextIO | None = None) -> int:
    out = out or sys.stdout
    config = StageConfig.from_params(vars(args))
    if args.dataset == 'shelf':
        gt = load_actors_gt(dataset_dir('shelf', args.data_root) / 'actorsGT.mat', SHELF_TEST_FRAMES)
        actors, reference = SHELF_ACTORS, PAPER_SHELF_PCP
    drop = FrameDrop(args.drop_every, args.drop_fraction, args.drop_seed)
    if args.score:
        if args.dataset != 'shelf':
            raise ValueError('--score is for shelf')
        results = [r for r, _ in read_results(args.score)]
        ev = evaluate(as_predictions(results), gt, actors)
        print(f'{args.score}\n{format_table(ev, reference)}\n{_summary(ev)}', file=out)
        print('\n'.join(identity_report(results, gt, actors).lines()), file=out)
        if args.confidence_report:
            _confidence_report(results, gt, actors, args.confidence_report, out)
        if args.error_sources:
            detector = OpenPoseDetectorConfig(stride=args.heatmap_stride, secondary_radius=args.secondary_radius)
            _error_sources(results, gt, actors, shelf_openpose(args.data_root, detector), out)
        return 0
    t0 = time.perf_counter()
    if args.dataset == 'shelf':
        detector = OpenPoseDetectorConfig(stride=args.heatmap_stride, secondary_radius=args.secondary_radius)
        seq = shelf_openpose(args.data_root, detector)
    elif args.dataset == 'campus':
        seq, gt, head_model = campus_sequence(args.data_root, args.campus_dir)
        actors, reference = CAMPUS_ACTORS, None
        if args.campus_dir is None:
            print('campus: no CampusSeq1 folder given; 2D people are the 3 ground-truth frames projected into '
                  'the cameras (an oracle: checks geometry, inference and scoring, not detection)', file=out)
    else:
        ring = RingConfig(**{name: getattr(args, option[2:].replace('-', '_'))
                             for option, (name, _, _) in RING_OPTIONS.items()})
        seq, gt, head_model = ring_sequence(args.data_root, ring)
        actors, reference = SHELF_ACTORS, None
        heights = ', '.join(f'{h:g}' for h in ring.heights)
        print(f'ring: {ring.cameras} synthetic cameras {ring.radius:g} m around the actors of the Shelf test frames '
              f'({heights} m above their centre, {ring.fov_deg:g} degrees), the annotated '
              f'joints projected with {ring.noise_px:g} px of noise and one of them {ring.outlier_px:g} px off in '
              f'{100 * ring.outlier_share:g} % of the views, {100 * ring.miss_share:g} % of the keypoints missed, '
              f'walking at {ring.walk_speed:g} m/s '
              f'(an oracle: checks how the 3D stage scales with cameras, not detection)', file=out)
    if args.dataset != 'shelf':  # their 2D people come with the head model they need
        config = replace(config, solver=replace(config.solver, head_model=head_model))
    if drop:
        n_all = len(seq.frames)
        seq = drop_frames(seq, drop)
        gt = _restricted(gt, seq.frames)
    prepared = prepare(seq, config)
    bp_timer = StageTimer()
    real_time = not args.evenly_spaced
    results = infer(prepared, config.solver.inference, config.solver.head_model, bp_timer, real_time)
    ev = evaluate(as_predictions(results), gt, actors)
    mode = f'window {args.window}, lag {args.lag}' if args.window else 'whole clip'
    print(f'{args.dataset}: {len(seq.frames)} frames, {len(seq.cameras)} cameras, terms {",".join(args.terms)}, '
          f'{mode}, M={args.hypotheses}, head model {config.solver.head_model}', file=out)
    if drop:
        print(f'uneven frames: {n_all - len(seq.frames)} of {n_all} left out (every {args.drop_every or "-"}, '
              f'fraction {args.drop_fraction}, seed {args.drop_seed}), scored on the {len(seq.frames)} left; '
              f'temporal term {"with the real times" if real_time else "blind to the times (evenly spaced)"}, '
              f'max gap {args.max_gap} s', file=out)
    print(format_table(ev, reference), file=out)
    print(_summary(ev), file=out)
    print('\n'.join(identity_report(results, gt, actors).lines()), file=out)
    if args.dataset == 'campus':
        print(f'paper: Campus average {PAPER_CAMPUS_AVERAGE}', file=out)
    _print_speed(seq, prepared, bp_timer, out)
    if args.predictions:
        args.predictions.parent.mkdir(parents=True, exist_ok=True)
        with open(args.predictions, 'w', encoding='utf-8') as f:
            n = write_predictions(results, f)
        print(f'wrote {n} frames to {args.predictions}', file=out)
    if args.confidence_report:
        if args.dataset != 'shelf':
            raise ValueError('--confidence-report is for shelf')
        _confidence_report(results, gt, actors, args.confidence_report, out)
    if args.error_sources:
        if args.dataset != 'shelf':
            raise ValueError('--error-sources is for shelf')
        _error_sources(results, gt, actors, seq, out)
    if not args.no_ablation:
        _print_ablation(prepared, config, gt, actors, args.dataset == 'shelf', out, real_time)
    print(f'total {time.perf_counter() - t0:.1f} s', file=out)
    return 0


def _print_speed(seq: Sequence2D, prepared: Prepared, bp_timer: StageTimer, out) -> None:
    stages = {**seq.seconds, **prepared.timer.seconds, **bp_timer.seconds}
    n = len(seq.frames)
    total = sum(stages.values())
    print('3D stage time per frame (all cameras):', file=out)
    for name, sec in stages.items():
        print(f'  {name:24s} {1000 * sec / n:7.2f} ms', file=out)
    print(f'  {"total":24s} {1000 * total / n:7.2f} ms  -> {n / total:.1f} frames/s', file=out)


def _confidence_report(results, gt: GroundTruth, actors: Sequence[int], folder: Path, out) -> None:
    samples = confidence_samples(results, gt, actors)
    print('\n' + format_confidence_report(samples), file=out)
    for path in plot_confidence_report(samples, folder):
        print(f'wrote {path}', file=out)


def _error_sources(results, gt: GroundTruth, actors: Sequence[int], seq: Sequence2D, out) -> None:
    matches = match_actors(as_predictions(results), gt, actors)
    endpoints = wrong_endpoints(matches, actors, seq, gt.frames)
    print('\n' + format_error_sources(endpoints, head_offsets(matches, actors), actors), file=out)


def _restricted(gt: GroundTruth, frames: Sequence[int]) -> GroundTruth:
    """The ground truth of `frames` only (a subset of gt.frames)."""
    rows = np.searchsorted(gt.frames, frames)
    if not np.array_equal(gt.frames[rows], frames):
        raise ValueError('frames to score are not all in the ground truth')
    return replace(gt, frames=gt.frames[rows], poses=gt.poses[rows])


def _print_ablation(prepared: Prepared, config: StageConfig, gt, actors: Sequence[int], paper: bool, out,
                    real_time: bool = True) -> None:
    print('\nAblation (All PCP per actor, strict | lenient; same hypotheses, same window):', file=out)
    header = f'{"terms":22s} ' + ' '.join(f'A{a + 1:d} str  A{a + 1:d} len' for a in actors)
    print(header + '   avg-fw str/len   avg-act str/len' + ('   paper A1/A2/A3' if paper else ''), file=out)
    for name, terms in ABLATION:
        results = infer(prepared, replace(config.solver.inference, terms=terms), config.solver.head_model,
                        real_time=real_time)
        ev = evaluate(as_predictions(results), gt, actors)
        cells = ' '.join(f'{ev.pcp("strict", a):6.2f} {ev.pcp("lenient", a):6.2f}' for a in actors)
        row = (f'{name:22s} {cells}   {ev.frame_weighted("strict"):6.2f}/{ev.frame_weighted("lenient"):6.2f}'
               f'   {ev.actor_average("strict"):6.2f}/{ev.actor_average("lenient"):6.2f}')
        if paper and name in PAPER_ABLATION:
            row += '   ' + '/'.join(f'{v:.2f}' for v in PAPER_ABLATION[name])
        print(row, file=out)


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return run(args)
    except (FileNotFoundError, ValueError) as exc:
        print(f'mvpose-eval: error: {exc}', file=sys.stderr)
        return 2


if __name__ == '__main__':
    sys.exit(main())
