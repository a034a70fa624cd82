"""actorsGT loading and the datasets' facts on the real Shelf and Campus files."""
from __future__ import annotations

import numpy as np
import pytest

from mvpose_ros.core.datasets.shelf_campus import (CAMPUS_TEST_FRAMES, SHELF_TEST_FRAMES, dataset_dir, load_actors_gt,
                                                   load_actors_gt_2d)


@pytest.fixture(scope='module')
def shelf_mat():
    return dataset_dir('shelf') / 'actorsGT.mat'


def test_test_ranges():
    assert len(SHELF_TEST_FRAMES) == 301 and SHELF_TEST_FRAMES[0] == 300
    assert len(CAMPUS_TEST_FRAMES) == 222


def test_shelf_3d_test_frames(shelf_mat):
    gt = load_actors_gt(shelf_mat, SHELF_TEST_FRAMES)
    assert gt.poses.shape == (301, 4, 14, 3)
    np.testing.assert_array_equal(gt.frames, np.arange(300, 601))
    # What the file holds for frames 300..600 (0-based).
    np.testing.assert_array_equal(gt.present.sum(axis=0), [279, 37, 161, 33])
    # An actor is either fully annotated or fully NaN.
    finite = np.isfinite(gt.poses)
    assert np.all(finite.all(axis=(-2, -1)) | ~finite.any(axis=(-2, -1)))
    # Metres, z up: ankles near the floor, head tops at standing height.
    people = gt.poses[gt.present]
    assert np.all(people[:, [0, 5], 2] < 0.35)
    assert np.all((people[:, 13, 2] > 1.0) & (people[:, 13, 2] < 2.1))
    # Spot value straight from the file: actor 0, frame 300, right ankle.
    np.testing.assert_allclose(gt.poses[0, 0, 0], [-0.14304384, -0.09228449, -0.04118636],
                               atol=1e-8)


def test_annotated_gives_the_actors_of_a_frame_and_their_poses(shelf_mat):
    gt = load_actors_gt(shelf_mat, [300, 572])
    actors, poses = gt.annotated(1)
    assert actors.tolist() == [0, 2, 3]  # frame 572 annotates actors 1, 3 and 4
    np.testing.assert_array_equal(poses, gt.poses[1, [0, 2, 3]])
    assert np.isfinite(poses).all() and not np.isfinite(gt.poses[1, 1]).any()


def test_shelf_all_frames(shelf_mat):
    gt = load_actors_gt(shelf_mat)
    assert gt.poses.shape == (3200, 4, 14, 3)
    np.testing.assert_array_equal(gt.present.sum(axis=0), [433, 73, 424, 250])
    with pytest.raises(IndexError):
        load_actors_gt(shelf_mat, [3200])


def test_shelf_2d_matches_3d_presence(shelf_mat):
    uv = load_actors_gt_2d(shelf_mat, SHELF_TEST_FRAMES)
    gt = load_actors_gt(shelf_mat, SHELF_TEST_FRAMES)
    assert uv.shape == (301, 4, 5, 14, 2)
    np.testing.assert_array_equal(np.isfinite(uv).all(axis=(2, 3, 4)), gt.present)
    assert np.isnan(uv[~gt.present]).all()
    np.testing.assert_allclose(uv[0, 0, 0, 0], [244.17184684, 794.9880006], atol=1e-6)


def test_campus_subset():
    mat = dataset_dir('campus') / 'mmpose_subset' / 'actorsGT.mat'
    gt = load_actors_gt(mat)
    assert gt.poses.shape == (3, 3, 14, 3)
    np.testing.assert_array_equal(gt.present, [[True, False, False]] * 3)
    uv = load_actors_gt_2d(mat, [1, 2])
    assert uv.shape == (2, 3, 3, 14, 2)
    assert uv.dtype == float  # cameras 0 and 1 are stored as integers
    assert np.isfinite(uv[:, 0]).all() and np.isnan(uv[:, 1:]).all()
