"""The one throttled logger every node uses: a problem repeating every frame is logged once per
period with how many were not logged."""
from __future__ import annotations

from mvpose_ros.core.throttled_log import MAX_CAUSE_CHARS, MAX_CAUSES, OTHER_CAUSES, ThrottledLog


class _Logger:
    def __init__(self) -> None:
        self.lines: list[tuple[str, str]] = []

    def error(self, text: str) -> None:
        self.lines.append(('error', text))

    def warning(self, text: str) -> None:
        self.lines.append(('warning', text))


def test_a_problem_repeating_every_frame_is_logged_once_per_period_with_a_count():
    logger, now = _Logger(), [0.0]
    log = ThrottledLog(logger, period=5.0, clock=lambda: now[0])
    said = []
    for frame in range(250):  # 10 s at 25 Hz
        now[0] = frame / 25
        said.append(log.log(('cam2', 'late'), f'cam2 frame {frame} late'))
    assert [i for i, s in enumerate(said) if s] == [0, 125]  # at 0 s and at 5 s
    assert logger.lines == [('warning', 'cam2 frame 0 late'),
                            ('warning', 'cam2 frame 125 late (124 more like it in the last 5 s)')]
    assert log.counts[('cam2', 'late')] == 250


def test_keys_are_throttled_apart_and_summarised():
    logger, now = _Logger(), [0.0]
    log = ThrottledLog(logger, period=5.0, clock=lambda: now[0])
    assert log.log(('left', 'truncated'), 'a', 'error')
    assert not log.log(('left', 'truncated'), 'b', 'error')
    assert log.log(('right', 'truncated'), 'c', 'error')  # another subject
    assert log.log(('left', 'bayer'), 'd', 'error')  # another cause
    now[0] = 5.0
    assert log.log(('left', 'truncated'), 'e', 'error')
    assert logger.lines == [('error', 'a'), ('error', 'c'), ('error', 'd'),
                            ('error', 'e (1 more like it in the last 5 s)')]
    assert log.summary() == 'left: 1 x bayer; left: 3 x truncated; right: 1 x truncated'
    assert ThrottledLog(logger).summary() == 'none'


def test_junk_with_ever_new_causes_keeps_the_log_bounded():
    """Every junk message can carry a cause of its own (its size, its frame_id): past MAX_CAUSES
    per subject they are counted together, and a long cause is cut, so neither the lines nor the
    counts grow with a flood."""
    logger = _Logger()
    log = ThrottledLog(logger, clock=lambda: 0.0)
    for k in range(1000):
        cause = f"frame_id '{k}{'x' * 5000}' is not this camera"
        log.log(('left', cause), f'left: image dropped: {cause}', 'error')
    assert log.log(('right', 'Image data: 9 bytes'), 'right: Image data: 9 bytes', 'error')  # a subject of its own
    assert len(log.counts) == MAX_CAUSES + 2
    assert log.counts['left', OTHER_CAUSES] == 1000 - MAX_CAUSES
    assert max(len(cause) for _, cause in log.counts) <= MAX_CAUSE_CHARS
    assert sum(level == 'error' for level, _ in logger.lines) == MAX_CAUSES + 2  # the others counted, not told
    assert max(len(text) for _, text in logger.lines) <= 2 * MAX_CAUSE_CHARS


def test_an_rclpy_logger_takes_every_level_from_one_log():
    """rclpy refuses a second severity from one call site ('Logger severity cannot be changed
    between calls'): the detector logs dropped inputs as errors and dropped sets as warnings."""
    import rclpy.logging
    log = ThrottledLog(rclpy.logging.get_logger('throttled_log_test'), clock=lambda: 0.0)
    for k, level in enumerate(('error', 'warning', 'info', 'error')):
        assert log.log((f'cam{k}', level), f'a {level}', level)
