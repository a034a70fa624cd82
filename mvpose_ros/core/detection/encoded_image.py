"""JPEG and PNG data, decoded only after the size its own header declares has been checked, and
the bounds of any image from outside (its pixels, and its bytes against a camera's size).

A few hundred bytes of PNG or JPEG can declare 30000 x 30000 pixels (a decompression bomb):
OpenCV's decoder would allocate the whole image (2.7 GB as BGR; OpenCV's own limit is 2^30 pixels)
before anyone could look at its size. Here the size is read from the JPEG frame header or the PNG
IHDR first, and refused unless it is the expected one (when given) and at most MAX_PIXELS:
check_encoded does every check once, and decode_checked decodes what passed without checking it
again.

Used by every path that decodes an image from outside: Image and CompressedImage messages
(msg_adapters.image_msg) and image files (image_file). ValueErrors start with 'data: ' or 'size: '
so that the caller can say what held the data ('CompressedImage data: ...', '<file>: image size: ...').
"""
from __future__ import annotations

import struct

import cv2
import numpy as np

MAX_PIXELS = 1 << 25  # 33.5 megapixels: above 8K (7680 x 4320), far below what a bomb declares
# The most bytes a pixel takes, raw or encoded: every sensor_msgs encoding read here at most 6; PNG's
# largest pixel is 16-bit RGBA (noise of it took 8.02 bytes a pixel with the PNG overhead, JPEG
# 4:4:4 of noise at quality 100 4.1: measured at 1032x776; the excess is within HEADER_SLACK).
MAX_BYTES_PER_PIXEL = 8
HEADER_SLACK = 1 << 20  # bytes beyond the pixels: JPEG APPn (EXIF, ICC, XMP) and PNG text chunks, row padding

_PNG_SIGNATURE = b'\x89PNG\r\n\x1a\n'
_END_SEARCH = 64  # bytes at the end searched for the end marker (JPEG EOI, PNG IEND): padding allowed
# JPEG start-of-frame markers (baseline, extended, progressive, lossless, arithmetic...): not
# DHT (C4), JPG (C8) or DAC (CC)
_SOF_MARKERS = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}


def max_image_bytes(width: int, height: int) -> int:
    """The most bytes an image of width x height pixels can honestly take, raw (any row padding
    within HEADER_SLACK) or as JPEG/PNG: anything larger is refused unread."""
    return int(width) * int(height) * MAX_BYTES_PER_PIXEL + HEADER_SLACK


def declared_size(data: bytes | np.ndarray | memoryview) -> tuple[str, int, int]:
    """('jpeg' | 'png', width, height) declared by the header of encoded image data, read
    without decoding; ValueError when it is neither or the header is truncated or corrupt."""
    data = memoryview(data).cast('B')
    if data[:8].tobytes() == _PNG_SIGNATURE:
        head = data[8:24].tobytes()
        if len(head) < 16 or head[4:8] != b'IHDR':
            raise ValueError('data: PNG without an IHDR header (truncated or corrupt)')
        width, height = struct.unpack('>II', head[8:16])
        return 'png', width, height
    if data[:2].tobytes() == b'\xff\xd8':
        width, height = _jpeg_size(data)
        return 'jpeg', width, height
    raise ValueError(f'data: not a JPEG or PNG (starts with {data[:8].tobytes().hex()})')


def _jpeg_size(data: memoryview) -> tuple[int, int]:
    """Width, height from the first JPEG frame header (SOF), walking the marker segments."""
    i, n = 2, len(data)
    while True:
        while i < n and data[i] == 0xFF:  # fill bytes before a marker
            i += 1
        if i >= n:
            raise ValueError('data: JPEG ends before its frame header (truncated)')
        marker = data[i]
        i += 1
        if marker == 0x01 or 0xD0 <= marker <= 0xD7:  # TEM, RSTn: no length
            continue
        if marker in (0xD9, 0xDA):
            raise ValueError('data: JPEG without a frame header before its scan (corrupt)')
        if i + 2 > n:
            raise ValueError('data: JPEG ends inside a segment header (truncated)')
        length = (data[i] << 8) | data[i + 1]
        if length < 2:
            raise ValueError(f'data: JPEG segment of length {length} (corrupt)')
        if marker in _SOF_MARKERS:
            if i + 7 > n or length < 7:
                raise ValueError('data: JPEG frame header truncated')
            height = (data[i + 3] << 8) | data[i + 4]
            width = (data[i + 5] << 8) | data[i + 6]
            return width, height
        i += length


