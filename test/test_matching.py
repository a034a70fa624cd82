"""Cross-view matching, per-frame association and 3D ids on the real Shelf rig and ground truth.

Skeletons are the ground-truth 3D poses projected into each camera with ~2 px noise, so the
right answer (which skeleton is which actor) is known exactly.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from mvpose_ros.core.association.associator import AssociationConfig, Associator, rough_centres
from mvpose_ros.core.association.identity import IdentityKeeper
from mvpose_ros.core.association.matching import TIE_M, MatchingConfig, ViewRays, all_view_distances, cluster_views
from mvpose_ros.core.datasets.shelf_campus import dataset_dir, load_actors_gt
from mvpose_ros.core.geometry.body import NUM_INFERENCE_JOINTS, TOP_HEAD
from mvpose_ros.core.geometry.camera import Camera
from mvpose_ros.core.geometry.rays import closest_point_to_rays, ray_ray_distance
from mvpose_ros.core.heatmap import render_heatmap
from mvpose_ros.core.scenarios.frame_drops import FrameDrop
from mvpose_ros.core.types import Person2D

SHELF = dataset_dir('shelf')
FRAMES = range(576, 594)  # Shelf frames where actors 0, 1 and 2 are all annotated
FRAME = 580
NOISE_PX = 2.0
R_SHOULDER, L_SHOULDER = 8, 9


def view_distance(cam_a, people_a, cam_b, people_b, config):
    """Mean ray distance (Na, Nb) between two cameras' skeletons (all_view_distances of two)."""
    return all_view_distances([cam_a, cam_b], [people_a, people_b], config)[:len(people_a), len(people_a):]


@pytest.fixture(scope='module')
def rig(shelf_rig):
    return shelf_rig


@pytest.fixture(scope='module')
def poses() -> dict[int, np.ndarray]:
    """actorsGT frame -> (3, 14, 3) metres of actors 0, 1, 2."""
    gt = load_actors_gt(SHELF / 'actorsGT.mat', FRAMES)
    assert gt.present[:, :3].all()
    return {int(f): p[:3] for f, p in zip(gt.frames, gt.poses)}


def _inference_points(pose: np.ndarray) -> np.ndarray:
    """(14, 3) GT joints -> (16, 3): the GT joints then two ears beside and below the head top."""
    side = pose[R_SHOULDER] - pose[L_SHOULDER]
    side = 0.08 * side / np.linalg.norm(side)
    down = np.array([0.0, 0.0, 0.05])
    return np.concatenate([pose, [pose[TOP_HEAD] + side - down, pose[TOP_HEAD] - side - down]])


def _skeleton(cam: Camera, pose: np.ndarray, rng: np.random.Generator) -> Person2D:
    """The actor as a detector would report it: noisy keypoints, joints outside the image undetected."""
    uv = cam.project(_inference_points(pose)) + rng.normal(0.0, NOISE_PX, (NUM_INFERENCE_JOINTS, 2))
    inside = np.all((uv >= 0) & (uv < (cam.width, cam.height)), axis=1)
    kp = np.column_stack([uv, np.where(inside, 0.9, 0.0)])
    kp[~inside, :2] = np.nan
    heatmap = render_heatmap([kp[j:j + 1] for j in range(NUM_INFERENCE_JOINTS)], 4.0, 5.0)
    return Person2D(kp, heatmap)


def _frame(rig: list[Camera], pose: np.ndarray, rng: np.random.Generator,
           hidden: dict[int, set[int]] | None = None) -> tuple[list[list[Person2D]], list[list[int]]]:
    """Each camera's skeletons in a random order, minus the actors hidden from it
    (hidden: camera -> actors); also the actor of each skeleton."""
    people, actors = [], []
    for c, cam in enumerate(rig):
        visible = [a for a in range(len(pose)) if a not in (hidden or {}).get(c, set())]
        order = list(rng.permutation(visible))
        people.append([_skeleton(cam, pose[a], rng) for a in order])
        actors.append(order)
    return people, actors


def _as_actor_groups(clusters: list[dict[int, int]], actors: list[list[int]]) -> list[set[tuple[int, int]]]:
    """Each cluster as a set of (camera, actor) pairs."""
    return [{(c, actors[c][i]) for c, i in cl.items()} for cl in clusters]


def _truth(actors: list[list[int]]) -> list[set[tuple[int, int]]]:
    groups: dict[int, set[tuple[int, int]]] = {}
    for c, order in enumerate(actors):
        for a in order:
            groups.setdefault(a, set()).add((c, a))
    return [g for g in groups.values() if len(g) >= 2]


