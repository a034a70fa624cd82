"""Rig files: the one description of a camera rig (YAML), or a calibration file plus an image size.

A rig file gives the rig's `world_frame` and `up`, and per camera its name, image and camera_info
topics, frame id and extrinsics (`position`, metres, and `orientation`, world <- camera optical
frame); intrinsics are optional, else they come from each camera's CameraInfo
(RigCamera.with_info). Every error is a ValueError of one line naming the file, the camera and the
field. The format, field by field: docs/own_cameras.md#the-rig-file-format."""
from __future__ import annotations

import dataclasses
import math
import re
from pathlib import Path
from typing import Any, Callable

import numpy as np
import yaml

from mvpose_ros.core.geometry import lens
from mvpose_ros.core.geometry.camera import Camera, image_corners, load_rig

UNIT_TOLERANCE = 1e-3  # |norm(q) - 1| above this: not a rotation (rather than a rounded one)
DATA_ROOT_TOKEN = '{data_root}'
DataRoot = str | Path | Callable[[], str | Path] | None  # a folder, or a function finding it
NAME_PATTERN = re.compile(r'[A-Za-z_][A-Za-z0-9_]*')

_TOP_KEYS = {'world_frame', 'up', 'cameras', 'calibration', 'width', 'height'}
_TOPIC_KEYS = {'name', 'image', 'camera_info', 'frame_id'}
_CAMERA_KEYS = _TOPIC_KEYS | {'position', 'orientation', 'width', 'height', 'K', 'distortion_model', 'D', 'rectified'}


