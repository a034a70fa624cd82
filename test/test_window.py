"""Sliding-window and whole-clip temporal inference on synthetic people, and the predictions file.

Each synthetic person moves smoothly; every joint has M hypotheses per frame, one of them the
true position and the others scattered 10-40 cm around it afresh each frame. The data term
favours the truth, but in about a third of the (frame, joint) cells a distractor outscores it,
so the data alone decodes the wrong point there and only the temporal factor can fix it.
"""
from __future__ import annotations

import io
import json
import re

import numpy as np
import pytest

from mvpose_ros.core.geometry.body import LIMB_BONES, LIMB_LENGTHS, NUM_INFERENCE_JOINTS, SYMMETRIC_PAIRS
from mvpose_ros.core.evaluation.predictions import frame_line, read_predictions, write_predictions
from mvpose_ros.core.inference.window import InferenceConfig, SlidingWindow
from mvpose_ros.core.types import FrameResult, PersonFrame

J = NUM_INFERENCE_JOINTS
M = 10
T = 30
IDS = (4, 9)
FRAME0 = 300  # frame labels need not start at 0


def _truth(rng: np.random.Generator, n_frames: int) -> np.ndarray:
    """(T, J, 3) smooth trajectory: a rigid layout with joints >= 30 cm apart, walking ~2 cm per
    frame on a gently curving path, metres."""
    layout = np.stack(np.meshgrid(np.arange(4) * 0.3, np.arange(4) * 0.3, indexing='ij'), -1).reshape(J, 2)
    layout = np.column_stack([layout, 0.1 * np.arange(J) % 0.4 + 0.5])
    t = np.arange(n_frames)[:, None]
    path = rng.uniform(-2, 2, 3) * [1, 1, 0] + np.column_stack(
        [0.02 * t[:, 0], 0.3 * np.sin(t[:, 0] / 15.0), np.zeros(n_frames)])
    return path[:, None, :] + layout[None]


def _frames(rng: np.random.Generator, truth: np.ndarray, flip: float = 0.35
            ) -> tuple[list[np.ndarray], list[np.ndarray], np.ndarray]:
    """Hypotheses (J, M, 3) and data (J, M) per frame, and whether the data argmax is the truth
    (T, J)."""
    n = len(truth)
    offsets = rng.normal(size=(n, J, M, 3))
    offsets *= rng.uniform(0.10, 0.40, (n, J, M, 1)) / np.linalg.norm(offsets, axis=-1, keepdims=True)
    true_at = rng.integers(0, M, (n, J))
    offsets[np.arange(n)[:, None], np.arange(J)[None], true_at] = 0.0
    hyp = truth[:, :, None, :] + offsets
    data = rng.uniform(0.0, 0.6, (n, J, M))
    data[np.arange(n)[:, None], np.arange(J)[None], true_at] = 1.0
    beaten = rng.random((n, J)) < flip
    rival = (true_at + rng.integers(1, M, (n, J))) % M
    t_idx, j_idx = np.nonzero(beaten)
    data[t_idx, j_idx, rival[beaten]] = 1.3
    data /= data.sum(axis=-1, keepdims=True)
    return list(hyp), list(data), ~beaten


def _clip(seed: int = 0, n_frames: int = T, absent: dict[int, set[int]] | None = None):
    """Per frame the PersonFrames of both people (minus those absent: person id -> frame
    positions), and the true (T, J, 3) of each person."""
    rng = np.random.default_rng(seed)
    truth, data_right, frames = {}, {}, [[] for _ in range(n_frames)]
    for pid in IDS:
        truth[pid] = _truth(rng, n_frames)
        hyp, data, data_right[pid] = _frames(rng, truth[pid])
        for t in range(n_frames):
            if t not in (absent or {}).get(pid, set()):
                frames[t].append(PersonFrame(pid, hyp[t], data[t], np.ones(len(data[t]))))
    return frames, truth, data_right


