"""Image and CompressedImage decoding: every encoding round-trips (exactly where lossless), the
4:2:2 encodings decode to the BT.601 colours, each Bayer pattern to its colours, row padding and
byte order are honoured, and bad
data (unknown encodings, short rows, truncated or corrupt files, headers declaring huge images)
is refused with a one-line ValueError, the oversize ones before anything is decoded."""
from __future__ import annotations

import struct
import zlib

import cv2
import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import CompressedImage, Image
from std_msgs.msg import Header

from msg_adapters.image_msg import (ENCODINGS, compressed_to_image, image_to_compressed_msg,
                                    image_to_msg, msg_to_image, to_bgr)
from mvpose_ros.core.datasets.shelf_campus import dataset_dir
from mvpose_ros.core.detection.encoded_image import declared_size, max_image_bytes

HEADER = Header(frame_id='left_optical')
LOSSLESS = ('bgr8', 'rgb8', 'bgra8', 'rgba8', 'bgr16', 'rgb16')
MONO = ('mono8', 'mono16')
YUV422 = ('yuv422', 'uyvy', 'yuv422_yuy2', 'yuyv')
BAYER = tuple(f'bayer_{p}{bits}' for p in ('rggb', 'bggr', 'gbrg', 'grbg') for bits in (8, 16))


def _random(h: int = 6, w: int = 8, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (h, w, 3), dtype=np.uint8)


