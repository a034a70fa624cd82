"""The inputs refused per camera and cause, and the verdict that a camera cannot work: every one of
its first inputs refused for one cause, for long enough, and none used."""
from collections import Counter

from mvpose_ros.core.health.refusals import (MAX_CAUSES, OTHER_CAUSES, REFUSED_AFTER_S, REFUSED_MIN_MESSAGES,
                                             Refusals, refusals_of)
from mvpose_ros.core.health.status import Level, Status

WRONG = "frame_id 'a_optical' is not 'a'; set frame_id: a_optical in the rig file, or leave it out"


def test_a_camera_every_input_of_which_is_refused_for_one_cause_cannot_work():
    refusals = Refusals(['a', 'b'], 'image')
    for k in range(REFUSED_MIN_MESSAGES):
        refusals.refused('a', WRONG, 10.0 + 0.04 * k)
        refusals.used('b')
    assert refusals.verdict('a', 10.0 + REFUSED_AFTER_S - 0.01) is None, 'not yet long enough'
    assert refusals.verdict('a', 10.0 + REFUSED_AFTER_S) == f'every image refused: {WRONG}'
    assert refusals.verdict('b', 100.0) is None
    a, b = refusals.statuses('/heatmap_detector', 10.0 + REFUSED_AFTER_S)
    assert (a.name, a.level, a.message, a.hardware_id) == ('/heatmap_detector: refusals a', Level.ERROR,
                                                           f'every image refused: {WRONG}', 'a')
    assert (b.level, b.message) == (Level.OK, f'{REFUSED_MIN_MESSAGES} used, 0 refused since start')
    assert refusals_of(a) == ('a', Counter({WRONG: REFUSED_MIN_MESSAGES}))
    assert refusals_of(b) == ('b', Counter())


def test_one_input_used_two_causes_or_too_few_inputs_are_not_a_verdict():
    used = Refusals(['a'], 'image')
    used.used('a')
    two = Refusals(['a'], 'image')
    few = Refusals(['a'], 'image')
    for k in range(10):
        used.refused('a', WRONG, k)
        two.refused('a', WRONG if k % 2 else 'no intrinsics yet', k)
    few.refused('a', WRONG, 0.0)
    assert [r.verdict('a', 100.0) for r in (used, two, few)] == [None, None, None]


def test_causes_are_bounded_and_only_refusals_statuses_are_read():
    refusals = Refusals(['a'], 'openpose input')
    for k in range(MAX_CAUSES + 5):
        refusals.refused('a', f'cause {k}', 0.0)
    [status] = refusals.statuses('n', 1.0)
    camera, causes = refusals_of(status)
    assert len(causes) == MAX_CAUSES + 1 and causes[OTHER_CAUSES] == 5
    assert refusals_of(Status('n: input a', Level.ERROR, 'silent', {}, 'a')) is None
