"""Property-based tests of every msg_adapters decoder: arbitrary record bytes under a correct
PointCloud2 field layout, and arbitrary Image and CameraInfo fields, either decode to a valid
result (which re-encodes to the same thing) or raise ValueError, never another exception; and
random valid inputs survive encode -> decode. The image decoders, raw and compressed, also on random
sizes (headers declaring up to 65535 x 65535): nothing larger than the expected size or
MAX_PIXELS is ever decoded."""
from __future__ import annotations

import array
import dataclasses
import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from sensor_msgs.msg import CameraInfo, CompressedImage, Image
from std_msgs.msg import Header

from msg_adapters.camera_info_msg import camera_to_info, check_info, info_to_intrinsics
from msg_adapters.image_msg import (ENCODINGS, compressed_to_image, image_to_compressed_msg, image_to_msg,
                                    msg_to_image)
from msg_adapters.openpose_msg import OPENPOSE_DTYPE, msg_to_openpose, openpose_to_msg
from msg_adapters.people_msg import (BUNDLE_KEYS, bundles_to_msg, msg_to_bundles, msg_to_people,
                                     people_dtype, people_to_msg)
from msg_adapters.records import to_cloud
from msg_adapters.skeleton_msg import SKELETON_DTYPE, msg_to_skeletons, skeletons_to_msg
from mvpose_ros.core.datasets.shelf_campus import shelf_cameras
from mvpose_ros.core.detection.encoded_image import MAX_PIXELS, decode_encoded, max_image_bytes
from mvpose_ros.core.detection.openpose import BODY25_PAF_PAIRS, OpenPoseFrame
from mvpose_ros.core.geometry import lens
from mvpose_ros.core.heatmap import PersonHeatmap
from mvpose_ros.core.types import Person2D

FUZZ = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
HEADER = Header(frame_id='cam0')
floats32 = st.floats(width=32, allow_nan=True, allow_infinity=True)


def _cloud(dtype: np.dtype, n: int, data: bytes):
    """A message with dtype's exact layout for n records but arbitrary data."""
    msg = to_cloud(np.zeros(n, dtype), HEADER)
    msg.data = array.array('B', data)
    return msg


@st.composite
def raw_clouds(draw, dtype_of_count):
    """(dtype, message): random bytes, of the right length or not, under a correct layout."""
    dtype = dtype_of_count(draw(st.sampled_from([0, 16, 32, 96])))
    n = draw(st.integers(0, 6))
    size = n * dtype.itemsize + draw(st.sampled_from([0, 0, 0, -1, 1, -dtype.itemsize]))
    data = draw(st.binary(min_size=max(size, 0), max_size=max(size, 0)))
    return _cloud(dtype, n, data)


def _decodes_or_value_error(decode, msg):
    try:
        return decode(msg)
    except ValueError:
        return None


def _same_frame(a: OpenPoseFrame, b: OpenPoseFrame) -> bool:
    return all(np.array_equal(x, y) for x, y in zip(a.candidates + a.pafs, b.candidates + b.pafs))


