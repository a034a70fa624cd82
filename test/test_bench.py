"""mvpose-bench: scene multiplication (geometry of the copies, association of a crowd), the
OpenCV plots, and a smoke run of the command on a few real Shelf frames. No test asserts a time."""
from __future__ import annotations

import json
import sys
from dataclasses import asdict, replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from mvpose_ros.bench import report as bench_report, runs as bench_runs
from mvpose_ros.bench.pipelined import run_two_processes
from mvpose_ros.cli import bench
from mvpose_ros.core.association.associator import AssociationConfig, Associator
from mvpose_ros.core.datasets.shelf_campus import dataset_dir, shelf_cameras
from mvpose_ros.core.defaults import FRAME_RATE
from mvpose_ros.core.detection.openpose import read_body25
from mvpose_ros.core.detection.openpose_detector import OpenPoseDetectorConfig, detect_people
from mvpose_ros.core.drawing.plot import Series, line_plot, nice_ticks
from mvpose_ros.core.geometry.camera import Camera
from mvpose_ros.core.scenarios.crowd import (ScenePerson, choose_offsets, copy_person, copy_view, multiply_scene,
                                             scene_people, triangulate)
from mvpose_ros.core.stage import Stage3D, StageConfig
from mvpose_ros.core.types import Person2D
from mvpose_ros.graph.config import load_params

REPO = Path(__file__).resolve().parents[1]
N_JOINTS = 16


def _look_at(name: str, centre, target, f: float = 600.0, size=(1000, 800)) -> Camera:
    centre, target = np.asarray(centre, float), np.asarray(target, float)
    forward = (target - centre) / np.linalg.norm(target - centre)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    R = np.stack([right, down, forward])
    K = np.array([[f, 0, size[0] / 2], [0, f, size[1] / 2], [0, 0, 1]])
    return Camera(name, K, R, -R @ centre, np.zeros(5), *size)


@pytest.fixture(scope='module')
def rig() -> list[Camera]:
    """Four cameras 11 m from the middle, 3 m up, looking at it; no two face each other (rays
    of opposite cameras are nearly collinear, which lets people in line with them match)."""
    return [_look_at(str(i), (11 * np.cos(a), 11 * np.sin(a), 3.0), (0.0, 0.0, 1.0))
            for i, a in enumerate(np.radians([10, 85, 160, 235]))]


def _skeleton(at) -> np.ndarray:
    """(16, 3) a standing body's joints around floor point `at`."""
    rng = np.random.default_rng(7)
    heights = np.linspace(0.1, 1.7, N_JOINTS)
    side = rng.uniform(-0.2, 0.2, (N_JOINTS, 2))
    return np.column_stack([at[0] + side[:, 0], at[1] + side[:, 1], heights])


def _views(rig: list[Camera], joints: np.ndarray, score: float = 0.9) -> list[Person2D]:
    out = []
    for cam in rig:
        kp = np.column_stack([cam.project(joints), np.full(N_JOINTS, score)])
        out.append(Person2D.from_keypoints(kp, stride=4.0, sigma=6.0))
    return out


def _frames(rig, centres, n_frames: int = 5):
    """Per frame, per camera, the 2D people at `centres` (walking slowly along x)."""
    frames = []
    for t in range(n_frames):
        per_person = [_views(rig, _skeleton((x + 0.02 * t, y))) for x, y in centres]
        frames.append([[views[c] for views in per_person] for c in range(len(rig))])
    return frames


def test_copied_keypoint_is_exactly_the_projection_of_the_shifted_triangulated_point(rig):
    truth = _skeleton((0.5, -0.5))
    [[person]] = scene_people(rig, [0], [[[v] for v in _views(rig, truth)]])
    np.testing.assert_allclose(person.joints, truth, atol=1e-6)
    offset = np.array([2.5, 1.0, 0.0])
    copy = copy_person(rig, person, offset)
    assert sorted(copy) == [0, 1, 2, 3]
    for c, view in copy.items():
        np.testing.assert_array_equal(view.keypoints[:, :2], rig[c].project(person.joints + offset))
        np.testing.assert_array_equal(view.keypoints[:, 2], person.views[c].keypoints[:, 2])  # scores kept
        assert view.track_id == -1


def test_copied_heatmap_peak_moves_by_the_joint_displacement(rig):
    [[person]] = scene_people(rig, [0], [[[v] for v in _views(rig, _skeleton((0.0, 0.0)))]])
    offset = np.array([-2.0, 1.5, 0.0])
    for c, view in copy_person(rig, person, offset).items():
        shift = rig[c].project(person.joints + offset) - rig[c].project(person.joints)
        before, after = person.views[c].heatmap.peak(), view.heatmap.peak()
        np.testing.assert_allclose(after[:, :2], before[:, :2] + shift, atol=1e-9)
        np.testing.assert_array_equal(after[:, 2], before[:, 2])
        assert view.heatmap.cells is person.views[c].heatmap.cells  # cells unchanged, shared


