"""`mvpose-bench`: speed and memory of the 3D stage on the real Shelf detections.

    mvpose-bench [--data-root DIR] [--output out/bench] [--frames N] [--scaling none|quick|full]
                 [--cameras 1,2,3,4,5] [--people 3,10,20] [--windows 4,8,15] [--hypotheses 16,32,64]
                 [--profile] [--repeat N] [--no-two-processes]

Every run replays the Shelf test frames' OpenPose BODY25 output through the whole 3D stage as
the node graph streams it: grouping and per-person heatmaps (the detector nodes' work after the
network), tracking and cross-view matching (association), then hypothesis sampling, data term,
factor tables, BP and decoding over the sliding window (bp_solver). It prints the time per
frame of each stage (from the core's own timers; wall time they do not cover is 'other'), the
frames per second of the whole 3D stage and of its part from 2D people on, peak memory, and the
PCP of the runs on the original scene; it writes a JSON of every figure and PNG plots of the
time per frame against people, cameras, M and window length into --output. Last, the default row
runs again with its two halves (grouping, heatmaps and association | sampling onward) in two
processes, as the node graph splits them: the wall time per frame of the whole stage on two cores.

Each configuration runs in a fresh process (`python -m mvpose_ros.cli.bench --one CONFIG`), so
its peak RSS is its own. Rows: the graph's settings (config/shelf.yaml) and the offline
evaluator's (window 15, lag 7, 16 hypotheses in BP, 4 px heatmap cells); then the sweeps, each
changing one setting of the graph row: the first k cameras; people multiplied by shifted copies
of the scene (bench.scene); window length (lag = window // 2); M, hypotheses per joint.
"""
from __future__ import annotations

import argparse
import cProfile
import io
import json
import os
import platform
import pstats
import resource
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import Sequence, TextIO

import numpy as np

GROUPING = 'grouping and heatmaps'
OTHER = 'other (untimed)'
# the core's timer keys, in pipeline order; any other key the timer has is printed after these
PREFERRED = (GROUPING, 'association', 'sampling', 'data term', 'factors', 'bp', 'decoding')
LABELS = {'association': 'tracking and matching', 'bp': 'BP'}
SHORT = {GROUPING: 'group+hm', 'association': 'trk+match', 'sampling': 'sampling', 'data term': 'data',
         'factors': 'factors', 'bp': 'BP', 'decoding': 'decode', OTHER: 'other'}
SCENE_PEOPLE = 4  # Shelf test frames hold 3-4 people: a --people target up to this is the scene itself
SWEEPS = ('cameras', 'people', 'window', 'M')
FULL = {'cameras': (1, 2, 3, 4, 5), 'people': (3, 10, 20), 'window': (4, 6, 10, 15), 'M': (16, 32, 64)}
QUICK_FRAMES = 60
RESULT_TAG = 'MVPOSE-BENCH-RESULT '


@dataclass(frozen=True)
class RunConfig:
    """One benchmark run. Defaults: the graph's settings (config/shelf.yaml: heatmap_detector
    stride 8; bp_solver window 6, lag 3, M 64, 16 hypotheses in BP, one warm-started iteration
    per slide, terms data,temp,col)."""

    name: str = 'graph (default)'
    sweep: str = ''  # '' for the main rows, else the swept setting
    frames: int = 301
    cameras: int = 5
    people: float | None = None  # target 3D people per frame (scene copies); None = the scene
    window: int | None = 6
    lag: int = 3
    hypotheses: int = 64
    bp_hypotheses: int = 16
    slide_iterations: int = 1
    iterations: int = 5
    stride: float = 8.0
    terms: tuple[str, ...] = ('data', 'temp', 'col')
    head_model: str = 'anatomical'
    seed: int = 0
    pcp: bool = True

    @classmethod
    def from_dict(cls, d: dict) -> RunConfig:
        known = {f.name for f in fields(cls)}
        d = {k: v for k, v in d.items() if k in known}
        if 'terms' in d:
            d['terms'] = tuple(d['terms'])
        return cls(**d)

    def key(self) -> tuple:
        """What makes two runs the same measurement (name and sweep aside)."""
        return tuple(v for k, v in sorted(asdict(self).items()) if k not in ('name', 'sweep'))


GRAPH = RunConfig()
OFFLINE = replace(GRAPH, name='offline (mvpose-eval)', window=15, lag=7, bp_hypotheses=16, stride=4.0)


