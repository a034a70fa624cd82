"""A camera's image read from disk (JPEG or PNG), its size checked from the file's header before
it is decoded: against the camera's calibrated size when given, else against MAX_PIXELS."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from mvpose_ros.core.detection.encoded_image import MAX_PIXELS, decode_encoded, max_image_bytes
from mvpose_ros.core.geometry.camera import Camera


def read_image(path: str | Path, camera: Camera | None = None) -> np.ndarray:
    """(H, W, 3) uint8 BGR image (of `camera`, when given). FileNotFoundError when there is no
    such file; ValueError (naming the file) when it is larger than an image of its size can be,
    not a JPEG or PNG, declares another size than the camera's or more than MAX_PIXELS, or does
    not decode. Nothing is decoded before its header has passed."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f'{path}: no such image')
    expected = (camera.width, camera.height) if camera is not None else None
    limit = max_image_bytes(*expected) if expected else max_image_bytes(MAX_PIXELS, 1)
    size = path.stat().st_size
    if size > limit:
        of = f'camera {camera.name} ({camera.width}x{camera.height})' if camera else f'{MAX_PIXELS} pixels'
        raise ValueError(f'{path}: {size} bytes, more than an image of {of} takes ({limit}): not read')
    try:
        return decode_encoded(np.fromfile(path, dtype=np.uint8), expected)
    except ValueError as exc:
        whose = f" (camera {camera.name}'s calibrated size)" if camera else ''
        raise ValueError(f'{path}: image {exc}{whose}') from None
