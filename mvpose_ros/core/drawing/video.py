"""Predictions rendered for eyes without RViz: each frame's skeletons seen by a virtual camera
looking at the rig (with the rig's cameras as frusta and a 1 m floor grid), ids coloured as in the
RViz markers, the frame number and stamp written on it; optionally beside a rig camera's image
with the skeletons projected into it (where an image of that frame exists).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import cv2
import numpy as np

from mvpose_ros.core.drawing.colours import person_colour
from mvpose_ros.core.drawing.overlay import draw_ground_truth, draw_skeletons
from mvpose_ros.core.geometry.body import NUM_JOINTS, TOP_HEAD
from mvpose_ros.core.geometry.camera import Camera
from mvpose_ros.core.types import FrameResult

FONT = cv2.FONT_HERSHEY_SIMPLEX
BACKGROUND = (40, 40, 40)
GRID_BGR = (90, 90, 90)
CAMERA_BGR = (200, 200, 200)
TEXT_BGR = (255, 255, 255)
VIEW_FOV_DEG = 55.0
VIEW_ELEVATION_DEG = 35.0
FOURCC = {'.mp4': 'mp4v', '.avi': 'MJPG'}


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray, width: int, height: int,
            fov_deg: float = VIEW_FOV_DEG, name: str = 'view') -> Camera:
    """A pinhole Camera at eye (3,) looking at target (3,), `up` (3,) pointing up in its image,
    horizontal field of view fov_deg, image width x height."""
    z = target - eye
    z = z / np.linalg.norm(z)
    x = np.cross(z, up)
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)  # image down
    R = np.stack([x, y, z])  # world -> camera
    f = 0.5 * width / np.tan(np.radians(fov_deg) / 2)
    K = np.array([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]])
    return Camera(name, K, R, -R @ eye, np.zeros(5), width, height)


def virtual_camera(results: Sequence[FrameResult], rig: Sequence[Camera], up: np.ndarray, width: int,
                   height: int) -> Camera:
    """A view of where the people are from the side of the rig's cameras, raised
    VIEW_ELEVATION_DEG, far enough that every predicted joint is in the picture."""
    up = np.asarray(up, dtype=float) / np.linalg.norm(up)
    points = np.concatenate([r.joints.reshape(-1, 3) for r in results] + [np.zeros((0, 3))])
    if len(points) == 0:
        points = np.array([c.centre for c in rig]) if rig else np.zeros((1, 3))
    target = np.median(points, axis=0)
    horizontal = (np.mean([c.centre for c in rig], axis=0) - target) if rig else np.array([1.0, 1.0, 0.0])
    horizontal -= (horizontal @ up) * up
    if np.linalg.norm(horizontal) < 1e-6:
        horizontal = np.cross(up, [1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.cross(up, [0.0, 1.0, 0.0])
    horizontal /= np.linalg.norm(horizontal)
    elevation = np.radians(VIEW_ELEVATION_DEG)
    direction = np.cos(elevation) * horizontal + np.sin(elevation) * up
    radius = max(float(np.percentile(np.linalg.norm(points - target, axis=1), 98)), 1.0)
    half_fov = np.arctan(np.tan(np.radians(VIEW_FOV_DEG) / 2) * min(1.0, height / width))
    distance = 1.1 * radius / np.sin(half_fov)  # a sphere of that radius just fits
    return look_at(target + distance * direction, target, up, width, height)


def _line(img: np.ndarray, camera: Camera, a: np.ndarray, b: np.ndarray, colour, thickness: int = 1) -> None:
    uv = camera.project(np.stack([a, b]))
    if np.isfinite(uv).all():
        p, q = np.round(uv).astype(int).tolist()
        cv2.line(img, tuple(p), tuple(q), colour, thickness, cv2.LINE_AA)


def _floor(img: np.ndarray, camera: Camera, centre: np.ndarray, up: np.ndarray, half: int = 5) -> None:
    """A 1 m grid on the plane through the world origin normal to up, around centre."""
    e1 = np.cross(up, [1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.cross(up, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    c = np.round(centre - (centre @ up) * up)
    for k in range(-half, half + 1):
        _line(img, camera, c + k * e1 - half * e2, c + k * e1 + half * e2, GRID_BGR)
        _line(img, camera, c + k * e2 - half * e1, c + k * e2 + half * e1, GRID_BGR)


def _frusta(img: np.ndarray, camera: Camera, rig: Sequence[Camera], names: Sequence[str], depth: float = 0.5) -> None:
    for cam, name in zip(rig, names):
        corners = np.array([[0, 0], [cam.width, 0], [cam.width, cam.height], [0, cam.height]], dtype=float)
        rays = cam.directions(corners)
        far = cam.centre + rays * (depth / (rays @ cam.R[2]))[:, None]
        for k in range(4):
            _line(img, camera, cam.centre, far[k], CAMERA_BGR)
            _line(img, camera, far[k], far[(k + 1) % 4], CAMERA_BGR)
        uv = camera.project(cam.centre)
        if np.isfinite(uv).all():
            cv2.putText(img, name, tuple(np.round(uv + [4, -4]).astype(int).tolist()), FONT, 0.45, CAMERA_BGR, 1,
                        cv2.LINE_AA)


def _labels(img: np.ndarray, camera: Camera, result: FrameResult, scale: float) -> None:
    """Each person's id beside its head top, in its colour."""
    for pid, joints in zip(result.person_ids, result.joints):
        uv = camera.project(joints[TOP_HEAD])
        if np.isfinite(uv).all():
            r, g, b = person_colour(pid)
            cv2.putText(img, f'id {pid}', tuple(np.round(uv + [6, -8]).astype(int).tolist()), FONT, scale,
                        (int(255 * b), int(255 * g), int(255 * r)), 2, cv2.LINE_AA)