def _window(**kwargs) -> SlidingWindow:
    """The reference schedule (every hypothesis, windows re-solved) unless kwargs say otherwise,
    with the paper's terms: the synthetic layout is no human body, so the limb factor's bone
    lengths do not apply to it."""
    config = InferenceConfig(**{'bp_hypotheses': None, 'slide_iterations': None, 'terms': ('data', 'temp', 'col'),
                                **kwargs})
    return SlidingWindow(config, np.array(SYMMETRIC_PAIRS), LIMB_BONES, LIMB_LENGTHS)


def _run(window: SlidingWindow, frames: list[list[PersonFrame]]) -> tuple[list[list[FrameResult]], list[FrameResult]]:
    """What each push returned, and what flush returned."""
    pushed = [window.push(FRAME0 + t, people) for t, people in enumerate(frames)]
    return pushed, window.flush()


def _all(pushed: list[list[FrameResult]], flushed: list[FrameResult]) -> list[FrameResult]:
    return [r for out in pushed for r in out] + flushed


def _accuracy(results: list[FrameResult], truth: dict[int, np.ndarray]) -> float:
    """Fraction of decoded joints that are exactly the true hypothesis."""
    hits = [np.linalg.norm(joints - truth[pid][r.frame - FRAME0], axis=-1) < 1e-9
            for r in results for pid, joints in zip(r.person_ids, r.joints)]
    return float(np.mean(hits))


@pytest.fixture(scope='module')
def clip():
    return _clip()


@pytest.mark.parametrize('slide', [None, 1])
@pytest.mark.parametrize('window, lag', [(15, 7), (5, 0), (8, 7), (1, 0), (40, 12)])
def test_window_mode_emits_each_frame_once_lag_frames_late(clip, window, lag, slide):
    frames, _, _ = clip
    frames = [list(f) for f in frames]
    frames[5] = []  # nobody at all in one frame: it still comes out, empty
    pushed, flushed = _run(_window(window=window, lag=lag, slide_iterations=slide), frames)
    for t, out in enumerate(pushed):
        assert [r.frame for r in out] == ([FRAME0 + t - lag] if t >= lag else [])
    assert [r.frame for r in flushed] == [FRAME0 + t for t in range(T - lag, T)]
    results = _all(pushed, flushed)
    assert [r.frame for r in results] == [FRAME0 + t for t in range(T)]
    for r, people in zip(results, frames):
        assert r.person_ids == sorted(p.person_id for p in people)
        assert r.joints.shape == (len(people), J, 3)


def test_whole_clip_mode_emits_everything_at_flush(clip):
    frames, _, _ = clip
    pushed, flushed = _run(_window(window=None), frames)
    assert all(out == [] for out in pushed)
    assert [r.frame for r in flushed] == [FRAME0 + t for t in range(T)]
    assert all(r.person_ids == sorted(IDS) and r.joints.shape == (2, J, 3) for r in flushed)


@pytest.mark.parametrize('window', [None, 10])
def test_flush_twice_emits_nothing_new(clip, window):
    """flush outputs the frames not yet output: a second flush has none left."""
    frames, _, _ = clip
    sliding = _window(window=window, lag=5 if window else 0)
    _run(sliding, frames)
    assert sliding.flush() == []


def test_absent_person_is_output_only_where_present_and_its_chain_breaks():
    gap = {9: {0, 1, 12, 13, 14, 29}}
    frames, truth, _ = _clip(seed=1, absent=gap)
    for kwargs in ({'window': None}, {'window': 12, 'lag': 6}, {'window': 12, 'lag': 6, 'slide_iterations': 1}):
        results = _all(*_run(_window(**kwargs), frames))
        for t, r in enumerate(results):
            assert r.person_ids == ([4] if t in gap[9] else [4, 9])
    # Whole clip: person 9's segments decode exactly as they do on their own, so nothing links
    # frame 11 to frame 15; person 4 decodes as if alone.
    whole = {r.frame: dict(zip(r.person_ids, r.joints)) for r in _run(_window(window=None), frames)[1]}
    for segment in (range(2, 12), range(15, 29)):
        alone = _run(_window(window=None), [[p for p in frames[t] if p.person_id == 9] for t in segment])[1]
        for t, r in zip(segment, alone):
            np.testing.assert_array_equal(whole[FRAME0 + t][9], r.joints[0])
    solo = _run(_window(window=None), [[p for p in f if p.person_id == 4] for f in frames])[1]
    for t, r in enumerate(solo):
        np.testing.assert_array_equal(whole[FRAME0 + t][4], r.joints[0])


