"""Identity counts over a clip: switches, missed actors, people who are no annotated actor."""
import numpy as np

from mvpose_ros.core.datasets.shelf_campus import GroundTruth
from mvpose_ros.core.evaluation.identities import identity_report
from mvpose_ros.core.types import FrameResult


def _clip():
    """Two actors standing 2 m apart over 6 frames; actor 1 not annotated in frame 3."""
    rng = np.random.default_rng(0)
    pose = rng.normal(scale=0.3, size=(14, 3))
    poses = np.stack([np.stack([pose, pose + [2.0, 0, 0]])] * 6)  # (F, A, 14, 3)
    poses[3, 1] = np.nan
    return GroundTruth(np.arange(100, 106), poses), poses


def test_switches_missed_and_unmatched_people_are_counted():
    gt, poses = _clip()
    stranger = poses[0, 0] + [0, 5.0, 0]
    results = [
        FrameResult(100, [7, 8], poses[0][[0, 1]]),
        FrameResult(101, [7, 8], poses[1][[1, 0]]),  # the ids swap: a switch for each actor
        FrameResult(102, [7, 8, 9], np.stack([poses[2, 0], poses[2, 1], stranger])),  # and back; a stranger
        FrameResult(103, [7], poses[3][[0]]),  # actor 1 not annotated: nothing to count for it
        FrameResult(104, [7], poses[4][[0]] + 0.6),  # too far from actor 0: missed, and a person of nobody
        FrameResult(105, [7, 8], poses[5][[0, 1]]),
        FrameResult(200, [1], poses[0][[0]]),  # a frame without ground truth: ignored
    ]
    report = identity_report(results, gt, actors=(0, 1))
    assert report.ids == ((7, 8), (8, 7))
    assert report.switches == ((101, 102), (101, 102))
    assert report.annotated == 11 and report.missed == 2  # frame 104: both actors without a near person
    assert report.false_people == 2  # the stranger and the person 0.6 m off
    lines = report.lines()
    assert lines[0] == 'Actor 1: ids [7, 8], 2 switches (frames 101, 102)'
    assert lines[2].startswith('clip: 11 annotated actor-frames, missed 2, switches 4; 2 people')


def test_a_steady_id_has_no_switch():
    gt, poses = _clip()
    results = [FrameResult(100 + k, [3, 4], poses[k][[0, 1]]) for k in (0, 1, 2, 4, 5)]
    report = identity_report(results, gt, actors=(0,))
    assert report.ids == ((3,),) and report.switches == ((),)
    assert report.lines()[0] == 'Actor 1: ids [3], 0 switches'
    assert report.missed == 0 and report.false_people == 0