def graph_config_from(path: str | Path) -> RunConfig:
    """The graph row from a parameter file's heatmap_detector and bp_solver sections."""
    from mvpose_ros.graph.config import load_params
    params = load_params(path)
    det = next((v for k, v in params.items() if k.endswith('heatmap_detector')), {})
    bp = params.get('bp_solver', {})
    return replace(GRAPH, stride=float(det.get('stride', GRAPH.stride)), window=bp.get('window', GRAPH.window) or None,
                   lag=int(bp.get('lag', GRAPH.lag)), hypotheses=int(bp.get('hypotheses', GRAPH.hypotheses)),
                   bp_hypotheses=int(bp.get('bp_hypotheses', GRAPH.bp_hypotheses)),
                   slide_iterations=int(bp.get('slide_iterations', GRAPH.slide_iterations)),
                   iterations=int(bp.get('iterations', GRAPH.iterations)),
                   terms=tuple(bp.get('terms', GRAPH.terms)), head_model=str(bp.get('head_model', GRAPH.head_model)),
                   seed=int(bp.get('seed', GRAPH.seed)))


# --- one run (in its own process) ------------------------------------------------------------

def _rss_kib() -> int:
    """Current resident set size in KiB (Linux /proc; elsewhere the peak so far)."""
    try:
        with open('/proc/self/status', encoding='ascii') as f:
            for line in f:
                if line.startswith('VmRSS:'):
                    return int(line.split()[1])
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss


def _reset_peak() -> bool:
    """Reset this process's peak RSS (Linux >= 4.0: clear_refs 5), so that ru_maxrss from now on
    is the peak of what follows; False where that is not possible."""
    try:
        with open('/proc/self/clear_refs', 'w', encoding='ascii') as f:
            f.write('5')
        return True
    except OSError:
        return False


def _shelf_2d(root: str | None, detector, frames: Sequence[int], n_cameras: int,
              profiler: cProfile.Profile | None = None):
    """The 2D people of the first n_cameras Shelf cameras: core.offline.shelf_openpose, or the
    same steps for a camera subset (so that grouping is only timed for the cameras used) or
    with a profiler (enabled around grouping only, not around reading the files)."""
    from mvpose_ros.core.geometry.camera import load_rig
    from mvpose_ros.core.evaluation.datasets import SHELF_TEST_FRAMES, dataset_dir
    from mvpose_ros.core.evaluation.offline import Sequence2D, shelf_openpose
    from mvpose_ros.core.detection.openpose import read_body25
    from mvpose_ros.core.detection.openpose_detector import detect_people
    shelf = dataset_dir('shelf', root)
    cameras = load_rig(shelf / 'calibration' / 'calibration_shelf.json')
    if n_cameras >= len(cameras) and profiler is None:
        return shelf_openpose(root, detector, frames)
    cameras = cameras[:n_cameras]
    raw = [read_body25(shelf / 'openpose_body25' / f'{c}.txt', cam.width, cam.height) for c, cam in enumerate(cameras)]
    first = SHELF_TEST_FRAMES.start
    if profiler:
        profiler.enable()
    t0 = time.perf_counter()
    people = [[detect_people(raw[c][f - first], detector) for c in range(len(cameras))] for f in frames]
    seconds = time.perf_counter() - t0
    if profiler:
        profiler.disable()
    return Sequence2D(cameras, list(frames), people, {GROUPING: seconds})


