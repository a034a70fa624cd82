"""End to end: `mvpose-eval` on the real Shelf detections, on the Campus subset and on a synthetic ring."""
from __future__ import annotations

import io
import json
import re

import numpy as np
import pytest

from mvpose_ros.cli.evaluate import build_parser, main, run
from mvpose_ros.core.datasets.shelf_campus import SHELF_ACTORS, SHELF_TEST_FRAMES, dataset_dir, load_actors_gt
from mvpose_ros.core.evaluation.pcp import evaluate
from mvpose_ros.core.evaluation.predictions import read_predictions
from mvpose_ros.core.scenarios.ring import RingConfig, ring_cameras


@pytest.fixture(scope='module')
def shelf_run(tmp_path_factory):
    path = tmp_path_factory.mktemp('eval') / 'shelf.jsonl'
    out = io.StringIO()
    run(build_parser().parse_args(['shelf', '--no-ablation', '--predictions', str(path)]), out)
    return out.getvalue(), path


def test_shelf_writes_one_valid_line_per_test_frame(shelf_run):
    _, path = shelf_run
    lines = path.read_text().splitlines()
    assert [json.loads(line)['frame'] for line in lines] == list(SHELF_TEST_FRAMES)
    for line in lines:
        for person in json.loads(line)['people']:
            assert isinstance(person['id'], int) and len(person['joints']) == 14


def test_shelf_beats_the_paper_and_the_printed_table_matches_the_file(shelf_run):
    text, path = shelf_run
    gt = load_actors_gt(dataset_dir('shelf') / 'actorsGT.mat', SHELF_TEST_FRAMES)
    ev = evaluate(read_predictions(path), gt, SHELF_ACTORS)
    # The paper's Shelf average (strict PCP, weighted by frames) is 88.92.
    assert ev.frame_weighted('strict') > 88.92
    assert f'{ev.frame_weighted("strict"):6.2f} frame-weighted' in text
    assert 'frames/s' in text


def test_score_only_reads_a_predictions_file(shelf_run, capsys):
    _, path = shelf_run
    assert main(['shelf', '--score', str(path)]) == 0
    assert 'Actor 1 strict' in capsys.readouterr().out


def test_campus_subset_oracle_is_nearly_perfect(capsys):
    assert main(['campus', '--no-ablation']) == 0
    out = capsys.readouterr().out
    assert 'oracle' in out and 'lenient 100.00' in out


@pytest.mark.slow
def test_a_ring_of_eight_cameras_scores_the_oracle_within_a_few_centimetres(capsys):
    assert main(['ring', '--ring-cameras', '8', '--no-ablation']) == 0
    out = capsys.readouterr().out
    assert out.startswith('ring: 8 synthetic cameras') and '8 cameras' in out
    summary = re.search(r'strict +([\d.]+) frame-weighted .* MPJPE +([\d.]+) mm', out)
    assert float(summary[1]) > 99.0 and float(summary[2]) < 20.0


def _ring_summary(capsys, args):
    """(strict frame-weighted PCP, MPJPE mm) of `mvpose-eval ring` with args."""
    assert main(['ring', '--no-ablation', *args]) == 0
    summary = re.search(r'strict +([\d.]+) frame-weighted .* MPJPE +([\d.]+) mm', capsys.readouterr().out)
    return float(summary[1]), float(summary[2])


@pytest.mark.slow
def test_joints_three_cameras_miss_are_put_on_the_body(capsys):
    """Three cameras whose detector misses 30 % of the keypoints leave about 3 % of the joints seen
    by none: placed on the body (arms hang, the head above the neck) they score better than at the
    person's centre (91.1 against 89.4 strict, 44.8 against 49.3 mm over the whole clip)."""
    ring = ['--ring-cameras', '3', '--ring-miss', '0.3', '--window', '6', '--lag', '3']
    body = _ring_summary(capsys, ring)
    centre = _ring_summary(capsys, [*ring, '--unseen-joints', 'centre'])
    assert body[0] > centre[0] + 1.0 and body[1] < centre[1] - 2.0, (body, centre)


def test_a_ring_misses_its_share_of_keypoints():
    """miss_share: each view misses each keypoint on its own with that probability."""
    from mvpose_ros.core.scenarios.ring import ring_sequence
    seen = []
    for miss in (0.0, 0.3):
        seq = ring_sequence(None, RingConfig(cameras=3, miss_share=miss))[0]
        seen.append(np.mean([p.keypoints[:14, 2] > 0 for frame in seq.people[:20] for view in frame for p in view]))
    assert seen[0] > 0.98 and seen[1] == pytest.approx(0.7 * seen[0], abs=0.03), seen
    with pytest.raises(ValueError, match='miss_share'):
        RingConfig(miss_share=1.0)


