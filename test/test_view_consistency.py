"""Views a person's other views contradict are left out before 3D (core/association/view_consistency).

Synthetic: the Shelf ground truth projected into the real Shelf cameras with ~2 px noise, one view
replaced by a skeleton drawn partly on somebody else (what a half-hidden person gives). Real: the
frame-572 images without camera 3, where camera 1's skeleton of actor 3 is partly drawn on the man
in front of him.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mvpose_ros.core.association.associator import AssociationConfig, Associator
from mvpose_ros.core.association.matching import ViewRays
from mvpose_ros.core.association.view_consistency import consistent_views, leave_one_out_residuals
from mvpose_ros.core.datasets.shelf_campus import dataset_dir, load_actors_gt
from mvpose_ros.core.defaults import data_root
from mvpose_ros.core.geometry.camera import Camera
from mvpose_ros.core.geometry.rays import closest_point_to_rays, line_terms, solve_line_terms
from mvpose_ros.core.stage import Stage3D, StageConfig
from mvpose_ros.core.types import Person2D
from test_matching import _inference_points, _skeleton

SHELF = dataset_dir('shelf')
FRAME = 580  # actors 0, 1, 2 annotated
MIN_SCORE = 0.1
THRESHOLD = AssociationConfig().max_view_residual


@pytest.fixture(scope='module')
def pose() -> np.ndarray:
    """(14, 3) actor 0 at FRAME, metres."""
    return load_actors_gt(SHELF / 'actorsGT.mat', [FRAME]).poses[0, 0]


def _views(rig, pose, rng, cameras, bad=None, shift=np.zeros(3)):
    """One skeleton per camera of `cameras`; camera `bad`'s has its limbs drawn `shift` metres away
    and its head in place, as a detector mixing two people does."""
    people = []
    for c in cameras:
        moved = pose.copy()
        if c == bad:
            moved[:12] += shift
        people.append([_skeleton(rig[c], moved, rng)])
    return people


def _rows(people):
    return [list(range(len(people)))]


def test_residuals_equal_a_triangulation_without_each_view(shelf_rig, pose):
    rng = np.random.default_rng(0)
    cameras = [0, 1, 2, 3, 4]
    people = _views(shelf_rig, pose, rng, cameras, bad=1, shift=np.array([0.3, 0.0, 0.0]))
    rig = [shelf_rig[c] for c in cameras]
    rays = ViewRays.of(rig, people)
    got = leave_one_out_residuals(rig, rays, _rows(people), MIN_SCORE)[0]
    kp = rays.keypoints
    for out in range(len(cameras)):
        rest = [v for v in range(len(cameras)) if v != out]
        points = np.array([closest_point_to_rays(rays.origins[rest], rays.dirs[rest, j]) for j in range(kp.shape[1])])
        for v in range(len(cameras)):
            error = np.linalg.norm(rig[v].project(points) - kp[v, :, :2], axis=1)
            size = np.linalg.norm(kp[v, :, :2].max(axis=0) - kp[v, :, :2].min(axis=0))
            assert got[out, v] == pytest.approx(np.median(error) / size, rel=1e-6)


def _residuals_by_arrays(cameras, rays, people, min_score):
    """leave_one_out_residuals written with numpy arrays: line terms of every view summed, minus
    each view's own, solved; each view's keypoints against those joints projected."""
    width = max(len(v) for v in people)
    out = np.full((len(people), width, width), np.nan)
    for p, views in enumerate(people):
        seen = np.zeros((width, rays.keypoints.shape[1]), dtype=bool)
        seen[:len(views)] = rays.keypoints[views, :, 2] > min_score
        terms = np.zeros((9, width) + seen.shape[1:])
        terms[:, :len(views)] = line_terms(rays.origins[views][:, None], rays.dirs[views])
        terms *= seen
        points = solve_line_terms(terms.sum(axis=1, keepdims=True) - terms, width)  # (out, J, 3)
        points[seen.sum(axis=0) - seen < 2] = np.nan
        for v, row in enumerate(views):
            kp = rays.keypoints[row]
            error = np.linalg.norm(cameras[rays.owner[row]].project(points) - kp[:, :2], axis=-1)  # (out, J)
            error = np.where(seen[v] & np.isfinite(error), error, np.nan)
            box = kp[seen[v], :2]
            size = np.hypot(*(box.max(axis=0) - box.min(axis=0))) if len(box) else np.nan
            finite = np.isfinite(error).any(axis=1)
            out[p, finite, v] = np.nanmedian(error[finite], axis=1) / (size if size > 0 else np.nan)
    return out


def _distorted_rig(rng):
    """Three cameras a few metres from the origin looking at it, with lens distortion."""
    rig = []
    for c, angle in enumerate((0.0, 2.0, 4.0)):
        centre = np.array([4.0 * np.cos(angle), 4.0 * np.sin(angle), 1.5])
        forward = -centre / np.linalg.norm(centre)
        right = np.cross(forward, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        R = np.stack([right, np.cross(forward, right), forward])
        K = np.array([[800.0, 0.0, 500.0], [0.0, 800.0, 400.0], [0.0, 0.0, 1.0]])
        rig.append(Camera(str(c), K, R, -R @ centre, rng.normal(0.0, 0.05, 5), 1000, 800))
    return rig


def _random_people(rng, rig, views_per_person, noise_px=5.0, shifted=0.0):
    """People of the given numbers of views (each camera once) at random joints, seen with
    noise_px of noise; some joints unseen, some views with one joint only, a share `shifted` of
    the views drawn about 0.5 m off, each its own way. Their rays and each person's rows of them."""
    people = []
    for n_views in views_per_person:
        joints = rng.normal([0.0, 0.0, 1.0], 0.4, (16, 3))
        views = []
        for c in rng.choice(len(rig), min(n_views, len(rig)), replace=False):
            moved = joints + (rng.random() < shifted) * rng.choice([-0.3, 0.3], 3)
            uv = rig[c].project(moved) + rng.normal(0.0, noise_px, (16, 2))
            score = np.where(rng.random(16) < 0.3, 0.0, 0.9)
            if rng.random() < 0.2:
                score[1:] = 0.0
            views.append((c, np.column_stack([uv, score])))
        people.append(views)
    by_camera = [[kp for views in people for c, kp in views if c == cam] for cam in range(len(rig))]
    rays = ViewRays.of(rig, [[Person2D(kp, None) for kp in kps] for kps in by_camera])
    first = np.concatenate([[0], np.cumsum([len(k) for k in by_camera])])
    taken = [0] * len(rig)
    rows = []
    for views in people:
        rows.append([])
        for c, _ in views:
            rows[-1].append(int(first[c] + taken[c]))
            taken[c] += 1
    return rays, rows


