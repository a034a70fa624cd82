"""Simple line plots drawn with OpenCV (no plotting library): axes with labelled ticks, a title,
one line with point markers per series, a legend, written as PNG."""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np

FONT = cv2.FONT_HERSHEY_SIMPLEX
# BGR, a qualitative palette (tab10's hues), readable on white
PALETTE = ((180, 119, 31), (14, 127, 255), (44, 160, 44), (40, 39, 214), (189, 103, 148), (75, 86, 140),
           (194, 119, 227), (34, 189, 188), (207, 190, 23), (127, 127, 127))
BLACK, GRID, WHITE = (0, 0, 0), (225, 225, 225), (255, 255, 255)


@dataclass
class Series:
    """One line: points (x[i], y[i]) in order (NaN y: no point, the line breaks there)."""

    name: str
    x: Sequence[float]
    y: Sequence[float]
    color: tuple[int, int, int] | None = None  # BGR; None = next palette colour
    thickness: int = 2
    dashed: bool = False


def nice_ticks(lo: float, hi: float, count: int = 6) -> np.ndarray:
    """Round tick values (1, 2, 2.5 or 5 x 10^k apart) covering [lo, hi], about `count` of them."""
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return np.array([0.0, 1.0])
    if hi <= lo:
        hi = lo + (abs(lo) or 1.0)
    raw = (hi - lo) / max(count - 1, 1)
    mag = 10 ** math.floor(math.log10(raw))
    step = next(m * mag for m in (1, 2, 2.5, 5, 10) if m * mag >= raw)
    first = math.floor(lo / step + 1e-9) * step
    last = math.ceil(hi / step - 1e-9) * step
    return np.round(np.arange(first, last + step / 2, step), 10)


def _label(v: float) -> str:
    return f'{v:.0f}' if float(v).is_integer() else f'{v:g}'