def run_config(config: RunConfig, data_root: str | None = None, profiler: cProfile.Profile | None = None) -> dict:
    """Run one configuration in this process; every figure as a JSON-able dict. profiler: enabled
    around the stage's work only (grouping, then tracking onward), not around reading files."""
    from mvpose_ros.bench.scene import multiply_scene
    from mvpose_ros.core.association.associator import Associator
    from mvpose_ros.core.evaluation.datasets import SHELF_ACTORS, SHELF_TEST_FRAMES, dataset_dir, load_actors_gt
    from mvpose_ros.core.evaluation.pcp import evaluate
    from mvpose_ros.core.inference.hypotheses import SamplingConfig
    from mvpose_ros.core.evaluation.offline import as_predictions
    from mvpose_ros.core.detection.openpose_detector import OpenPoseDetectorConfig
    from mvpose_ros.core.inference.solver import Inference3D, StageConfig
    from mvpose_ros.core.inference.window import InferenceConfig

    rss_start = _rss_kib()
    frames = SHELF_TEST_FRAMES[:config.frames]
    seq = _shelf_2d(data_root, OpenPoseDetectorConfig(stride=config.stride), frames, config.cameras, profiler)
    people, scene = seq.people, {}
    if config.people is not None:
        t0 = time.perf_counter()
        multiplied = multiply_scene(seq.cameras, seq.frames, seq.people, config.people)
        people = multiplied.people
        scene = {'copies': len(multiplied.offsets) - 1, 'offsets_m': multiplied.offsets[:, :2].round(2).tolist(),
                 'scene_people': multiplied.original, 'expected_people': multiplied.expected,
                 'setup_s': time.perf_counter() - t0}
    windowed = config.window is not None
    stage = StageConfig(sampling=SamplingConfig(hypotheses=config.hypotheses),
                        inference=InferenceConfig(terms=config.terms, window=config.window,
                                                  lag=config.lag if windowed else 0, iterations=config.iterations,
                                                  bp_hypotheses=config.bp_hypotheses or None,
                                                  slide_iterations=(config.slide_iterations or None) if windowed
                                                  else None),
                        head_model=config.head_model, seed=config.seed)
    rss_ready = _rss_kib()
    peak_setup = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # reading files, grouping, copies
    stage_peak_known = _reset_peak()

    inference = Inference3D(seq.cameras, stage)
    associator = Associator(seq.cameras, stage.association)
    results: list = []
    found = []
    if profiler:
        profiler.enable()
    t_start = time.perf_counter()
    for frame, per_camera in zip(seq.frames, people):
        t0 = time.perf_counter()
        observations = associator.update(frame, per_camera)
        inference.timer.add('association', t0)
        bundles = [(obs.person_id, obs.views) for obs in observations]
        found.append(len(bundles))
        results += inference.push(frame, bundles)
    results += inference.flush()
    wall = time.perf_counter() - t_start
    if profiler:
        profiler.disable()
    peak_stage = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss

    timed = dict(inference.timer.seconds)
    stages = {GROUPING: seq.seconds.get(GROUPING, 0.0), **timed, OTHER: max(wall - sum(timed.values()), 0.0)}
    out = {
        'config': asdict(config),
        'frames': len(seq.frames),
        'cameras': len(seq.cameras),
        'stages_s': stages,
        'stage_wall_s': wall,
        'people_2d_per_camera': float(np.mean([[len(p or []) for p in f] for f in people])) if people else 0.0,
        'people_3d': float(np.mean(found)) if found else 0.0,
        'people_out': float(np.mean([len(r.person_ids) for r in results])) if results else 0.0,
        'frames_out': len(results),
        'empty_frames': int(sum(1 for n in found if n == 0)),
        'scene': scene,
        'rss_start_kib': rss_start,
        'rss_ready_kib': rss_ready,
        'peak_rss_kib': max(peak_setup, peak_stage),
        'peak_stage_kib': peak_stage if stage_peak_known else None,
        'pcp': None,
    }
    if config.pcp:  # with copies too: the original actors are still there to find
        gt = load_actors_gt(dataset_dir('shelf', data_root) / 'actorsGT.mat', frames)
        ev = evaluate(as_predictions(results), gt, SHELF_ACTORS)
        out['pcp'] = {'strict_frame_weighted': ev.frame_weighted('strict'),
                      'strict_actor_avg': ev.actor_average('strict'),
                      'lenient_frame_weighted': ev.frame_weighted('lenient'),
                      'lenient_actor_avg': ev.actor_average('lenient'), 'mpjpe_mm': ev.mpjpe_all}
    return out


def _run_in_process(config: RunConfig, data_root: str | None) -> dict:
    """Run one configuration in a fresh interpreter; its result, or {'error': ...}."""
    cmd = [sys.executable, '-m', 'mvpose_ros.cli.bench', '--one', json.dumps(asdict(config))]
    if data_root:
        cmd += ['--data-root', data_root]
    # one BLAS thread per process, as the graph runs its nodes (see README)
    env = {'OMP_NUM_THREADS': '1', 'OPENBLAS_NUM_THREADS': '1', **os.environ}
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, check=False)
    for line in reversed(proc.stdout.splitlines()):
        if line.startswith(RESULT_TAG):
            return json.loads(line[len(RESULT_TAG):])
    tail = '\n'.join((proc.stderr or proc.stdout).strip().splitlines()[-5:])
    return {'config': asdict(config), 'error': f'exit {proc.returncode}: {tail}'}


