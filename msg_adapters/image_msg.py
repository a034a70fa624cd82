"""sensor_msgs/Image and CompressedImage <-> (H, W, 3) uint8 BGR arrays.

Image encodings: bgr8, rgb8, mono8, bgra8, rgba8, the 16-bit bgr16, rgb16, mono16 (byte order
from is_bigendian; the high byte is kept) and the packed 4:2:2 encodings drivers publish:
'yuv422' and 'uyvy' (U Y0 V Y1), 'yuv422_yuy2' and 'yuyv' (Y0 U Y1 V), BT.601 as OpenCV converts
them, and the Bayer mosaics machine-vision drivers publish as image_raw (bayer_rggb8, bayer_bggr8,
bayer_gbrg8, bayer_grbg8 and their 16-bit forms; the letters are the top-left 2x2 cell, row by
row), demosaiced as cv_bridge does. Rows may be padded (step > width * bytes per pixel).

CompressedImage: jpeg and png, the format string as image_transport writes it ('jpeg', 'png',
'bgr8; jpeg compressed bgr8', 'rgb8; png compressed rgb8', ...). The image size is read from the
data's own header (JPEG frame header, PNG IHDR: core.detection.encoded_image) and checked against
the caller's expected size and MAX_PIXELS before anything is decoded: a small message declaring a
huge image is refused without allocating it.

Bounded input: with an expected size, a message's data may hold at most max_image_bytes of it
(either type), checked first. check_camera_image runs every check short of decoding, once, on
arrival; its CheckedImage decodes without checking again.

Every failure is a ValueError with a one-line reason.
"""
from __future__ import annotations

import array
from dataclasses import dataclass

import cv2
import numpy as np
from sensor_msgs.msg import CompressedImage, Image
from std_msgs.msg import Header

from mvpose_ros.core.detection.encoded_image import MAX_PIXELS, check_bytes, check_encoded, check_size, decode_checked

# encoding -> (channels, bytes per channel, channel order to BGR or a cv2 4:2:2 conversion)
_PLAIN = {
    'bgr8': (3, 1, [0, 1, 2]), 'rgb8': (3, 1, [2, 1, 0]), 'mono8': (1, 1, [0, 0, 0]),
    'bgra8': (4, 1, [0, 1, 2]), 'rgba8': (4, 1, [2, 1, 0]),
    'bgr16': (3, 2, [0, 1, 2]), 'rgb16': (3, 2, [2, 1, 0]), 'mono16': (1, 2, [0, 0, 0]),
}
_YUV422 = {  # encoding -> (decode, encode) cv2 conversions
    'yuv422': (cv2.COLOR_YUV2BGR_UYVY, cv2.COLOR_BGR2YUV_UYVY),
    'uyvy': (cv2.COLOR_YUV2BGR_UYVY, cv2.COLOR_BGR2YUV_UYVY),
    'yuv422_yuy2': (cv2.COLOR_YUV2BGR_YUY2, cv2.COLOR_BGR2YUV_YUY2),
    'yuyv': (cv2.COLOR_YUV2BGR_YUY2, cv2.COLOR_BGR2YUV_YUY2),
}
# pattern -> cv2 demosaicing; OpenCV names a mosaic by its second row's second and third pixels
_DEMOSAIC = {'rggb': cv2.COLOR_BayerBG2BGR, 'bggr': cv2.COLOR_BayerRG2BGR,
             'gbrg': cv2.COLOR_BayerGR2BGR, 'grbg': cv2.COLOR_BayerGB2BGR}