def check_bytes(length: int, expected: tuple[int, int] | None) -> None:
    """ValueError ('data: ...') when `length` bytes are more than an image of expected (width,
    height) can take (max_image_bytes; nothing to check without expected)."""
    if expected is not None and length > max_image_bytes(*expected):
        raise ValueError(f'data: {length} bytes, more than a {expected[0]}x{expected[1]} image takes '
                         f'({max_image_bytes(*expected)})')


def check_size(width: int, height: int, expected: tuple[int, int] | None = None, max_pixels: int = MAX_PIXELS,
               declared: str = '') -> None:
    """ValueError ('size: <declared>WxH, ...') unless an image of width x height pixels is at least
    1x1, exactly expected (width, height) if given, and at most max_pixels."""
    said = f'size: {declared}{width}x{height}'
    if width < 1 or height < 1:
        raise ValueError(f'{said}, not at least 1x1 pixels')
    if expected is not None and (width, height) != tuple(expected):
        raise ValueError(f'{said}, expected {expected[0]}x{expected[1]}')
    if width * height > max_pixels:
        raise ValueError(f'{said}, more than {max_pixels} pixels')


def check_encoded(data: np.ndarray, expected: tuple[int, int] | None = None,
                  max_pixels: int = MAX_PIXELS) -> tuple[str, int, int]:
    """('jpeg' | 'png', width, height) of encoded data (N,) uint8 of at most the bytes an image of
    expected (width, height) takes, whose header declares at least 1x1 pixels, exactly expected if
    given, at most max_pixels, and which ends with its end marker: everything short of decoding.
    ValueError otherwise."""
    check_bytes(len(data), expected)
    kind, width, height = declared_size(data)
    check_size(width, height, expected, max_pixels, f'the {kind} header declares ')
    # A decoder fills a cut-off image with grey rather than failing: refuse one without its end.
    end = {'jpeg': b'\xff\xd9', 'png': b'IEND'}[kind]
    if end not in data[-_END_SEARCH:].tobytes():
        raise ValueError(f'data: the {kind} ({width}x{height}) has no end marker (truncated)')
    return kind, width, height


# libjpeg's DCT scaling: a JPEG decodes at 1/2, 1/4 or 1/8 of its size for much less than a whole
# decode and a shrink (figures: docs/own_cameras.md, JPEG decoding)
REDUCED_JPEG = {1: cv2.IMREAD_COLOR, 2: cv2.IMREAD_REDUCED_COLOR_2, 4: cv2.IMREAD_REDUCED_COLOR_4,
                8: cv2.IMREAD_REDUCED_COLOR_8}


def decode_checked(data: np.ndarray, kind: str, width: int, height: int, reduce: int = 1) -> np.ndarray:
    """(H, W, 3) uint8 BGR of JPEG or PNG data (N,) uint8 that check_encoded passed as (kind, width,
    height), decoded without checking it again; the decoded image must have that size. reduce
    (REDUCED_JPEG's keys): a JPEG is decoded at 1/reduce of its size, ceil(W / reduce) x
    ceil(H / reduce) (a PNG whole). ValueError otherwise."""
    if reduce not in REDUCED_JPEG:
        raise ValueError(f'reduce {reduce}: not one of {sorted(REDUCED_JPEG)}')
    k = reduce if kind == 'jpeg' else 1
    bgr = cv2.imdecode(data, REDUCED_JPEG[k])
    if bgr is None:
        raise ValueError(f'data: the {kind} ({width}x{height}) does not decode (truncated or corrupt)')
    if bgr.shape[:2] != (-(-height // k), -(-width // k)):
        raise ValueError(f'size: decoded {bgr.shape[1]}x{bgr.shape[0]}, the header declares {width}x{height}'
                         f'{f" (at 1/{k})" if k > 1 else ""}')
    return bgr


def decode_encoded(data: np.ndarray, expected: tuple[int, int] | None = None,
                   max_pixels: int = MAX_PIXELS, reduce: int = 1) -> np.ndarray:
    """(H, W, 3) uint8 BGR of JPEG or PNG data (N,) uint8: check_encoded, then decode_checked."""
    return decode_checked(data, *check_encoded(data, expected, max_pixels), reduce)