def _cells(heat) -> list[np.ndarray]:
    """Per map (n, 3): pixel u, v and value of its non-zero cells, in row-major order (which
    cutting a map to its evidence keeps)."""
    out, start = [], 0
    for (h, w), origin in zip(heat.shape, heat.origin):
        values = heat.cells[start:start + h * w]
        start += h * w
        at = np.flatnonzero(values)
        out.append(np.column_stack([origin[0] + heat.stride * (at % w), origin[1] + heat.stride * (at // w),
                                    values[at]]))
    return out


def _same_maps(a, b) -> bool:
    """The same non-zero cells at the same pixels (to float32 rounding of the origins)."""
    return a.stride == b.stride and all(
        len(x) == len(y) and np.array_equal(x[:, 2], y[:, 2])
        and np.allclose(x[:, :2], y[:, :2], rtol=1e-6, atol=1e-6 * a.stride)
        for x, y in zip(_cells(a), _cells(b)))


def _same_people(a: list[Person2D], b: list[Person2D]) -> bool:
    return len(a) == len(b) and all(
        np.array_equal(p.keypoints, q.keypoints, equal_nan=True) and _same_maps(p.heatmap, q.heatmap)
        for p, q in zip(a, b))


def _check_frame(frame: OpenPoseFrame) -> None:
    assert len(frame.candidates) == 25 and len(frame.pafs) == 26
    assert all(c.ndim == 2 and c.shape[1] == 3 and np.isfinite(c).all() for c in frame.candidates)
    for (a, b), paf in zip(BODY25_PAF_PAIRS, frame.pafs):
        assert paf.shape == (len(frame.candidates[a]), len(frame.candidates[b]))
    assert _same_frame(frame, msg_to_openpose(openpose_to_msg(frame, HEADER)))


def _check_people(people: list[Person2D]) -> None:
    for p in people:
        assert p.keypoints.shape == (16, 3) and np.isfinite(p.keypoints[:, 2]).all()
        assert ((p.heatmap.cells >= 0) & (p.heatmap.cells <= 1)).all()
        assert p.heatmap.stride > 0 and np.isfinite(p.heatmap.origin).all()
    assert _same_people(people, msg_to_people(people_to_msg(people, HEADER)))


# --- arbitrary bytes ---------------------------------------------------------------------

@FUZZ
@given(raw_clouds(lambda _: OPENPOSE_DTYPE))
def test_openpose_decoder_on_random_bytes(msg):
    frame = _decodes_or_value_error(msg_to_openpose, msg)
    if frame is not None:
        _check_frame(frame)


@FUZZ
@given(raw_clouds(people_dtype))
def test_people_decoder_on_random_bytes(msg):
    people = _decodes_or_value_error(msg_to_people, msg)
    if people is not None:
        _check_people(people)


@FUZZ
@given(raw_clouds(lambda n: people_dtype(n, BUNDLE_KEYS)))
def test_bundles_decoder_on_random_bytes(msg):
    bundles = _decodes_or_value_error(msg_to_bundles, msg)
    if bundles is not None:
        _check_people([p for _, views in bundles for p in views.values()])


@FUZZ
@given(raw_clouds(lambda _: SKELETON_DTYPE))
def test_skeleton_decoder_on_random_bytes(msg):
    result = _decodes_or_value_error(msg_to_skeletons, msg)
    if result is not None:
        ids, joints, confidence = result
        assert joints.shape == (len(ids), 14, 3) and np.isfinite(joints).all()
        assert confidence.shape == (len(ids), 14) and ((confidence >= 0) & (confidence <= 1)).all()


# --- plausible records: small fields, so the semantic checks are reached -----------------

@st.composite
def openpose_records(draw):
    n = draw(st.integers(0, 40))
    small = st.integers(0, 2)
    records = np.zeros(n, OPENPOSE_DTYPE)
    records['kind'] = draw(hnp.arrays(np.uint8, n, elements=st.sampled_from([0, 0, 1, 1, 2])))
    records['part'] = draw(hnp.arrays(np.uint8, n, elements=st.integers(0, 26)))
    records['a'] = draw(hnp.arrays(np.uint16, n, elements=small))
    records['b'] = draw(hnp.arrays(np.uint16, n, elements=small))
    for field in ('u', 'v', 'score'):
        records[field] = draw(hnp.arrays(np.float32, n, elements=floats32))
    return records


@pytest.mark.slow
@FUZZ
@given(openpose_records())
def test_openpose_decoder_on_plausible_records(records):
    frame = _decodes_or_value_error(msg_to_openpose, to_cloud(records, HEADER))
    if frame is not None:
        _check_frame(frame)


@pytest.mark.slow
@FUZZ
@given(st.data())
def test_skeleton_decoder_on_plausible_records(data):
    n = data.draw(st.sampled_from([0, 13, 14, 28, 29]))
    records = np.zeros(n, SKELETON_DTYPE)
    records['person'] = np.sort(data.draw(hnp.arrays(np.uint32, n, elements=st.integers(0, 2))))
    records['joint'] = np.arange(n) % 14
    if data.draw(st.booleans()):
        records['joint'] = data.draw(hnp.arrays(np.uint8, n, elements=st.integers(0, 14)))
    for field in ('x', 'y', 'z', 'confidence'):
        records[field] = data.draw(hnp.arrays(np.float32, n, elements=floats32))
    result = _decodes_or_value_error(msg_to_skeletons, to_cloud(records, HEADER))
    if result is not None:
        ids, joints, confidence = result
        assert np.isfinite(joints).all() and (np.diff(ids) > 0).all()
        assert ((confidence >= 0) & (confidence <= 1)).all()


@FUZZ
@given(st.data())
def test_people_decoder_on_plausible_records(data):
    n = data.draw(st.integers(0, 3))
    h, w = data.draw(st.integers(1, 3)), data.draw(st.integers(1, 3))
    records = np.zeros(n, people_dtype(16 * h * w if n else 0))
    records['grid'] = (h, w) * 16
    if n > 1 and data.draw(st.booleans()):
        records['grid'][-1, :2] = data.draw(st.tuples(st.integers(0, 3), st.integers(0, 3)))
    special = st.sampled_from([0.0, np.nan, np.inf, -1.0, 500.0])
    values = st.one_of(special, floats32)
    kp = data.draw(hnp.arrays(np.float32, (n, 16, 3), elements=st.one_of(special, special, floats32)))
    records['keypoints'] = kp.reshape(n, 48)
    records['origin'] = data.draw(hnp.arrays(np.float32, (n, 32), elements=values))
    records['stride'] = data.draw(hnp.arrays(np.float32, n, elements=values))
    records['heatmap'] = data.draw(hnp.arrays(np.uint8, records['heatmap'].shape))
    people = _decodes_or_value_error(msg_to_people, to_cloud(records, HEADER))
    if people is not None:
        _check_people(people)


# --- valid inputs round trip -------------------------------------------------------------

@st.composite
def frames(draw):
    counts = draw(st.lists(st.integers(0, 3), min_size=25, max_size=25))
    values = st.floats(-1e4, 1e4, width=32)
    candidates = [draw(hnp.arrays(np.float64, (n, 3), elements=values)) for n in counts]
    pafs = [draw(hnp.arrays(np.float64, (counts[a], counts[b]), elements=values))
            for a, b in BODY25_PAF_PAIRS]
    return OpenPoseFrame(candidates, pafs)


@st.composite
def people(draw, max_people: int = 3):
    out = []
    for _ in range(draw(st.integers(0, max_people))):
        h, w = draw(st.integers(1, 5)), draw(st.integers(1, 5))
        kp = draw(hnp.arrays(np.float64, (16, 3), elements=st.floats(0, 2000, width=32)))
        kp[draw(hnp.arrays(bool, 16)), :] = (np.nan, np.nan, 0.0)
        maps = draw(hnp.arrays(np.float32, (16, h, w), elements=st.floats(-1, 2, width=32)))
        origin = draw(hnp.arrays(np.float64, (16, 2), elements=st.floats(-1e3, 1e3, width=32)))
        stride = draw(st.floats(0.5, 16, width=32))
        out.append(Person2D(kp, PersonHeatmap(maps, origin, stride)))
    return out


@pytest.mark.slow
@FUZZ
@given(frames())
def test_openpose_round_trip(frame):
    assert _same_frame(frame, msg_to_openpose(openpose_to_msg(frame, HEADER)))


@pytest.mark.slow
@FUZZ
@given(people())
def test_people_round_trip(people_in):
    back = msg_to_people(people_to_msg(people_in, HEADER))
    assert len(back) == len(people_in)
    for p, q in zip(people_in, back):
        assert np.array_equal(p.keypoints, q.keypoints, equal_nan=True) and p.heatmap.stride == q.heatmap.stride
        sent = np.clip(np.rint(p.heatmap.cells * np.float32(255)), 0, 255) / np.float32(255)
        quantised = PersonHeatmap.from_cells(sent.astype(np.float32), p.heatmap.shape,
                                             p.heatmap.origin.astype(np.float32), p.heatmap.stride)
        assert _same_maps(quantised, q.heatmap)


@FUZZ
@given(st.dictionaries(st.integers(0, 2 ** 32 - 1), st.dictionaries(st.integers(0, 9), st.just(0),
                                                                    min_size=1, max_size=3),
                       max_size=3), people(max_people=1).filter(bool))
def test_bundles_round_trip(layout, one):
    bundles = [(pid, {c: one[0] for c in cams}) for pid, cams in layout.items()]
    back = msg_to_bundles(bundles_to_msg(bundles, HEADER))
    assert [(pid, sorted(v)) for pid, v in back] == sorted((pid, sorted(v)) for pid, v in bundles)
    decoded = msg_to_people(people_to_msg(one, HEADER))  # the same quantisation as in a bundle
    assert all(_same_people([p], decoded) for _, views in back for p in views.values())


@pytest.mark.slow
@FUZZ
@given(st.lists(st.integers(0, 2 ** 32 - 1), max_size=4, unique=True), st.data())
def test_skeleton_round_trip(ids, data):
    joints = data.draw(hnp.arrays(np.float64, (len(ids), 14, 3),
                                  elements=st.floats(-1e4, 1e4, width=32)))
    confidence = data.draw(hnp.arrays(np.float64, (len(ids), 14), elements=st.floats(0, 1, width=32)))
    back_ids, back, back_conf = msg_to_skeletons(skeletons_to_msg(np.array(ids, dtype=np.int64), joints, HEADER,
                                                                  confidence=confidence))
    order = np.argsort(ids)
    assert back_ids.tolist() == sorted(ids)
    assert np.array_equal(back, joints[order]) and np.array_equal(back_conf, confidence[order])


# --- images and camera infos ---------------------------------------------------------------

@FUZZ
@given(st.sampled_from([*ENCODINGS, '', 'xyz', '8UC3']), st.integers(0, 5), st.integers(0, 5),
       st.integers(0, 30), st.booleans(), st.binary(max_size=120))
def test_image_decoder_on_random_fields(encoding, width, height, step, bigendian, data):
    msg = Image(header=HEADER, encoding=encoding, width=width, height=height, step=step,
                is_bigendian=int(bigendian), data=array.array('B', data))
    bgr = _decodes_or_value_error(msg_to_image, msg)
    if bgr is not None:
        assert bgr.shape == (height, width, 3) and bgr.dtype == np.uint8
        np.testing.assert_array_equal(msg_to_image(image_to_msg(bgr, HEADER)), bgr)


@FUZZ
@given(st.sampled_from(['jpeg', 'png', 'bgr8; jpeg compressed bgr8', 'tiff']), st.sampled_from(['jpeg', 'png']),
       st.integers(0, 400), st.integers(0, 255), st.integers(0, 64), st.binary(max_size=64))
def test_compressed_decoder_on_damaged_data(fmt, kind, position, value, cut, junk):
    """A real small jpeg or png with one byte changed, its end cut off or junk appended decodes to
    an image of the declared size or raises ValueError, never anything else."""
    data = bytearray(image_to_compressed_msg(np.full((12, 16, 3), 90, np.uint8), HEADER, kind).data)
    data[position % len(data)] = value
    msg = CompressedImage(header=HEADER, format=fmt, data=array.array('B', bytes(data[:len(data) - cut]) + junk))
    bgr = _decodes_or_value_error(compressed_to_image, msg)
    if bgr is not None:
        assert bgr.dtype == np.uint8 and bgr.ndim == 3 and bgr.shape[2] == 3


@FUZZ
@given(st.sampled_from(['jpeg', 'png']), st.binary(max_size=200))
def test_compressed_decoder_on_random_bytes(fmt, data):
    for head in (b'', b'\x89PNG\r\n\x1a\n', b'\xff\xd8'):
        msg = CompressedImage(header=HEADER, format=fmt, data=array.array('B', head + data))
        bgr = _decodes_or_value_error(compressed_to_image, msg)
        assert bgr is None or (bgr.dtype == np.uint8 and bgr.shape[2] == 3)


SMALL = (16, 12)  # (width, height) of the small real images the header fuzzing starts from


def _small_encoded(kind: str) -> bytes:
    return bytes(image_to_compressed_msg(np.full((SMALL[1], SMALL[0], 3), 90, np.uint8), HEADER, kind).data)


@pytest.mark.slow
@FUZZ
@given(st.sampled_from(['jpeg', 'png']), st.integers(0, 2 ** 16 - 1), st.integers(0, 2 ** 16 - 1),
       st.booleans(), st.binary(max_size=32))
def test_decoders_on_random_declared_sizes(kind, width, height, with_expected, junk):
    """A real small jpeg or png whose header is changed to declare any size (up to 65535 x 65535,
    4.3 gigapixels): refused with a ValueError unless the size is exactly the expected one (given)
    or within MAX_PIXELS; so what is decoded is never larger than that bound (and decoding takes
    no longer than such an image). The message path and the file path (decode_encoded) alike."""
    data = bytearray(_small_encoded(kind))
    if kind == 'png':
        data[16:24] = struct.pack('>II', width, height)  # IHDR width, height (its CRC is not checked first)
    else:
        sof = data.index(b'\xff\xc0')
        data[sof + 5:sof + 9] = struct.pack('>HH', height, width)
    data = bytes(data) + junk
    expected = SMALL if with_expected else None
    for decode in (lambda: compressed_to_image(CompressedImage(format=kind, data=data), expected),
                   lambda: decode_encoded(np.frombuffer(data, np.uint8), expected)):
        bgr = _decodes_or_value_error(lambda _: decode(), None)
        if bgr is not None:
            assert bgr.shape[:2] == (height, width) and width * height <= MAX_PIXELS
            assert not with_expected or (width, height) == SMALL


@FUZZ
@given(st.binary(max_size=300), st.sampled_from([b'', b'\x89PNG\r\n\x1a\n', b'\xff\xd8']), st.booleans())
def test_the_file_decoder_on_random_bytes(data, head, with_expected):
    """What read_image decodes: random bytes, bare or behind a PNG or JPEG signature."""
    bgr = _decodes_or_value_error(lambda d: decode_encoded(np.frombuffer(d, np.uint8), SMALL if with_expected
                                                           else None), head + data)
    assert bgr is None or (bgr.dtype == np.uint8 and bgr.shape[2] == 3)


@FUZZ
@given(st.sampled_from(ENCODINGS), st.integers(0, 2 ** 20), st.integers(0, 2 ** 20), st.integers(0, 2 ** 22),
       st.integers(0, 3000))
def test_the_image_decoder_on_random_sizes_with_an_expected_size(encoding, width, height, step, length):
    """Any width, height and step an Image declares, with any data length (up to 3000 bytes): with
    an expected size it is refused unless it is exactly that size and within the byte bound."""
    msg = Image(header=HEADER, encoding=encoding, width=width, height=height, step=step, data=bytes(length))
    bgr = _decodes_or_value_error(lambda m: msg_to_image(m, SMALL), msg)
    if bgr is not None:
        assert (width, height) == SMALL and bgr.shape == (SMALL[1], SMALL[0], 3)
        assert length <= max_image_bytes(*SMALL)


@FUZZ
@given(st.sampled_from([*lens.MODELS, 'fisheye', '']),
       st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=0, max_size=15),
       hnp.arrays(np.float64, 9, elements=st.one_of(st.floats(-2e3, 2e3), st.sampled_from([0.0, 1.0, np.nan]))),
       st.integers(0, 3000), st.integers(0, 3000), st.integers(0, 4000), st.integers(0, 4000),
       st.lists(st.integers(0, 4000), min_size=4, max_size=4))
