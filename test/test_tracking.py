"""Box IoU against hand-computed values and the per-camera IoU tracker's id bookkeeping."""
from __future__ import annotations

import numpy as np
import pytest

from mvpose_ros.core.geometry.body import NUM_INFERENCE_JOINTS
from mvpose_ros.core.heatmap import PersonHeatmap
from mvpose_ros.core.types import Person2D
from mvpose_ros.core.association.tracking import IouTracker, box_iou, shared_box_iou

EMPTY_MAPS = PersonHeatmap(np.zeros((NUM_INFERENCE_JOINTS, 1, 1), np.float32), np.zeros(2), 1.0)


def _person(u0: float, v0: float, u1: float, v1: float) -> Person2D:
    """A skeleton whose detected keypoints span exactly the box; two joints are undetected and
    lie outside it, so the box must come from detected joints only."""
    rng = np.random.default_rng(int(u0 * 7 + v0))
    uv = rng.uniform((u0, v0), (u1, v1), (NUM_INFERENCE_JOINTS, 2))
    uv[:4] = [(u0, v0), (u1, v1), (u0, v1), (u1, v0)]
    kp = np.column_stack([uv, np.full(NUM_INFERENCE_JOINTS, 0.8)])
    kp[-2:] = [(u1 + 500, v1 + 500, 0.0), (np.nan, np.nan, 0.0)]
    return Person2D(kp, EMPTY_MAPS)


def _shifted(box: tuple[float, float, float, float], du: float) -> Person2D:
    u0, v0, u1, v1 = box
    return _person(u0 + du, v0, u1 + du, v1)


@pytest.mark.parametrize('a, b, expected', [
    ((0, 0, 2, 2), (1, 1, 3, 3), 1 / 7),          # corner overlap: 1 / (4 + 4 - 1)
    ((0, 0, 4, 4), (1, 1, 3, 3), 4 / 16),         # contained
    ((0, 0, 2, 2), (0, 0, 2, 2), 1.0),            # identical
    ((0, 0, 2, 2), (2, 0, 4, 2), 0.0),            # touching edges
    ((0, 0, 2, 2), (5, 5, 6, 6), 0.0),            # disjoint
    ((0, 0, 10, 4), (5, 2, 15, 10), 10 / 110),    # 5x2 overlap of areas 40 and 80
])
def test_box_iou_hand_values(a, b, expected):
    iou = box_iou(np.array([a], float), np.array([b], float))
    assert iou.shape == (1, 1)
    assert iou[0, 0] == pytest.approx(expected, abs=1e-12)
    assert box_iou(np.array([b], float), np.array([a], float))[0, 0] == pytest.approx(expected, abs=1e-12)


def test_box_iou_is_pairwise_and_degenerate_boxes_give_zero():
    a = np.array([[0, 0, 2, 2], [1, 1, 3, 3], [5, 5, 5, 5]], float)  # last: a point, zero area
    b = np.array([[0, 0, 2, 2], [5, 5, 5, 5]], float)
    iou = box_iou(a, b)
    np.testing.assert_allclose(iou, [[1, 0], [1 / 7, 0], [0, 0]], atol=1e-12)
    assert box_iou(np.zeros((0, 4)), b).shape == (0, 2)


