"""The benchmark's runs: what one run is (RunConfig), running it in this process or a fresh one,
the plan of rows and sweeps, the two-process run and the profiled run.

Every run replays the Shelf test frames' OpenPose BODY25 output through the whole 3D stage as
the node graph streams it: grouping and per-person heatmaps (the detector nodes' work after the
network), then core.stage.Stage3D (association, sampling, data term, factor tables, BP and
decoding over the sliding window). Rows: the graph's settings (config/shelf.yaml) and the
defaults (the offline evaluator's window); sweeps change one setting of the graph row: the first k
cameras; people multiplied by shifted copies of the scene (core.scenarios.crowd); window length (lag =
window // 2); M, hypotheses per joint. A paced row feeds the graph row's 2D people at a camera rate
and sleeps between frames, as a node waits for its next message: code that has not just run takes
longer than back to back, and that is the time a frame costs in the graph.
"""
from __future__ import annotations

import cProfile
import json
import os
import resource
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from mvpose_ros.core.datasets.shelf_campus import SHELF_ACTORS, SHELF_TEST_FRAMES, dataset_dir, load_actors_gt
from mvpose_ros.core.detection.openpose_detector import OpenPoseDetectorConfig
from mvpose_ros.core.evaluation.offline import GROUPING, as_predictions, detect_sequence, shelf_openpose_raw
from mvpose_ros.core.evaluation.pcp import Evaluation, evaluate
from mvpose_ros.core.scenarios.crowd import multiply_scene
from mvpose_ros.core.stage import ALL_PARAMETERS, Stage3D, StageConfig
from mvpose_ros.graph.memory import rss_kib
from mvpose_ros.package_files import package_path

OTHER = 'other (untimed)'  # wall time no core timer covers

SCENE_PEOPLE = 4  # Shelf test frames hold 3-4 people: a --people target up to this is the scene itself
SWEEPS = ('cameras', 'people', 'window', 'M')
FULL = {'cameras': (1, 2, 3, 4, 5), 'people': (3, 10, 20), 'window': (4, 6, 10, 15), 'M': (16, 32, 64)}
QUICK_FRAMES = 60
RESULT_TAG = 'MVPOSE-BENCH-RESULT '
# The graph's parameter file, in the checkout or where colcon / pip install the package's config.
GRAPH_CONFIG = 'config/shelf.yaml'


@dataclass(frozen=True)
class RunConfig:
    """One benchmark run: which frames, cameras and people, the heatmap cell size, and `settings`,
    the 3D stage's flat parameters as the nodes take them (every core.stage name; window 0 = the
    whole clip; by default StageConfig's own)."""

    name: str = 'offline (mvpose-eval)'
    sweep: str = ''  # '' for the main rows, else the swept setting
    frames: int = len(SHELF_TEST_FRAMES)
    cameras: int = 5
    people: float | None = None  # target 3D people per frame (scene copies); None = the scene
    stride: float = OpenPoseDetectorConfig.stride
    pcp: bool = True
    pace: float = 0.0  # Hz the 2D people are fed at, sleeping between frames; 0: back to back
    settings: dict[str, Any] = field(default_factory=lambda: StageConfig().to_params())

    @classmethod
    def from_dict(cls, d: dict) -> RunConfig:
        """A run from its dict (bench.json's `config`), keys that are not fields ignored."""
        known = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in d.items() if k in known})

    def with_settings(self, **changes: Any) -> RunConfig:
        """This run with some of the stage's parameters changed."""
        unknown = set(changes) - set(ALL_PARAMETERS)
        if unknown:
            raise ValueError(f'not parameters of the 3D stage: {sorted(unknown)}')
        return replace(self, settings={**self.settings, **changes})

    def key(self) -> tuple:
        """What makes two runs the same measurement (name and sweep aside)."""
        run = tuple(v for k, v in sorted(asdict(self).items()) if k not in ('name', 'sweep', 'settings'))
        stage = self.stage().to_params()
        return run + tuple((k, tuple(v) if isinstance(v, list) else v) for k, v in sorted(stage.items()))

    def stage(self) -> StageConfig:
        """The 3D stage's configuration of this run."""
        return StageConfig.from_params(self.settings)

    def detector(self) -> OpenPoseDetectorConfig:
        """The OpenPose detector's configuration of this run (its heatmap cells)."""
        return replace(OpenPoseDetectorConfig(), stride=self.stride)