@pytest.mark.parametrize('terms', [('data', 'temp'), ('data', 'temp', 'col')])
@pytest.mark.parametrize('window, lag, slide', [(None, 0, None), (15, 7, None), (15, 7, 1), (8, 3, 1)])
def test_temporal_bp_beats_the_data_term_alone(clip, terms, window, lag, slide):
    frames, truth, data_right = clip
    data_only = _all(*_run(_window(terms=('data',), window=window, lag=lag, slide_iterations=slide), frames))
    temporal = _all(*_run(_window(terms=terms, window=window, lag=lag, slide_iterations=slide), frames))
    data_acc = _accuracy(data_only, truth)
    # data-only decoding is the argmax of the data term, right exactly where the truth wins it
    assert data_acc == pytest.approx(np.mean([data_right[pid] for pid in IDS]))
    assert 0.55 < data_acc < 0.75
    assert _accuracy(temporal, truth) > 0.95


@pytest.mark.parametrize('terms', [('data', 'temp', 'col'), ('data', 'temp', 'col', 'limb')])
@pytest.mark.parametrize('extra', [0, 6])
def test_window_spanning_the_clip_equals_whole_clip(terms, extra):
    frames, _, _ = _clip(seed=2, n_frames=12, absent={4: {5}})
    window = len(frames) + extra
    sliding = _all(*_run(_window(terms=terms, window=window, lag=window - 1), frames))
    whole = _run(_window(terms=terms, window=None), frames)[1]
    assert [r.frame for r in sliding] == [r.frame for r in whole]
    for a, b in zip(sliding, whole):
        assert a.person_ids == b.person_ids
        np.testing.assert_array_equal(a.joints, b.joints)


MODES = [{'window': None}, {'window': 10, 'lag': 4}, {'window': 10, 'lag': 4, 'slide_iterations': 1}]


def _push_all(window: SlidingWindow, labels, frames, times=None) -> list[FrameResult]:
    times = times or [None] * len(labels)
    return [r for f, people, ts in zip(labels, frames, times) for r in window.push(f, people, ts)] + window.flush()


@pytest.mark.parametrize('kwargs', MODES)
def test_a_gap_longer_than_max_gap_breaks_every_chain(kwargs):
    """Frames 300..309 then 320..329 (0.4 s later, max_gap 0.2 s): nothing links 309 to 320, so
    each side decodes as if the other did not exist."""
    frames, _, _ = _clip(seed=3, n_frames=20)
    labels = [FRAME0 + t + 10 * (t >= 10) for t in range(20)]
    both = _push_all(_window(**kwargs), labels, frames)
    assert [r.frame for r in both] == labels
    for part in (slice(0, 10), slice(10, 20)):
        out = _push_all(_window(**kwargs), labels[part], frames[part])
        for a, b in zip(out, both[part]):
            np.testing.assert_array_equal(a.joints, b.joints)
    # every second frame missing (80 ms steps): within max_gap the chains hold and the temporal
    # term fixes the data term; with max_gap below the step nothing is linked: no temporal term
    frames, truth, data_right = _clip(seed=3, n_frames=20)
    labels = [FRAME0 + 2 * t for t in range(20)]
    truth = {pid: np.repeat(x, 2, axis=0) for pid, x in truth.items()}  # indexed by frame - FRAME0
    data_acc = np.mean([data_right[pid] for pid in IDS])
    assert _accuracy(_push_all(_window(**kwargs), labels, frames), truth) > 0.95 > data_acc + 0.2
    unlinked = _push_all(_window(max_gap=0.05, **kwargs), labels, frames)
    for a, b in zip(unlinked, _push_all(_window(terms=('data', 'col'), **kwargs), labels, frames)):
        np.testing.assert_array_equal(a.joints, b.joints)