def test_camera_info_decoder_on_random_fields(model, d, k, width, height, binning_x, binning_y, roi):
    msg = CameraInfo(header=HEADER, distortion_model=model, d=d, k=k.tolist(), width=width, height=height,
                     binning_x=binning_x, binning_y=binning_y)
    msg.roi.x_offset, msg.roi.y_offset, msg.roi.width, msg.roi.height = roi
    out = _decodes_or_value_error(info_to_intrinsics, msg)
    if out is not None:
        K, dist, w, h, lens_model = out
        assert np.isfinite(K).all() and K[0, 0] > 0 and K[1, 1] > 0 and K[2, 2] == 1
        assert dist.shape == (len(lens.MODELS[lens_model]),) and np.isfinite(dist).all() and w >= 1 and h >= 1


@FUZZ
@given(st.floats(-5, 5), st.floats(-30, 30), st.integers(-3, 3))
def test_camera_info_check_on_plausible_changes(scale_error, shift_px, size_error):
    """A CameraInfo made from the rig's own camera passes, one changed beyond tolerance fails with
    the name of what changed: never another exception."""
    camera = shelf_cameras()[0]
    changed = dataclasses.replace(camera, K=camera.K + [[scale_error, 0, shift_px], [0, 0, 0], [0, 0, 0]],
                                  width=camera.width + size_error)
    try:
        check_info(camera_to_info(changed, HEADER), camera)
        assert size_error == 0 and abs(scale_error) <= 0.5 and abs(shift_px) <= 0.5
    except ValueError as exc:
        assert str(exc).startswith('CameraInfo ')