def graph_config_from(path: str | Path) -> RunConfig:
    """The graph row from a parameter file's heatmap_detector and bp_solver sections."""
    from mvpose_ros.graph.config import load_params
    params = load_params(path)
    det = next((v for k, v in params.items() if k.endswith('heatmap_detector')), {})
    bp = params.get('bp_solver', {})
    return RunConfig(name='graph (default)', stride=float(det.get('stride', RunConfig.stride))).with_settings(
        **{k: v for k, v in bp.items() if k in ALL_PARAMETERS})


def default_graph_config() -> RunConfig:
    """The graph row from the package's config/shelf.yaml (checkout or installed share folder)."""
    return graph_config_from(package_path(GRAPH_CONFIG))


OFFLINE = RunConfig()


# --- one run (in its own process) ------------------------------------------------------------

def _reset_peak() -> bool:
    """Reset this process's peak RSS (Linux >= 4.0: clear_refs 5), so that ru_maxrss from now on
    is the peak of what follows; False where that is not possible."""
    try:
        with open('/proc/self/clear_refs', 'w', encoding='ascii') as f:
            f.write('5')
        return True
    except OSError:
        return False


def pcp_figures(ev: Evaluation) -> dict[str, float]:
    """The four PCP figures and the MPJPE of an evaluation, as the report prints them."""
    return {'strict_frame_weighted': ev.frame_weighted('strict'), 'strict_actor_avg': ev.actor_average('strict'),
            'lenient_frame_weighted': ev.frame_weighted('lenient'), 'lenient_actor_avg': ev.actor_average('lenient'),
            'mpjpe_mm': ev.mpjpe_all}


def run_config(config: RunConfig, data_root: str | None = None, profiler: cProfile.Profile | None = None) -> dict:
    """Run one configuration in this process; every figure as a JSON-able dict. profiler: enabled
    around the stage's work only (grouping, then tracking onward), not around reading files."""
    rss_start = rss_kib()
    frames = SHELF_TEST_FRAMES[:config.frames]
    cameras, raw = shelf_openpose_raw(data_root, config.cameras)
    if profiler:
        profiler.enable()
    seq = detect_sequence(cameras, raw, frames, config.detector())
    if profiler:
        profiler.disable()
    people, scene = seq.people, {}
    if config.people is not None:
        t0 = time.perf_counter()
        multiplied = multiply_scene(seq.cameras, seq.frames, seq.people, config.people)
        people = multiplied.people
        scene = {'copies': len(multiplied.offsets) - 1, 'offsets_m': multiplied.offsets[:, :2].round(2).tolist(),
                 'scene_people': multiplied.original, 'expected_people': multiplied.expected,
                 'setup_s': time.perf_counter() - t0}
    stage = Stage3D(seq.cameras, config.stage())
    rss_ready = rss_kib()
    peak_setup = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # reading files, grouping, copies
    stage_peak_known = _reset_peak()

    results: list = []
    found = []
    frame_s = []  # each frame's time from its 2D people to its push's end
    if profiler:
        profiler.enable()
    t_start = time.perf_counter()
    for i, (frame, per_camera) in enumerate(zip(seq.frames, people)):
        if config.pace > 0:
            time.sleep(max(t_start + i / config.pace - time.perf_counter(), 0.0))
        t0 = time.perf_counter()
        bundles = stage.associate(frame, per_camera)
        found.append(len(bundles))
        results += stage.solver.push(frame, bundles)
        frame_s.append(time.perf_counter() - t0)
    t0 = time.perf_counter()
    results += stage.flush()
    wall = sum(frame_s) + time.perf_counter() - t0  # the sleeps between paced frames left out
    if profiler:
        profiler.disable()
    peak_stage = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss

    timed = dict(stage.timer.seconds)
    stages = {GROUPING: seq.seconds.get(GROUPING, 0.0), **timed, OTHER: max(wall - sum(timed.values()), 0.0)}
    out = {
        'config': asdict(config),
        'frames': len(seq.frames),
        'cameras': len(seq.cameras),
        'stages_s': stages,
        'stage_wall_s': wall,
        'frame_ms': {'p50': 1e3 * float(np.median(frame_s)), 'p95': 1e3 * float(np.percentile(frame_s, 95))}
        if frame_s else None,
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
        out['pcp'] = pcp_figures(evaluate(as_predictions(results), gt, SHELF_ACTORS))
    return out


def run_in_process(config: RunConfig, data_root: str | None) -> dict:
    """Run one configuration in a fresh interpreter; its result, or {'error': ...}."""
    cmd = [sys.executable, '-m', 'mvpose_ros.cli.bench', '--one', json.dumps(asdict(config))]
    if data_root:
        cmd += ['--data-root', data_root]
    # one BLAS thread per process, as the graph runs its nodes (see docs/benchmarks.md)
    env = {'OMP_NUM_THREADS': '1', 'OPENBLAS_NUM_THREADS': '1', **os.environ}
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, check=False)
    for line in reversed(proc.stdout.splitlines()):
        if line.startswith(RESULT_TAG):
            return json.loads(line[len(RESULT_TAG):])
    tail = '\n'.join((proc.stderr or proc.stdout).strip().splitlines()[-5:])
    return {'config': asdict(config), 'error': f'exit {proc.returncode}: {tail}'}