def test_a_joint_without_3d_or_outside_the_image_is_dropped(rig):
    views = _views(rig, _skeleton((0.0, 0.0)))
    for v in views[1:]:  # joint 3 seen by camera 0 only: no 3D estimate
        v.keypoints[3] = (np.nan, np.nan, 0.0)
    person = ScenePerson({c: v for c, v in enumerate(views)}, triangulate(rig, [dict(enumerate(views))], 0.1)[0])
    assert np.isnan(person.joints[3]).all() and np.isfinite(np.delete(person.joints, 3, axis=0)).all()
    moved = copy_view(rig[0], views[0], person.joints, np.array([1.0, 0.0, 0.0]))
    assert moved.keypoints[3, 2] == 0 and np.isnan(moved.keypoints[3, :2]).all()
    assert not moved.heatmap.maps[3].any() and views[0].heatmap.maps[3].any()
    # high above every camera's view: no view of the copy
    assert copy_person(rig, person, np.array([0.0, 0.0, 100.0])) == {}
    # half out of the image: kept with min_inside 0.5 only while at least half its joints stay in
    cam = _look_at('narrow', (11.0, 0.0, 3.0), (0.0, 0.0, 1.0), f=3000.0)
    view = Person2D.from_keypoints(np.column_stack([cam.project(person.joints), np.full(N_JOINTS, 0.9)]), 4.0, 6.0)
    lifts = np.arange(0.0, 2.0, 0.02)
    out = [(~(cam.project(person.joints + [0, 0, dz])[:, 1] >= 0)).sum() - 1 for dz in lifts]  # joint 3: NaN
    dz = lifts[next(i for i, n in enumerate(out) if 0 < n < 7)]  # the head out, most of the body in
    assert copy_view(cam, view, person.joints, np.array([0, 0, dz]), min_inside=1.0) is None
    lenient = copy_view(cam, view, person.joints, np.array([0, 0, dz]), min_inside=0.5)
    dropped = lenient.keypoints[:, 2] == 0
    assert 1 < dropped.sum() < 8 and np.isnan(lenient.keypoints[dropped, :2]).all()
    assert not lenient.heatmap.maps[dropped].any()


def test_copies_do_not_merge_in_association(rig):
    frames = _frames(rig, [(-1.0, 0.0), (1.0, 0.5)])
    offsets = np.array([[0, 0, 0], [0, 3.0, 0], [3.0, 0, 0], [-3.0, -3.0, 0]])
    counts = []
    for k in range(1, len(offsets) + 1):
        scene = multiply_scene(rig, range(len(frames)), frames, 0, offsets=offsets[:k])
        associator = Associator(rig, AssociationConfig())
        found = [len(associator.update(f / FRAME_RATE, people)) for f, people in enumerate(scene.people)]
        counts.append(found)
        assert all(len(per_camera) == 2 * k for per_camera in scene.people[0])
    assert counts == [[2 * k] * len(frames) for k in range(1, len(offsets) + 1)]  # linear in copies


def test_offsets_reach_the_target_and_keep_people_apart(rig):
    frames = _frames(rig, [(-1.0, 0.0), (1.0, 0.5)])
    scene = scene_people(rig, range(len(frames)), frames)
    offsets, expected = choose_offsets(rig, scene, 6, sample_every=1)
    assert len(offsets) == 3 and not offsets[0].any() and (offsets[:, 2] == 0).all()
    assert expected == pytest.approx(6)
    centres = np.array([[p.centre[:2] + d[:2] for d in offsets for p in scene[f]] for f in range(len(scene))])
    gaps = np.linalg.norm(centres[:, :, None] - centres[:, None], axis=-1)
    assert gaps[:, ~np.eye(centres.shape[1], dtype=bool)].min() >= 0.6
    # a target the scene already has: no copies
    assert len(choose_offsets(rig, scene, 2)[0]) == 1


def test_line_plot_writes_a_png_of_the_size_with_the_series_drawn(tmp_path):
    red = (0, 0, 255)
    path = line_plot(tmp_path / 'p.png', [Series('total', [1, 2, 5], [3.0, 6.5, 14.0], color=red),
                                          Series('bp', [1, 2, 5], [1.0, 2.0, float('nan')])],
                     title='t', xlabel='people', ylabel='ms', size=(640, 400))
    img = cv2.imread(str(path))
    assert img.shape == (400, 640, 3)
    assert (img < 250).any(axis=-1).mean() > 0.01  # not blank
    assert np.all(img == red, axis=-1).sum() > 100  # the red line and its markers