def test_view_distance_separates_true_and_wrong_pairs(rig, poses):
    rng = np.random.default_rng(0)
    people, actors = _frame(rig, poses[FRAME], rng)
    config = MatchingConfig()
    true, wrong = [], []
    for a in range(len(rig)):
        for b in range(a + 1, len(rig)):
            dist = view_distance(rig[a], people[a], rig[b], people[b], config)
            assert dist.shape == (3, 3)
            same = np.array(actors[a])[:, None] == np.array(actors[b])[None, :]
            true += list(dist[same])
            wrong += list(dist[~same])
    true, wrong = np.array(true), np.array(wrong)
    assert true.max() < 0.05
    # Rays of different people can pass fairly close on this rig (camera pairs looking along
    # the line between two actors), but never as close as a true pair, and mostly far.
    assert wrong.min() > 2 * true.max()
    assert np.median(wrong) > 0.2
    assert np.mean(wrong > config.max_distance) > 0.6


def test_view_distance_needs_enough_shared_joints(rig, poses):
    rng = np.random.default_rng(1)
    a = _skeleton(rig[0], poses[FRAME][0], rng)
    b = _skeleton(rig[1], poses[FRAME][0], rng)
    config = MatchingConfig(min_shared=4)
    assert np.isfinite(view_distance(rig[0], [a], rig[1], [b], config)[0, 0])
    few = Person2D(b.keypoints.copy(), b.heatmap)
    few.keypoints[3:, 2] = 0.0  # only three joints left
    assert view_distance(rig[0], [a], rig[1], [few], config)[0, 0] == np.inf
    low = Person2D(b.keypoints.copy(), b.heatmap)
    low.keypoints[3:, 2] = config.min_score / 2  # detected, but below the score that counts
    assert view_distance(rig[0], [a], rig[1], [low], config)[0, 0] == np.inf
    assert view_distance(rig[0], [], rig[1], [b], config).shape == (0, 1)


def _random_rays(rng: np.random.Generator, per_camera: list[int], n_joints: int = 16) -> ViewRays:
    """Skeletons of random unit rays from cameras a few metres apart; about a third of the
    keypoints unseen, and the first two skeletons of different cameras given parallel rays."""
    owner = np.repeat(np.arange(len(per_camera)), per_camera)
    centres = rng.normal(0.0, 3.0, (len(per_camera), 3))
    dirs = rng.normal(size=(len(owner), n_joints, 3))
    cameras = np.unique(owner)
    if len(cameras) >= 2:
        first, second = (np.flatnonzero(owner == c)[0] for c in cameras[:2])
        dirs[second] = dirs[first]
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
    scores = np.where(rng.random((len(owner), n_joints)) < 0.35, 0.0, rng.uniform(0.2, 1.0, (len(owner), n_joints)))
    keypoints = np.concatenate([rng.uniform(0, 1000, (len(owner), n_joints, 2)), scores[..., None]], axis=-1)
    return ViewRays(keypoints, owner, centres[owner], dirs)


def _view_distances_by_pairs(rays: ViewRays, config: MatchingConfig) -> np.ndarray:
    """all_view_distances written pair by pair with rays.ray_ray_distance."""
    n = len(rays.owner)
    out = np.full((n, n), np.inf)
    seen = rays.keypoints[..., 2] > config.min_score
    for a in range(n):
        for b in range(n):
            shared = seen[a] & seen[b]
            if rays.owner[a] != rays.owner[b] and shared.sum() >= config.min_shared:
                out[a, b] = ray_ray_distance(rays.origins[a], rays.dirs[a, shared], rays.origins[b],
                                             rays.dirs[b, shared]).mean()
    return out


@pytest.mark.parametrize('per_camera', [[3, 4, 2, 5, 3], [0, 3, 0, 2, 0], [4], [1, 1], [0, 0, 0], []])
def test_all_view_distances_equal_each_pairs_ray_distances(per_camera):
    rng = np.random.default_rng(len(per_camera) + sum(per_camera))
    rays = _random_rays(rng, per_camera)
    config = MatchingConfig(min_shared=4)
    dist = all_view_distances([None] * len(per_camera), [[None] * k for k in per_camera], config, rays)
    expected = _view_distances_by_pairs(rays, config)
    assert dist.shape == (sum(per_camera),) * 2
    np.testing.assert_array_equal(np.isinf(dist), np.isinf(expected))
    np.testing.assert_allclose(dist[np.isfinite(dist)], expected[np.isfinite(expected)], rtol=1e-9, atol=1e-12)