def _text(img: np.ndarray, text: str, org: tuple[int, int], scale: float = 0.5, color=BLACK, thickness: int = 1,
          align: str = 'left', valign: str = 'baseline') -> None:
    (w, h), base = cv2.getTextSize(text, FONT, scale, thickness)
    x, y = org
    x -= {'left': 0, 'centre': w // 2, 'right': w}[align]
    y += {'baseline': 0, 'middle': h // 2, 'top': h}[valign]
    cv2.putText(img, text, (int(x), int(y)), FONT, scale, color, thickness, cv2.LINE_AA)


def _vertical_text(img: np.ndarray, text: str, centre: tuple[int, int], scale: float = 0.55) -> None:
    (w, h), base = cv2.getTextSize(text, FONT, scale, 1)
    patch = np.full((h + base + 4, w + 4, 3), 255, np.uint8)
    cv2.putText(patch, text, (2, h + 2), FONT, scale, BLACK, 1, cv2.LINE_AA)
    patch = cv2.rotate(patch, cv2.ROTATE_90_COUNTERCLOCKWISE)
    ph, pw = patch.shape[:2]
    x0, y0 = max(centre[0] - pw // 2, 0), max(centre[1] - ph // 2, 0)
    region = img[y0:y0 + ph, x0:x0 + pw]
    region[...] = np.minimum(region, patch[:region.shape[0], :region.shape[1]])


def _dashed(img: np.ndarray, p: tuple[int, int], q: tuple[int, int], color, thickness: int, dash: int = 8) -> None:
    length = math.hypot(q[0] - p[0], q[1] - p[1])
    for s in np.arange(0, length, 2 * dash):
        a, b = s / max(length, 1e-9), min(s + dash, length) / max(length, 1e-9)
        cv2.line(img, (round(p[0] + a * (q[0] - p[0])), round(p[1] + a * (q[1] - p[1]))),
                 (round(p[0] + b * (q[0] - p[0])), round(p[1] + b * (q[1] - p[1]))), color, thickness, cv2.LINE_AA)


def line_plot(path: str | Path, series: Sequence[Series], *, title: str, xlabel: str, ylabel: str,
              size: tuple[int, int] = (1000, 620), xticks: Sequence[float] | None = None,
              legend_width: int = 260) -> Path:
    """Draw the series on shared axes (y from 0) and write a PNG of size (width, height) to path.
    xticks: where to put the x ticks (default: round values over the data)."""
    width, height = size
    img = np.full((height, width, 3), 255, np.uint8)
    left, right, top, bottom = 80, legend_width, 56, 64
    x0, x1, y0, y1 = left, width - right, top, height - bottom  # plot area in pixels (y0 top)
    xs = np.array([v for s in series for v in s.x], dtype=float)
    ys = np.array([v for s in series for v in s.y], dtype=float)
    xs, ys = xs[np.isfinite(xs)], ys[np.isfinite(ys)]
    if xticks is None:
        xt = nice_ticks(xs.min(), xs.max()) if len(xs) else np.array([0.0, 1.0])
    else:
        xt = np.asarray(xticks, dtype=float)
    xlo, xhi = (min(xt.min(), xs.min(initial=xt.min())), max(xt.max(), xs.max(initial=xt.max())))
    if xhi <= xlo:
        xlo, xhi = xlo - 1, xhi + 1
    pad = 0.04 * (xhi - xlo)
    xlo, xhi = xlo - pad, xhi + pad
    yt = nice_ticks(0.0, ys.max() if len(ys) and ys.max() > 0 else 1.0)
    ylo, yhi = 0.0, yt.max()

    def px(x: float, y: float) -> tuple[int, int]:
        return (round(x0 + (x - xlo) / (xhi - xlo) * (x1 - x0)), round(y1 - (y - ylo) / (yhi - ylo) * (y1 - y0)))

    for v in yt:
        y = px(xlo, v)[1]
        cv2.line(img, (x0, y), (x1, y), GRID, 1)
        _text(img, _label(v), (x0 - 8, y), 0.45, align='right', valign='middle')
    for v in xt:
        x = px(v, 0)[0]
        cv2.line(img, (x, y0), (x, y1), GRID, 1)
        cv2.line(img, (x, y1), (x, y1 + 5), BLACK, 1)
        _text(img, _label(v), (x, y1 + 10), 0.45, align='centre', valign='top')
    cv2.rectangle(img, (x0, y0), (x1, y1), BLACK, 1)
    _text(img, title, ((x0 + x1) // 2, 30), 0.65, thickness=2, align='centre')
    _text(img, xlabel, ((x0 + x1) // 2, height - 16), 0.55, align='centre')
    _vertical_text(img, ylabel, (20, (y0 + y1) // 2))

    colours = iter(PALETTE * 4)
    legend_y = y0 + 8
    for s in series:
        colour = s.color or next(colours)
        pts = [(px(x, y) if math.isfinite(x) and math.isfinite(y) else None) for x, y in zip(s.x, s.y)]
        for p, q in zip(pts, pts[1:]):
            if p is not None and q is not None:
                if s.dashed:
                    _dashed(img, p, q, colour, s.thickness)
                else:
                    cv2.line(img, p, q, colour, s.thickness, cv2.LINE_AA)
        for p in pts:
            if p is not None and not s.dashed:
                cv2.circle(img, p, s.thickness + 2, colour, -1, cv2.LINE_AA)
        lx = x1 + 16
        if s.dashed:
            _dashed(img, (lx, legend_y), (lx + 30, legend_y), colour, s.thickness, 5)
        else:
            cv2.line(img, (lx, legend_y), (lx + 30, legend_y), colour, s.thickness, cv2.LINE_AA)
            cv2.circle(img, (lx + 15, legend_y), s.thickness + 2, colour, -1, cv2.LINE_AA)
        _text(img, s.name, (lx + 38, legend_y), 0.45, valign='middle')
        legend_y += 24
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), img):
        raise OSError(f'could not write {path}')
    return path