def test_nice_ticks_are_round_and_cover_the_range():
    ticks = nice_ticks(0, 37.3)
    assert ticks[0] == 0 and ticks[-1] >= 37.3 and np.allclose(np.diff(ticks), ticks[1] - ticks[0])
    assert ticks[1] in (5, 10)


GRAPH = bench_runs.default_graph_config()


def test_the_default_row_is_the_graph_config():
    params = load_params(REPO / 'config' / 'shelf.yaml')['bp_solver']
    assert GRAPH.stage() == StageConfig.from_params(params)
    assert (GRAPH.settings['window'], GRAPH.settings['lag']) == (params['window'], params['lag'])
    assert bench_runs.OFFLINE.stage() == StageConfig()


def test_a_runs_stage_settings_are_the_stage_parameters_and_survive_json():
    assert set(GRAPH.settings) == set(StageConfig().to_params())
    wider = GRAPH.with_settings(window=10, lag=5)
    assert wider.stage().solver.inference.window == 10 and GRAPH.settings['window'] == 6  # a copy changed
    assert bench_runs.RunConfig.from_dict(json.loads(json.dumps(asdict(wider)))) == wider
    assert GRAPH.with_settings(window=6).key() == GRAPH.key() != wider.key()
    with pytest.raises(ValueError, match='windows'):
        GRAPH.with_settings(windows=10)


def test_plan_measures_each_setting_once():
    runs = bench_runs.plan(GRAPH, 100, 'quick', {'people': (3, 10)})
    assert runs[0] == replace(GRAPH, frames=100) and runs[1].name.startswith('offline')
    sweeps = {s: [r for r in runs if r.sweep == s] for s in bench_runs.SWEEPS}
    assert [r.cameras for r in sweeps['cameras']] == [1, 2, 3, 4, 5]
    assert [r.people for r in sweeps['people']] == [None, 10.0]
    assert all(r.frames == bench_runs.QUICK_FRAMES for s in sweeps.values() for r in s)
    assert len({r.key() for r in runs}) < len(runs)  # cameras=5, people~3, window=8, M=64: one run


def test_plan_adds_the_paced_default_row_only_when_asked():
    runs = bench_runs.plan(GRAPH, 100, 'none', {}, pace=25.0)
    assert runs[0] == replace(GRAPH, frames=100) and runs[2].name.startswith('offline') and len(runs) == 3
    assert runs[1] == replace(GRAPH, frames=100, pace=25.0, name='graph (default) at 25 Hz')
    assert runs[1].key() != runs[0].key()  # measured on its own
    assert all(not r.pace for r in bench_runs.plan(GRAPH, 100, 'quick', {}))