# --- what the parent prints and plots --------------------------------------------------------

def stage_order(names) -> list[str]:
    """Stage names in pipeline order: the known ones first, then others, 'other' last."""
    names = list(dict.fromkeys(names))
    known = [n for n in PREFERRED if n in names]
    return known + [n for n in names if n not in PREFERRED and n != OTHER] + ([OTHER] if OTHER in names else [])


def stage_label(name: str, names: Sequence[str]) -> str:
    if name == 'bp' and 'factors' not in names:
        return 'BP (with factors and decoding)'
    return LABELS.get(name, name)


def figures(result: dict) -> dict:
    """Per-frame milliseconds of each stage and the frame rates of one result."""
    n = max(result['frames'], 1)
    ms = {k: 1000.0 * v / n for k, v in result['stages_s'].items()}
    total = sum(result['stages_s'].values())
    after = total - result['stages_s'].get(GROUPING, 0.0)
    return {'ms': ms, 'total_ms': 1000.0 * total / n, 'from_2d_ms': 1000.0 * after / n,
            'fps': n / total if total > 0 else float('inf'), 'fps_from_2d': n / after if after > 0 else float('inf')}


def _mib(kib: float) -> float:
    return kib / 1024.0


def print_tables(results: Sequence[dict], out: TextIO) -> None:
    ok = [r for r in results if 'error' not in r]
    names = stage_order([k for r in ok for k in r['stages_s']])
    head = (f'{"run":24s} {"cams":>4s} {"people":>6s} {"M":>3s} {"win":>4s} '
            + ' '.join(f'{SHORT.get(n, n[:9]):>9s}' for n in names) + f' {"total":>8s} {"fps":>7s} {"fps 2D+":>7s}')
    print('Time per frame (ms) of each stage; fps = frames per second of the whole 3D stage (grouping and '
          'heatmaps onward); fps 2D+ = from 2D people on (tracking and matching onward)', file=out)
    print(head, file=out)
    print('-' * len(head), file=out)
    for r in results:
        c = r['config']
        win = str(c['window']) if c['window'] else 'all'
        if 'error' in r:
            print(f'{c["name"]:24s} failed: {r["error"]}', file=out)
            continue
        f = figures(r)
        cells = ' '.join(f'{f["ms"][n]:9.2f}' if n in f['ms'] else f'{"-":>9s}' for n in names)
        print(f'{c["name"]:24s} {r["cameras"]:4d} {r["people_3d"]:6.1f} {c["hypotheses"]:3d} {win:>4s} {cells} '
              f'{f["total_ms"]:8.2f} {f["fps"]:7.1f} {f["fps_from_2d"]:7.1f}', file=out)
    print('stages: ' + '; '.join(f'{SHORT.get(n, n)} = {stage_label(n, names)}' for n in names), file=out)
    notes = []
    same = [f'{r["config"]["name"]} = {r["same_run_as"]}' for r in ok if r.get('same_run_as')]
    if same:
        notes.append('measured once: ' + ', '.join(same))
    for r in ok:
        c = r['config']
        if r.get('same_run_as'):
            continue
        if r['people_3d'] == 0:
            notes.append(f'{c["name"]}: no 3D people (with {r["cameras"]} camera(s) no joint is seen twice); '
                         f'only grouping and association ran')
        if r['scene']:
            s = r['scene']
            notes.append(f'{c["name"]}: target {c["people"]:g} people: {s["copies"]} shifted copies of the scene '
                         f'(offsets {", ".join(f"({x:+.1f},{y:+.1f})" for x, y in s["offsets_m"][1:])} m), '
                         f'{r["people_3d"]:.1f} 3D people and {r["people_2d_per_camera"]:.1f} 2D people per camera '
                         f'per frame; grouping and heatmaps measured on the original detections only')
    if notes:
        print('notes:\n  ' + '\n  '.join(notes), file=out)

    print('\nMemory (MiB; each run its own process) and accuracy (PCP %, alpha 0.5, actors 1-3)', file=out)
    head = (f'{"run":24s} {"frames":>6s} {"2D/cam":>6s} {"3D":>5s} {"out":>5s} {"start":>6s} {"ready":>6s} '
            f'{"peak":>6s} {"stage":>6s} {"growth":>6s}   {"strict fw/aa":>13s} {"lenient fw/aa":>13s} {"MPJPE":>8s}')
    print(head, file=out)
    print('-' * len(head), file=out)
    for r in ok:
        c = r['config']
        p = r['pcp']
        acc = (f'{p["strict_frame_weighted"]:6.2f}/{p["strict_actor_avg"]:6.2f} '
               f'{p["lenient_frame_weighted"]:6.2f}/{p["lenient_actor_avg"]:6.2f} {p["mpjpe_mm"]:5.1f} mm') if p else ''
        stage = r['peak_stage_kib']
        stage_cells = (f'{_mib(stage):6.1f} {_mib(stage - r["rss_ready_kib"]):6.1f}' if stage is not None
                       else f'{"n/a":>6s} {"n/a":>6s}')
        print(f'{c["name"]:24s} {r["frames"]:6d} {r["people_2d_per_camera"]:6.1f} {r["people_3d"]:5.1f} '
              f'{r["people_out"]:5.1f} {_mib(r["rss_start_kib"]):6.1f} {_mib(r["rss_ready_kib"]):6.1f} '
              f'{_mib(r["peak_rss_kib"]):6.1f} {stage_cells}   {acc}', file=out)
    print('2D/cam, 3D, out: people per frame (2D per camera, associated, output). RSS: start = after imports; '
          'ready = every frame\'s 2D people held in memory (the bench holds the clip; the graph streams it); '
          'peak = the process maximum (ru_maxrss); stage = peak from tracking onward (peak reset at ready); '
          'growth = stage - ready', file=out)