@pytest.mark.parametrize('kwargs', MODES)
def test_evenly_spaced_times_give_exactly_the_results_of_frame_numbers(kwargs):
    """Times of frames 40 ms apart however they are written (rounded floats far from zero,
    nanosecond stamps) give the evenly spaced factors bit for bit."""
    frames, _, _ = _clip(seed=4, n_frames=20)
    labels = [FRAME0 + t for t in range(20)]
    reference = _push_all(_window(**kwargs), labels, frames)
    for times in ([1.7e6 + 0.04 * t for t in range(20)], [(12_000_000_000 + 40_000_000 * t) / 1e9 for t in range(20)],
                  [0.04 * t for t in range(20)]):
        for a, b in zip(_push_all(_window(**kwargs), list(range(20)), frames, times), reference):
            np.testing.assert_array_equal(a.joints, b.joints)


def _fast_clip(seed: int, n_frames: int):
    """A clip whose people move five times as fast as _clip's (about 10 cm per frame)."""
    rng = np.random.default_rng(seed)
    truth, frames = {}, [[] for _ in range(n_frames)]
    for pid in IDS:
        truth[pid] = _truth(rng, 5 * n_frames)[::5]
        hyp, data, _ = _frames(rng, truth[pid])
        for t in range(n_frames):
            frames[t].append(PersonFrame(pid, hyp[t], data[t], np.ones(len(data[t]))))
    return frames, truth


@pytest.mark.parametrize('kwargs', MODES)
def test_frames_dropped_at_random_are_bridged_with_the_real_times(kwargs):
    """40 % of the frames of a fast clip dropped (gaps of 1 to 4 periods): the temporal term with
    the real times still fixes the data term; blind to the times (the frames taken as evenly
    spaced) it does worse."""
    frames, truth = _fast_clip(seed=7, n_frames=80)
    kept = sorted(np.random.default_rng(8).choice(80, 48, replace=False).tolist())
    labels = [FRAME0 + t for t in kept]
    sub = [frames[t] for t in kept]
    data_only = _accuracy(_push_all(_window(terms=('data',), **kwargs), labels, sub), truth)
    real = _accuracy(_push_all(_window(**kwargs), labels, sub), truth)
    blind = _accuracy(_push_all(_window(**kwargs), labels, sub, [k / 25 for k in range(len(kept))]), truth)
    assert real > 0.98 and real > blind + 0.02 and real > data_only + 0.3, (data_only, blind, real)


def test_times_must_increase():
    window = _window(window=10, lag=4)
    window.push(FRAME0, [], 1.0)
    with pytest.raises(ValueError, match='times must increase'):
        window.push(FRAME0 + 1, [], 1.0)


def test_frames_must_increase():
    window = _window(window=10, lag=4)
    window.push(FRAME0, [])
    with pytest.raises(ValueError, match='frames must increase'):
        window.push(FRAME0, [])


def _top(data: np.ndarray, k: int) -> np.ndarray:
    """(J, k) indices of the k largest data values of each joint."""
    return np.argsort(-data, axis=1)[:, :k]