def _iou_by_arrays(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    lo = np.maximum(a[:, None, :2], b[None, :, :2])
    hi = np.minimum(a[:, None, 2:], b[None, :, 2:])
    inter = np.prod(np.clip(hi - lo, 0.0, None), axis=-1)
    union = np.prod(a[:, 2:] - a[:, :2], axis=-1)[:, None] + np.prod(b[:, 2:] - b[:, :2], axis=-1)[None] - inter
    with np.errstate(invalid='ignore', divide='ignore'):
        return np.where(union > 0, inter / union, 0.0)


@pytest.mark.parametrize('n, k', [(6, 7), (1, 1), (0, 3), (3, 0)])
def test_box_iou_equals_the_array_formulation(n, k):
    """Random boxes, some sharing edges, some points, some NaN (a person with no keypoint)."""
    rng = np.random.default_rng(n * 10 + k)
    corners = rng.integers(0, 20, (n + k, 2, 2)).astype(float)
    boxes = np.concatenate([corners.min(axis=1), corners.max(axis=1)], axis=1)
    boxes[rng.random(n + k) < 0.2] = np.nan
    a, b = boxes[:n], boxes[n:]
    np.testing.assert_array_equal(box_iou(a, b), _iou_by_arrays(a, b))


def test_shared_box_iou_equals_the_array_formulation():
    """Random keypoints, a third undetected, one person with none detected, one with a NaN on a
    detected keypoint (its displacement counts as the largest; were it kept, numpy's min and max
    would give NaN there, and the pair IoU 0): each pair's boxes over the keypoints both detect less
    the fifth that moved most, then box_iou."""
    rng = np.random.default_rng(0)
    kp = np.concatenate([rng.uniform(0, 1000, (6, NUM_INFERENCE_JOINTS, 2)),
                         np.where(rng.random((6, NUM_INFERENCE_JOINTS, 1)) < 0.3, 0.0, 0.7)], axis=-1)
    kp[kp[..., 2] == 0, :2] = np.nan
    kp[1, :, 2] = 0.0
    kp[2, 3] = (np.nan, 5.0, 0.9)
    a, b = kp[:4], kp[2:] + [3.0, -2.0, 0.0]
    expected = np.zeros((len(a), len(b)))
    for i, k in np.ndindex(*expected.shape):
        both = np.flatnonzero((a[i, :, 2] > 0) & (b[k, :, 2] > 0))
        if len(both):
            moved = np.nan_to_num(((a[i, both, :2] - b[k, both, :2]) ** 2).sum(axis=1), nan=np.inf)
            kept = both[np.argsort(moved, kind='stable')[:len(both) - len(both) // 5]]
            boxes = [np.concatenate([x[kept, :2].min(axis=0), x[kept, :2].max(axis=0)]) for x in (a[i], b[k])]
            expected[i, k] = box_iou(boxes[0][None], boxes[1][None])[0, 0]
    np.testing.assert_array_equal(shared_box_iou(a, b), expected)
    assert shared_box_iou(a, np.zeros((0, NUM_INFERENCE_JOINTS, 3))).shape == (4, 0)


def test_bbox_uses_detected_keypoints_only():
    np.testing.assert_allclose(_person(10, 20, 110, 220).bbox(), [10, 20, 110, 220])


def test_small_motion_keeps_ids_and_ids_follow_boxes_not_list_order():
    tracker = IouTracker(0.7)
    boxes = [(0, 0, 100, 200), (300, 0, 400, 200), (600, 50, 700, 250)]
    first = [_person(*b) for b in boxes]
    tracker.update(first)
    assert [p.track_id for p in first] == [0, 1, 2]
    # shift by 10 px: IoU 90 / 110 = 0.82; the new frame lists the people in another order
    order = [2, 0, 1]
    second = [_shifted(boxes[k], 10) for k in order]
    tracker.update(second)
    assert [p.track_id for p in second] == order
    third = [_shifted(boxes[k], 20) for k in (1, 2, 0)]
    tracker.update(third)
    assert [p.track_id for p in third] == [1, 2, 0]


@pytest.mark.parametrize('du, same', [(10, True), (17, True), (18, False), (20, False), (60, False)])
def test_threshold_on_overlap(du, same):
    """Box 100 x 200 moved du px along u: IoU (100 - du) / (100 + du); 0.7 lies between 17 and 18."""
    tracker = IouTracker(0.7)
    before = _person(0, 0, 100, 200)
    tracker.update([before])
    after = _shifted((0, 0, 100, 200), du)
    tracker.update([after])
    assert (after.track_id == before.track_id) == same
    if not same:
        assert after.track_id == 1


def test_iou_exactly_at_threshold_keeps_the_id():
    tracker = IouTracker(0.7)
    before = _person(0, 0, 170, 100)
    tracker.update([before])
    after = _person(30, 0, 200, 100)  # IoU = 140 / 200 = 0.7 exactly
    tracker.update([after])
    assert after.track_id == before.track_id


def test_close_people_are_assigned_one_to_one():
    tracker = IouTracker(0.7)
    a, b = (0, 0, 100, 200), (12, 0, 112, 200)  # IoU(a, b) = 88 / 112 = 0.79
    tracker.update([_person(*a), _person(*b)])
    # both move right by 8: the new a overlaps b's old box more than its own (0.92 vs 0.85), so
    # only the best total (one-to-one) assignment keeps the identities apart
    new_a, new_b = _shifted(a, 8), _shifted(b, 8)
    iou = box_iou(np.array([new_a.bbox(), new_b.bbox()]), np.array([a, b], float))
    assert iou[0, 1] > iou[0, 0] >= 0.7 and iou[1, 1] >= 0.7
    tracker.update([new_a, new_b])
    assert (new_a.track_id, new_b.track_id) == (0, 1)


def test_one_box_over_two_tracks_takes_one_id():
    tracker = IouTracker(0.7)
    tracker.update([_person(0, 0, 100, 200), _person(10, 0, 110, 200)])
    merged = _person(5, 0, 105, 200)
    tracker.update([merged])
    assert merged.track_id in (0, 1)
    # the track it did not take is gone: the same box again keeps the merged id only
    again = [_person(5, 0, 105, 200), _person(400, 0, 500, 200)]
    tracker.update(again)
    assert again[0].track_id == merged.track_id
    assert again[1].track_id == 2


def test_new_people_get_fresh_ids_never_reused():
    tracker = IouTracker(0.7)
    seen: list[int] = []
    a, b = (0, 0, 100, 200), (500, 0, 600, 200)
    for frame in ([a], [a, b], [b], [], [a, b], [(900, 0, 1000, 200)]):
        people = [_person(*box) for box in frame]
        tracker.update(people)
        seen.append([p.track_id for p in people])
    # a: 0; b appears: 1; a leaves, b stays 1; nobody; both come back as new tracks 2, 3; a
    # stranger: 4. Ids of tracks that ended are never handed out again.
    assert seen == [[0], [0, 1], [1], [], [2, 3], [4]]


def test_empty_frames_are_fine():
    tracker = IouTracker(0.7)
    tracker.update([])
    p = _person(0, 0, 50, 50)
    tracker.update([p])
    assert p.track_id == 0


def test_a_person_walking_out_of_the_image_keeps_his_track():
    """His lower joints leave the image (undetected) as he moves 3 px: the box over all his
    keypoints halves (IoU 0.5), the boxes over the keypoints both frames detect barely move."""
    tracker = IouTracker(0.7)
    v = np.linspace(100.0, 400.0, NUM_INFERENCE_JOINTS)  # head to feet
    u = 150.0 + 50.0 * np.cos(np.arange(NUM_INFERENCE_JOINTS))
    before = Person2D(np.column_stack([u, v, np.full_like(u, 0.9)]), EMPTY_MAPS)
    tracker.update([before])
    kp = before.keypoints.copy()
    kp[:, 0] += 3.0
    kp[v > 250.0, 2] = 0.0  # below the image's lower edge now
    after = Person2D(kp, EMPTY_MAPS)
    assert box_iou(before.bbox()[None], after.bbox()[None])[0, 0] < 0.7
    tracker.update([after])
    assert after.track_id == before.track_id


def test_a_keypoint_gone_astray_does_not_break_a_track():
    """One of his 16 keypoints lands 60 px off (a detector's wrist on his neighbour): the box over
    every shared keypoint grows past IoU 0.7; less the fifth that moved most, it barely moves."""
    tracker = IouTracker(0.7)
    v = np.linspace(100.0, 400.0, NUM_INFERENCE_JOINTS)
    u = 150.0 + 50.0 * np.cos(np.arange(NUM_INFERENCE_JOINTS))
    before = Person2D(np.column_stack([u, v, np.full_like(u, 0.9)]), EMPTY_MAPS)
    tracker.update([before])
    kp = before.keypoints.copy()
    kp[:, 1] += 2.0
    kp[6, 0] = u.max() + 60.0  # astray, beside him
    after = Person2D(kp, EMPTY_MAPS)
    assert box_iou(before.bbox()[None], after.bbox()[None])[0, 0] < 0.7
    tracker.update([after])
    assert after.track_id == before.track_id