def print_default(result: dict, out: TextIO) -> None:
    """The default row in detail: every stage with its share, both frame rates, memory, PCP."""
    f = figures(result)
    names = stage_order(result['stages_s'])
    c = result['config']
    print(f'\n{c["name"]}: {result["frames"]} frames, {result["cameras"]} cameras, {result["people_3d"]:.2f} 3D people '
          f'per frame; window {c["window"]}, lag {c["lag"]}, M {c["hypotheses"]}, {c["bp_hypotheses"]} in BP, '
          f'heatmap cells {c["stride"]:g} px', file=out)
    for n in names:
        ms = f['ms'][n]
        print(f'  {stage_label(n, names):32s} {ms:8.2f} ms/frame {100 * ms / f["total_ms"]:5.1f} %', file=out)
    print(f'  {"whole 3D stage":32s} {f["total_ms"]:8.2f} ms/frame -> {f["fps"]:.1f} frames/s '
          f'(grouping and heatmaps onward, all stages)', file=out)
    print(f'  {"from 2D people":32s} {f["from_2d_ms"]:8.2f} ms/frame -> {f["fps_from_2d"]:.1f} frames/s '
          f'(tracking and matching onward)', file=out)
    stage = result['peak_stage_kib']
    print(f'  peak memory {_mib(result["peak_rss_kib"]):.1f} MiB '
          f'(RSS after imports {_mib(result["rss_start_kib"]):.1f}, '
          f'with the 2D people of every frame {_mib(result["rss_ready_kib"]):.1f}'
          + (f', peak from tracking onward {_mib(stage):.1f}: the stage grows by '
             f'{_mib(stage - result["rss_ready_kib"]):.1f})' if stage is not None else ')'), file=out)
    if result['pcp']:
        p = result['pcp']
        print(f'  PCP strict {p["strict_frame_weighted"]:.2f} frame-weighted / {p["strict_actor_avg"]:.2f} '
              f'actor-average'
              f' | lenient {p["lenient_frame_weighted"]:.2f} / {p["lenient_actor_avg"]:.2f} | MPJPE '
              f'{p["mpjpe_mm"]:.1f} mm', file=out)


def _sweep_value(result: dict, sweep: str) -> float:
    c = result['config']
    return {'cameras': result['cameras'], 'people': result['people_3d'], 'window': c['window'] or result['frames'],
            'M': c['hypotheses']}[sweep]