def test_a_walking_ring_moves_its_scene_at_its_speed():
    """walk_speed: the scene goes round a 1 m circle at that speed, annotation and keypoints alike."""
    from mvpose_ros.core.scenarios.ring import WALK_RADIUS, ring_sequence, walked
    frames = np.arange(300, 326)
    path = walked(frames, 1.4)
    np.testing.assert_allclose(np.linalg.norm(np.diff(path, axis=0), axis=1), 1.4 / 25, rtol=1e-3)
    np.testing.assert_allclose(path[0], 0.0)
    assert np.linalg.norm(path + [WALK_RADIUS, 0, 0], axis=1) == pytest.approx(WALK_RADIUS)
    still, still_gt, _ = ring_sequence(None, RingConfig(cameras=3))
    moving, moving_gt, _ = ring_sequence(None, RingConfig(cameras=3, walk_speed=1.4))
    shift = moving_gt.poses - still_gt.poses  # NaN where an actor is not annotated
    expected = np.broadcast_to(walked(still_gt.frames, 1.4)[:, None, None], shift.shape)
    present = np.isfinite(shift)
    np.testing.assert_allclose(shift[present], expected[present], atol=1e-12)
    assert moving.people[0][0][0].keypoints[0, 0] == pytest.approx(still.people[0][0][0].keypoints[0, 0])
    assert moving.people[100][0][0].keypoints[0, 0] != pytest.approx(still.people[100][0][0].keypoints[0, 0], abs=5)


def test_ring_cameras_look_at_the_actors_from_around_them():
    centre = np.array([1.0, 2.0, 1.0])
    config = RingConfig(cameras=7)
    cameras = ring_cameras(centre, config)
    assert len(cameras) == 7 and len({c.name for c in cameras}) == 7
    for camera in cameras:
        np.testing.assert_allclose(camera.project(centre[None])[0], [config.width / 2, config.height / 2], atol=1e-6)
        assert np.linalg.norm((camera.centre - centre)[:2]) == pytest.approx(config.radius)
    # evenly around: the directions to the cameras sum to nothing horizontally
    assert np.linalg.norm(np.sum([(c.centre - centre)[:2] for c in cameras], axis=0)) < 1e-9
    with pytest.raises(ValueError, match='at least 2 cameras'):
        RingConfig(cameras=1)
    assert build_parser().parse_args(['ring', '--ring-heights=-0.6,0.3']).ring_heights == (-0.6, 0.3)
    with pytest.raises(SystemExit):
        build_parser().parse_args(['ring', '--ring-heights', 'low,high'])


def test_bad_input_is_a_clear_error(tmp_path, capsys):
    assert main(['shelf', '--data-root', str(tmp_path / 'nowhere')]) == 2
    assert 'nowhere' in capsys.readouterr().err
    with pytest.raises(SystemExit):
        build_parser().parse_args(['shelf', '--terms', 'temp,bogus'])


def test_confidence_report_on_shelf_error_falls_as_confidence_rises(shelf_run, tmp_path, capsys):
    """The predictions carry each joint's confidence, and on the real Shelf run it ranks errors:
    a negative rank correlation, the least sure tenth of joints worse than the surest tenth, and
    the least sure tenth of limbs the least often correct."""
    _, path = shelf_run
    assert all('confidence' in p for line in path.read_text().splitlines() for p in json.loads(line)['people'])
    assert main(['shelf', '--score', str(path), '--confidence-report', str(tmp_path)]) == 0
    out = capsys.readouterr().out
    rho = float(out.split('Spearman rank correlation (confidence, joint error) ')[1].split()[0])
    assert rho < -0.15
    joint_rows = out.split('median mm\n')[1].split('\n\n')[0].splitlines()
    means = [float(row.split()[4]) for row in joint_rows]
    assert len(means) == 10 and means[0] > 1.5 * means[-1]
    limb_rows = out.split('lenient %\n')[1].split('\n\n')[0].splitlines()
    strict = [float(row.split()[4]) for row in limb_rows]
    assert strict[0] == min(strict) and strict[-1] > strict[0] + 10
    assert (tmp_path / 'confidence_joints.png').is_file() and (tmp_path / 'confidence_limbs.png').is_file()


@pytest.mark.slow
def test_the_secondary_radius_reaches_the_detector(shelf_run, tmp_path):
    """--secondary-radius 0 leaves other candidates out of the heatmaps, so the skeletons move."""
    path = tmp_path / 'r0.jsonl'
    run(build_parser().parse_args(['shelf', '--no-ablation', '--secondary-radius', '0', '--predictions', str(path)]),
        io.StringIO())
    assert path.read_text() != shelf_run[1].read_text()


def test_error_sources_name_what_the_detections_back(shelf_run, capsys):
    _, path = shelf_run
    assert main(['shelf', '--score', str(path), '--error-sources']) == 0
    text = capsys.readouterr().out
    report = text[text.index('Wrong endpoints'):]
    rows = re.findall(r'Actor \d: (\d+), backing the estimate (\d+), the annotation (\d+), neither (\d+)', report)
    assert len(rows) == 3
    for total, *verdicts in ([int(n) for n in row] for row in rows):
        assert total == sum(verdicts)
    assert len(re.findall(r'Actor \d \(\d+ frames\): length', report)) == 3
