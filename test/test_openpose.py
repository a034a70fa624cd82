"""The BODY25 text reader on the five real Shelf detection files."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mvpose_ros.core.defaults import data_root
from mvpose_ros.core.detection.openpose import BODY25_PAF_PAIRS, read_body25

WIDTH, HEIGHT = 1032, 776


def _detection_file(cam: int) -> Path:
    return data_root() / 'data' / 'shelf' / 'openpose_body25' / f'{cam}.txt'


def test_paf_pairs():
    assert len(BODY25_PAF_PAIRS) == 26
    assert BODY25_PAF_PAIRS[0] == (1, 8) and BODY25_PAF_PAIRS[-1] == (11, 24)
    assert {j for pair in BODY25_PAF_PAIRS for j in pair} == set(range(25))


@pytest.mark.parametrize('cam', range(5))
def test_real_file_fully_consumed_and_consistent(cam):
    path = _detection_file(cam)
    n_tokens = len(path.read_text().split())
    frames, consumed = read_body25(path, WIDTH, HEIGHT, return_consumed=True)
    assert consumed == n_tokens
    assert len(frames) == 301
    n_candidates = 0
    for frame in frames:
        assert len(frame.candidates) == 25 and len(frame.pafs) == 26
        for cand in frame.candidates:
            assert cand.ndim == 2 and cand.shape[1] == 3
            assert np.all((cand[:, 0] >= 0) & (cand[:, 0] <= WIDTH - 1))
            assert np.all((cand[:, 1] >= 0) & (cand[:, 1] <= HEIGHT - 1))
            assert np.all(cand[:, 2] > 0)
            n_candidates += len(cand)
        for (a, b), paf in zip(BODY25_PAF_PAIRS, frame.pafs):
            assert paf.shape == (len(frame.candidates[a]), len(frame.candidates[b]))
            assert np.all(paf >= 0)
    assert n_candidates > 301 * 25 * 2  # several people per frame


def test_first_values_of_camera_0():
    frames = read_body25(_detection_file(0))
    # the file starts "4 301 / 1 / 0.638639 / 0.209176 / 0.912332 / 2 / ..." (nose, then neck)
    np.testing.assert_allclose(frames[0].candidates[0],
                               [[0.638639 * (WIDTH - 1), 0.209176 * (HEIGHT - 1), 0.912332]])
    np.testing.assert_allclose(frames[0].candidates[1][:, 2], [0.798634, 0.762484])


def _write_tokens(path: Path, tokens: list[str]) -> Path:
    path.write_text(' '.join(tokens) + '\n')
    return path


@pytest.fixture(scope='module')
def tokens() -> list[str]:
    return _detection_file(0).read_text().split()


def test_truncated_file_raises_naming_it(tmp_path, tokens):
    path = _write_tokens(tmp_path / 'cut.txt', tokens[:len(tokens) // 2])
    with pytest.raises(ValueError, match=r'cut\.txt.*truncated at frame \d+'):
        read_body25(path)


def test_truncated_inside_candidates_names_joint(tmp_path, tokens):
    # header, then frame 0 joint 0: "1 x y s", joint 1: "2 ..." -> cut inside joint 1's rows
    path = _write_tokens(tmp_path / 'cut.txt', tokens[:2 + 4 + 3])
    with pytest.raises(ValueError, match=r'cut\.txt.*frame 0, joint 1'):
        read_body25(path)


def test_malformed_files_raise(tmp_path, tokens):
    bad_count = tokens.copy()
    bad_count[2] = '1.5'
    with pytest.raises(ValueError, match=r'bad\.txt.*frame 0, joint 0'):
        read_body25(_write_tokens(tmp_path / 'bad.txt', bad_count))
    with pytest.raises(ValueError, match=r'word\.txt'):
        read_body25(_write_tokens(tmp_path / 'word.txt', tokens[:5] + ['x'] + tokens[6:]))
    with pytest.raises(ValueError, match=r'trail\.txt.*trailing'):
        read_body25(_write_tokens(tmp_path / 'trail.txt', tokens + ['0.5']))
    with pytest.raises(ValueError, match=r'type\.txt.*BODY25'):
        read_body25(_write_tokens(tmp_path / 'type.txt', ['3'] + tokens[1:]))
