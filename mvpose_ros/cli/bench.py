"""`mvpose-bench`: speed and memory of the 3D stage on the real Shelf detections.

    mvpose-bench [--data-root DIR] [--output out/bench] [--frames N] [--scaling none|quick|full]
                 [--cameras 1,2,3,4,5] [--people 3,10,20] [--windows 4,8,15] [--hypotheses 16,32,64]
                 [--profile] [--repeat N] [--no-two-processes] [--pace HZ]

Prints the time per frame of each stage of the 3D stage, frames per second, peak memory and PCP,
and writes every figure as JSON and the scaling plots into --output. Each configuration runs in a
fresh process, so its peak RSS is its own. What a run is: bench.runs; what is printed:
bench.report; every row and option: docs/cli.md#benchmarks."""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Sequence, TextIO

import numpy as np

from mvpose_ros.bench import report
from mvpose_ros.bench.runs import (QUICK_FRAMES, RESULT_TAG, SCENE_PEOPLE, RunConfig, default_graph_config,
                                   graph_config_from, plan, profile_run, run_config, run_in_process, two_processes)
from mvpose_ros.core.datasets.shelf_campus import SHELF_TEST_FRAMES, dataset_dir


def _ints(text: str) -> tuple[int, ...]:
    try:
        values = tuple(int(v) for v in text.split(',') if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected comma-separated integers, got {text!r}') from None
    if any(v < 1 for v in values):
        raise argparse.ArgumentTypeError(f'values must be >= 1, got {text!r}')
    return values


def _rate(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected frames per second, got {text!r}') from None
    if not 0 <= value <= 1000:
        raise argparse.ArgumentTypeError(f'must be in 0..1000 frames/s, got {text!r}')
    return value


def build_parser() -> argparse.ArgumentParser:
    """The command line of `mvpose-bench`."""
    p = argparse.ArgumentParser(prog='mvpose-bench', description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('--data-root', help='folder holding data/ (default: $MVPOSE_DATA_ROOT or ../shared)')
    p.add_argument('--output', type=Path, default=Path('out/bench'),
                   help='PNG plots and bench.json (default: out/bench)')
    p.add_argument('--frames', type=int, default=len(SHELF_TEST_FRAMES),
                   help=f'the first N Shelf test frames (default: all {len(SHELF_TEST_FRAMES)})')
    p.add_argument('--scaling', choices=('none', 'quick', 'full'), default='full',
                   help=f'sweeps: none; quick (on the first {QUICK_FRAMES} frames); full (on --frames; default). '
                        'The flags below replace one sweep\'s values')
    p.add_argument('--cameras', type=_ints, help='camera counts (the first k cameras), e.g. 1,2,3,4,5')
    p.add_argument('--people', type=_ints,
                   help=f'target 3D people per frame, e.g. 3,10,20 (up to {SCENE_PEOPLE}: the scene itself)')
    p.add_argument('--windows', type=_ints, help='window lengths, e.g. 4,8,15 (lag = window // 2)')
    p.add_argument('--hypotheses', type=_ints, help='M values, e.g. 16,32,64')
    p.add_argument('--config', type=Path, help='take the default row from this parameter file\'s heatmap_detector '
                                               'and bp_solver sections (default: the package\'s config/shelf.yaml)')
    p.add_argument('--profile', action='store_true',
                   help='also profile the default run (cProfile, in this process): top 20 functions by own time')
    p.add_argument('--no-offline', action='store_true', help='skip the offline evaluator\'s row')
    p.add_argument('--no-two-processes', action='store_true',
                   help='skip the default row pipelined over two processes (bench.pipelined)')
    p.add_argument('--pace', type=_rate, default=0.0, metavar='HZ',
                   help='also run the default row with its 2D people fed at HZ frames/s (sleeping between frames, '
                        'as a node waits for its next message; e.g. 25, the Shelf cameras\' rate) and print its time '
                        'per frame against back to back (default 0: not run)')
    p.add_argument('--repeat', type=int, default=1,
                   help='run each configuration this many times (each a fresh process) and keep the fastest '
                        '(on a shared machine the minimum is the least disturbed figure; default 1)')
    p.add_argument('--one', metavar='JSON', help=argparse.SUPPRESS)  # internal: run one configuration
    return p


def run(args: argparse.Namespace, out: TextIO | None = None, err: TextIO | None = None) -> int:
    """Do what the parsed command line `args` of `mvpose-bench` says; returns the exit code."""
    out = out or sys.stdout
    err = err or sys.stderr
    shelf = dataset_dir('shelf', args.data_root)
    if not (shelf / 'openpose_body25').is_dir():
        raise FileNotFoundError(f'Shelf OpenPose detections not found under {shelf}')
    if not 1 <= args.frames <= len(SHELF_TEST_FRAMES):
        raise ValueError(f'--frames must be in 1..{len(SHELF_TEST_FRAMES)}, got {args.frames}')
    base = graph_config_from(args.config) if args.config else default_graph_config()
    given = {'cameras': args.cameras, 'people': args.people, 'window': args.windows, 'M': args.hypotheses}
    runs = plan(base, args.frames, args.scaling, given, offline=not args.no_offline, pace=args.pace)
    t_all = time.perf_counter()
    measured: dict[tuple, tuple[str, dict]] = {}
    results = []
    for cfg in runs:
        if cfg.key() not in measured:
            t0 = time.perf_counter()
            print(f'mvpose-bench: {cfg.name} ({cfg.frames} frames) ...', end=' ', file=err, flush=True)
            tries = [run_in_process(cfg, args.data_root) for _ in range(max(args.repeat, 1))]
            good = [r for r in tries if 'error' not in r]
            best = min(good, key=lambda r: sum(r['stages_s'].values())) if good else tries[0]
            if good and len(tries) > 1:
                best = {**best, 'repeats_total_s': [sum(r['stages_s'].values()) for r in good]}
            measured[cfg.key()] = cfg.name, best
            print(f'{time.perf_counter() - t0:.1f} s', file=err, flush=True)
        first, result = measured[cfg.key()]
        result = {**result, 'config': {**result['config'], 'name': cfg.name, 'sweep': cfg.sweep}}
        if first != cfg.name:
            result['same_run_as'] = first
        results.append(result)

    print(f'mvpose-bench: Shelf test frames, real OpenPose BODY25 detections; {os.cpu_count()} CPUs, '
          f'python {platform.python_version()}, numpy {np.__version__}, OMP_NUM_THREADS='
          f'{os.environ.get("OMP_NUM_THREADS", "1")}; every run a fresh process'
          + (f', fastest of {args.repeat}' if args.repeat > 1 else ''), file=out)
    main_rows = [r for r in results if not r['config']['sweep']]
    sweep_rows = [r for r in results if r['config']['sweep']]
    report.print_tables(main_rows + sweep_rows, out)
    if 'error' not in results[0]:
        report.print_default(results[0], out)
    report.print_paced(results, out)
    report.print_crowds(results, out)
    pipelined = None if args.no_two_processes else two_processes(replace(base, frames=args.frames),
                                                                 args.data_root, args.repeat)
    if pipelined:
        report.print_two_processes(pipelined, out)
    if args.profile:
        report.print_profile(*profile_run(replace(base, frames=args.frames), args.data_root), args.output, out)
    args.output.mkdir(parents=True, exist_ok=True)
    plots = report.write_plots(results, args.output)
    meta = {'cpus': os.cpu_count(), 'python': platform.python_version(), 'numpy': np.__version__,
            'platform': platform.platform(), 'time': time.strftime('%Y-%m-%d %H:%M:%S'),
            'seconds': time.perf_counter() - t_all}
    for r in results:
        if 'error' not in r:
            r['figures'] = report.figures(r)
    path = args.output / 'bench.json'
    path.write_text(json.dumps({'meta': meta, 'runs': results, 'two_processes': pipelined}, indent=1) + '\n',
                    encoding='utf-8')
    print(f'\nwrote {path}' + ''.join(f'\nwrote {p}' for p in plots), file=out)
    return 0 if all('error' not in r for r in results) else 1


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of `mvpose-bench`; returns the exit code."""
    args = build_parser().parse_args(argv)
    try:
        if args.one:
            result = run_config(RunConfig.from_dict(json.loads(args.one)), args.data_root)
            print(RESULT_TAG + json.dumps(result), flush=True)
            return 0
        return run(args)
    except (FileNotFoundError, ValueError) as exc:
        print(f'mvpose-bench: error: {exc}', file=sys.stderr)
        return 2


if __name__ == '__main__':
    sys.exit(main())