def test_bp_hypotheses_keeps_the_top_k_by_data(clip):
    frames, truth, data_right = clip
    # k = 1: only the data argmax survives, whatever the other factors say
    one = _all(*_run(_window(window=None, bp_hypotheses=1), frames))
    assert _accuracy(one, truth) == pytest.approx(np.mean([data_right[pid] for pid in IDS]))
    # k = 2: the truth is the best or second best everywhere, so BP can still find it; and
    # every decoded joint is one of the two best-data hypotheses of its frame
    two = _all(*_run(_window(window=None, bp_hypotheses=2), frames))
    assert _accuracy(two, truth) > 0.9
    for r, people in zip(two, frames):
        for p, joints in zip(sorted(people, key=lambda q: q.person_id), r.joints):
            kept = np.take_along_axis(p.hypotheses, _top(p.data, 2)[..., None], axis=1)  # (J, 2, 3)
            assert np.all(np.min(np.linalg.norm(kept - joints[:, None], axis=-1), axis=1) < 1e-12)
    # k >= M: the same as no pruning
    full = _all(*_run(_window(window=None), frames))
    many = _all(*_run(_window(window=None, bp_hypotheses=M + 3), frames))
    for a, b in zip(full, many):
        np.testing.assert_array_equal(a.joints, b.joints)


@pytest.mark.parametrize('kwargs', [
    {'terms': ('temp', 'col')},           # no data term
    {'terms': ('data', 'velocity')},      # unknown term
    {'window': 10, 'lag': 10},
    {'window': 10, 'lag': 12},
    {'window': 10, 'lag': -1},
    {'max_gap': 0.0},
    {'frame_rate': 0.0},
])
def test_inference_config_rejects(kwargs):
    with pytest.raises(ValueError):
        InferenceConfig(**kwargs)


@pytest.mark.parametrize('kwargs', [{'window': 10, 'lag': 9}, {'window': 1, 'lag': 0}, {'window': None},
                                    {'terms': ('data', 'temp', 'col', 'limb')}])
def test_inference_config_accepts(kwargs):
    InferenceConfig(**kwargs)


# --- predictions file -------------------------------------------------------------------------

def _results(rng: np.random.Generator) -> list[FrameResult]:
    counts = [2, 0, 3, 1]
    return [FrameResult(FRAME0 + 2 * i, list(range(7, 7 + n)), rng.uniform(-3, 3, (n, 14, 3)))
            for i, n in enumerate(counts)]


def test_predictions_round_trip(tmp_path):
    results = _results(np.random.default_rng(0))
    path = tmp_path / 'pred.jsonl'
    with open(path, 'w', encoding='utf-8') as f:
        assert write_predictions(results, f) == len(results)
    back = read_predictions(path)
    assert list(back) == [r.frame for r in results]
    for r in results:
        assert back[r.frame].shape == r.joints.shape
        np.testing.assert_allclose(back[r.frame], r.joints, atol=5.1e-5)  # written to 0.1 mm
    assert len(path.read_text().splitlines()) == len(results)


def _write_lines(tmp_path, lines: list[str]):
    path = tmp_path / 'bad.jsonl'
    path.write_text(''.join(line + '\n' for line in lines), encoding='utf-8')
    return path


def _good_line(frame: int, rng: np.random.Generator) -> str:
    return frame_line(FrameResult(frame, [1], rng.uniform(-1, 1, (1, 14, 3))))


@pytest.mark.parametrize('bad', [
    'this is not json',
    '{"frame": 5}',                                    # no people
    '{"people": []}',                                  # no frame
    '{"frame": 5, "people": [{"id": 1, "joints": [[0, 0, 0]]}]}',  # one joint, not 14
    '[1, 2, 3]',
])
def test_read_predictions_names_file_and_line_of_a_malformed_line(tmp_path, bad):
    rng = np.random.default_rng(1)
    path = _write_lines(tmp_path, [_good_line(1, rng), _good_line(2, rng), bad])
    with pytest.raises(ValueError, match=rf'{re.escape(path.name)}:3\b'):
        read_predictions(path)