@pytest.mark.parametrize('distorted', [False, True])
def test_residuals_equal_the_array_formulation_on_random_people(shelf_rig, distorted):
    """Random joints seen by random views (some joints by fewer than three, some views by one
    joint), people of one to five views, on the Shelf rig and a distorted one."""
    rng = np.random.default_rng(5)
    rig = _distorted_rig(rng) if distorted else shelf_rig
    rays, rows = _random_people(rng, rig, (5, 2, 3, 4, 3, 1))
    got = leave_one_out_residuals(rig, rays, rows, MIN_SCORE)
    expected = _residuals_by_arrays(rig, rays, rows, MIN_SCORE)
    np.testing.assert_allclose(got, expected, rtol=1e-12, equal_nan=True)
    assert leave_one_out_residuals(rig, rays, [], MIN_SCORE).shape == (0, 0, 0)


def _consistent_by_rounds(cameras, rays, people, min_score, max_residual):
    """consistent_views written as rounds over every person still checked, on
    leave_one_out_residuals of them all at once."""
    kept = [list(v) for v in people]
    active = [p for p, v in enumerate(kept) if len(v) >= 3]
    while active:
        r = leave_one_out_residuals(cameras, rays, [kept[p] for p in active], min_score)
        left_out = np.diagonal(r, axis1=1, axis2=2)
        spread = np.where(np.eye(r.shape[1], dtype=bool) | np.isnan(r), -np.inf, r).max(axis=2)
        candidate = np.isfinite(left_out) & np.isfinite(spread)
        worst = np.argmin(np.where(candidate, spread, np.inf), axis=1)
        out, rest = left_out[np.arange(len(active)), worst], spread[np.arange(len(active)), worst]
        drop = candidate.any(axis=1) & (out > max_residual) & (rest < out)
        for row in np.flatnonzero(drop):
            del kept[active[row]][worst[row]]
        active = [active[row] for row in np.flatnonzero(drop) if len(kept[active[row]]) >= 3]
    return kept


@pytest.mark.parametrize('seed', range(4))
def test_consistent_views_equal_the_rounds_on_random_people(shelf_rig, seed):
    """Random people of two to five views, a third of the views drawn off (some people lose two:
    more than one round), with little noise; and people without any view."""
    rng = np.random.default_rng(seed)
    rays, rows = _random_people(rng, shelf_rig, (5, 5, 4, 3, 2, 5, 4, 3), noise_px=1.0, shifted=0.35)
    kept = consistent_views(shelf_rig, rays, rows, MIN_SCORE, THRESHOLD)
    assert kept == _consistent_by_rounds(shelf_rig, rays, rows, MIN_SCORE, THRESHOLD)
    assert kept != rows
    assert consistent_views(shelf_rig, rays, rows + [[]], MIN_SCORE, THRESHOLD) == kept + [[]]
    assert consistent_views(shelf_rig, rays, [], MIN_SCORE, THRESHOLD) == []


