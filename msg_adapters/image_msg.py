"""sensor_msgs/Image and CompressedImage <-> (H, W, 3) uint8 BGR arrays.

Image encodings: bgr8, rgb8, mono8, bgra8, rgba8, the 16-bit bgr16, rgb16, mono16 (byte order
from is_bigendian; the high byte is kept) and the packed 4:2:2 encodings drivers publish:
'yuv422' and 'uyvy' (U Y0 V Y1), 'yuv422_yuy2' and 'yuyv' (Y0 U Y1 V), BT.601 as OpenCV converts
them. Rows may be padded (step > width * bytes per pixel).

CompressedImage: jpeg and png, the format string as image_transport writes it ('jpeg', 'png',
'bgr8; jpeg compressed bgr8', 'rgb8; png compressed rgb8', ...). The image size is read from the
data's own header (JPEG frame header, PNG IHDR) and checked against the caller's expected size
and MAX_PIXELS before anything is decoded: a small message declaring a huge image is refused
without allocating it.

Every failure is a ValueError with a one-line reason.
"""
from __future__ import annotations

import array
import struct

import cv2
import numpy as np
from sensor_msgs.msg import CompressedImage, Image
from std_msgs.msg import Header

MAX_PIXELS = 1 << 25  # 33.5 megapixels: above 8K (7680 x 4320), far below what a bomb declares

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
ENCODINGS = tuple(_PLAIN) + tuple(_YUV422)
COMPRESSED_FORMATS = ('jpeg', 'png')

_PNG_SIGNATURE = b'\x89PNG\r\n\x1a\n'
_END_SEARCH = 64  # bytes at the end searched for the end marker (JPEG EOI, PNG IEND): padding allowed
# JPEG start-of-frame markers (baseline, extended, progressive, lossless, arithmetic...): not
# DHT (C4), JPG (C8) or DAC (CC)
_SOF_MARKERS = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}


def _bytes_per_pixel(encoding: str) -> int:
    if encoding in _YUV422:
        return 2
    channels, depth, _ = _PLAIN[encoding]
    return channels * depth


def _check_bgr(bgr: np.ndarray) -> np.ndarray:
    bgr = np.asarray(bgr)
    if bgr.ndim != 3 or bgr.shape[2] != 3 or bgr.dtype != np.uint8:
        raise ValueError(f'image: expected (H, W, 3) uint8, got {bgr.dtype} {bgr.shape}')
    if bgr.shape[0] < 1 or bgr.shape[1] < 1:
        raise ValueError(f'image: expected at least 1x1 pixels, got {bgr.shape[1]}x{bgr.shape[0]}')
    return np.ascontiguousarray(bgr)


def image_to_msg(bgr: np.ndarray, header: Header, encoding: str = 'bgr8', padding: int = 0,
                 bigendian: bool = False) -> Image:
    """An Image of bgr (H, W, 3) uint8 in `encoding` (any of ENCODINGS; mono keeps the luma, 16-bit
    ones scale by 257, 4:2:2 ones need an even width), each row followed by `padding` bytes;
    bigendian: the byte order of 16-bit encodings."""
    bgr = _check_bgr(bgr)
    if encoding not in ENCODINGS:
        raise ValueError(f'Image encoding: expected one of {list(ENCODINGS)}, got {encoding!r}')
    h, w = bgr.shape[:2]
    if encoding in _YUV422:
        if w % 2:
            raise ValueError(f'Image width: {encoding} packs pixel pairs, so the width must be even, got {w}')
        pixels = cv2.cvtColor(bgr, _YUV422[encoding][1])  # (H, W, 2)
    else:
        channels, depth, _ = _PLAIN[encoding]
        if channels == 1:
            pixels = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)[..., None]
        else:
            order = [2, 1, 0] if encoding.startswith('rgb') else [0, 1, 2]
            pixels = bgr[..., order]
            if channels == 4:
                pixels = np.concatenate([pixels, np.full((h, w, 1), 255, np.uint8)], axis=2)
        if depth == 2:
            pixels = (pixels.astype(np.uint16) * 257).astype('>u2' if bigendian else '<u2')
    row = pixels.reshape(h, -1).view(np.uint8)
    rows = np.zeros((h, row.shape[1] + padding), np.uint8)
    rows[:, :row.shape[1]] = row
    return Image(header=header, height=h, width=w, encoding=encoding, is_bigendian=int(bigendian),
                 step=rows.shape[1], data=array.array('B', rows.tobytes()))


def msg_to_image(msg: Image, expected: tuple[int, int] | None = None) -> np.ndarray:
    """(H, W, 3) uint8 BGR of an Image in any of ENCODINGS; step may exceed the packed row
    (padding). expected: (width, height) pixels the image must have, if given."""
    encoding = msg.encoding
    if encoding not in ENCODINGS:
        raise ValueError(f'Image encoding: expected one of {list(ENCODINGS)}, got {encoding!r}')
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    if h < 1 or w < 1:
        raise ValueError(f'Image size: expected at least 1x1 pixels, got {w}x{h}')
    if expected is not None and (w, h) != tuple(expected):
        raise ValueError(f'Image size: {w}x{h}, expected {expected[0]}x{expected[1]}')
    packed = _bytes_per_pixel(encoding) * w
    if step < packed:
        raise ValueError(f'Image step: {step} is less than {_bytes_per_pixel(encoding)} * width = {packed}')
    data = np.frombuffer(msg.data, dtype=np.uint8)
    if len(data) != step * h:
        raise ValueError(f'Image data: expected step * height = {step * h} bytes, got {len(data)}')
    rows = np.ascontiguousarray(data.reshape(h, step)[:, :packed])
    if encoding in _YUV422:
        if w % 2:
            raise ValueError(f'Image width: {encoding} packs pixel pairs, so the width must be even, got {w}')
        return cv2.cvtColor(rows.reshape(h, w, 2), _YUV422[encoding][0])
    channels, depth, order = _PLAIN[encoding]
    if depth == 2:
        rows = (rows.view('>u2' if msg.is_bigendian else '<u2') >> 8).astype(np.uint8)
    return np.ascontiguousarray(rows.reshape(h, w, channels)[..., order])


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