def write_plots(results: Sequence[dict], output: Path) -> list[Path]:
    """One PNG per sweep run: time per frame of each stage and the total against the setting."""
    from mvpose_ros.bench.plot import Series, line_plot
    titles = {'cameras': ('cameras', 'cameras (the first k of Shelf\'s 5)'),
              'people': ('people', '3D people per frame (scene copies; measured)'),
              'window': ('window', 'window length (frames; lag = window // 2)'),
              'M': ('M', 'M, hypotheses sampled per joint')}
    paths = []
    ok = [r for r in results if 'error' not in r]
    for sweep in SWEEPS:
        rows = [r for r in ok if r['config']['sweep'] == sweep]
        if len(rows) < 2:
            continue
        rows.sort(key=lambda r: _sweep_value(r, sweep))
        label, xlabel = titles[sweep]
        xs = [_sweep_value(r, sweep) for r in rows]
        figs = [figures(r) for r in rows]
        names = stage_order([k for r in rows for k in r['stages_s']])
        series = [Series(stage_label(n, names), xs, [f['ms'].get(n, float('nan')) for f in figs]) for n in names]
        series.append(Series('total', xs, [f['total_ms'] for f in figs], color=(0, 0, 0), thickness=3))
        if sweep == 'people':  # copies are made from the original scene's 2D people, not regrouped
            series[names.index(GROUPING)].name += ' (scene)' if GROUPING in names else ''
        if sweep in ('people', 'cameras'):
            ref = next((i for i, r in enumerate(rows) if r['people_3d'] > 0 and xs[i] > 0), None)
            if ref is not None:
                slope = figs[ref]['total_ms'] / xs[ref]
                series.append(Series(f'linear from {xs[ref]:.3g} {label}', [xs[ref], max(xs)],
                                     [figs[ref]['total_ms'], slope * max(xs)], color=(140, 140, 140), dashed=True))
        frames = rows[0]['frames']
        title = f'Time per frame against {label} (Shelf, {frames} frames; graph settings otherwise)'
        xticks = xs if sweep != 'people' else None
        paths.append(line_plot(output / f'time_vs_{sweep.lower()}.png', series, title=title, xlabel=xlabel,
                               ylabel='ms per frame', xticks=xticks))
    return paths


# --- command line ------------------------------------------------------------------------------