class _FakeClock:
    """time for bench.runs: a clock that only sleep() moves, and sleep() does not sleep. Work
    then takes no time on it, so a paced run's waits and wall time are exact."""

    def __init__(self) -> None:
        self.now = 0.0
        self.waits: list[float] = []

    def perf_counter(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.waits.append(seconds)
        self.now += seconds


def test_a_paced_run_waits_for_each_frame_and_gives_the_same_results(monkeypatch):
    clock = _FakeClock()
    monkeypatch.setattr(bench_runs, 'time', clock)
    paced = bench_runs.run_config(replace(GRAPH, frames=4, pace=1.0))
    monkeypatch.undo()
    back = bench_runs.run_config(replace(GRAPH, frames=4))
    assert clock.waits == [0.0, 1.0, 1.0, 1.0]  # frame i is due i / pace after the first
    assert paced['stage_wall_s'] == 0.0 and paced['frame_ms'] == {'p50': 0.0, 'p95': 0.0}  # the waits are not work
    assert paced['pcp'] == back['pcp'] and paced['people_3d'] == back['people_3d'] > 0
    assert 0 < back['frame_ms']['p50'] <= back['frame_ms']['p95']


def test_the_paced_line_sets_the_paced_run_beside_the_same_run_back_to_back(capsys):
    def fake(pace, p50, p95, cameras=5):
        return {'config': asdict(replace(GRAPH, pace=pace, cameras=cameras)), 'frame_ms': {'p50': p50, 'p95': p95}}
    bench_report.print_paced([fake(0.0, 4.0, 5.0), fake(25.0, 6.0, 8.0), fake(30.0, 9.0, 9.5, cameras=4),
                              {**fake(0.0, 1.0, 1.0, cameras=3), 'error': 'exit 1'}, fake(30.0, 2.0, 2.0, cameras=3)],
                             sys.stdout)
    lines = [line for line in capsys.readouterr().out.splitlines() if line]
    # a paced run whose twin did not run back to back (or failed) has nothing to be set beside
    assert lines == ['fed at 25 Hz (sleeping between frames): from 2D people p50 / p95 6.00 / 8.00 ms per frame; '
                     'back to back 4.00 / 5.00 ms (x1.50 at the median)']


def test_one_camera_gives_no_people_and_no_crash():
    result = bench_runs.run_config(replace(GRAPH, frames=3, cameras=1))
    assert result['people_3d'] == 0 and result['frames_out'] == 3 and result['pcp']['strict_frame_weighted'] == 0


@pytest.mark.slow
def test_smoke_prints_every_stage_and_the_frame_rates(tmp_path, capsys):
    assert bench.main(['--frames', '5', '--scaling', 'none', '--output', str(tmp_path)]) == 0
    out = capsys.readouterr().out
    for stage in ('grouping and heatmaps', 'tracking and matching', 'sampling', 'data term', 'BP'):
        assert stage in out
    assert 'whole 3D stage' in out and 'from 2D people' in out and 'frames/s' in out
    data = json.loads((tmp_path / 'bench.json').read_text())
    names = [r['config']['name'] for r in data['runs']]
    assert names == ['graph (default)', 'offline (mvpose-eval)']
    for r in data['runs']:
        assert r['frames'] == 5 and r['figures']['fps'] > 0 and r['peak_rss_kib'] > r['rss_start_kib'] > 0
        assert {'grouping and heatmaps', 'association', 'sampling', 'data term'} <= set(r['stages_s'])
    assert 'on two processes' in out and data['two_processes']['frames'] == 5
    assert data['two_processes']['pcp'] == data['runs'][0]['pcp']  # the same solver on the same input


def test_two_processes_give_the_results_of_one():
    shelf = dataset_dir('shelf')
    cameras = shelf_cameras()
    files = [read_body25(shelf / 'openpose_body25' / f'{c}.txt')[:20] for c in range(len(cameras))]
    frames = list(range(300, 320))
    raw = [[f[k] for f in files] for k in range(len(frames))]
    detector = OpenPoseDetectorConfig(stride=8.0)
    config = StageConfig.from_params({'window': 6, 'lag': 3})
    two = run_two_processes(cameras, frames, raw, detector, config)
    stage, one = Stage3D(cameras, config), []
    for frame, per_camera in zip(frames, raw):
        one += stage.push(frame, [detect_people(f, detector) for f in per_camera])
    one += stage.flush()
    assert [r.frame for r in two.results] == frames == [r.frame for r in one]
    for a, b in zip(two.results, one):
        assert a.person_ids == b.person_ids and len(a.person_ids) >= 2
        np.testing.assert_array_equal(a.joints, b.joints)
    assert {'grouping and heatmaps', 'association', 'sampling', 'bp'} <= set(two.seconds) and two.wall_s > 0


def test_crowd_lines_give_the_time_per_person_of_each_people_run(capsys):
    def fake(name, sweep, people, seconds):
        config = {**asdict(replace(GRAPH, sweep=sweep)), 'name': name}
        return {'config': config, 'frames': 10, 'cameras': 5, 'people_3d': people,
                'stages_s': {'grouping and heatmaps': 1.0, 'association': seconds / 2, 'sampling': seconds / 2}}
    bench_report.print_crowds([fake('graph (default)', None, 3.2, 0.1), fake('people~20', 'people', 19.5, 0.39),
                               fake('people~40', 'people', 0.0, 0.0)], sys.stdout)
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[0].startswith('crowd scenes') and len(lines) == 2  # only people runs with people
    assert lines[1].split() == ['people~20', '19.5', '3D', 'people', 'per', 'frame', '39.00', 'ms/frame', '->', '2.00',
                                'ms', 'per', 'person']


def test_plots_of_the_sweeps(tmp_path):
    def fake(sweep, value, people, ms):
        config = replace(GRAPH, sweep=sweep, cameras=value if sweep == 'cameras' else 5)
        stages = {'grouping and heatmaps': ms / 4000, 'association': ms / 4000, 'sampling': ms / 2000}
        return {'config': asdict(config), 'frames': 1, 'cameras': config.cameras, 'people_3d': people,
                'stages_s': stages}
    results = [fake('cameras', k, 3.0 if k > 1 else 0.0, 5.0 * k) for k in (1, 2, 3)]
    results += [fake('people', 0, p, 3.0 * p) for p in (3.1, 9.0, 17.5)]
    paths = bench_report.write_plots(results, tmp_path)
    assert sorted(p.name for p in paths) == ['time_vs_cameras.png', 'time_vs_people.png']
    assert all(cv2.imread(str(p)).shape == (620, 1000, 3) for p in paths)