def _greedy_by_lists(dist: np.ndarray, owner: np.ndarray, max_distance: float) -> list[list[int]]:
    """cluster_views' clustering written with Python lists: edges closest first (ties in index
    order), one view per camera, a group joins another when their views are close on average."""
    a, b = np.nonzero(np.triu(dist <= max_distance, 1))
    order = np.argsort(np.round(dist[a, b] / TIE_M), kind='stable')
    cluster_of: dict[int, int] = {}
    clusters: list[list[int]] = []
    for u, v in zip(a[order], b[order]):
        cu, cv = cluster_of.get(u), cluster_of.get(v)
        if cu is not None and cu == cv:
            continue
        x = clusters[cu] if cu is not None else [u]
        y = clusters[cv] if cv is not None else [v]
        if set(owner[x]) & set(owner[y]):
            continue
        cross = dist[np.ix_(x, y)]
        if len(x) + len(y) > 2 and not np.mean(cross[np.isfinite(cross)]) <= max_distance:
            continue
        target = cu if cu is not None else cv if cv is not None else len(clusters)
        if target == len(clusters):
            clusters.append([])
        clusters[target] = x + y
        if cu is not None and cv is not None:
            clusters[cv] = []
        for w in x + y:
            cluster_of[w] = target
    return [[int(w) for w in c] for c in clusters if c]


@pytest.mark.parametrize('seed', range(6))
def test_cluster_views_equals_the_greedy_clustering_written_with_lists(monkeypatch, seed):
    """Random distances, a quarter of them tied exactly; the same clusters, views in the same order."""
    rng = np.random.default_rng(seed)
    per_camera = list(rng.integers(0, 6, 5))
    owner = np.repeat(np.arange(5), per_camera)
    n = len(owner)
    d = rng.uniform(0.0, 0.3, (n, n))
    d = np.where(rng.random((n, n)) < 0.25, 0.05, d)
    d = np.minimum(d, d.T)
    d[owner[:, None] == owner[None]] = np.inf
    d[rng.random((n, n)) < 0.1] = np.inf
    d = np.minimum(d, d.T)
    from mvpose_ros.core.association import matching
    monkeypatch.setattr(matching, 'all_view_distances', lambda *_: d)
    people = [[object()] * k for k in per_camera]
    first = np.concatenate([[0], np.cumsum(per_camera)])
    clusters = cluster_views([None] * 5, people, MatchingConfig(max_distance=0.15))
    assert [[first[c] + i for c, i in cl.items()] for cl in clusters] == _greedy_by_lists(d, owner, 0.15)


def test_rough_centres_equal_the_mean_of_each_persons_triangulated_joints():
    """Random rays of nine cameras (sums of eight lines and more go in numpy's pairwise order);
    people of one to nine views, one whose joints no two views see."""
    rng = np.random.default_rng(3)
    rays = _random_rays(rng, [3] * 9)
    people = [[0, 4, 7, 10, 13, 16, 19, 22, 25], [1, 5], [2, 8, 11, 14, 17, 20, 23, 26], [6], [9, 12, 15]]
    even = np.arange(16) % 2 == 0
    rays.keypoints[9, :, 2], rays.keypoints[12, :, 2], rays.keypoints[15, :, 2] = 0.9 * even, 0.9 * ~even, 0.0
    expected = []
    for views in people:
        seen = rays.keypoints[views, :, 2].T > 0.1  # (J, K)
        points = closest_point_to_rays(np.broadcast_to(rays.origins[views], seen.shape + (3,)),
                                       np.where(seen[..., None], rays.dirs[views].transpose(1, 0, 2), 0.0), seen)
        twice = seen.sum(axis=1) >= 2
        expected.append(points[twice].mean(axis=0) if twice.any() else np.full(3, np.nan))
    np.testing.assert_allclose(rough_centres(rays, people, 0.1), expected, rtol=1e-12, equal_nan=True)
    assert np.isnan(rough_centres(rays, people, 0.1)[4]).all()
    assert rough_centres(rays, [], 0.1).shape == (0, 3)


@pytest.mark.parametrize('seed', range(3))
def test_cluster_views_recovers_the_actors(rig, poses, seed):
    rng = np.random.default_rng(seed)
    people, actors = _frame(rig, poses[FRAME + seed], rng, hidden={1 + seed: {seed}})
    clusters = cluster_views(rig, people, MatchingConfig())
    groups = _as_actor_groups(clusters, actors)
    # each cluster holds one actor only, every camera that sees the actor, one skeleton per camera
    assert sorted(map(sorted, groups)) == sorted(map(sorted, _truth(actors)))
    assert all(len(cl) >= 2 for cl in clusters)
    assert len(groups[0]) + len(groups[1]) + len(groups[2]) == 3 * len(rig) - 1


def test_person_seen_by_one_camera_is_dropped(rig, poses):
    rng = np.random.default_rng(5)
    people, actors = _frame(rig, poses[FRAME], rng, hidden={1: {2}, 2: {2}, 3: {2}, 4: {2}})
    clusters = cluster_views(rig, people, MatchingConfig())
    groups = _as_actor_groups(clusters, actors)
    assert sorted(map(sorted, groups)) == sorted(map(sorted, _truth(actors)))
    assert len(clusters) == 2
    assert all((0, 2) not in g for g in groups)