def _ints(text: str) -> tuple[int, ...]:
    try:
        values = tuple(int(v) for v in text.split(',') if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected comma-separated integers, got {text!r}') from None
    if any(v < 1 for v in values):
        raise argparse.ArgumentTypeError(f'values must be >= 1, got {text!r}')
    return values


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog='mvpose-bench', description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('--data-root', help='folder holding data/ (default: $MVPOSE_DATA_ROOT or ../shared)')
    p.add_argument('--output', type=Path, default=Path('out/bench'),
                   help='PNG plots and bench.json (default: out/bench)')
    p.add_argument('--frames', type=int, default=301, help='the first N Shelf test frames (default: all 301)')
    p.add_argument('--scaling', choices=('none', 'quick', 'full'), default='full',
                   help=f'sweeps: none; quick (on the first {QUICK_FRAMES} frames); full (on --frames; default). '
                        'The flags below replace one sweep\'s values')
    p.add_argument('--cameras', type=_ints, help='camera counts (the first k cameras), e.g. 1,2,3,4,5')
    p.add_argument('--people', type=_ints,
                   help=f'target 3D people per frame, e.g. 3,10,20 (up to {SCENE_PEOPLE}: the scene itself)')
    p.add_argument('--windows', type=_ints, help='window lengths, e.g. 4,8,15 (lag = window // 2)')
    p.add_argument('--hypotheses', type=_ints, help='M values, e.g. 16,32,64')
    p.add_argument('--config', type=Path, help='take the default row from this parameter file\'s heatmap_detector '
                                               'and bp_solver sections (default: built in, = config/shelf.yaml)')
    p.add_argument('--profile', action='store_true',
                   help='also profile the default run (cProfile, in this process): top 20 functions by own time')
    p.add_argument('--no-offline', action='store_true', help='skip the offline evaluator\'s row')
    p.add_argument('--no-two-processes', action='store_true',
                   help='skip the default row pipelined over two processes (bench.pipelined)')
    p.add_argument('--repeat', type=int, default=1,
                   help='run each configuration this many times (each a fresh process) and keep the fastest '
                        '(on a shared machine the minimum is the least disturbed figure; default 1)')
    p.add_argument('--one', metavar='JSON', help=argparse.SUPPRESS)  # internal: run one configuration
    return p


def plan(args: argparse.Namespace, base: RunConfig) -> list[RunConfig]:
    """The runs: the default and offline rows, then each sweep (a run equal to one already
    planned is measured once)."""
    base = replace(base, frames=args.frames)
    runs = [base] + ([] if args.no_offline else [replace(OFFLINE, frames=args.frames)])
    lists = {k: () for k in SWEEPS} if args.scaling == 'none' else dict(FULL)
    for key, given in (('cameras', args.cameras), ('people', args.people), ('window', args.windows),
                       ('M', args.hypotheses)):
        if given is not None:
            lists[key] = given
    frames = min(args.frames, QUICK_FRAMES) if args.scaling == 'quick' else args.frames
    sweep_base = replace(base, frames=frames, pcp=True)
    for sweep in SWEEPS:
        for v in lists[sweep]:
            if sweep == 'cameras':
                cfg = replace(sweep_base, cameras=v, name=f'cameras={v}')
            elif sweep == 'people':
                target = None if v <= SCENE_PEOPLE else float(v)
                cfg = replace(sweep_base, people=target, name=f'people~{v}')
            elif sweep == 'window':
                cfg = replace(sweep_base, window=v, lag=v // 2, name=f'window={v}')
            else:
                cfg = replace(sweep_base, hypotheses=v, name=f'M={v}')
            runs.append(replace(cfg, sweep=sweep))
    return runs


def run(args: argparse.Namespace, out: TextIO | None = None, err: TextIO | None = None) -> int:
    out = out or sys.stdout
    err = err or sys.stderr
    from mvpose_ros.core.evaluation.datasets import dataset_dir
    shelf = dataset_dir('shelf', args.data_root)
    if not (shelf / 'openpose_body25').is_dir():
        raise FileNotFoundError(f'Shelf OpenPose detections not found under {shelf}')
    if not 1 <= args.frames <= 301:
        raise ValueError(f'--frames must be in 1..301, got {args.frames}')
    base = graph_config_from(args.config) if args.config else GRAPH
    runs = plan(args, base)
    t_all = time.perf_counter()
    measured: dict[tuple, tuple[str, dict]] = {}
    results = []
    for cfg in runs:
        if cfg.key() not in measured:
            t0 = time.perf_counter()
            print(f'mvpose-bench: {cfg.name} ({cfg.frames} frames) ...', end=' ', file=err, flush=True)
            tries = [_run_in_process(cfg, args.data_root) for _ in range(max(args.repeat, 1))]
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
    print_tables(main_rows + sweep_rows, out)
    if 'error' not in results[0]:
        print_default(results[0], out)
    pipelined = None if args.no_two_processes else two_processes(replace(base, frames=args.frames),
                                                                  args.data_root, args.repeat)
    if pipelined:
        print_two_processes(pipelined, out)
    if args.profile:
        print_profile(replace(base, frames=args.frames), args.data_root, args.output, out)
    args.output.mkdir(parents=True, exist_ok=True)
    plots = write_plots(results, args.output)
    meta = {'cpus': os.cpu_count(), 'python': platform.python_version(), 'numpy': np.__version__,
            'platform': platform.platform(), 'time': time.strftime('%Y-%m-%d %H:%M:%S'),
            'seconds': time.perf_counter() - t_all}
    for r in results:
        if 'error' not in r:
            r['figures'] = figures(r)
    path = args.output / 'bench.json'
    path.write_text(json.dumps({'meta': meta, 'runs': results, 'two_processes': pipelined}, indent=1) + '\n',
                    encoding='utf-8')
    print(f'\nwrote {path}' + ''.join(f'\nwrote {p}' for p in plots), file=out)
    return 0 if all('error' not in r for r in results) else 1


def two_processes(config: RunConfig, data_root: str | None, repeat: int) -> dict:
    """The whole 3D stage of `config` pipelined over two processes (bench.pipelined): the fastest
    of `repeat` runs' wall time per frame and frame rate, each half's stage times, and the PCP."""
    from mvpose_ros.bench.pipelined import run_two_processes
    from mvpose_ros.core.geometry.camera import load_rig
    from mvpose_ros.core.evaluation.datasets import SHELF_ACTORS, SHELF_TEST_FRAMES, dataset_dir, load_actors_gt
    from mvpose_ros.core.evaluation.pcp import evaluate
    from mvpose_ros.core.inference.hypotheses import SamplingConfig
    from mvpose_ros.core.evaluation.offline import as_predictions
    from mvpose_ros.core.detection.openpose import read_body25
    from mvpose_ros.core.detection.openpose_detector import OpenPoseDetectorConfig
    from mvpose_ros.core.inference.solver import StageConfig
    from mvpose_ros.core.inference.window import InferenceConfig
    shelf = dataset_dir('shelf', data_root)
    cameras = load_rig(shelf / 'calibration' / 'calibration_shelf.json')[:config.cameras]
    files = [read_body25(shelf / 'openpose_body25' / f'{c}.txt', cam.width, cam.height) for c, cam in enumerate(cameras)]
    frames = list(SHELF_TEST_FRAMES[:config.frames])
    raw = [[f[k] for f in files] for k in range(len(frames))]
    stage = StageConfig(sampling=SamplingConfig(hypotheses=config.hypotheses),
                        inference=InferenceConfig(terms=config.terms, window=config.window, lag=config.lag,
                                                  iterations=config.iterations,
                                                  bp_hypotheses=config.bp_hypotheses or None,
                                                  slide_iterations=config.slide_iterations or None),
                        head_model=config.head_model, seed=config.seed)
    runs = [run_two_processes(cameras, frames, raw, OpenPoseDetectorConfig(stride=config.stride), stage)
            for _ in range(max(repeat, 1))]
    best = min(runs, key=lambda r: r.wall_s)
    ev = evaluate(as_predictions(best.results), load_actors_gt(shelf / 'actorsGT.mat', frames), SHELF_ACTORS)
    n = len(frames)
    return {'config': asdict(config), 'frames': n, 'wall_ms': 1e3 * best.wall_s / n, 'fps': n / best.wall_s,
            'walls_ms': [1e3 * r.wall_s / n for r in runs],
            'stages_ms': {k: 1e3 * v / n for k, v in best.seconds.items()},
            'pcp': {'strict_frame_weighted': ev.frame_weighted('strict'), 'strict_actor_avg': ev.actor_average('strict'),
                    'lenient_frame_weighted': ev.frame_weighted('lenient'),
                    'lenient_actor_avg': ev.actor_average('lenient'), 'mpjpe_mm': ev.mpjpe_all}}


def print_two_processes(result: dict, out: TextIO) -> None:
    front = ('grouping and heatmaps', 'association')
    ms = result['stages_ms']
    p = result['pcp']
    print(f"\n{result['config']['name']} on two processes (grouping, heatmaps and association | sampling onward, "
          f"frames streamed through a pipe; bench.pipelined):", file=out)
    print(f"  whole 3D stage {result['wall_ms']:.2f} ms/frame wall -> {result['fps']:.1f} frames/s "
          f"(runs: {', '.join(f'{w:.2f}' for w in result['walls_ms'])} ms/frame)", file=out)
    print(f"  process 1: {sum(ms.get(k, 0.0) for k in front):.2f} ms/frame ("
          + ', '.join(f'{k} {ms[k]:.2f}' for k in front if k in ms) + '); process 2: '
          f"{sum(v for k, v in ms.items() if k not in front):.2f} ms/frame ("
          + ', '.join(f'{k} {v:.2f}' for k, v in ms.items() if k not in front) + ')', file=out)
    print(f"  PCP strict {p['strict_frame_weighted']:.2f} / {p['strict_actor_avg']:.2f} | lenient "
          f"{p['lenient_frame_weighted']:.2f} / {p['lenient_actor_avg']:.2f} | MPJPE {p['mpjpe_mm']:.1f} mm "
          f"(the single-process run's: the same solver on the same input)", file=out)


def print_profile(config: RunConfig, data_root: str | None, output: Path, out: TextIO) -> None:
    """cProfile of one run in this process: the top 20 functions by own time."""
    profile = cProfile.Profile()
    result = run_config(replace(config, pcp=False), data_root, profile)
    output.mkdir(parents=True, exist_ok=True)
    path = output / 'profile_default.prof'
    profile.dump_stats(str(path))
    text = io.StringIO()
    pstats.Stats(profile, stream=text).strip_dirs().sort_stats('tottime').print_stats(20)
    lines = [line for line in text.getvalue().splitlines() if line.strip()]
    start = next((i for i, line in enumerate(lines) if 'function calls' in line), 0)
    f = figures(result)
    print(f'\nProfile of the default run ({config.frames} frames, grouping onward, reading files left out; '
          f'cProfile, top 20 functions by own time; full profile: {path}); under the profiler: '
          f'{f["total_ms"]:.2f} ms/frame', file=out)
    print('\n'.join(lines[start:]), file=out)


def main(argv: Sequence[str] | None = None) -> int:
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
