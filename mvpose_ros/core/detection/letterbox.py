"""The letterbox transform: an image region scaled into a square network input, centred and
padded with zeros, and turned by quarter turns (a camera mounted on its side or upside down: the
network sees people upright), as an affine map both ways; and maps on the network's grid
resampled onto an image-aligned grid of cells.

Coordinates are pixel centres: pixel (0, 0) is at (0.0, 0.0) and covers [-0.5, 0.5]^2, as in
OpenCV (cv2.resize, cv2.warpAffine). The region is cut at whole image pixels and resized (resized)
with its pixel edges on the input's, so the map between them is exact:
input = scale * image + shift, per axis (the two scales differ only by the rounding of the
resized size).
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class Letterbox:
    """roi: (x0, y0, x1, y1) image pixels cut (end exclusive); content: (x, y, w, h) where the
    resized roi lies in the size x size input before it is turned; scale, shift: (2,) u, v then
    x, y of the map unturned input = scale * image + shift; turns: quarter turns of the input,
    counterclockwise as shown (np.rot90's), after that map."""

    roi: tuple[int, int, int, int]
    content: tuple[int, int, int, int]
    size: int
    scale: np.ndarray
    shift: np.ndarray
    turns: int = 0

    def to_input(self, uv: np.ndarray) -> np.ndarray:
        """Network input pixels (..., 2) of image pixels uv (..., 2)."""
        return _turned(np.asarray(uv, dtype=np.float64) * self.scale + self.shift, self.turns, self.size)

    def to_image(self, xy: np.ndarray) -> np.ndarray:
        """Image pixels (..., 2) of network input pixels xy (..., 2)."""
        return (_turned(np.asarray(xy, dtype=np.float64), -self.turns, self.size) - self.shift) / self.scale

    def contains(self, uv: np.ndarray) -> np.ndarray:
        """(...,) whether image pixels uv (..., 2) lie in the cut region (False for NaN)."""
        uv = np.asarray(uv, dtype=np.float64)
        x0, y0, x1, y1 = self.roi
        return (uv[..., 0] >= x0 - 0.5) & (uv[..., 0] <= x1 - 0.5) & (uv[..., 1] >= y0 - 0.5) & (uv[..., 1] <= y1 - 0.5)

    def apply(self, image: np.ndarray, shrink: np.ndarray | None = None) -> np.ndarray:
        """The (size, size, C) input of image (H, W, C): the roi resized into the content
        rectangle, zeros around (see resized). shrink (2,): camera pixels per image pixel along
        u, v when image is a shrunk copy of the image the letterbox was made for."""
        x0, y0, x1, y1 = self.roi
        cx, cy, cw, ch = self.content
        out = np.zeros((self.size, self.size) + image.shape[2:], dtype=image.dtype)
        if shrink is None:
            out[cy:cy + ch, cx:cx + cw] = resized(image[y0:y1, x0:x1], cw, ch)
        else:
            edges = np.array([x0, y0, x1, y1], dtype=np.float64) / np.tile(np.asarray(shrink, dtype=np.float64), 2)
            out[cy:cy + ch, cx:cx + cw] = resized(image, cw, ch, edges)
        return np.ascontiguousarray(np.rot90(out, self.turns)) if self.turns % 4 else out

    def image_grid(self, stride: float) -> tuple[np.ndarray, tuple[int, int]]:
        """An image-aligned grid of cells `stride` px apart over the roi: the pixel of cell
        [0, 0] (2,) (the roi's first pixel) and the grid shape (h, w)."""
        x0, y0, x1, y1 = self.roi
        w = int(np.floor((x1 - 1 - x0) / stride)) + 1
        h = int(np.floor((y1 - 1 - y0) / stride)) + 1
        return np.array([x0, y0], dtype=np.float64), (h, w)

    def maps_to_image(self, maps: np.ndarray, origin: np.ndarray, stride: float,
                      shape: tuple[int, int]) -> np.ndarray:
        """Resample maps (size, size, J), channel last as the network gives them, value [y, x, j]
        at input pixel (x, y), onto the image grid whose cell [r, c] is at image pixel origin +
        stride * (c, r), shape (h, w): returns (J, h, w). Separable tent interpolation whose
        support widens to one output cell when cells are coarser than the input's pixels (bilinear
        otherwise), so a peak keeps its mass; 0 where a cell falls outside the input."""
        maps = np.rot90(maps, -self.turns)  # back to the image's axes: the affine map's input
        h, w = shape
        cols = origin[0] + stride * np.arange(w)
        rows = origin[1] + stride * np.arange(h)
        cols, rows = cols * self.scale[0] + self.shift[0], rows * self.scale[1] + self.shift[1]
        ix, wx = _tent_taps(cols, self.size, stride * self.scale[0])  # (w, K)
        iy, wy = _tent_taps(rows, self.size, stride * self.scale[1])  # (h, K)
        maps = np.asarray(maps, dtype=np.float32)
        # rows first: each tap is a whole contiguous input row, and only the grid's rows are read
        down = np.einsum('hk,hkxj->hxj', wy, maps[iy], optimize=True)  # (h, size, J)
        return np.einsum('wk,hwkj->jhw', wx, down[:, ix], optimize=True)  # (J, h, w)


def _turned(xy: np.ndarray, turns: int, size: int) -> np.ndarray:
    """Pixels (..., 2) of a size x size square turned `turns` quarter turns as np.rot90 turns an
    array (counterclockwise as shown; negative: clockwise); pixel centres map to pixel centres."""
    k = turns % 4
    if k == 0:
        return xy
    x, y, far = xy[..., 0], xy[..., 1], size - 1
    turned = {1: (y, far - x), 2: (far - x, far - y), 3: (far - y, x)}[k]
    return np.stack(turned, axis=-1)


def resized(image: np.ndarray, width: int, height: int, box: np.ndarray | None = None) -> np.ndarray:
    """The part box (4,) x0, y0, x1, y1 (pixel edges: 0 is pixel 0's left edge; default the whole
    image) of image (H, W, C) resized to (height, width, C), box's edges mapped onto the output's
    exactly (as cv2.resize maps an image's). Shrinking by k or more (k >= 2 whole) averages k x k
    blocks first (area averaging, so small people are not aliased; OpenCV's whole-factor path,
    several times faster than its general one), then interpolates bilinearly by the rest, less than
    2; outside the image's whole blocks, pixels are replicated from the edge."""
    h, w = image.shape[:2]
    box = np.array([0.0, 0.0, w, h] if box is None else box, dtype=np.float64)
    k = int(min((box[2] - box[0]) / width, (box[3] - box[1]) / height))
    if k >= 2:
        x0, y0 = int(box[0]) // k * k, int(box[1]) // k * k  # whole blocks from a multiple of k
        x1 = x0 + (min(w, int(np.ceil(box[2]))) - x0) // k * k
        y1 = y0 + (min(h, int(np.ceil(box[3]))) - y0) // k * k
        image = cv2.resize(image[y0:y1, x0:x1], ((x1 - x0) // k, (y1 - y0) // k), interpolation=cv2.INTER_AREA)
        box = (box - [x0, y0, x0, y0]) / k
        if image.shape[:2] == (height, width) and np.allclose(box, [0, 0, width, height]):
            return image
    # output pixel centre X: X + 0.5 = a * (x + 0.5 - box edge), per axis
    a = np.array([width / (box[2] - box[0]), height / (box[3] - box[1])])
    m = np.array([[a[0], 0.0, a[0] * (0.5 - box[0]) - 0.5], [0.0, a[1], a[1] * (0.5 - box[1]) - 0.5]])
    return cv2.warpAffine(image, m, (width, height), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def _tent_taps(positions: np.ndarray, n: int, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Interpolation of samples 0..n-1 at fractional positions (N,): sample indices and weights
    (N, K) of a tent of half-width max(1, step) samples, weights summing to 1 (all 0 for
    positions outside [0, n - 1])."""
    radius = max(1.0, float(step))
    k = np.arange(-int(np.ceil(radius)), int(np.ceil(radius)) + 1)
    index = np.floor(positions)[:, None].astype(np.intp) + k[None, :]
    weights = np.maximum(0.0, 1.0 - np.abs(positions[:, None] - index) / radius)
    weights[(index < 0) | (index >= n)] = 0.0
    total = weights.sum(axis=1, keepdims=True)
    inside = (positions >= 0) & (positions <= n - 1)
    weights = np.where(inside[:, None] & (total > 0), weights / np.where(total > 0, total, 1.0), 0.0)
    return np.clip(index, 0, n - 1), weights.astype(np.float32)


def letterbox(width: int, height: int, box: np.ndarray, size: int, turns: int = 0) -> Letterbox:
    """The letterbox of the image region box (u0, v0, u1, v1), pixel edges in pixel-centre
    coordinates (the whole image is (-0.5, -0.5, width - 0.5, height - 0.5)), cut to the image
    and to whole pixels, into a size x size input turned `turns` quarter turns (np.rot90's).
    ValueError when the region holds no pixel."""
    u0, v0, u1, v1 = np.asarray(box, dtype=np.float64)
    x0, y0 = max(0, int(np.floor(u0 + 0.5))), max(0, int(np.floor(v0 + 0.5)))
    x1, y1 = min(width, int(np.ceil(u1 + 0.5))), min(height, int(np.ceil(v1 + 0.5)))
    if not (x1 > x0 and y1 > y0):
        raise ValueError(f'letterbox region {np.round([u0, v0, u1, v1], 1).tolist()} holds no pixel of '
                         f'the {width}x{height} image')
    n = np.array([x1 - x0, y1 - y0], dtype=np.float64)
    fitted = np.maximum(1, np.round(n * size / n.max())).astype(int)
    offset = (size - fitted) // 2
    scale = fitted / n
    # edges map to edges: x + 0.5 = offset + scale * (u + 0.5 - x0)
    shift = offset + scale * (0.5 - np.array([x0, y0])) - 0.5
    return Letterbox(roi=(x0, y0, x1, y1), content=(int(offset[0]), int(offset[1]), int(fitted[0]), int(fitted[1])),
                     size=int(size), scale=scale, shift=shift, turns=int(turns) % 4)


def whole_image(width: int, height: int, size: int, turns: int = 0) -> Letterbox:
    """The letterbox of a whole width x height image into size x size, turned `turns` quarter turns."""
    return letterbox(width, height, np.array([-0.5, -0.5, width - 0.5, height - 0.5]), size, turns)