def _observed_actor(observation, skeleton_actor: dict[int, int]) -> int:
    """The one actor behind every view of an observation."""
    actors = {skeleton_actor[id(p)] for p in observation.views.values()}
    assert len(actors) == 1
    return actors.pop()


def _observe(associator: Associator, time_s: float, people: list[list[Person2D] | None],
             actors: list[list[int]]) -> dict:
    """actor -> his PersonObservation at time_s; every observation of one actor, none two."""
    skeleton_actor = {id(p): a for ps, order in zip(people, actors) if ps is not None for p, a in zip(ps, order)}
    out = associator.update(time_s, people)
    observed = {_observed_actor(obs, skeleton_actor): obs for obs in out}
    assert len({obs.person_id for obs in observed.values()}) == len(out)
    return observed


def _run(associator: Associator, frame: int, people: list[list[Person2D] | None],
         actors: list[list[int]]) -> dict[int, int]:
    """actor -> person id for one frame."""
    return {a: obs.person_id for a, obs in _observe(associator, frame * PERIOD, people, actors).items()}


@pytest.mark.parametrize('single_view_people', [True, False])
def test_a_person_one_camera_alone_sees_keeps_his_id_while_it_is_remembered(rig, poses, single_view_people):
    """Actor 2 walks out of every view but camera 0's: with single_view_people his one view keeps his
    id (no rough centre: the solver places him from where he was) until the frames have gone
    id_memory without two cameras seeing him; without it he is dropped at once. The others keep
    theirs."""
    rng = np.random.default_rng(9)
    config = AssociationConfig(single_view_people=single_view_people)
    associator = Associator(rig, config)
    ids = [_run(associator, FRAMES[k], *_frame(rig, poses[FRAMES[k]], rng)) for k in range(4)]
    assert all(i == ids[0] for i in ids)
    last_seen = FRAMES[3] * PERIOD
    hidden = {c: {2} for c in range(1, len(rig))}
    for k in range(1, 40):
        t = last_seen + k * PERIOD
        out = _observe(associator, t, *_frame(rig, poses[FRAMES[3]], rng, hidden=hidden))
        assert {a: o.person_id for a, o in out.items() if a != 2} == {0: ids[0][0], 1: ids[0][1]}
        kept = single_view_people and t - PERIOD - last_seen <= config.id_memory
        assert (2 in out) == kept, t - last_seen
        if kept:
            assert out[2].person_id == ids[0][2] and list(out[2].views) == [0]
            assert np.isnan(out[2].centre).all()


def test_a_view_alone_keeps_the_id_its_track_had_unless_that_id_is_taken():
    """continue_alone: the id a track was part of the most frames; -1 when the frame's people took
    it (the view is a duplicate), for a track without history, for the second view voting for the
    same id, and once the id is forgotten."""
    keeper = _keeper()
    centres = np.array([[0.0, 0.0, 1.0], [2.0, 0.0, 1.0]])
    assert keeper.assign(0.0, _members([0, 1]), centres) == [0, 1]
    assert keeper.assign(PERIOD, _members([0, 1]), centres) == [0, 1]
    assert keeper.assign(2 * PERIOD, [{(0, 0), (1, 0)}, {(0, 1), (2, 7)}], centres) == [0, 1]
    assert keeper.assign(3 * PERIOD, [{(0, 0), (1, 0)}], centres[:1]) == [0]
    assert keeper.continue_alone([(0, 1), (1, 0), (3, 5)], taken={0}) == [1, -1, -1]
    # (0, 1) was part of id 1 three frames, (2, 7) one: the longer history wins whatever the order
    assert keeper.continue_alone([(2, 7), (0, 1)], taken={0}) == [-1, 1]
    for t in (3 * PERIOD + keeper.memory + 0.01, 4 * PERIOD + keeper.memory + 0.01):  # frames without id 1
        assert keeper.assign(t, [], np.zeros((0, 3))) == []
    assert keeper.continue_alone([(0, 1)], taken=set()) == [-1]


def test_associator_keeps_ids_over_consecutive_frames(rig, poses):
    rng = np.random.default_rng(7)
    associator = Associator(rig, AssociationConfig())
    first = None
    for frame in FRAMES[:8]:
        people, actors = _frame(rig, poses[frame], rng)
        if frame == FRAMES[3]:
            people[2] = None  # a camera missing for one frame
        ids = _run(associator, frame, people, actors)
        assert set(ids) == {0, 1, 2}
        first = first or ids
        assert ids == first
    for obs in associator.update(FRAMES[8] * PERIOD, _frame(rig, poses[FRAMES[8]], rng)[0]):
        assert len(obs.views) == len(rig)
        # the rough centre lies inside the actor's body
        assert np.min(np.linalg.norm(poses[FRAMES[8]].mean(axis=1) - obs.centre, axis=1)) < 0.2


