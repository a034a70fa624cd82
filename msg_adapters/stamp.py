"""The dataset timeline: frame f is stamped f / rate seconds exactly (the datasets' 25 Hz by
default: frame 300 -> 12 s), and a stamp maps back to the nearest frame."""
from __future__ import annotations

from fractions import Fraction

from builtin_interfaces.msg import Time

from mvpose_ros.core.defaults import FRAME_RATE

NS_PER_S = 1_000_000_000
MAX_SEC = (1 << 31) - 1  # Time.sec is INT32


def _check_rate(rate: float) -> Fraction:
    if not rate > 0 or rate == float('inf'):
        raise ValueError(f'frame rate: must be finite and > 0, got {rate}')
    return Fraction(rate)


def stamp_of_frame(frame: int, rate: float = FRAME_RATE) -> Time:
    """Header stamp of dataset frame (>= 0) at rate frames per second, rounded to the ns."""
    if int(frame) != frame or frame < 0:
        raise ValueError(f'frame: expected an integer >= 0, got {frame}')
    ns = round(int(frame) * NS_PER_S / _check_rate(rate))  # exact rational arithmetic
    if ns // NS_PER_S > MAX_SEC:
        raise ValueError(f'frame {frame} at {rate} Hz: stamp beyond the INT32 seconds range')
    return Time(sec=ns // NS_PER_S, nanosec=ns % NS_PER_S)


def stamp_ns(stamp: Time) -> int:
    """A stamp in integer nanoseconds (also the bag record time)."""
    return stamp.sec * NS_PER_S + stamp.nanosec


def stamp_of_ns(ns: int) -> Time:
    """The stamp of integer nanoseconds (>= 0): the inverse of stamp_ns."""
    return Time(sec=int(ns) // NS_PER_S, nanosec=int(ns) % NS_PER_S)


def frame_of_stamp(stamp: Time, rate: float = FRAME_RATE) -> int:
    """The frame nearest to stamp at rate frames per second."""
    return round(stamp_ns(stamp) * _check_rate(rate) / NS_PER_S)