def compressed_size(data: bytes) -> tuple[str, int, int]:
    """('jpeg' | 'png', width, height) declared by the header of compressed image data, read
    without decoding; ValueError when it is neither or the header is truncated or corrupt."""
    data = memoryview(data).cast('B')
    if data[:8].tobytes() == _PNG_SIGNATURE:
        head = data[8:24].tobytes()
        if len(head) < 16 or head[4:8] != b'IHDR':
            raise ValueError('CompressedImage data: PNG without an IHDR header (truncated or corrupt)')
        width, height = struct.unpack('>II', head[8:16])
        return 'png', width, height
    if data[:2].tobytes() == b'\xff\xd8':
        width, height = _jpeg_size(data)
        return 'jpeg', width, height
    raise ValueError(f'CompressedImage data: not a JPEG or PNG (starts with {data[:8].hex()})')


def _jpeg_size(data: memoryview) -> tuple[int, int]:
    """Width, height from the first JPEG frame header (SOF), walking the marker segments."""
    i, n = 2, len(data)
    while True:
        while i < n and data[i] == 0xFF:  # fill bytes before a marker
            i += 1
        if i >= n:
            raise ValueError('CompressedImage data: JPEG ends before its frame header (truncated)')
        marker = data[i]
        i += 1
        if marker == 0x01 or 0xD0 <= marker <= 0xD7:  # TEM, RSTn: no length
            continue
        if marker in (0xD9, 0xDA):
            raise ValueError('CompressedImage data: JPEG without a frame header before its scan (corrupt)')
        if i + 2 > n:
            raise ValueError('CompressedImage data: JPEG ends inside a segment header (truncated)')
        length = (data[i] << 8) | data[i + 1]
        if length < 2:
            raise ValueError(f'CompressedImage data: JPEG segment of length {length} (corrupt)')
        if marker in _SOF_MARKERS:
            if i + 7 > n or length < 7:
                raise ValueError('CompressedImage data: JPEG frame header truncated')
            height = (data[i + 3] << 8) | data[i + 4]
            width = (data[i + 5] << 8) | data[i + 6]
            return width, height
        i += length


def compressed_to_image(msg: CompressedImage, expected: tuple[int, int] | None = None,
                        max_pixels: int = MAX_PIXELS) -> np.ndarray:
    """(H, W, 3) uint8 BGR of a jpeg or png CompressedImage. Before decoding, the size its header
    declares must be at least 1x1, within expected (width, height) pixels if given, and at most
    max_pixels; the decoded image must have that size."""
    fmt = compressed_format(msg.format)
    data = np.frombuffer(msg.data, dtype=np.uint8)
    kind, width, height = compressed_size(data)
    if kind != fmt:
        raise ValueError(f'CompressedImage data: format {msg.format!r} says {fmt}, the data is a {kind.upper()}')
    if width < 1 or height < 1:
        raise ValueError(f'CompressedImage size: the {kind} header declares {width}x{height}')
    if expected is not None and (width > expected[0] or height > expected[1]):
        raise ValueError(f'CompressedImage size: the {kind} header declares {width}x{height}, larger than the '
                         f'expected {expected[0]}x{expected[1]}')
    if width * height > max_pixels:
        raise ValueError(f'CompressedImage size: the {kind} header declares {width}x{height}, more than '
                         f'{max_pixels} pixels')
    # A decoder fills a cut-off image with grey rather than failing: refuse one without its end.
    end = {'jpeg': b'\xff\xd9', 'png': b'IEND'}[kind]
    if end not in data[-_END_SEARCH:].tobytes():
        raise ValueError(f'CompressedImage data: the {kind} ({width}x{height}) has no end marker (truncated)')
    bgr = cv2.imdecode(data, cv2.IMREAD_COLOR)
    if bgr is None:
        raise ValueError(f'CompressedImage data: the {kind} ({width}x{height}) does not decode (truncated or corrupt)')
    if bgr.shape[:2] != (height, width):
        raise ValueError(f'CompressedImage size: decoded {bgr.shape[1]}x{bgr.shape[0]}, the header declares '
                         f'{width}x{height}')
    return bgr


def to_bgr(msg: Image | CompressedImage, expected: tuple[int, int] | None = None) -> np.ndarray:
    """(H, W, 3) uint8 BGR of an Image or CompressedImage (expected: (width, height) pixels: an
    Image must have exactly that size, a CompressedImage at most that before decoding)."""
    if isinstance(msg, CompressedImage):
        return compressed_to_image(msg, expected)
    return msg_to_image(msg, expected)