def test_associator_recovers_ids_after_everyone_was_occluded(rig, poses):
    rng = np.random.default_rng(8)
    associator = Associator(rig, AssociationConfig())
    people, actors = _frame(rig, poses[FRAMES[0]], rng)
    before = _run(associator, FRAMES[0], people, actors)
    old_tracks = {(c, p.track_id) for c, ps in enumerate(people) for p in ps}
    assert associator.update(FRAMES[1] * PERIOD, [[] for _ in rig]) == []  # nobody detected anywhere
    people, actors = _frame(rig, poses[FRAMES[2]], rng)
    after = _run(associator, FRAMES[2], people, actors)
    # every per-camera track is new, so only the 3D position can carry the ids over
    assert not old_tracks & {(c, p.track_id) for c, ps in enumerate(people) for p in ps}
    assert after == before


def _gt_centres(poses: dict[int, np.ndarray], frame: int) -> np.ndarray:
    return poses[frame].mean(axis=1)  # (3, 3)


def _members(tracks: list[int]) -> list[set[tuple[int, int]]]:
    """One person per track id, seen by cameras 0 and 1 under that id."""
    return [{(0, t), (1, t)} for t in tracks]


PERIOD = 0.04  # s: Shelf's frames at 25 Hz


def _keeper(**kwargs) -> IdentityKeeper:
    return IdentityKeeper(**{'max_jump': 0.5, 'max_speed': 2.5, 'memory': 1.0, **kwargs})


def test_identity_follows_shared_tracks_as_far_as_a_person_moves(poses):
    keeper = _keeper()
    centres = _gt_centres(poses, FRAMES[0])
    ids = keeper.assign(0.0, _members([0, 1, 2]), centres)
    assert ids == [0, 1, 2]
    # listed in another order, the same tracks: same ids, one of them 0.65 m on after two frames
    # (within 0.5 m + 2.5 m/s x 0.08 s)
    moved = centres[[2, 0, 1]] + [[0.65, 0, 0], [0, 0, 0], [0, 0, 0]]
    assert keeper.assign(2 * PERIOD, _members([2, 0, 1]), moved) == [2, 0, 1]
    # one of two cameras switched track: the shared one still votes
    assert keeper.assign(3 * PERIOD, [{(0, 0), (1, 9)}], centres[[0]]) == [0]
    # its tracks 2 m away one frame later: no one walks that far, a new id
    assert keeper.assign(4 * PERIOD, _members([1]), centres[[1]] + [2.0, 0, 0]) == [3]


def test_a_stray_cluster_holding_a_persons_track_far_away_does_not_take_its_id():
    """Shelf with every second frame dropped, frame 596: camera 1's view of a person goes into a
    two-view cluster 1.8 m away with another person's view, while the person's other cameras
    all start new tracks. Its track's history gave the stray cluster the id and the person a new
    one."""
    keeper = _keeper()
    a, b = np.array([1.4, -1.1, 0.9]), np.array([0.1, 0.1, 0.9])
    for frame in range(0, 40, 2):
        assert keeper.assign(frame * PERIOD, [{(1, 123), (2, 64), (3, 84)}, {(0, 76), (2, 57)}],
                             np.stack([a, b])) == [0, 1]
    stray = np.array([-0.4, -0.6, 0.9])
    ids = keeper.assign(40 * PERIOD, [{(2, 80), (3, 85)}, {(0, 76), (1, 123)}, {(2, 57)}], np.stack([a, stray, b]))
    assert ids[0] == 0 and ids[1] not in (0, 1)


def test_identity_recovered_by_position_when_all_tracks_changed(poses):
    keeper = _keeper()
    start = _gt_centres(poses, FRAMES[0])
    ids = keeper.assign(0.0, _members([0, 1, 2]), start)
    later = _gt_centres(poses, FRAMES[10])
    assert np.linalg.norm(later - start, axis=1).max() < 0.5
    order = [1, 2, 0]
    recovered = keeper.assign(10 * PERIOD, _members([10, 11, 12]), later[order])
    assert recovered == [ids[k] for k in order]


def test_people_walking_past_a_slow_detector_keep_their_ids():
    """Sets 0.4 s apart (a CPU detector at 2.5 sets/s) of two people walking 1.4 m/s side by side,
    1.2 m apart: every set their boxes have moved too far for the 2D tracks (new track ids), and
    each has moved 0.56 m, beyond max_jump. The reach grows with the time since the frame before
    (0.5 m + 2.5 m/s x 0.4 s), so both keep their ids; the rule counting 0.5 m whatever the time
    gave both new ids at every set."""
    keeper = _keeper()
    start = np.array([[0.0, 0.0, 0.9], [0.0, 1.2, 0.9]])
    for k in range(10):
        here = start + [1.4 * 0.4 * k, 0.0, 0.0]
        assert keeper.assign(0.4 * k, _members([2 * k, 2 * k + 1]), here) == [0, 1]


