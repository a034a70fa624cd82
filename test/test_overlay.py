"""Overlay images: the estimate in its person's colour and, where given, the annotated pose in the
ground-truth colour, each where its joints project."""
from __future__ import annotations

import numpy as np

from mvpose_ros.core.drawing.colours import person_colour
from mvpose_ros.core.drawing.overlay import GROUND_TRUTH_BGR, overlay
from mvpose_ros.core.drawing.video import look_at


def _person(x: float) -> np.ndarray:
    """A standing stick person (14, 3) at (x, 0), z up."""
    z = np.array([0.0, 0.45, 0.9, 0.9, 0.45, 0.0, 0.9, 1.15, 1.4, 1.4, 1.15, 0.9, 1.5, 1.75])
    dx = np.array([-0.1, -0.1, -0.1, 0.1, 0.1, 0.1, -0.3, -0.25, -0.2, 0.2, 0.25, 0.3, 0.0, 0.0])
    return np.column_stack([dx + x, np.zeros(14), z])


def _near(img: np.ndarray, uv: np.ndarray, bgr: tuple[int, int, int], radius: int) -> bool:
    """Some pixel within radius of uv (2,) has colour bgr (within anti-aliasing)."""
    u, v = np.round(uv).astype(int)
    patch = img[v - radius:v + radius + 1, u - radius:u + radius + 1].reshape(-1, 3).astype(int)
    return bool((np.abs(patch - np.array(bgr)).sum(axis=1) < 60).any())


def test_the_ground_truth_is_drawn_in_its_colour_at_its_joints_and_not_over_the_estimate():
    camera = look_at(np.array([0.0, -6.0, 1.0]), np.array([0.0, 0.0, 1.0]), np.array([0, 0, 1.0]), 800, 600)
    estimate, truth = _person(-0.8), _person(0.8)
    image = np.zeros((600, 800, 3), np.uint8)
    colour = tuple(int(255 * c) for c in reversed(person_colour(3)))  # (b, g, r)

    plain = overlay(image, camera, [], estimate[None], [person_colour(3)])
    drawn = overlay(image, camera, [], estimate[None], [person_colour(3)], truth[None], [1])

    assert not (image != 0).any()  # a copy is drawn on
    for uv in camera.project(truth):
        assert _near(drawn, uv, GROUND_TRUTH_BGR, 6) and not _near(plain, uv, GROUND_TRUTH_BGR, 6)
    for uv in camera.project(estimate):
        assert _near(drawn, uv, colour, 4) and not _near(drawn, uv, GROUND_TRUTH_BGR, 6)
    # the label stands beside the annotated head top
    top = camera.project(truth[13])
    label = drawn[int(top[1]) - 40:int(top[1]), int(top[0]):int(top[0]) + 80]
    assert (np.abs(label.astype(int) - GROUND_TRUTH_BGR).sum(axis=2) < 60).sum() > 30


def test_an_image_drawn_at_half_its_size_gets_everything_at_half_the_pixels_and_labels():
    """scale 0.5 (an image decoded shrunk): the skeleton's joints and the detections land at half
    the camera's pixels; each person's label is written in its colour beside its head top."""
    from mvpose_ros.core.types import Person2D
    camera = look_at(np.array([0.0, -6.0, 1.0]), np.array([0.0, 0.0, 1.0]), np.array([0, 0, 1.0]), 800, 600)
    estimate = _person(-0.8)
    colour = tuple(int(255 * c) for c in reversed(person_colour(7)))
    keypoints = np.zeros((16, 3))
    keypoints[:14, :2] = camera.project(_person(0.8))
    keypoints[:14, 2] = 1.0
    half = np.zeros((300, 400, 3), np.uint8)
    drawn = overlay(half, camera, [Person2D.from_keypoints(keypoints, 4.0, 6.0)], estimate[None], [person_colour(7)],
                    scale=0.5, labels=['id 7'])
    for uv in camera.project(estimate):
        assert _near(drawn, 0.5 * uv, colour, 3)
    for u, v in np.round(0.5 * keypoints[:14, :2]).astype(int):  # thin anti-aliased white lines
        assert (drawn[v - 2:v + 3, u - 2:u + 3].min(axis=2) > 100).any()
    top = 0.5 * camera.project(estimate[13])
    label = drawn[int(top[1]) - 25:int(top[1]), int(top[0]):int(top[0]) + 50]
    assert (np.abs(label.astype(int) - colour).sum(axis=2) < 60).sum() > 10


def test_the_caption_is_white_on_a_darkened_band_at_the_top_left():
    from mvpose_ros.core.drawing.overlay import draw_caption
    image = np.full((300, 400, 3), 150, np.uint8)
    draw_caption(image, 'left  set 1.000 s  2 people')
    band = image[:12, :150]
    assert (band == 50).any() and (band == 255).all(axis=2).any()  # darkened, and white text on it
    assert (image[100:] == 150).all()
