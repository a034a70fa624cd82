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

from mvpose_ros.core.datasets.shelf_campus import SHELF_ACTORS, GroundTruth
from mvpose_ros.core.detection.openpose_detector import OpenPoseDetectorConfig
from mvpose_ros.core.evaluation.clips import load_clip, shelf_ground_truth, thinned
from mvpose_ros.core.evaluation.identities import identity_report
from mvpose_ros.core.evaluation.offline import as_predictions, infer, prepare, shelf_openpose
from mvpose_ros.core.evaluation.pcp import PAPER_CAMPUS_AVERAGE, PAPER_SHELF_PCP, evaluate, format_table
from mvpose_ros.core.evaluation.predictions import read_results, write_predictions
from mvpose_ros.core.evaluation.reports import (ablation_lines, confidence_report, error_sources_report, speed_report,
                                                summary)
from mvpose_ros.core.geometry.body import HEAD_MODELS
from mvpose_ros.core.inference.hypotheses import SINGLE_VIEW_DEPTHS, UNSEEN_JOINTS
from mvpose_ros.core.inference.window import TERMS
from mvpose_ros.core.scenarios.frame_drops import FrameDrop
from mvpose_ros.core.scenarios.ring import RingConfig
from mvpose_ros.core.stage import ASSOCIATION_PARAMETERS, SOLVER_PARAMETERS, StageConfig
from mvpose_ros.core.timing import StageTimer
from mvpose_ros.core.types import FrameResult, Sequence2D


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
    """The command line of `mvpose-eval`."""
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


def run(args: argparse.Namespace, out: TextIO | None = None) -> int:
    """Do what the parsed command line `args` of `mvpose-eval` says; returns the exit code."""
    out = out or sys.stdout
    config = StageConfig.from_params(vars(args))
    detector = OpenPoseDetectorConfig(stride=args.heatmap_stride, secondary_radius=args.secondary_radius)
    drop = FrameDrop(args.drop_every, args.drop_fraction, args.drop_seed)
    if args.score:
        return _score(args, detector, out)
    t0 = time.perf_counter()
    ring = RingConfig(**{name: getattr(args, option[2:].replace('-', '_'))
                         for option, (name, _, _) in RING_OPTIONS.items()}) if args.dataset == 'ring' else None
    clip = load_clip(args.dataset, args.data_root, detector, args.campus_dir, ring)
    if clip.note:
        print(clip.note, file=out)
    if clip.head_model is not None:  # an oracle's 2D people come with the head model they need
        config = replace(config, solver=replace(config.solver, head_model=clip.head_model))
    n_all = len(clip.seq.frames)
    clip = thinned(clip, drop) if drop else clip
    seq, gt, actors = clip.seq, clip.gt, clip.actors
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
    print(f'{format_table(ev, clip.reference)}\n{summary(ev)}', file=out)
    print('\n'.join(identity_report(results, gt, actors).lines()), file=out)
    if args.dataset == 'campus':
        print(f'paper: Campus average {PAPER_CAMPUS_AVERAGE}', file=out)
    print(speed_report(seq, prepared, bp_timer), file=out)
    if args.predictions:
        args.predictions.parent.mkdir(parents=True, exist_ok=True)
        with open(args.predictions, 'w', encoding='utf-8') as f:
            n = write_predictions(results, f)
        print(f'wrote {n} frames to {args.predictions}', file=out)
    _shelf_reports(args, results, gt, seq, out)
    if not args.no_ablation:
        for line in ablation_lines(prepared, config, gt, actors, args.dataset == 'shelf', real_time):
            print(line, file=out)
    print(f'total {time.perf_counter() - t0:.1f} s', file=out)
    return 0


def _score(args: argparse.Namespace, detector: OpenPoseDetectorConfig, out: TextIO) -> int:
    """--score: the predictions file scored against Shelf's annotation, with the reports asked for."""
    if args.dataset != 'shelf':
        raise ValueError('--score is for shelf')
    gt = shelf_ground_truth(args.data_root)
    results = [r for r, _ in read_results(args.score)]
    ev = evaluate(as_predictions(results), gt, SHELF_ACTORS)
    print(f'{args.score}\n{format_table(ev, PAPER_SHELF_PCP)}\n{summary(ev)}', file=out)
    print('\n'.join(identity_report(results, gt, SHELF_ACTORS).lines()), file=out)
    _shelf_reports(args, results, gt, shelf_openpose(args.data_root, detector) if args.error_sources else None, out)
    return 0


def _shelf_reports(args: argparse.Namespace, results: list[FrameResult], gt: GroundTruth, seq: Sequence2D | None,
                   out: TextIO) -> None:
    """--confidence-report and --error-sources (Shelf only: they need its detections and annotation)."""
    if (args.confidence_report or args.error_sources) and args.dataset != 'shelf':
        raise ValueError(f'--{"confidence-report" if args.confidence_report else "error-sources"} is for shelf')
    if args.confidence_report:
        print(confidence_report(results, gt, SHELF_ACTORS, args.confidence_report), file=out)
    if args.error_sources:
        print(error_sources_report(results, gt, SHELF_ACTORS, seq), file=out)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of `mvpose-eval`; returns the exit code."""
    args = build_parser().parse_args(argv)
    try:
        return run(args)
    except (FileNotFoundError, ValueError) as exc:
        print(f'mvpose-eval: error: {exc}', file=sys.stderr)
        return 2


if __name__ == '__main__':
    sys.exit(main())