def test_read_predictions_rejects_nan(tmp_path):
    rng = np.random.default_rng(2)
    joints = rng.uniform(-1, 1, (2, 14, 3))
    joints[1, 4, 2] = np.nan
    nan_line = frame_line(FrameResult(3, [1, 2], joints))
    assert 'NaN' in nan_line  # json writes it; the reader must refuse it
    path = _write_lines(tmp_path, [_good_line(1, rng), nan_line])
    with pytest.raises(ValueError, match=rf'{re.escape(path.name)}:2\b') as err:
        read_predictions(path)
    assert str(path) in str(err.value)


def test_read_predictions_rejects_a_repeated_frame(tmp_path):
    rng = np.random.default_rng(3)
    path = _write_lines(tmp_path, [_good_line(1, rng), _good_line(2, rng), '', _good_line(1, rng)])
    with pytest.raises(ValueError, match=rf'{re.escape(path.name)}:4\b') as err:
        read_predictions(path)
    assert str(path) in str(err.value) and 'repeated' in str(err.value)


def test_write_predictions_streams_one_line_per_frame():
    stream = io.StringIO()
    results = _results(np.random.default_rng(4))
    write_predictions(results, stream)
    lines = stream.getvalue().splitlines()
    assert [json.loads(line)['frame'] for line in lines] == [r.frame for r in results]


@pytest.mark.parametrize('slide', [None, 1])
def test_live_estimate_is_the_lag_0_output_and_uses_no_future_frame(slide):
    frames, truth, _ = _clip(seed=3)
    other, _, _ = _clip(seed=4)  # other frames after t: another future for the same past
    t_cut = 12
    lagged = _window(window=6, lag=3, slide_iterations=slide)
    causal = _window(window=6, lag=0, slide_iterations=slide)
    changed = _window(window=6, lag=3, slide_iterations=slide)
    live, live_changed, lag0 = [], [], []
    for t in range(T):
        lagged.push(FRAME0 + t, frames[t])
        live.append(lagged.live())
        lag0 += causal.push(FRAME0 + t, frames[t])
        changed.push(FRAME0 + t, frames[t] if t <= t_cut else other[t])
        live_changed.append(changed.live())
    for a, b in zip(live, lag0):  # the same BP state: the live estimate is what lag 0 outputs
        assert a.frame == b.frame and a.person_ids == b.person_ids and np.array_equal(a.joints, b.joints)
    for a, b in zip(live[:t_cut + 1], live_changed[:t_cut + 1]):
        assert np.array_equal(a.joints, b.joints)
    # the lagged output of a frame before the cut does see the changed future
    assert any(not np.array_equal(a.joints, b.joints) for a, b in
               zip(_all(*_run(_window(window=6, lag=3, slide_iterations=slide), frames))[t_cut - 2:t_cut + 1],
                   _all(*_run(_window(window=6, lag=3, slide_iterations=slide),
                              frames[:t_cut + 1] + other[t_cut + 1:]))[t_cut - 2:t_cut + 1]))


def test_live_before_any_frame_is_none():
    assert _window(window=6, lag=3).live() is None


def test_a_mode_only_frames_gone_from_the_window_supported_does_not_outlive_them():
    """Every joint has two places 0.5 m apart. The first 3 frames' evidence says A firmly (0.9),
    every later frame's says B (0.7). Warm-started, the chain must follow the window: once those
    3 frames have left it (6 frames), B; their evidence must not linger as a prior that holds A
    for good (the shelf_rig bag's wrist that stayed 0.49 m off; with the prior, A held for all 20
    frames even at 0.8 for B)."""
    places = np.zeros((J, 2, 3))
    places[:, 1, 0] = 0.5
    window = _window(window=6, lag=0, slide_iterations=1, terms=('data', 'temp'))
    decoded = []
    for t in range(20):
        data = np.tile([0.9, 0.1] if t < 3 else [0.3, 0.7], (J, 1))
        out = window.push(FRAME0 + t, [PersonFrame(1, places, data, np.ones(J))])
        decoded.append(out[0].joints[0, :, 0])  # x of every joint
    assert np.all(np.array(decoded[:3]) == 0.0)  # A while the evidence says so
    assert np.all(np.array(decoded[12:]) == 0.5)  # B well after the A frames left the window