@pytest.mark.parametrize('cameras', [(0, 1, 2, 3, 4), (0, 1, 2, 4), (1, 2, 3)])
def test_a_view_drawn_partly_on_someone_else_is_left_out(shelf_rig, pose, cameras):
    rng = np.random.default_rng(1)
    bad = cameras[1]
    people = _views(shelf_rig, pose, rng, cameras, bad=bad, shift=np.array([0.0, 0.4, 0.0]))
    rig = [shelf_rig[c] for c in cameras]
    kept = consistent_views(rig, ViewRays.of(rig, people), _rows(people), MIN_SCORE, THRESHOLD)
    assert kept == [[v for v in range(len(cameras)) if cameras[v] != bad]]


@pytest.mark.parametrize('cameras', [(0, 1, 2, 3, 4), (0, 1, 2, 4), (1, 2, 3)])
def test_views_that_agree_are_all_kept(shelf_rig, pose, cameras):
    rng = np.random.default_rng(2)
    people = _views(shelf_rig, pose, rng, cameras)
    rig = [shelf_rig[c] for c in cameras]
    rays = ViewRays.of(rig, people)
    assert consistent_views(rig, rays, _rows(people), MIN_SCORE, THRESHOLD) == _rows(people)
    assert np.nanmax(leave_one_out_residuals(rig, rays, _rows(people), MIN_SCORE)) < 0.3 * THRESHOLD


def test_two_views_are_never_split_and_zero_keeps_every_view(shelf_rig, pose):
    rng = np.random.default_rng(3)
    shift = np.array([0.0, 0.4, 0.0])
    two = _views(shelf_rig, pose, rng, (0, 2), bad=2, shift=shift)
    rig = [shelf_rig[0], shelf_rig[2]]
    assert consistent_views(rig, ViewRays.of(rig, two), _rows(two), MIN_SCORE, THRESHOLD) == [[0, 1]]
    five = _views(shelf_rig, pose, rng, range(5), bad=1, shift=shift)
    assert consistent_views(shelf_rig, ViewRays.of(shelf_rig, five), _rows(five), MIN_SCORE, 0.0) == _rows(five)


def test_the_associator_bundles_the_person_without_the_contradicted_view(shelf_rig, pose):
    people = _views(shelf_rig, pose, np.random.default_rng(4), range(5), bad=3, shift=np.array([0.4, 0.0, 0.0]))
    (checked,) = Associator(shelf_rig, AssociationConfig()).update(0, people)
    (unchecked,) = Associator(shelf_rig, AssociationConfig(max_view_residual=0.0)).update(0, people)
    assert sorted(checked.views) == [0, 1, 2, 4]
    assert sorted(unchecked.views) == [0, 1, 2, 3, 4]
    truth = _inference_points(pose).mean(axis=0)
    assert np.linalg.norm(checked.centre - truth) < 0.02 < np.linalg.norm(unchecked.centre - truth)


def test_frame_572_without_camera_3_places_actor_3_from_his_consistent_views():
    """Camera 1 sees actor 3 half behind another man; with cameras 0, 1, 2, 4 its skeleton and one
    other view agree by chance on hips and knees 0.4 m off. Left out, actor 3 comes out closer
    (measured: 65 mm against 81 mm with every view kept)."""
    from mvpose_ros.core.detection.image_file import read_image
    from mvpose_ros.core.detection.onnx_detector import OnnxDetectorConfig, OnnxPoseDetector
    from mvpose_ros.core.geometry.camera import load_rig

    cameras = (0, 1, 2, 4)
    rig = load_rig(SHELF / 'calibration' / 'calibration_shelf.json', 1032, 776)
    rig = [rig[c] for c in cameras]
    detector = OnnxPoseDetector(OnnxDetectorConfig(model_dir=data_root() / 'models'))
    people = detector.detect_set([read_image(Path(SHELF / 'frames' / f'cam{c}_000572.png')) for c in cameras])
    actor_3 = load_actors_gt(SHELF / 'actorsGT.mat', [572]).poses[0, 2]

    def mpjpe(residual: float) -> float:
        stage = Stage3D(rig, StageConfig.from_params({'window': 0, 'max_view_residual': residual}))
        (result,) = stage.push(572, people) + stage.flush()
        return float(np.linalg.norm(result.joints - actor_3, axis=-1).mean(axis=1).min())

    assert mpjpe(THRESHOLD) < mpjpe(0.0) - 0.01