def plan(base: RunConfig, frames: int, scaling: str, given: dict[str, tuple[int, ...] | None],
         offline: bool = True, pace: float = 0.0) -> list[RunConfig]:
    """The runs: the default row, with pace > 0 the same fed at `pace` Hz, the offline row, then
    each sweep (scaling 'none', 'quick' or 'full'; given: a sweep's values replacing the built-in
    ones). A run equal to one already planned is measured once."""
    base = replace(base, frames=frames)
    runs = [base] + ([replace(base, pace=pace, name=f'{base.name} at {pace:g} Hz')] if pace > 0 else [])
    runs += [replace(OFFLINE, frames=frames)] if offline else []
    lists = {k: () for k in SWEEPS} if scaling == 'none' else dict(FULL)
    lists.update({k: v for k, v in given.items() if v is not None})
    sweep_base = replace(base, frames=min(frames, QUICK_FRAMES) if scaling == 'quick' else frames, pcp=True)
    for sweep in SWEEPS:
        for v in lists[sweep]:
            if sweep == 'cameras':
                cfg = replace(sweep_base, cameras=v, name=f'cameras={v}')
            elif sweep == 'people':
                target = None if v <= SCENE_PEOPLE else float(v)
                cfg = replace(sweep_base, people=target, name=f'people~{v}')
            elif sweep == 'window':
                cfg = replace(sweep_base.with_settings(window=v, lag=v // 2), name=f'window={v}')
            else:
                cfg = replace(sweep_base.with_settings(hypotheses=v), name=f'M={v}')
            runs.append(replace(cfg, sweep=sweep))
    return runs


def two_processes(config: RunConfig, data_root: str | None, repeat: int) -> dict:
    """The whole 3D stage of `config` pipelined over two processes (bench.pipelined): the fastest
    of `repeat` runs' wall time per frame and frame rate, each half's stage times, and the PCP."""
    from mvpose_ros.bench.pipelined import run_two_processes
    cameras, files = shelf_openpose_raw(data_root, config.cameras)
    frames = list(SHELF_TEST_FRAMES[:config.frames])
    raw = [[f[k] for f in files] for k in range(len(frames))]
    runs = [run_two_processes(cameras, frames, raw, config.detector(), config.stage())
            for _ in range(max(repeat, 1))]
    best = min(runs, key=lambda r: r.wall_s)
    gt = load_actors_gt(dataset_dir('shelf', data_root) / 'actorsGT.mat', frames)
    n = len(frames)
    return {'config': asdict(config), 'frames': n, 'wall_ms': 1e3 * best.wall_s / n, 'fps': n / best.wall_s,
            'walls_ms': [1e3 * r.wall_s / n for r in runs],
            'stages_ms': {k: 1e3 * v / n for k, v in best.seconds.items()},
            'pcp': pcp_figures(evaluate(as_predictions(best.results), gt, SHELF_ACTORS))}


def profile_run(config: RunConfig, data_root: str | None) -> tuple[dict, cProfile.Profile]:
    """One run of `config` in this process under cProfile (without PCP)."""
    profile = cProfile.Profile()
    return run_config(replace(config, pcp=False), data_root, profile), profile