def test_a_person_lost_a_while_is_not_recovered_from_afar_in_a_fast_stream():
    """At 25 Hz the position reach is the motion of one frame, not of the person's absence: a
    person unseen for 0.5 s is not handed to a newcomer 1 m away (a duplicate part or a stranger),
    though 1 m is within 0.5 + 2.5 x 0.5 m; with sets 0.5 s apart it is the same person."""
    fast, slow = _keeper(), _keeper()
    gone, other = np.array([[0.0, 0.0, 0.9]]), np.array([[3.0, 0.0, 0.9]])
    for keeper in (fast, slow):
        assert keeper.assign(0.0, _members([0, 1]), np.vstack([gone, other])) == [0, 1]
    for frame in range(1, 13):  # the other person is seen every frame, the first not
        fast.assign(frame * PERIOD, _members([1]), other)
    newcomer = gone + [1.0, 0.0, 0.0]
    assert fast.assign(13 * PERIOD, _members([5, 1]), np.vstack([newcomer, other])) == [2, 1]
    assert slow.assign(13 * PERIOD, _members([5, 1]), np.vstack([newcomer, other])) == [0, 1]


def test_a_person_split_for_a_few_frames_keeps_its_long_standing_id():
    """Shelf frames 431-435: a duplicate detection in one camera splits a person into two
    clusters. The part left without an id, made of tracks that vote for the id beside it, is the
    person seen twice and shares the id; merged again, the person keeps it."""
    keeper = _keeper()
    here = np.array([[0.0, 0.0, 0.9]])
    for frame in range(20):
        assert keeper.assign(frame * PERIOD, [{(0, 5), (1, 0), (2, 1), (3, 28)}], here) == [0]
    split = [{(0, 5), (1, 0)}, {(1, 91), (2, 1), (3, 29)}]  # camera 2's track went to the newcomer
    newcomer = here + [0.05, 0.05, 0.0]
    for frame in range(20, 24):
        assert keeper.assign(frame * PERIOD, split, np.vstack([here, newcomer])) == [0, 0]
    # merged again, two tracks shared with each id and nearer the newcomer's centre
    merged = {(0, 5), (1, 0), (2, 1), (3, 29)}
    assert keeper.assign(24 * PERIOD, [merged], newcomer) == [0]


@pytest.mark.parametrize('jump, same', [(0.3, True), (0.55, True), (0.65, False), (1.5, False)])
def test_identity_new_beyond_its_reach(poses, jump, same):
    """One frame (0.04 s) on, new tracks: the id goes as far as 0.5 m + 2.5 m/s x 0.04 s."""
    keeper = _keeper()
    centre = _gt_centres(poses, FRAME)[[0]]
    assert keeper.assign(0.0, _members([0]), centre) == [0]
    ids = keeper.assign(PERIOD, _members([5]), centre + [jump, 0.0, 0.0])
    assert ids == ([0] if same else [1])


@pytest.mark.parametrize('absent, same', [(0.04, True), (1.0, True), (1.04, False), (4.0, False)])
def test_identity_new_once_frames_went_its_memory_without_it(poses, absent, same):
    """Frames at 25 Hz that lack the person for `absent` s, then he is back on new tracks: his id
    is forgotten once the frames went more than memory (1 s) without him."""
    keeper = _keeper()
    centre, other = _gt_centres(poses, FRAME)[[0, 1]]
    keeper.assign(0.0, _members([0, 1]), np.vstack([centre, other]))
    frames = round(absent / PERIOD)
    for k in range(1, frames + 1):
        keeper.assign(k * PERIOD, _members([1]), other[None])
    ids = keeper.assign((frames + 1) * PERIOD, _members([5, 1]), np.vstack([centre + [0.05, 0.0, 0.0], other]))
    assert ids == ([0, 1] if same else [2, 1])


@pytest.mark.parametrize('stall', [1.04, 4.0])
def test_identity_kept_over_a_stream_that_stalls(poses, stall):
    """No frame at all for `stall` s (an overloaded graph dropping sets, a paused bag) is no sign
    that anyone left: the people of the next frame keep their ids, on new tracks by position."""
    keeper = _keeper()
    centres = _gt_centres(poses, FRAME)[:2]
    assert keeper.assign(0.0, _members([0, 1]), centres) == [0, 1]
    assert keeper.assign(stall, _members([6, 5]), centres[::-1] + [0.05, 0.0, 0.0]) == [1, 0]