def quaternion_to_matrix(q: np.ndarray) -> np.ndarray:
    """(4,) unit quaternion x, y, z, w -> (3, 3) rotation matrix."""
    x, y, z, w = np.asarray(q, dtype=float)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def matrix_to_quaternion(R: np.ndarray) -> np.ndarray:
    """(3, 3) rotation matrix -> (4,) unit quaternion x, y, z, w with w >= 0."""
    R = np.asarray(R, dtype=float)
    # Shepperd's method: build from the largest of the four squared components (stable).
    squares = np.array([1 + R[0, 0] - R[1, 1] - R[2, 2], 1 - R[0, 0] + R[1, 1] - R[2, 2],
                        1 - R[0, 0] - R[1, 1] + R[2, 2], 1 + np.trace(R)])
    i = int(np.argmax(squares))
    s = 2.0 * math.sqrt(squares[i])
    if i == 0:
        q = [s / 4, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s, (R[2, 1] - R[1, 2]) / s]
    elif i == 1:
        q = [(R[0, 1] + R[1, 0]) / s, s / 4, (R[1, 2] + R[2, 1]) / s, (R[0, 2] - R[2, 0]) / s]
    elif i == 2:
        q = [(R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, s / 4, (R[1, 0] - R[0, 1]) / s]
    else:
        q = [(R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, s / 4]
    q = np.array(q)
    return q if q[3] >= 0 else -q


def intrinsics_camera(where: str, name: str, R: np.ndarray, t: np.ndarray, K: Any, D: Any, width: Any,
                      height: Any, distortion_model: str = lens.DEFAULT_MODEL) -> Camera:
    """A Camera from extrinsics (R (3, 3) world -> camera, t (3,) metres) and intrinsics: K (3, 3),
    9 numbers or fx, fy, cx, cy (pixels); D the coefficients of distortion_model (lens.MODELS, in
    CameraInfo's order; missing trailing ones 0); width, height pixels. ValueError of one line
    starting with `where`."""
    if distortion_model not in lens.MODELS:
        raise ValueError(f'{where}: {lens.unsupported(distortion_model)}')
    K = _intrinsic_matrix(where, K)
    d = lens.coefficients(distortion_model, _numbers(where, 'D', D), f'{where}: D')
    size = []
    for field, value in (('width', width), ('height', height)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise ValueError(f'{where}: {field}: expected a whole number of pixels >= 1, got {value!r}')
        size.append(int(value))
    _no_fold(where, K, d, *size, distortion_model)
    return Camera(name, K, R, t, d, *size, distortion_model)


def _no_fold(where: str, K: np.ndarray, d: np.ndarray, width: int, height: int, model: str) -> None:
    """ValueError when the lens folds back inside the image (lens.fold), in pixels from the
    principal point (at the geometric mean focal length)."""
    normalised = (image_corners(width, height) - K[:2, 2]) / np.diag(K)[:2]
    reach = float(np.sqrt((normalised ** 2).sum(axis=1)).max())
    folded = lens.fold(model, d, reach)
    if folded is not None:
        f = float(np.sqrt(K[0, 0] * K[1, 1]))
        raise ValueError(f'{where}: D: the {model} lens folds back about {folded * f:.0f} px from the principal '
                         f'point, inside the {width}x{height} image (its corners reach {reach * f:.0f} px): beyond '
                         f'that, two rays land on one pixel. Recalibrate with views near the corners')


@dataclasses.dataclass(frozen=True, eq=False)
class RigCamera:
    """One camera of a rig: names, topics and extrinsics, and its Camera once intrinsics are known.

    R: (3, 3) world -> camera optical rotation; t: (3,) metres (x_cam = R @ X + t, as Camera);
    camera: the calibrated Camera when the rig gives intrinsics, else None (see with_info);
    rectified: its images are rectified (image_proc's image_rect), so CameraInfo's P, not K and D,
    describes them, and its R turns them from this pose (a stereo pair's; msg_adapters'
    camera_info_msg.info_camera).
    """

    name: str
    image: str
    camera_info: str
    frame_id: str | None  # None: learned from its messages (core.geometry.frame_id)
    R: np.ndarray
    t: np.ndarray
    camera: Camera | None = None
    rectified: bool = False

    @property
    def position(self) -> np.ndarray:
        """(3,) optical centre in the world, metres."""
        return -self.R.T @ self.t

    @property
    def orientation(self) -> np.ndarray:
        """(4,) quaternion x, y, z, w of the rotation world <- camera optical frame."""
        return matrix_to_quaternion(self.R.T)

    def with_info(self, K: np.ndarray, D: np.ndarray, width: int, height: int,
                  distortion_model: str = lens.DEFAULT_MODEL, rectification: np.ndarray | None = None) -> Camera:
        """This camera's Camera with intrinsics from a CameraInfo: K (3, 3) pixels, D the
        coefficients of distortion_model, image size in pixels; rectification (3, 3): the rotation
        from this camera's optical frame to its images' (a stereo pair's rectified frame; None:
        the same). ValueError naming the camera and field."""
        turn = np.eye(3) if rectification is None else np.asarray(rectification, dtype=np.float64)
        return intrinsics_camera(f'camera {self.name!r}', self.name, turn @ self.R, turn @ self.t,
                                 np.asarray(K).tolist(), np.asarray(D).tolist(), width, height, distortion_model)


@dataclasses.dataclass(frozen=True, eq=False)
class Rig:
    """A rig: world frame id, up (3,) unit vector in the world, cameras in rig order."""

    world_frame: str
    up: np.ndarray
    cameras: list[RigCamera]
    path: Path | None = None

    @property
    def names(self) -> list[str]:
        """Camera names in rig order."""
        return [c.name for c in self.cameras]

    @property
    def calibrated(self) -> bool:
        """Every camera has its intrinsics (no CameraInfo needed)."""
        return all(c.camera is not None for c in self.cameras)

    def calibrated_cameras(self) -> list[Camera]:
        """The Cameras in rig order; ValueError naming the cameras still lacking intrinsics."""
        lacking = [c.name for c in self.cameras if c.camera is None]
        if lacking:
            raise ValueError(f'{self.path or "rig"}: cameras {", ".join(lacking)}: no intrinsics in the rig file '
                             f'(they come from CameraInfo)')
        return [c.camera for c in self.cameras]


def load_rig_file(path: str | Path, width: int | None = None, height: int | None = None,
                  data_root: DataRoot = None) -> Rig:
    """A Rig from a YAML rig file (.yaml, .yml), or from a calibration (json, P<i>.txt or a folder,
    see camera.load_rig) with the image size width x height pixels given here (required then).

    A YAML rig of the calibration form takes its width/height from the file, these arguments
    otherwise. data_root: replaces '{data_root}' at the start of the file's calibration path; a
    function giving it is called only then, so a rig that names no data root needs none (association
    on a host without the shared data).
    Calibration cameras are named cam<c> (rig index c), with topics cam<c>/image_raw and
    cam<c>/camera_info and frame id cam<c>; their Camera keeps the calibration's own name.
    """
    path = Path(path)
    if path.suffix.lower() not in ('.yaml', '.yml'):
        return _calibration_rig(path, load_rig(path, width, height), 'world', np.array([0.0, 0.0, 1.0]), None)
    try:
        doc = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ValueError(f'{path}: not valid YAML ({" ".join(str(exc).split())})') from None
    except UnicodeDecodeError as exc:
        raise ValueError(f'{path}: not a text file ({exc})') from None
    if not isinstance(doc, dict):
        raise ValueError(f'{path}: expected a mapping with cameras, got {type(doc).__name__}')
    _no_unknown(str(path), doc, _TOP_KEYS)
    world_frame = _string(str(path), 'world_frame', doc.get('world_frame', 'world'))
    up = _numbers(str(path), 'up', doc.get('up', [0.0, 0.0, 1.0]), 3)
    if not np.linalg.norm(up) > 1e-9:
        raise ValueError(f'{path}: up: must be a non-zero vector, got {up.tolist()}')
    up = up / np.linalg.norm(up)
    if 'calibration' in doc:
        return _calibration_form(path, doc, world_frame, up, width, height, data_root)
    for field in ('width', 'height'):
        if field in doc:
            raise ValueError(f'{path}: {field}: only with calibration (give each camera its own size)')
    entries = doc.get('cameras')
    if entries is None:
        raise ValueError(f'{path}: missing cameras (or calibration)')
    if not isinstance(entries, list) or not entries:
        raise ValueError(f'{path}: cameras: expected a non-empty list, got {entries!r}')
    cameras = [_explicit_camera(path, i, e) for i, e in enumerate(entries)]
    _no_duplicates(path, cameras)
    return Rig(world_frame, up, cameras, path)


def _calibration_form(path: Path, doc: dict, world_frame: str, up: np.ndarray, width: int | None,
                      height: int | None, data_root: DataRoot) -> Rig:
    calibration = _string(str(path), 'calibration', doc['calibration'])
    if calibration.startswith(DATA_ROOT_TOKEN):
        if data_root is None:
            raise ValueError(f'{path}: calibration: {calibration!r} needs a data root, and none was given')
        root = data_root() if callable(data_root) else data_root
        calib_path = Path(root) / calibration[len(DATA_ROOT_TOKEN):].lstrip('/')
    else:
        calib_path = path.parent / Path(calibration).expanduser()
    size = []
    for field, fallback in (('width', width), ('height', height)):
        value = doc.get(field, fallback)
        if value is None:
            raise ValueError(f'{path}: missing {field} (image size in pixels: the calibration does not record it)')
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f'{path}: {field}: expected a whole number of pixels >= 1, got {value!r}')
        size.append(value)
    try:
        cams = load_rig(calib_path, *size)
    except FileNotFoundError as exc:
        raise ValueError(f'{path}: calibration: {exc}') from None
    except ValueError as exc:
        raise ValueError(f'{path}: calibration: {" ".join(str(exc).split())}') from None
    return _calibration_rig(path, cams, world_frame, up, doc.get('cameras'))


def _calibration_rig(path: Path, cams: list[Camera], world_frame: str, up: np.ndarray,
                     overrides: Any) -> Rig:
    if overrides is None:
        overrides = [{}] * len(cams)
    if not isinstance(overrides, list) or len(overrides) != len(cams):
        raise ValueError(f'{path}: cameras: expected a list of {len(cams)} entries (one per calibration camera), '
                         f'got {overrides!r}')
    cameras = []
    for c, (cam, entry) in enumerate(zip(cams, overrides)):
        where = f'{path}: camera {c}'
        if not isinstance(entry, dict):
            raise ValueError(f'{where}: expected a mapping, got {entry!r}')
        _no_unknown(where, entry, _TOPIC_KEYS)
        name, image, info, frame_id = _names(where, entry, f'cam{c}')
        cameras.append(RigCamera(name, image, info, frame_id, cam.R, cam.t, cam))
    _no_duplicates(path, cameras)
    return Rig(world_frame, up, cameras, path)


def _explicit_camera(path: Path, index: int, e: Any) -> RigCamera:
    where = f'{path}: camera {index}'
    if not isinstance(e, dict):
        raise ValueError(f'{where}: expected a mapping, got {e!r}')
    if 'name' not in e:
        raise ValueError(f'{where}: missing name')
    where = f'{path}: camera {e["name"]!r}'
    _no_unknown(where, e, _CAMERA_KEYS)
    name, image, info, frame_id = _names(where, e, None)
    for field in ('position', 'orientation'):
        if field not in e:
            raise ValueError(f'{where}: missing {field}')
    position = _numbers(where, 'position', e['position'], 3)
    q = _numbers(where, 'orientation', e['orientation'], 4)
    norm = float(np.linalg.norm(q))
    if not abs(norm - 1.0) <= UNIT_TOLERANCE:
        raise ValueError(f'{where}: orientation: not a rotation (quaternion x y z w of norm {norm:.6g}, '
                         f'expected 1 within {UNIT_TOLERANCE})')
    R = quaternion_to_matrix(q / norm).T  # world -> camera
    t = -R @ position
    intrinsics = [k for k in ('width', 'height', 'K', 'distortion_model', 'D') if k in e]
    rectified = e.get('rectified', False)
    if not isinstance(rectified, bool):
        raise ValueError(f'{where}: rectified: expected true or false, got {rectified!r}')
    if rectified and intrinsics:
        raise ValueError(f'{where}: rectified: only for intrinsics from CameraInfo (here give the rectified '
                         f"image's K and no D instead)")
    camera = None
    if intrinsics:
        missing = [k for k in ('width', 'height', 'K') if k not in e]
        if missing:
            raise ValueError(f'{where}: missing {", ".join(missing)} (intrinsics are all of width, height, K, '
                             f'or none: then they come from CameraInfo)')
        model = e.get('distortion_model', lens.DEFAULT_MODEL)
        camera = intrinsics_camera(where, name, R, t, e['K'], e.get('D', []), e['width'], e['height'],
                                   _string(where, 'distortion_model', model))
    return RigCamera(name, image, info, frame_id, R, t, camera, rectified)


def _names(where: str, e: dict, default_name: str | None) -> tuple[str, str, str, str | None]:
    """name, image topic, camera_info topic, frame_id (None: not given) of a camera entry."""
    name = _string(where, 'name', e.get('name', default_name))
    if not NAME_PATTERN.fullmatch(name):
        raise ValueError(f'{where}: name: {name!r} is not a valid name ([A-Za-z_][A-Za-z0-9_]*: it names '
                         f'namespaces)')
    image = _string(where, 'image', e.get('image', f'{name}/image_raw'))
    info = _string(where, 'camera_info', e.get('camera_info', f'{name}/camera_info'))
    frame_id = _string(where, 'frame_id', e['frame_id']) if 'frame_id' in e else None
    for field, topic in (('image', image), ('camera_info', info)):
        if re.search(r'\s', topic):
            raise ValueError(f'{where}: {field}: {topic!r} is not a topic name')
    return name, image, info, frame_id


def _no_duplicates(path: Path, cameras: list[RigCamera]) -> None:
    """One name per camera, and one image topic: two entries on one stream (a copied entry left
    unedited) would put one camera's people at two poses. A camera_info topic too where either
    camera reads its intrinsics from it."""
    names: set[str] = set()
    images: dict[str, str] = {}
    infos: dict[str, RigCamera] = {}
    for cam in cameras:
        if cam.name in names:
            raise ValueError(f'{path}: camera {cam.name!r}: name: duplicate camera name')
        names.add(cam.name)
        if cam.image in images:
            raise ValueError(f'{path}: camera {cam.name!r}: image: {cam.image!r} is also the image topic of camera '
                             f'{images[cam.image]!r} (each camera needs its own)')
        images[cam.image] = cam.name
        other = infos.get(cam.camera_info)
        if other is not None and (other.camera is None or cam.camera is None):
            raise ValueError(f'{path}: camera {cam.name!r}: camera_info: {cam.camera_info!r} is also the camera_info '
                             f'topic of camera {other.name!r}, and intrinsics come from it (each camera needs its own)')
        infos.setdefault(cam.camera_info, cam)


def _no_unknown(where: str, mapping: dict, allowed: set[str]) -> None:
    unknown = sorted(str(k) for k in mapping if k not in allowed)
    if unknown:
        raise ValueError(f'{where}: unknown field {", ".join(repr(k) for k in unknown)} '
                         f'(expected {", ".join(sorted(allowed))})')


def _string(where: str, field: str, value: Any) -> str:
    if not isinstance(value, str) or not value.strip():
        raise ValueError(f'{where}: {field}: expected a non-empty string, got {value!r}')
    return value


def _numbers(where: str, field: str, value: Any, count: int | None = None) -> np.ndarray:
    """A flat list of finite numbers (nested lists flattened) with `count` entries if given."""
    flat = _flatten(value)
    if flat is None:
        raise ValueError(f'{where}: {field}: expected a list of numbers, got {value!r}')
    for v in flat:
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ValueError(f'{where}: {field}: {v!r} is not a number')
    out = np.array(flat, dtype=float)
    if count is not None and out.size != count:
        raise ValueError(f'{where}: {field}: expected {count} numbers, got {out.size}')
    if not np.isfinite(out).all():
        raise ValueError(f'{where}: {field}: not finite: {out.tolist()}')
    return out


def _flatten(value: Any) -> list | None:
    if not isinstance(value, (list, tuple)):
        return None
    out = []
    for v in value:
        if isinstance(v, (list, tuple)):
            inner = _flatten(v)
            if inner is None:
                return None
            out.extend(inner)
        else:
            out.append(v)
    return out


def _intrinsic_matrix(where: str, K: Any) -> np.ndarray:
    """(3, 3) K from 3x3 rows, 9 numbers or fx, fy, cx, cy; fx, fy > 0, last row 0 0 1."""
    k = _numbers(where, 'K', K)
    if k.size == 4:
        fx, fy, cx, cy = k
        k = np.array([fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0])
    if k.size != 9:
        raise ValueError(f'{where}: K: expected 3x3, 9 numbers or fx fy cx cy, got {k.size} numbers')
    K = k.reshape(3, 3)
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        raise ValueError(f'{where}: K: focal lengths fx, fy must be > 0, got {K[0, 0]}, {K[1, 1]}')
    if (K[1, 0], K[2, 0], K[2, 1], K[2, 2]) != (0, 0, 0, 1):
        raise ValueError(f'{where}: K: expected an upper-triangular matrix with K[2, 2] = 1, got {k.tolist()}')
    return K
