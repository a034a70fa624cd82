"""The letterbox transform both ways: image pixels into the network input (the image itself,
resized into place) and the network's maps back onto image pixels, for whole non-square images,
person crops, and crops cut by the image border."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from mvpose_ros.core.heatmap import PersonHeatmap
from mvpose_ros.core.detection.letterbox import letterbox, resized, whole_image

# (width, height, region u0, v0, u1, v1 in pixel-centre coordinates, input side)
CASES = [
    (1032, 776, (-0.5, -0.5, 1031.5, 775.5), 384),   # a whole landscape image
    (300, 500, (-0.5, -0.5, 299.5, 499.5), 256),     # a whole portrait image
    (1032, 776, (412.3, 80.7, 688.9, 742.2), 224),   # a tall person crop
    (1032, 776, (-60.0, 500.0, 150.0, 900.0), 224),  # cut by the left and bottom borders
    (1032, 776, (900.0, -40.0, 1100.0, 120.0), 256),  # cut by the right and top borders
]


def _blob(shape: tuple[int, int], centre: np.ndarray, sigma: float) -> np.ndarray:
    v, u = np.mgrid[:shape[0], :shape[1]]
    return np.exp(-0.5 * ((u - centre[0]) ** 2 + (v - centre[1]) ** 2) / sigma ** 2)


def _centroid(image: np.ndarray) -> np.ndarray:
    v, u = np.mgrid[:image.shape[0], :image.shape[1]]
    return np.array([(u * image).sum(), (v * image).sum()]) / image.sum()


@pytest.mark.parametrize('width, height, box, side', CASES)
def test_maps_are_inverse_and_region_edges_land_on_the_content_edges(width, height, box, side):
    lb = letterbox(width, height, np.array(box), side)
    x0, y0, x1, y1 = lb.roi
    assert 0 <= x0 < x1 <= width and 0 <= y0 < y1 <= height
    cx, cy, cw, ch = lb.content
    assert max(cw, ch) == side and 0 <= cx and cx + cw <= side and 0 <= cy and cy + ch <= side
    # centred: the padding differs by at most one pixel on the two sides
    assert abs(cx - (side - cx - cw)) <= 1 and abs(cy - (side - cy - ch)) <= 1
    # the cut region's outer pixel edges are the content's edges
    np.testing.assert_allclose(lb.to_input([[x0 - 0.5, y0 - 0.5], [x1 - 0.5, y1 - 0.5]]),
                               [[cx - 0.5, cy - 0.5], [cx + cw - 0.5, cy + ch - 0.5]], atol=1e-9)
    uv = np.random.default_rng(0).uniform([x0, y0], [x1 - 1, y1 - 1], size=(50, 2))
    np.testing.assert_allclose(lb.to_image(lb.to_input(uv)), uv, atol=1e-9)
    assert lb.contains(uv).all()
    assert not lb.contains(np.array([[x0 - 1.0, y0], [x0, y1], [np.nan, y0]])).any()
    # uniform scale up to the rounding of the resized size
    assert abs(lb.scale[0] / lb.scale[1] - 1) < 2 / min(cw, ch)


@pytest.mark.parametrize('width, height, box, side', CASES)
def test_an_image_blob_lands_at_its_mapped_input_pixel(width, height, box, side):
    lb = letterbox(width, height, np.array(box), side)
    x0, y0, x1, y1 = lb.roi
    # a blob well inside the cut region, at a fractional position
    centre = np.array([x0 + 0.37 * (x1 - x0) + 0.3, y0 + 0.61 * (y1 - y0) + 0.7])
    sigma = 0.03 * max(x1 - x0, y1 - y0)
    image = (255 * _blob((height, width), centre, sigma))[..., None].repeat(3, axis=2).astype(np.float32)
    net = lb.apply(image)[..., 0]
    assert net.shape == (side, side)
    # area resampling keeps a blob's centroid in place to well under an input pixel
    np.testing.assert_allclose(_centroid(net), lb.to_input(centre), atol=0.15)
    # nothing outside the content rectangle
    cx, cy, cw, ch = lb.content
    mask = np.zeros_like(net, dtype=bool)
    mask[cy:cy + ch, cx:cx + cw] = True
    assert net[~mask].max() == 0


@pytest.mark.parametrize('width, height, box, side', CASES)
@pytest.mark.parametrize('stride', [1.0, 4.0, 8.0])
def test_a_heatmap_peak_at_a_known_input_cell_maps_back_to_its_image_pixel(width, height, box, side, stride):
    lb = letterbox(width, height, np.array(box), side)
    cx, cy, cw, ch = lb.content
    # peaks at known input cells, one per joint, inside the content rectangle
    cells = np.array([[cx + 0.3 * cw, cy + 0.5 * ch], [cx + 0.8 * cw + 0.4, cy + 0.2 * ch],
                      [cx + 0.5 * cw, cy + 0.9 * ch - 0.3]])
    maps = np.stack([_blob((side, side), c, 3.0) for c in cells]).astype(np.float32)
    origin, shape = lb.image_grid(stride)
    resampled = lb.maps_to_image(maps.transpose(1, 2, 0), origin, stride, shape)  # channel last, as networks give
    assert resampled.shape == (len(cells),) + shape
    expected = lb.to_image(cells)
    # the map's mass centre, in image pixels, is the mapped cell (sub-pixel)
    got = np.array([origin + stride * _centroid(m) for m in resampled])
    np.testing.assert_allclose(got, expected, atol=0.05 * stride / lb.scale.min() + 0.2)
    # and the heatmap's peak cell is the one nearest it
    peak = PersonHeatmap(resampled, origin, stride).peak()
    assert np.all(np.abs(peak[:, :2] - expected) <= 0.5 * stride + 0.5 / lb.scale.min())
    # a peak keeps its mass (cells coarser than the input's pixels average, finer ones interpolate)
    step = stride * lb.scale
    np.testing.assert_allclose(resampled.sum(axis=(1, 2)) * step[0] * step[1], maps.sum(axis=(1, 2)), rtol=0.05)


def test_the_image_grid_covers_the_cut_region_only():
    lb = letterbox(1032, 776, np.array([-60.0, 500.0, 150.0, 900.0]), 224)
    assert lb.roi == (0, 500, 151, 776)
    origin, (h, w) = lb.image_grid(4.0)
    np.testing.assert_array_equal(origin, [0, 500])
    assert origin[0] + 4.0 * (w - 1) <= 150 < origin[0] + 4.0 * w
    assert origin[1] + 4.0 * (h - 1) <= 775 < origin[1] + 4.0 * h


def test_whole_image_and_empty_regions():
    lb = whole_image(1032, 776, 384)
    assert lb.roi == (0, 0, 1032, 776) and lb.content == (0, 47, 384, 289)
    with pytest.raises(ValueError, match='holds no pixel of the 1032x776 image'):
        letterbox(1032, 776, np.array([1100.0, 10.0, 1200.0, 50.0]), 224)


@pytest.mark.parametrize('width, height, box, side', CASES)
@pytest.mark.parametrize('turns', [1, 2, 3])
def test_a_turned_letterbox_is_the_letterbox_turned(width, height, box, side, turns):
    """Turned by quarter turns (a camera on its side or upside down): the input is np.rot90 of the
    unturned input, a blob still lands at its mapped input pixel, the maps go both ways, and maps
    the network gives in the turned input resample onto the image grid as the unturned maps do."""
    plain = letterbox(width, height, np.array(box), side)
    lb = letterbox(width, height, np.array(box), side, turns)
    assert (lb.roi, lb.content, lb.turns) == (plain.roi, plain.content, turns)
    x0, y0, x1, y1 = lb.roi
    centre = np.array([x0 + 0.37 * (x1 - x0) + 0.3, y0 + 0.61 * (y1 - y0) + 0.7])
    image = (255 * _blob((height, width), centre, 0.03 * max(x1 - x0, y1 - y0)))[..., None].repeat(3, axis=2)
    net = lb.apply(image.astype(np.float32))
    np.testing.assert_array_equal(net, np.rot90(plain.apply(image.astype(np.float32)), turns))
    assert net.flags.c_contiguous
    np.testing.assert_allclose(_centroid(net[..., 0]), lb.to_input(centre), atol=0.15)
    uv = np.random.default_rng(1).uniform([x0, y0], [x1 - 1, y1 - 1], size=(50, 2))
    np.testing.assert_allclose(lb.to_image(lb.to_input(uv)), uv, atol=1e-9)
    if turns % 2:  # a quarter turn swaps the input's axes: an image row becomes an input column
        assert np.ptp(lb.to_input(np.stack([uv[:, 0], np.full(50, uv[0, 1])], -1))[:, 1]) > 0
    maps = np.random.default_rng(2).random((side, side, 3)).astype(np.float32)
    origin, shape = lb.image_grid(4.0)
    np.testing.assert_array_equal(lb.maps_to_image(np.rot90(maps, turns), origin, 4.0, shape),
                                  plain.maps_to_image(maps, origin, 4.0, shape))


def test_quarter_turns_of_the_input_square():
    """Where the image's top-right pixel goes under each turn, on a 4 x 4 input the image fills:
    counterclockwise as shown, to the top-left, the bottom-left, then the bottom-right corner."""
    expected = {0: (3, 0), 1: (0, 0), 2: (0, 3), 3: (3, 3)}  # (x, y) input pixel
    for turns, xy in expected.items():
        lb = whole_image(4, 4, 4, turns)
        marked = np.zeros((4, 4, 3), dtype=np.float32)
        marked[0, 3] = 1.0  # row 0, column 3
        (row_col,) = np.argwhere(lb.apply(marked)[..., 0] == 1.0)
        assert tuple(row_col[::-1]) == xy
        np.testing.assert_allclose(lb.to_input([3.0, 0.0]), xy, atol=1e-12)
        np.testing.assert_allclose(lb.to_image(np.array(xy, dtype=float)), [3.0, 0.0], atol=1e-12)


@pytest.mark.parametrize('width, height, out_w, out_h', [(1003, 777, 384, 289), (460, 320, 134, 192),
                                                         (320, 460, 192, 134), (150, 90, 100, 70)])
def test_resized_maps_pixel_edges_exactly_and_averages_when_shrinking(width, height, out_w, out_h):
    """A ramp's value is its pixel's centre, so each output pixel must hold the image coordinate
    of its own centre (edges to edges: x + 0.5 = (X + 0.5) * width / out_w), whatever whole-block
    factor and bilinear rest the shrink takes; the rows and columns no whole block holds stay
    within a pixel of it at the far edge. A one-pixel checkerboard shrunk by 2 or more averages
    to grey rather than aliasing."""
    u = np.tile(np.arange(width, dtype=np.float32), (height, 1))
    v = np.tile(np.arange(height, dtype=np.float32)[:, None], (1, width))
    out = resized(np.stack([u, v, u], axis=-1), out_w, out_h)
    assert out.shape == (out_h, out_w, 3)
    expect_u = (np.arange(out_w) + 0.5) * width / out_w - 0.5
    expect_v = (np.arange(out_h) + 0.5) * height / out_h - 0.5
    np.testing.assert_allclose(out[1:-1, 1:-1, 0], np.tile(expect_u[1:-1], (out_h - 2, 1)), atol=0.02)
    np.testing.assert_allclose(out[1:-1, 1:-1, 1], np.tile(expect_v[1:-1, None], (1, out_w - 2)), atol=0.02)
    np.testing.assert_allclose(out[..., 0], np.tile(expect_u, (out_h, 1)), atol=1.0)
    checker = ((np.add.outer(np.arange(height), np.arange(width)) % 2) * 255).astype(np.uint8)
    grey = resized(checker[..., None].repeat(3, axis=-1), out_w, out_h)
    if min(width / out_w, height / out_h) >= 2:
        assert np.abs(grey[1:-1, 1:-1].astype(float) - 127.5).max() < 40


@pytest.mark.parametrize('box, out_w, out_h', [((101.3, 40.6, 587.9, 702.2), 141, 192),
                                               ((3.5, 7.25, 80.0, 61.0), 150, 110),
                                               ((0.0, 0.0, 1003.0, 777.0), 384, 297)])
def test_resized_maps_a_boxs_fractional_edges_exactly(box, out_w, out_h):
    """Part of an image (a crop cut from a shrunk copy has fractional edges) on the output:
    output pixel X holds the image coordinate box[0] + (X + 0.5) * (box[2] - box[0]) / out_w - 0.5."""
    width, height = 1003, 777
    u = np.tile(np.arange(width, dtype=np.float32), (height, 1))
    v = np.tile(np.arange(height, dtype=np.float32)[:, None], (1, width))
    out = resized(np.stack([u, v, u], axis=-1), out_w, out_h, np.array(box))
    expect_u = box[0] + (np.arange(out_w) + 0.5) * (box[2] - box[0]) / out_w - 0.5
    expect_v = box[1] + (np.arange(out_h) + 0.5) * (box[3] - box[1]) / out_h - 0.5
    np.testing.assert_allclose(out[1:-1, 1:-1, 0], np.tile(expect_u[1:-1], (out_h - 2, 1)), atol=0.02)
    np.testing.assert_allclose(out[1:-1, 1:-1, 1], np.tile(expect_v[1:-1, None], (1, out_w - 2)), atol=0.02)


def test_a_crop_cut_from_a_shrunk_copy_is_the_crop_of_the_image():
    """A person crop's input from a copy of the image half its size (a JPEG decoded at half
    scale) against the same crop from the image itself: the same picture, within the detail
    the copy lost."""
    v, u = np.mgrid[0:776, 0:1032]
    wave = (127 + 100 * np.sin(u / 9.0) * np.cos(v / 11.0)).astype(np.uint8)  # a few px of detail
    image = np.ascontiguousarray(np.stack([wave, wave[::-1], wave[:, ::-1]], axis=-1))
    half = cv2.resize(image, (516, 388), interpolation=cv2.INTER_AREA)
    lb = letterbox(1032, 776, np.array([412.3, 80.7, 688.9, 742.2]), 192)
    full = lb.apply(image).astype(float)
    assert np.abs(full - lb.apply(half, np.array([2.0, 2.0]))).mean() < 1.0
    # a copy's scale wrong by half a percent along either axis moves the picture visibly
    for wrong in ([2.01, 2.0], [2.0, 2.01]):
        assert np.abs(full - lb.apply(half, np.array(wrong))).mean() > 2.0