def test_identity_never_reuses_ids_and_is_unique_per_frame(poses):
    keeper = _keeper(memory=2 * PERIOD)
    centres = _gt_centres(poses, FRAME)
    assert keeper.assign(0.0, _members([0, 1]), centres[:2]) == [0, 1]
    # two people both within max_jump of old person 0 only: one keeps it, the other is new
    near = centres[[0, 0]] + [[0.05, 0, 0], [-0.05, 0, 0]]
    ids = keeper.assign(PERIOD, _members([7, 8]), near)
    assert sorted(ids) == [0, 2]
    # everyone expired in frames without them: a person where 0 was gets a brand new id, not 0 or 1 again
    assert keeper.assign(5 * PERIOD, [], np.zeros((0, 3))) == []
    assert keeper.assign(10 * PERIOD, _members([9]), centres[[0]]) == [3]


def test_a_view_close_to_one_view_of_a_person_but_not_the_others_does_not_join_it(monkeypatch):
    """Two people near each other: camera 3's skeleton of the second person passes close to
    camera 2's of the first (0.10 m) but far from its cameras 0 and 1 (0.50 m). Closest pairs
    first with single linkage chained it into the first person; on average it is 0.37 m away, so
    it stays with camera 4's view of the second person."""
    d = np.full((5, 5), np.inf)
    for (u, v), value in {(0, 1): 0.05, (0, 2): 0.05, (1, 2): 0.05, (2, 3): 0.10, (0, 3): 0.50, (1, 3): 0.50,
                          (3, 4): 0.12, (0, 4): 0.60, (1, 4): 0.60, (2, 4): 0.60}.items():
        d[u, v] = d[v, u] = value
    from mvpose_ros.core.association import matching
    monkeypatch.setattr(matching, 'all_view_distances', lambda *_: d)
    people = [[object()] for _ in range(5)]  # one skeleton per camera; only their count is used
    clusters = cluster_views([None] * 5, people, MatchingConfig(max_distance=0.15))
    assert sorted(sorted(c.items()) for c in clusters) == [[(0, 0), (1, 0), (2, 0)], [(3, 0), (4, 0)]]


def test_a_person_nobody_matches_takes_a_new_id_rather_than_another_persons():
    """Shelf frame 593: a stray two-view cluster that may take no free id (it shares a track with
    a person whose id is taken, and is far from the rest). Every row of the assignment must go
    somewhere: without new ids to go to, the stray one took person a's id and pushed a onto a
    recent, weaker one."""
    keeper = _keeper()
    a, c = np.array([0.0, 0.0, 0.9]), np.array([3.0, 0.0, 0.9])
    for frame in range(30):
        assert keeper.assign(frame * PERIOD, [{(0, 1), (1, 1), (2, 1)}, {(3, 9), (5, 9), (6, 9)}],
                             np.stack([a, c])) == [0, 1]
    # a splits: camera 0's view of a goes with a stray view into a cluster 0.3 m off, a seen twice
    assert keeper.assign(30 * PERIOD, [{(1, 1), (2, 1), (4, 4)}, {(0, 1), (7, 7)}, {(3, 9), (5, 9), (6, 9)}],
                         np.stack([a, a + [0.3, 0, 0], c])) == [0, 0, 1]
    # a whole again; a stray cluster with a's weak track (4, 4) and c's (3, 9), far from everyone
    ids = keeper.assign(31 * PERIOD, [{(0, 1), (1, 1), (2, 1)}, {(4, 4), (3, 9)}, {(5, 9), (6, 9)}],
                        np.stack([a, [1.5, 2.0, 0.9], c]))
    assert ids == [0, 2, 1]


def test_identity_state_restored_keeps_ids_by_position_and_never_reuses_one(poses):
    """A restarted association: its new keeper takes over the old one's state; the people where
    they were keep their ids although every camera track is new; a newcomer gets a fresh id."""
    old = _keeper()
    centres = _gt_centres(poses, FRAME)
    assert old.assign(40 * PERIOD, _members([0, 1, 2]), centres) == [0, 1, 2]
    state = json.loads(json.dumps(old.state()))  # as written to and read from the state file
    assert state['next_id'] == 3 and [p['id'] for p in state['people']] == [0, 1, 2]
    new = _keeper()
    new.restore(state)
    far = centres[[0]] + [[5.0, 0.0, 0.0]]
    ids = new.assign(0.0, _members([7, 8, 9]), np.concatenate([centres[[2, 0]] + 0.1, far]))
    assert ids == [2, 0, 3]
    # without the state the same people would have been 0, 1, 2 in order: ids reused for others
    assert _keeper().assign(0.0, _members([7, 8, 9]), np.concatenate([centres[[2, 0]], far])) == [0, 1, 2]


@pytest.mark.parametrize('state, problem', [
    ({'people': []}, "missing or malformed 'next_id'"),
    ({'next_id': -1, 'people': []}, 'next_id must be an integer >= 0'),
    ({'next_id': 2, 'people': [{'id': 2, 'centre': [0, 0, 0]}]}, 'person id 2 is not in 0..next_id-1'),
    ({'next_id': 2, 'people': [{'id': 0, 'centre': [0, 'x', 0]}]}, 'missing or malformed'),
    ({'next_id': 2, 'people': [{'id': 0, 'centre': [0, float('nan'), 0]}]}, 'person 0: centre must be 3 finite'),
])
def test_identity_state_malformed_is_a_value_error(state, problem):
    with pytest.raises(ValueError, match=problem):
        _keeper().restore(state)