def _smooth(h: int = 96, w: int = 128) -> np.ndarray:
    """A smooth colour image (JPEG keeps it within a few grey levels)."""
    y, x = np.mgrid[0:h, 0:w]
    return np.stack([x * 255 // (w - 1), y * 255 // (h - 1), (x + y) * 255 // (w + h - 2)], -1).astype(np.uint8)


def _through_the_wire(msg):
    return deserialize_message(serialize_message(msg), type(msg))


def test_every_encoding_is_decodable():
    assert set(ENCODINGS) == set(LOSSLESS + MONO + YUV422 + BAYER)


@pytest.mark.parametrize('encoding', LOSSLESS + MONO + YUV422)
@pytest.mark.parametrize('padding', [0, 5])
@pytest.mark.parametrize('bigendian', [False, True])
def test_round_trip(encoding, padding, bigendian):
    bgr = _random()
    if encoding in MONO:
        bgr = np.repeat(bgr[..., :1], 3, axis=2)  # grey: what mono keeps
    if encoding in YUV422:
        bgr = np.repeat(bgr[:, ::2], 2, axis=1)  # pixel pairs share their chroma
    msg = _through_the_wire(image_to_msg(bgr, HEADER, encoding, padding=padding, bigendian=bigendian))
    assert (msg.encoding, msg.width, msg.height, msg.header.frame_id) == (encoding, 8, 6, 'left_optical')
    sizes = {'bgra8': 4, 'rgba8': 4, 'bgr16': 6, 'rgb16': 6, 'mono8': 1, 'mono16': 2} | dict.fromkeys(YUV422, 2)
    per_pixel = sizes.get(encoding, 3)
    assert msg.step == per_pixel * 8 + padding and len(msg.data) == msg.step * 6
    back = msg_to_image(msg)
    assert back.shape == (6, 8, 3) and back.dtype == np.uint8
    if encoding in YUV422:
        assert np.abs(back.astype(int) - bgr).max() <= 2  # 8-bit YCbCr rounding
    else:
        np.testing.assert_array_equal(back, bgr)


@pytest.mark.parametrize('encoding', BAYER)
@pytest.mark.parametrize('padding', [0, 5])
@pytest.mark.parametrize('bigendian', [False, True])
def test_bayer_round_trip(encoding, padding, bigendian):
    """A mosaic keeps one colour per pixel; demosaicing a linear ramp gives it back exactly away
    from the border (the interpolation is bilinear there)."""
    bgr = _smooth(24, 32)
    msg = _through_the_wire(image_to_msg(bgr, HEADER, encoding, padding=padding, bigendian=bigendian))
    depth = 2 if encoding.endswith('16') else 1
    assert (msg.width, msg.height, msg.step) == (32, 24, depth * 32 + padding) and len(msg.data) == msg.step * 24
    back = msg_to_image(msg)
    assert back.shape == bgr.shape and back.dtype == np.uint8
    ramp = bgr.astype(int)
    assert np.abs(back[2:-2, 2:-2].astype(int) - ramp[2:-2, 2:-2]).max() <= 1


@pytest.mark.parametrize('pattern', ['rggb', 'bggr', 'gbrg', 'grbg'])
def test_bayer_patterns_decode_to_their_colours(pattern):
    """A flat colour mosaiced by hand: the pattern's letters name the top-left 2x2 cell row by row,
    so each pattern read as another one would swap red and blue or mix green into them."""
    colour = {'b': 10, 'g': 50, 'r': 200}
    cell = [colour[letter] for letter in pattern]
    row0, row1 = bytes(cell[:2] * 4), bytes(cell[2:] * 4)
    msg = Image(height=8, width=8, encoding=f'bayer_{pattern}8', step=8, data=(row0 + row1) * 4)
    out = msg_to_image(msg)
    assert out[2:-2, 2:-2].reshape(-1, 3).tolist() == [[10, 50, 200]] * 16


def _yuv_pair(layout: str, y0: int, u: int, y1: int, v: int) -> bytes:
    return bytes([u, y0, v, y1] if layout == 'uyvy' else [y0, u, y1, v])


@pytest.mark.parametrize('encoding', YUV422)
def test_yuv422_byte_orders_decode_to_bt601_colours(encoding):
    """Limited-range BT.601 colour bars, packed by hand in the encoding's byte order."""
    layout = 'uyvy' if encoding in ('yuv422', 'uyvy') else 'yuyv'
    bars = {(81, 90, 240): (0, 0, 255), (145, 54, 34): (0, 255, 0), (41, 240, 110): (255, 0, 0),
            (235, 128, 128): (255, 255, 255), (16, 128, 128): (0, 0, 0)}  # Y, U, V -> B, G, R
    row = b''.join(_yuv_pair(layout, y, u, y, v) for y, u, v in bars)
    padded = row + b'\x07' * 3
    msg = Image(height=2, width=2 * len(bars), encoding=encoding, step=len(padded), data=padded * 2)
    out = msg_to_image(msg)
    expected = np.repeat(np.array(list(bars.values()), dtype=int), 2, axis=0)
    assert np.abs(out[0].astype(int) - expected).max() <= 2 and np.array_equal(out[0], out[1])


def test_16_bit_byte_order_and_alpha():
    big = Image(height=1, width=1, encoding='mono16', is_bigendian=1, step=2, data=bytes([0x12, 0x34]))
    little = Image(height=1, width=1, encoding='mono16', is_bigendian=0, step=2, data=bytes([0x34, 0x12]))
    assert msg_to_image(big).tolist() == msg_to_image(little).tolist() == [[[0x12] * 3]]
    rgba = Image(height=1, width=2, encoding='rgba8', step=8, data=bytes([1, 2, 3, 0, 4, 5, 6, 9]))
    assert msg_to_image(rgba).tolist() == [[[3, 2, 1], [6, 5, 4]]]  # alpha ignored, R and B swapped


@pytest.mark.parametrize('change, problem', [
    (dict(encoding='xyz'), "Image encoding: expected one of .* got 'xyz'"),
    (dict(encoding='16UC1'), "got '16UC1'"),
    (dict(step=20), r'Image step: 20 is less than 3 \* width = 21'),
    (dict(height=7), 'Image data: expected step \\* height = 147 bytes, got 126'),
    (dict(width=0, step=0, data=b''), 'Image size: 0x6, not at least 1x1 pixels'),
    (dict(encoding='yuyv', step=14, data=b'\0' * 84), 'the width must be even, got 7'),
])
def test_image_rejects(change, problem):
    msg = image_to_msg(_random(6, 7), HEADER)
    for field, value in change.items():
        setattr(msg, field, value)
    with pytest.raises(ValueError, match=problem) as err:
        msg_to_image(msg)
    assert '\n' not in str(err.value)


def test_image_expected_size_and_encoder_rejects():
    msg = image_to_msg(_random(6, 7), HEADER)
    assert msg_to_image(msg, expected=(7, 6)).shape == (6, 7, 3)
    with pytest.raises(ValueError, match='Image size: 7x6, expected 1032x776'):
        msg_to_image(msg, expected=(1032, 776))
    with pytest.raises(ValueError, match=r'expected \(H, W, 3\) uint8'):
        image_to_msg(_random().astype(np.float32), HEADER)
    with pytest.raises(ValueError, match="Image encoding: expected one of .* got 'bgr9'"):
        image_to_msg(_random(), HEADER, 'bgr9')
    with pytest.raises(ValueError, match='must be even'):
        image_to_msg(_random(6, 7), HEADER, 'yuv422')


@pytest.mark.parametrize('fmt', ['jpeg', 'png'])
def test_compressed_round_trip(fmt):
    bgr = _smooth()
    msg = _through_the_wire(image_to_compressed_msg(bgr, HEADER, fmt))
    assert msg.format == f'bgr8; {fmt} compressed bgr8'
    assert declared_size(msg.data) == (fmt, 128, 96)
    back = compressed_to_image(msg, expected=(128, 96))
    assert back.shape == (96, 128, 3) and back.dtype == np.uint8
    if fmt == 'png':
        np.testing.assert_array_equal(back, bgr)
    else:
        assert np.abs(back.astype(int) - bgr).mean() < 2.0
    assert np.array_equal(to_bgr(msg), back)


def test_a_real_image_as_jpeg_and_png():
    bgr = cv2.imread(str(dataset_dir('shelf') / 'frames' / 'cam0_000572.png'), cv2.IMREAD_COLOR)
    h, w = bgr.shape[:2]
    assert (w, h) == (1032, 776)
    for fmt in ('jpeg', 'png'):
        msg = image_to_compressed_msg(bgr, HEADER, fmt, quality=90)
        back = compressed_to_image(msg, expected=(w, h))
        assert back.shape == bgr.shape and np.abs(back.astype(int) - bgr).mean() < (3.0 if fmt == 'jpeg' else 1e-9)


def test_a_jpeg_decodes_shrunk_on_request_and_other_images_whole():
    """reduce k: a JPEG comes back at ceil(W / k) x ceil(H / k), close to the whole image shrunk
    by area; a PNG and a raw Image whole; a factor libjpeg has not is refused."""
    bgr = cv2.imread(str(dataset_dir('shelf') / 'frames' / 'cam0_000572.png'), cv2.IMREAD_COLOR)[:775, :1031]
    jpeg = image_to_compressed_msg(bgr, HEADER, 'jpeg', quality=95)
    for k in (2, 4, 8):
        small = to_bgr(jpeg, expected=(1031, 775), reduce=k)
        assert small.shape == (-(-775 // k), -(-1031 // k), 3)
        area = cv2.resize(bgr, small.shape[1::-1], interpolation=cv2.INTER_AREA)
        assert np.abs(small.astype(int) - area).mean() < 3.0
    assert to_bgr(image_to_compressed_msg(bgr, HEADER, 'png'), reduce=4).shape == bgr.shape
    assert to_bgr(image_to_msg(bgr, HEADER), reduce=4).shape == bgr.shape
    with pytest.raises(ValueError, match=r'reduce 3: not one of \[1, 2, 4, 8\]'):
        to_bgr(jpeg, reduce=3)


@pytest.mark.parametrize('fmt, kind', [
    ('jpeg', 'jpeg'), ('png', 'png'), ('bgr8; jpeg compressed bgr8', 'jpeg'),
    ('rgb8; jpeg compressed bgr8', 'jpeg'), ('mono8; jpeg compressed mono8', 'jpeg'),
    ('rgb8; png compressed rgb8', 'png'), ('bgra8; png compressed bgra8', 'png'),
    ('JPEG', 'jpeg'), ('jpg', 'jpeg'),
])
def test_image_transport_format_strings(fmt, kind):
    bgr = _smooth(16, 24)
    msg = image_to_compressed_msg(bgr, HEADER, kind)
    msg.format = fmt
    assert compressed_to_image(msg).shape == (16, 24, 3)


@pytest.mark.parametrize('fmt', ['', 'tiff', 'bgr8; compressedDepth png', '16UC1; compressedDepth', 'jpeg png'])
def test_unknown_compressed_formats(fmt):
    msg = image_to_compressed_msg(_smooth(16, 24), HEADER, 'png')
    msg.format = fmt
    with pytest.raises(ValueError, match='CompressedImage format: expected jpeg or png'):
        compressed_to_image(msg)


def test_progressive_jpeg_and_app_segments():
    bgr = _smooth()
    ok, data = cv2.imencode('.jpg', bgr, [cv2.IMWRITE_JPEG_PROGRESSIVE, 1])
    assert ok
    data = data.tobytes()
    # an APP1 segment (as EXIF adds) before the frame header, holding bytes that look like markers
    app1 = b'\xff\xe1' + struct.pack('>H', 2 + 40) + b'\xff\xc0\x00\x11\x08\x99\x99' + b'\0' * 33
    data = data[:2] + app1 + data[2:]
    assert declared_size(data) == ('jpeg', 128, 96)
    msg = CompressedImage(format='jpeg', data=data)
    assert np.abs(compressed_to_image(msg).astype(int) - bgr).mean() < 2.0


def _png_chunk(kind: bytes, body: bytes) -> bytes:
    return struct.pack('>I', len(body)) + kind + body + struct.pack('>I', zlib.crc32(kind + body))


def _png_bomb(width: int, height: int) -> bytes:
    """A PNG of a few dozen bytes whose header declares width x height (and whose data would
    inflate to it: a zlib stream of zeros)."""
    ihdr = struct.pack('>IIBBBBB', width, height, 8, 2, 0, 0, 0)
    idat = zlib.compress(b'\0' * 1000)
    return b'\x89PNG\r\n\x1a\n' + _png_chunk(b'IHDR', ihdr) + _png_chunk(b'IDAT', idat) + _png_chunk(b'IEND', b'')


def test_a_png_declaring_a_huge_image_is_refused_before_decoding(monkeypatch):
    msg = CompressedImage(format='png', data=_png_bomb(20000, 20000))
    assert len(msg.data) < 200 and declared_size(msg.data) == ('png', 20000, 20000)
    _no_decoding(monkeypatch)
    with pytest.raises(ValueError, match='the png header declares 20000x20000, more than 33554432 pixels'):
        compressed_to_image(msg)
    with pytest.raises(ValueError, match='declares 20000x20000, expected 1032x776'):
        compressed_to_image(msg, expected=(1032, 776))


def _no_decoding(monkeypatch) -> None:
    """Refused from the header: cv2.imdecode must not run (20000 x 20000 x 3 would allocate 1.2 GB)."""
    def refuse(*args):
        raise AssertionError('cv2.imdecode was called')
    monkeypatch.setattr(cv2, 'imdecode', refuse)


def test_a_jpeg_declaring_a_huge_image_is_refused_before_decoding(monkeypatch):
    data = bytearray(image_to_compressed_msg(_smooth(), HEADER, 'jpeg').data)
    sof = next(i for i in range(2, len(data) - 1) if data[i] == 0xFF and data[i + 1] in (0xC0, 0xC2))
    data[sof + 5:sof + 9] = struct.pack('>HH', 60000, 60000)  # height, width
    msg = CompressedImage(format='jpeg', data=bytes(data))
    with monkeypatch.context() as patched:
        _no_decoding(patched)
        with pytest.raises(ValueError, match='the jpeg header declares 60000x60000'):
            compressed_to_image(msg)
    big = image_to_compressed_msg(_smooth(96, 200), HEADER, 'jpeg')
    with pytest.raises(ValueError, match='declares 200x96, expected 128x96'):
        compressed_to_image(big, expected=(128, 96))
    small = image_to_compressed_msg(_smooth(96, 100), HEADER, 'jpeg')  # smaller: refused undecoded too
    with pytest.raises(ValueError, match='declares 100x96, expected 128x96'):
        compressed_to_image(small, expected=(128, 96))


@pytest.mark.parametrize('compressed', [False, True])
def test_data_larger_than_the_expected_image_can_take_is_refused_unread(compressed):
    """The byte bound of a w x h camera: max_image_bytes = 8 w h + 1 MiB (16-bit RGBA PNG, the
    largest pixel); one byte more is refused before the header or fields are looked at."""
    w, h = 128, 96
    limit = max_image_bytes(w, h)
    assert limit == 8 * w * h + 2 ** 20
    if compressed:
        data = bytes(image_to_compressed_msg(_smooth(), HEADER, 'png').data)
        fits = CompressedImage(format='png', data=data + bytes(limit - len(data)))  # padding after IEND
        over = CompressedImage(format='png', data=data + bytes(limit + 1 - len(data)))
        with pytest.raises(ValueError, match='no end marker'):  # within the bound: the next checks run
            compressed_to_image(fits, expected=(w, h))
    else:
        fits = Image(encoding='bgr8', width=w, height=h, step=limit // h, data=bytes(limit // h * h))
        assert msg_to_image(fits, expected=(w, h)).shape == (h, w, 3)  # padded rows, within the bound
        over = Image(encoding='bgr8', width=w, height=h, step=limit // h + 1, data=bytes((limit // h + 1) * h))
    kind = 'CompressedImage data' if compressed else 'Image data'
    with pytest.raises(ValueError, match=f'^{kind}: {len(over.data)} bytes, more than a 128x96 image takes '
                                         f'\\({limit}\\)$'):
        to_bgr(over, expected=(w, h))


@pytest.mark.parametrize('fmt', ['jpeg', 'png'])
@pytest.mark.parametrize('cut', [1, 4, 12, 30, 0.5, -100, -2])
def test_truncated_compressed_data(fmt, cut):
    data = bytes(image_to_compressed_msg(_smooth(), HEADER, fmt).data)
    data = data[:int(len(data) * cut)] if isinstance(cut, float) else data[:cut]
    with pytest.raises(ValueError, match='CompressedImage (data|size)') as err:
        compressed_to_image(CompressedImage(format=fmt, data=data))
    assert '\n' not in str(err.value)


def test_corrupt_compressed_data():
    png = bytearray(image_to_compressed_msg(_smooth(), HEADER, 'png').data)
    png[60:80] = bytes(20)  # inside the compressed data: the chunk CRC no longer matches
    with pytest.raises(ValueError, match='does not decode'):
        compressed_to_image(CompressedImage(format='png', data=bytes(png)))
    with pytest.raises(ValueError, match='not a JPEG or PNG'):
        compressed_to_image(CompressedImage(format='jpeg', data=bytes(range(100))))
    png_as_jpeg = CompressedImage(format='jpeg', data=image_to_compressed_msg(_smooth(), HEADER, 'png').data)
    with pytest.raises(ValueError, match="format 'jpeg' says jpeg, the data is a PNG"):
        compressed_to_image(png_as_jpeg)
    zero = CompressedImage(format='png', data=_png_bomb(0, 10))
    with pytest.raises(ValueError, match='declares 0x10'):
        compressed_to_image(zero)
    no_frame = CompressedImage(format='jpeg', data=b'\xff\xd8\xff\xda\x00\x02' + bytes(20) + b'\xff\xd9')
    with pytest.raises(ValueError, match='JPEG without a frame header'):
        compressed_to_image(no_frame)