def _t_pose() -> np.ndarray:
    """(16, 3) inference joints of a person standing in a T-pose, every bone at its typical
    length (body.LIMB_LENGTHS)."""
    joints = np.zeros((NUM_INFERENCE_JOINTS, 3))
    joints[[12, 13, 14, 15]] = (0.0, 0.0, 1.5), (0.0, 0.1, 1.65), (-0.08, 0.0, 1.65), (0.08, 0.0, 1.65)
    joints[[8, 9]] = (-0.2, 0.0, 1.5), (0.2, 0.0, 1.5)
    joints[[7, 10]] = (-0.53, 0.0, 1.5), (0.53, 0.0, 1.5)
    joints[[6, 11]] = (-0.79, 0.0, 1.5), (0.79, 0.0, 1.5)
    joints[[2, 3]] = (-0.1, 0.0, 1.0), (0.1, 0.0, 1.0)
    joints[[1, 4]] = (-0.1, 0.0, 0.57), (0.1, 0.0, 0.57)
    joints[[0, 5]] = (-0.1, 0.0, 0.14), (0.1, 0.0, 0.14)
    return joints


@pytest.mark.parametrize('window', [None, 4])
def test_the_limb_factor_rules_out_a_wrist_half_a_metre_from_its_elbow(window):
    """Two views agreeing on a wrong keypoint give a wrist hypothesis 0.54 m from the elbow with
    more data than the right one 0.26 m away: the data term alone takes it, the limb factor
    (a forearm of 0.26 m typical, 0.18-0.34 m plausible) does not, whole clip or sliding window."""
    pose = _t_pose()
    hyp = np.repeat(pose[:, None], 2, axis=1)  # (16, 2, 3): both hypotheses of every joint alike
    hyp[11, 1] = pose[10] + (0.54, 0.0, 0.0)
    data = np.tile([0.5, 0.5], (NUM_INFERENCE_JOINTS, 1))
    data[11] = (0.4, 0.6)
    chosen = {}
    for terms in (('data',), ('data', 'limb')):
        config = InferenceConfig(terms=terms, window=window, lag=1 if window else 0)
        win = SlidingWindow(config, np.array(SYMMETRIC_PAIRS), LIMB_BONES, LIMB_LENGTHS)
        results = []
        for f in range(3):
            results += win.push(f, [PersonFrame(0, hyp, data, np.ones(NUM_INFERENCE_JOINTS))])
        results += win.flush()
        chosen[terms] = [np.linalg.norm(r.joints[0, 11] - pose[10]) for r in results]
    np.testing.assert_allclose(chosen[('data',)], 0.54)
    np.testing.assert_allclose(chosen[('data', 'limb')], 0.26)


@pytest.mark.parametrize('k', [1, 5, 7])
def test_pruning_is_numpys_to_the_bit(k):
    """_pruned against the numpy formulation it replaces: a stable sort (ties keep index order),
    rows of zeros, no joints."""
    from mvpose_ros.core.inference.window import _pruned
    rng = np.random.default_rng(3)
    for n_j in (4, 0):
        data = rng.integers(0, 4, (n_j, 8)).astype(float) / 4  # many ties
        data[:1] = 0.0
        p = PersonFrame(1, rng.normal(size=(n_j, 8, 3)), data, np.ones(n_j))
        keep = np.argsort(-data, axis=1, kind='stable')[:, :k]
        kept = np.take_along_axis(data, keep, axis=1)
        out = _pruned(p, k)
        np.testing.assert_array_equal(out.hypotheses, np.take_along_axis(p.hypotheses, keep[..., None], axis=1))
        total = np.maximum(kept.sum(axis=1, keepdims=True), np.finfo(float).tiny)
        np.testing.assert_array_equal(out.data, kept / total)
        assert out.person_id == 1 and out.support is p.support