def _caption(img: np.ndarray, text: str) -> None:
    (w, h), base = cv2.getTextSize(text, FONT, 0.7, 2)
    cv2.rectangle(img, (0, 0), (w + 24, h + base + 20), (0, 0, 0), -1)
    cv2.putText(img, text, (12, 12 + h), FONT, 0.7, TEXT_BGR, 2, cv2.LINE_AA)


@dataclass
class Scene:
    """What every frame is drawn with: the virtual camera, the rig (cameras and names), up,
    optionally a rig camera to project into with image(frame) -> BGR or None where none exists, and
    optionally truth(frame) -> the actors annotated in it (A,) and their poses (A, 14, 3), drawn as
    overlay.draw_ground_truth draws them (A may be 0)."""

    view: Camera
    rig: Sequence[Camera]
    names: Sequence[str]
    up: np.ndarray
    camera: int | None = None
    image: Callable[[int], np.ndarray | None] | None = None
    truth: Callable[[int], tuple[np.ndarray, np.ndarray]] | None = None


def render_frame(scene: Scene, result: FrameResult, stamp_ns: int | None) -> np.ndarray:
    """One video frame (BGR): the virtual view, and beside it the rig camera's panel (same
    height) when scene.camera is set."""
    view = scene.view
    img = np.full((view.height, view.width, 3), BACKGROUND, np.uint8)
    target = np.median(result.joints.reshape(-1, 3), axis=0) if len(result.joints) else np.zeros(3)
    _floor(img, view, target, scene.up)
    _frusta(img, view, scene.rig, scene.names)
    colours = [person_colour(pid) for pid in result.person_ids]
    draw_skeletons(img, view, result.joints, colours)
    actors, truth = scene.truth(result.frame) if scene.truth else ((), np.zeros((0, NUM_JOINTS, 3)))
    draw_ground_truth(img, view, truth, actors)
    _labels(img, view, result, 0.55)
    stamp = f'{stamp_ns / 1e9:.3f} s' if stamp_ns is not None else '-'
    _caption(img, f'frame {result.frame}  stamp {stamp}  {len(result.person_ids)} people')
    if scene.camera is None:
        return img
    cam = scene.rig[scene.camera]
    photo = scene.image(result.frame) if scene.image else None
    panel = np.zeros((cam.height, cam.width, 3), np.uint8) if photo is None else photo.copy()
    draw_skeletons(panel, cam, result.joints, colours)
    draw_ground_truth(panel, cam, truth, actors)
    _labels(panel, cam, result, 0.9)
    _caption(panel, f'{scene.names[scene.camera]}' + ('' if photo is not None else ' (no image of this frame)'))
    width = 2 * round(cam.width * view.height / cam.height / 2)  # even: video codecs drop an odd column
    panel = cv2.resize(panel, (width, view.height), interpolation=cv2.INTER_AREA)
    return np.concatenate([img, panel], axis=1)


def write_video(path: str | Path, frames: Sequence[tuple[FrameResult, int | None]], scene: Scene,
                fps: float) -> int:
    """Render every (result, stamp ns or None) to path (.mp4: mp4v, .avi: MJPG); returns the
    number of frames written. ValueError when the container is unknown or OpenCV cannot write it."""
    path = Path(path)
    if path.suffix not in FOURCC:
        raise ValueError(f'{path}: the video must end in {" or ".join(FOURCC)}')
    if not frames:
        raise ValueError('no frames to render')
    first = render_frame(scene, *frames[0])
    path.parent.mkdir(parents=True, exist_ok=True)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*FOURCC[path.suffix]), fps,
                             (first.shape[1], first.shape[0]))
    if not writer.isOpened():
        raise ValueError(f'{path}: OpenCV cannot write {FOURCC[path.suffix]} video here')
    try:
        writer.write(first)
        for result, stamp in frames[1:]:
            writer.write(render_frame(scene, result, stamp))
    finally:
        writer.release()
    return len(frames)