_BAYER = {f'bayer_{pattern}{bits}': (pattern, bits // 8) for pattern in _DEMOSAIC for bits in (8, 16)}
ENCODINGS = tuple(_PLAIN) + tuple(_YUV422) + tuple(_BAYER)
COMPRESSED_FORMATS = ('jpeg', 'png')


def _bytes_per_pixel(encoding: str) -> int:
    if encoding in _YUV422:
        return 2
    if encoding in _BAYER:
        return _BAYER[encoding][1]
    channels, depth, _ = _PLAIN[encoding]
    return channels * depth


def _sixteen_bit(encoding: str) -> bool:
    return encoding.endswith('16')


def _check_bgr(bgr: np.ndarray) -> np.ndarray:
    bgr = np.asarray(bgr)
    if bgr.ndim != 3 or bgr.shape[2] != 3 or bgr.dtype != np.uint8:
        raise ValueError(f'image: expected (H, W, 3) uint8, got {bgr.dtype} {bgr.shape}')
    if bgr.shape[0] < 1 or bgr.shape[1] < 1:
        raise ValueError(f'image: expected at least 1x1 pixels, got {bgr.shape[1]}x{bgr.shape[0]}')
    return np.ascontiguousarray(bgr)


def image_to_msg(bgr: np.ndarray, header: Header, encoding: str = 'bgr8', padding: int = 0,
                 bigendian: bool = False) -> Image:
    """An Image of bgr (H, W, 3) uint8 in `encoding` (any of ENCODINGS; mono keeps the luma, a
    Bayer mosaic each pixel's colour of its pattern, 16-bit ones scale by 257, 4:2:2 ones need an
    even width), each row followed by `padding` bytes; bigendian: the byte order of 16-bit encodings."""
    bgr = _check_bgr(bgr)
    if encoding not in ENCODINGS:
        raise ValueError(f'Image encoding: expected one of {list(ENCODINGS)}, got {encoding!r}')
    h, w = bgr.shape[:2]
    if encoding in _YUV422:
        if w % 2:
            raise ValueError(f'Image width: {encoding} packs pixel pairs, so the width must be even, got {w}')
        pixels = cv2.cvtColor(bgr, _YUV422[encoding][1])  # (H, W, 2)
    elif encoding in _BAYER:
        pixels = _mosaic(bgr, _BAYER[encoding][0])
    elif _PLAIN[encoding][0] == 1:
        pixels = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    else:
        pixels = bgr[..., [2, 1, 0]] if encoding.startswith('rgb') else bgr
        if _PLAIN[encoding][0] == 4:
            pixels = np.concatenate([pixels, np.full((h, w, 1), 255, np.uint8)], axis=2)
    if _sixteen_bit(encoding):
        pixels = (pixels.astype(np.uint16) * 257).astype('>u2' if bigendian else '<u2')
    row = pixels.reshape(h, -1).view(np.uint8)
    rows = np.zeros((h, row.shape[1] + padding), np.uint8)
    rows[:, :row.shape[1]] = row
    return Image(header=header, height=h, width=w, encoding=encoding, is_bigendian=int(bigendian),
                 step=rows.shape[1], data=array.array('B', rows.tobytes()))


def check_image(msg: Image, expected: tuple[int, int] | None = None) -> None:
    """Every check of msg_to_image short of converting: the data at most max_image_bytes of
    expected (width, height) (first, if given), the encoding, exactly that size (at most
    MAX_PIXELS anyway), step and data length. ValueError otherwise."""
    try:
        check_bytes(len(msg.data), expected)
    except ValueError as exc:
        raise _with_prefix('Image', exc) from None
    encoding = msg.encoding
    if encoding not in ENCODINGS:
        raise ValueError(f'Image encoding: expected one of {list(ENCODINGS)}, got {encoding!r}')
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    try:
        check_size(w, h, expected)
    except ValueError as exc:
        raise _with_prefix('Image', exc) from None
    packed = _bytes_per_pixel(encoding) * w
    if step < packed:
        raise ValueError(f'Image step: {step} is less than {_bytes_per_pixel(encoding)} * width = {packed}')
    if len(msg.data) != step * h:
        raise ValueError(f'Image data: expected step * height = {step * h} bytes, got {len(msg.data)}')
    if encoding in _YUV422 and w % 2:
        raise ValueError(f'Image width: {encoding} packs pixel pairs, so the width must be even, got {w}')


def msg_to_image(msg: Image, expected: tuple[int, int] | None = None) -> np.ndarray:
    """(H, W, 3) uint8 BGR of an Image in any of ENCODINGS; step may exceed the packed row
    (padding). expected: (width, height) pixels the image must have, if given (check_image)."""
    check_image(msg, expected)
    return _converted(msg)


def _converted(msg: Image) -> np.ndarray:
    """(H, W, 3) uint8 BGR of an Image that check_image passed."""
    encoding = msg.encoding
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    packed = _bytes_per_pixel(encoding) * w
    rows = np.ascontiguousarray(np.frombuffer(msg.data, dtype=np.uint8).reshape(h, step)[:, :packed])
    if encoding in _YUV422:
        return cv2.cvtColor(rows.reshape(h, w, 2), _YUV422[encoding][0])
    if _sixteen_bit(encoding):
        rows = (rows.view('>u2' if msg.is_bigendian else '<u2') >> 8).astype(np.uint8)
    if encoding in _BAYER:
        return cv2.cvtColor(rows, _DEMOSAIC[_BAYER[encoding][0]])
    channels, _, order = _PLAIN[encoding]
    return np.ascontiguousarray(rows.reshape(h, w, channels)[..., order])


def _mosaic(bgr: np.ndarray, pattern: str) -> np.ndarray:
    """(H, W) uint8: each pixel of bgr (H, W, 3) keeps the channel its place in the 2x2 `pattern`
    (e.g. 'rggb': R at even rows and columns) names."""
    out = np.empty(bgr.shape[:2], np.uint8)
    for k, colour in enumerate(pattern):
        out[k // 2::2, k % 2::2] = bgr[k // 2::2, k % 2::2, 'bgr'.index(colour)]
    return out


def image_to_compressed_msg(bgr: np.ndarray, header: Header, fmt: str = 'jpeg', quality: int = 95) -> CompressedImage:
    """A CompressedImage of bgr (H, W, 3) uint8 as image_transport writes it: fmt 'jpeg' (quality
    0..100) or 'png' (lossless), format string 'bgr8; <fmt> compressed bgr8'."""
    bgr = _check_bgr(bgr)
    if fmt not in COMPRESSED_FORMATS:
        raise ValueError(f'CompressedImage format: expected one of {list(COMPRESSED_FORMATS)}, got {fmt!r}')
    params = [cv2.IMWRITE_JPEG_QUALITY, int(quality)] if fmt == 'jpeg' else []
    ok, buffer = cv2.imencode('.jpg' if fmt == 'jpeg' else '.png', bgr, params)
    if not ok:
        raise ValueError(f'CompressedImage: {fmt} encoding failed')
    return CompressedImage(header=header, format=f'bgr8; {fmt} compressed bgr8',
                           data=array.array('B', buffer.tobytes()))


def compressed_format(fmt: str) -> str:
    """'jpeg' or 'png' of an image_transport format string ('jpeg', 'png', 'bgr8; jpeg compressed
    bgr8', ...); ValueError for anything else (compressedDepth included)."""
    words = fmt.lower().replace(';', ' ').split()
    found = {'jpeg' if w in ('jpeg', 'jpg') else w for w in words} & set(COMPRESSED_FORMATS)
    if len(found) != 1 or 'compresseddepth' in words:
        raise ValueError(f'CompressedImage format: expected jpeg or png (as image_transport writes them), '
                         f'got {fmt!r}')
    return found.pop()


def _with_prefix(what: str, exc: ValueError) -> ValueError:
    return ValueError(f'{what} {exc}')


def check_compressed(msg: CompressedImage, expected: tuple[int, int] | None = None,
                     max_pixels: int = MAX_PIXELS) -> tuple[str, int, int]:
    """('jpeg' | 'png', width, height) of a CompressedImage whose format string and data agree,
    whose data is at most what an image of expected (width, height) takes and whose header
    declares exactly that size (if given; at most max_pixels anyway), with its end marker: every
    check short of decoding. ValueError otherwise."""
    fmt = compressed_format(msg.format)
    try:
        kind, width, height = check_encoded(np.frombuffer(msg.data, dtype=np.uint8), expected, max_pixels)
    except ValueError as exc:
        raise _with_prefix('CompressedImage', exc) from None
    if kind != fmt:
        raise ValueError(f'CompressedImage data: format {msg.format!r} says {fmt}, the data is a {kind.upper()}')
    return kind, width, height


@dataclass(frozen=True)
class CheckedImage:
    """An Image or CompressedImage that passed every check short of decoding (check_camera_image),
    with what they found: kind ('jpeg', 'png', or 'raw' for an Image), the size it declares, and
    the size it was checked against (None: a camera whose size was not known yet, see fits)."""

    msg: Image | CompressedImage
    kind: str
    width: int
    height: int
    expected: tuple[int, int] | None

    def fits(self, expected: tuple[int, int]) -> CheckedImage:
        """This image, checked against the size of its camera (expected (width, height)) from what
        its check found, nothing read again. ValueError when it is another size or too large."""
        raw = self.kind == 'raw'
        what, declared = ('Image', '') if raw else ('CompressedImage', f'the {self.kind} header declares ')
        try:
            check_bytes(len(self.msg.data), expected)
            check_size(self.width, self.height, expected, declared=declared)
        except ValueError as exc:
            raise _with_prefix(what, exc) from None
        return CheckedImage(self.msg, self.kind, self.width, self.height, tuple(expected))

    def decode(self, reduce: int = 1) -> np.ndarray:
        """(H, W, 3) uint8 BGR, decoded without checking again; a JPEG may come back at 1/reduce of
        its size (encoded_image.decode_checked), other images whole."""
        if self.kind == 'raw':
            return _converted(self.msg)
        try:
            return decode_checked(np.frombuffer(self.msg.data, dtype=np.uint8), self.kind, self.width, self.height,
                                  reduce)
        except ValueError as exc:
            raise _with_prefix('CompressedImage', exc) from None


def compressed_to_image(msg: CompressedImage, expected: tuple[int, int] | None = None,
                        max_pixels: int = MAX_PIXELS, reduce: int = 1) -> np.ndarray:
    """(H, W, 3) uint8 BGR of a jpeg or png CompressedImage, decoded once check_compressed passes
    (a jpeg at 1/reduce of its size: encoded_image.decode_checked)."""
    return CheckedImage(msg, *check_compressed(msg, expected, max_pixels), expected).decode(reduce)


def check_camera_image(msg: Image | CompressedImage, expected: tuple[int, int] | None) -> CheckedImage:
    """Every check of to_bgr short of decoding, for a camera of expected (width, height) pixels
    (None: a camera whose size is not known yet, at most MAX_PIXELS; CheckedImage.fits checks its
    size later): cheap enough for every message that arrives, before it is queued or decoded.
    ValueError."""
    if isinstance(msg, CompressedImage):
        return CheckedImage(msg, *check_compressed(msg, expected), expected)
    check_image(msg, expected)
    return CheckedImage(msg, 'raw', int(msg.width), int(msg.height), expected)


def to_bgr(msg: Image | CompressedImage, expected: tuple[int, int] | None = None, reduce: int = 1) -> np.ndarray:
    """(H, W, 3) uint8 BGR of an Image or CompressedImage (expected: (width, height) pixels the
    image must have; a CompressedImage's header is checked before it is decoded). reduce: a JPEG
    may come back at 1/reduce of its size, where decoding it so costs less (other images whole)."""
    return check_camera_image(msg, expected).decode(reduce)
