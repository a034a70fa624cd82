"""Speed-ups leave the 3D stage's results as they were: on real Shelf frames, the whole stage
(grouping and heatmaps, association, sampling, data term, factors, BP, decoding) gives the same
frames, the same person ids, the same decoded joints (to 1e-6 m) and confidences (to 1e-6) as the
reference the code before the speed-ups wrote.

The reference, test/data/speedups_reference.npz, is written by

    .venv/bin/python test/test_speedups.py --write

Regenerate it only for a change that is meant to alter results, in a commit of its own that says why.
Cases: the graph's settings (window 6, lag 3, heatmap stride 8) on 40 frames of 3-5 people; a
crowd (20 of those frames, the scene with six shifted copies: about 16 people, core.scenarios.crowd) at
those settings; the whole clip at once with every term (loopy BP, limb tables); windows re-solved
from scratch.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from mvpose_ros.core.datasets.shelf_campus import SHELF_TEST_FRAMES
from mvpose_ros.core.detection.openpose_detector import OpenPoseDetectorConfig
from mvpose_ros.core.evaluation.offline import detect_sequence, shelf_openpose_raw
from mvpose_ros.core.scenarios.crowd import multiply_scene
from mvpose_ros.core.stage import Stage3D, StageConfig

REFERENCE = Path(__file__).parent / 'data' / 'speedups_reference.npz'
GRAPH = {'window': 6, 'lag': 3}
# copies of the scene (metres in the floor plane), as core.scenarios.crowd.choose_offsets picks them for
# about 16 people on the crowd's frames
CROWD_OFFSETS = [(0.0, 0.0, 0.0), (0.5, -0.5, 0.0), (1.0, -1.0, 0.0), (2.0, 0.5, 0.0), (2.5, 0.0, 0.0),
                 (-1.0, -1.5, 0.0), (3.0, -0.5, 0.0)]
ALL_TERMS = ['data', 'temp', 'col', 'limb']
# name: (first test frame index, frames, heatmap stride, stage parameters, scene copies)
CASES = {
    'graph': (120, 40, 8.0, GRAPH, None),
    'crowd': (120, 20, 8.0, GRAPH, CROWD_OFFSETS),
    'clip': (120, 20, 4.0, {'window': 0, 'terms': ALL_TERMS}, None),
    'resolve': (140, 20, 8.0, {**GRAPH, 'slide_iterations': 0, 'terms': ALL_TERMS}, None),
}


def run_case(shelf, name: str, **overrides) -> dict[str, np.ndarray]:
    """The stage's output over a case as flat arrays: per decoded person, its frame, id, joints
    (14, 3) and confidence (14,); overrides: stage parameters on top of the case's."""
    start, n_frames, stride, params, offsets = CASES[name]
    params = {**params, **overrides}
    cameras, raw = shelf
    seq = detect_sequence(cameras, raw, list(SHELF_TEST_FRAMES[start:start + n_frames]),
                          OpenPoseDetectorConfig(stride=stride))
    people = seq.people
    if offsets is not None:
        people = multiply_scene(cameras, seq.frames, people, 0.0, offsets=np.array(offsets)).people
    stage = Stage3D(cameras, StageConfig.from_params(params))
    results = []
    for frame, per_camera in zip(seq.frames, people):
        results += stage.push(frame, per_camera)
    results += stage.flush()
    return {'frames': np.array([r.frame for r in results]),
            'frame': np.concatenate([[r.frame] * len(r.person_ids) for r in results]).astype(int),
            'ids': np.concatenate([r.person_ids for r in results]).astype(int),
            'joints': np.concatenate([r.joints for r in results]),
            'confidence': np.concatenate([r.confidence for r in results])}


@pytest.fixture(scope='module')
def reference() -> dict[str, np.ndarray]:
    with np.load(REFERENCE) as f:
        return dict(f)


@pytest.mark.slow
@pytest.mark.parametrize('name', CASES)
def test_the_stage_gives_the_reference_results(shelf_openpose, reference, name):
    out = run_case(shelf_openpose, name)
    ref = {k: reference[f'{name}/{k}'] for k in out}
    np.testing.assert_array_equal(out['frames'], ref['frames'])
    np.testing.assert_array_equal(out['frame'], ref['frame'])
    np.testing.assert_array_equal(out['ids'], ref['ids'])
    assert np.isfinite(out['joints']).all()
    np.testing.assert_allclose(out['joints'], ref['joints'], rtol=0, atol=1e-6)
    np.testing.assert_allclose(out['confidence'], ref['confidence'], rtol=0, atol=1e-6)
    if name == 'crowd':  # the crowd really is one
        assert len(out['ids']) / len(out['frames']) > 12


@pytest.mark.parametrize('name', ['crowd', 'resolve'])
def test_the_thread_count_changes_nothing(shelf_openpose, name):
    """People's chains and temporal tables solved by one thread or three: the same bits."""
    one, three = (run_case(shelf_openpose, name, threads=n) for n in (1, 3))
    for key in one:
        np.testing.assert_array_equal(one[key], three[key])


def write_reference() -> None:
    shelf = shelf_openpose_raw(None)
    arrays = {f'{name}/{k}': v for name in CASES for k, v in run_case(shelf, name).items()}
    REFERENCE.parent.mkdir(exist_ok=True)
    np.savez_compressed(REFERENCE, **arrays)
    print(f'wrote {REFERENCE} ({REFERENCE.stat().st_size // 1024} KiB)')


if __name__ == '__main__':
    if sys.argv[1:] != ['--write']:
        sys.exit('usage: test_speedups.py --write   (writes the reference from the current code)')
    write_reference()
