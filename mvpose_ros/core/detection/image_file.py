"""A camera's image read from disk, checked against the camera's calibrated size when given."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from mvpose_ros.core.geometry.camera import Camera


def read_image(path: str | Path, camera: Camera | None = None) -> np.ndarray:
    """(H, W, 3) uint8 BGR image (of `camera`, when given). FileNotFoundError when there is no
    such file, ValueError (naming the file) when it is not a readable image or not the camera's
    calibrated size."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f'{path}: no such image')
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise ValueError(f'{path}: not a readable image')
    if camera is not None and bgr.shape[:2] != (camera.height, camera.width):
        raise ValueError(f'{path}: image size {bgr.shape[1]}x{bgr.shape[0]}, camera {camera.name} '
                         f'is calibrated for {camera.width}x{camera.height}')
    return bgr