def test_a_person_seen_twice_shares_its_id_only_beside_it_and_by_its_tracks():
    """Shelf with 30% of its frames dropped, frames 518-522: a duplicate split actor 1 into two
    clusters, and the part left without an id took a new one, which his next frames then went
    to. A part whose tracks vote for an id taken in the frame, within max_jump of it, shares it;
    one farther away, or whose tracks vote for no one, is someone else."""
    keeper = _keeper()
    here = np.array([0.1, 0.0, 0.9])
    for frame in range(20):
        assert keeper.assign(frame * PERIOD, [{(0, 1), (1, 7), (3, 1), (4, 7)}], here[None]) == [0]
    split = [{(0, 1), (3, 1)}, {(1, 7), (4, 7)}]
    assert keeper.assign(20 * PERIOD, split, np.stack([here, here + [0.1, 0.05, 0.1]])) == [0, 0]
    assert keeper.assign(21 * PERIOD, [{(1, 7), (4, 7)}], (here + [0.1, 0.05, 0.1])[None]) == [0]
    assert keeper.assign(22 * PERIOD, split, np.stack([here, here + [0.8, 0.0, 0.0]])) == [0, 1]
    assert keeper.assign(23 * PERIOD, [{(0, 1), (3, 1)}, {(1, 8), (4, 8)}],
                         np.stack([here, here - [0.2, 0.0, 0.0]])) == [0, 2]


def test_the_associator_merges_a_person_seen_twice(shelf_people):
    """Shelf frame 520: cameras 1 and 4 found actor 1 twice, and he came out as two people of
    four and three views, 0.3 and 0.18 m from his annotated centre. Seen twice, he is one, with
    a view from every camera."""
    gt = load_actors_gt(SHELF / 'actorsGT.mat')
    associator = Associator(shelf_people.cameras, AssociationConfig())
    for k in range(200, 221):  # frames 500-520: his tracks' history
        people = associator.update(shelf_people.frames[k] * PERIOD, shelf_people.people[k])
    centre = gt.poses[520, 0].mean(axis=0)
    near = [p for p in people if np.linalg.norm(p.centre - centre) < 0.5]
    assert len(near) == 1 and sorted(near[0].views) == [0, 1, 2, 3, 4]
    assert np.linalg.norm(near[0].centre - centre) < 0.1
    assert len({p.person_id for p in people}) == len(people)


@pytest.fixture(scope='module')
def shelf_people(shelf_openpose):
    """The 2D people of every Shelf test frame from the shared OpenPose output."""
    from mvpose_ros.core.detection.openpose_detector import OpenPoseDetectorConfig
    from mvpose_ros.core.evaluation.offline import detect_sequence
    cameras, raw = shelf_openpose
    return detect_sequence(cameras, raw, list(range(300, 601)), OpenPoseDetectorConfig())


@pytest.mark.parametrize('drop', [FrameDrop(), FrameDrop(every=2), FrameDrop(every=3), FrameDrop(fraction=0.3, seed=0),
                                  FrameDrop(fraction=0.3, seed=1), FrameDrop(fraction=0.3, seed=4),
                                  FrameDrop(fraction=0.5, seed=0), FrameDrop(fraction=0.5, seed=1)])
def test_each_actor_keeps_its_id_with_frames_dropped_upstream(shelf_people, drop):
    """Association alone over Shelf's 301 frames, whole and thinned as a loaded camera system
    drops sets: in every frame with one person within 0.5 m of an annotated actor, that person
    has the actor's one id (where a duplicate detection puts two people there, which of them is
    nearer is chance). Before a person seen twice shared its id and tracks were limited to a
    person's pace, these thinned clips had 1-4 changes each (docs/method.md, Identities)."""
    gt = load_actors_gt(SHELF / 'actorsGT.mat')
    associator = Associator(shelf_people.cameras, AssociationConfig())
    ids: dict[int, set[int]] = {0: set(), 1: set(), 2: set()}
    for k in drop.kept(len(shelf_people.frames)):
        frame = shelf_people.frames[k]
        people = associator.update(frame * PERIOD, shelf_people.people[k])
        for actor, pose in enumerate(gt.poses[frame, :3]):
            if np.isfinite(pose).all():
                near = [p.person_id for p in people if np.linalg.norm(p.centre - pose.mean(axis=0)) < 0.5]
                ids[actor] |= set(near) if len(near) == 1 else set()
    assert all(len(i) == 1 for i in ids.values())
