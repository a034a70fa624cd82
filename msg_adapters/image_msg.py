"""sensor_msgs/Image <-> BGR uint8 arrays (bgr8 out; bgr8 or rgb8 in, row padding allowed)."""
from __future__ import annotations

import array

import numpy as np
from sensor_msgs.msg import Image
from std_msgs.msg import Header

CHANNEL_ORDER = {'bgr8': [0, 1, 2], 'rgb8': [2, 1, 0]}  # -> BGR


def image_to_msg(bgr: np.ndarray, header: Header) -> Image:
    """A bgr8 Image of bgr (H, W, 3) uint8, rows unpadded."""
    bgr = np.asarray(bgr)
    if bgr.ndim != 3 or bgr.shape[2] != 3 or bgr.dtype != np.uint8:
        raise ValueError(f'image: expected (H, W, 3) uint8, got {bgr.dtype} {bgr.shape}')
    h, w = bgr.shape[:2]
    return Image(header=header, height=h, width=w, encoding='bgr8', is_bigendian=0, step=3 * w,
                 data=array.array('B', np.ascontiguousarray(bgr).tobytes()))


def msg_to_image(msg: Image) -> np.ndarray:
    """(H, W, 3) uint8 BGR of a bgr8 or rgb8 Image; step may exceed 3 * width (row padding)."""
    if msg.encoding not in CHANNEL_ORDER:
        raise ValueError(f'Image encoding: expected one of {sorted(CHANNEL_ORDER)}, '
                         f'got {msg.encoding!r}')
    h, w, step = msg.height, msg.width, msg.step
    if step < 3 * w:
        raise ValueError(f'Image step: {step} is less than 3 * width = {3 * w}')
    data = np.frombuffer(msg.data, dtype=np.uint8)
    if len(data) != step * h:
        raise ValueError(f'Image data: expected step * height = {step * h} bytes, got {len(data)}')
    rows = data.reshape(h, step)[:, :3 * w].reshape(h, w, 3)
    return np.ascontiguousarray(rows[..., CHANNEL_ORDER[msg.encoding]])
