"""What goes into each bag the project ships recipes for, built from the real data.

`shelf` (Shelf's frames 300..600 as OpenPose output, optionally a bumped or unplugged camera),
`shelf_images` (frame 572's images), the `shelf_rig` family (frame 572's images as a foreign
rig's driver records them: plain, raw, turned on their mounts, behind other lenses; with their rig
file, rig_file_text), `shelf_crowd` (the scene multiplied to a crowd) and `campus` (a user's
CampusSeq1). Frame f is stamped f / 25 s, but in the shelf_rig bags, whose stamps are a driver's.
A recipe also names the files it reads, so a bag can tell whether it is still up to date.
Each bag's content: docs/cli.md#the-bags."""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

import cv2
import numpy as np
import yaml
from sensor_msgs.msg import CompressedImage, Image
from std_msgs.msg import Header

from msg_adapters.camera_info_msg import camera_to_info
from msg_adapters.image_msg import image_to_compressed_msg, image_to_msg
from msg_adapters.openpose_msg import openpose_to_msg
from msg_adapters.skeleton_msg import skeletons_to_msg
from msg_adapters.stamp import stamp_ns, stamp_of_frame
from mvpose_ros.core.datasets.shelf_campus import (CAMPUS_TEST_FRAMES, SHELF_TEST_FRAMES, dataset_cameras, dataset_dir,
                                                   load_actors_gt)
from mvpose_ros.core.detection.image_file import read_image
from mvpose_ros.core.detection.openpose import OpenPoseFrame, read_body25
from mvpose_ros.core.geometry import lens
from mvpose_ros.core.geometry.body import NUM_JOINTS
from mvpose_ros.core.geometry.bump import axis_rotation, bumped_camera, bumped_pixels
from mvpose_ros.core.geometry.camera import Camera
from mvpose_ros.core.geometry.rig import matrix_to_quaternion
from mvpose_ros.core.scenarios.crowd_openpose import crowd_openpose
from mvpose_ros.core.scenarios.frame_drops import FrameDrop

# Part of every bag's fingerprint: bump it when a recipe's output changes for the same inputs,
# so bags made by older code count as out of date.
RECIPE_VERSION = 1
RECIPES = ('shelf', 'shelf_images', 'shelf_crowd', 'shelf_rig', 'shelf_rig_raw', 'shelf_rig_turned', 'shelf_rig_lenses',
           'shelf_rig_hd', 'campus')
CROWD_PEOPLE = 20  # 3D people per frame the shelf_crowd bag aims at
SHELF_IMAGE_FRAMES = (572,)
GROUND_TRUTH_TOPIC = '/ground_truth/skeletons'
RIG_FILE = 'rig.yaml'  # a bag's own rig file, inside its folder (ros2 bag ignores it)

Item = tuple[str, Any, int]  # (topic, rclpy message, log stamp ns)


@dataclass(frozen=True)
class Recipe:
    """A bag's content: its name, the files it is made from, its messages in log-time order and,
    for a bag of a rig the project has no file for, the text of its rig file (RIG_FILE in the bag
    folder)."""

    name: str
    inputs: tuple[Path, ...]
    items: Callable[[], Iterator[Item]]
    rig_text: Callable[[], str] | None = None
    variant: str = ''  # e.g. the frames dropped (FrameDrop.label)

    def fingerprint(self) -> str:
        """Hash of the recipe version and variant and each input's path, size and modification time."""
        h = hashlib.sha256(f'{self.name} v{RECIPE_VERSION} {self.variant}'.encode())
        for path in self.inputs:
            st = path.stat()
            h.update(f'\n{path.resolve()} {st.st_size} {st.st_mtime_ns}'.encode())
        return h.hexdigest()


def make_recipe(name: str, data_root: str | None = None, campus_dir: str | Path | None = None,
                drop: FrameDrop = FrameDrop(), fault: CameraFault | None = None) -> Recipe:
    """The recipe `name` (one of RECIPES); campus needs campus_dir, the others the data root.
    `drop` leaves frames of the shelf bag out, as sets dropped upstream, and `fault` puts a camera
    fault on it (the other recipes refuse both)."""
    if drop and name != 'shelf':
        raise ValueError(f'dropping frames is for the shelf bag, not {name}')
    if fault is not None and name != 'shelf':
        raise ValueError(f'a camera fault (--rotate-camera, --unplug-camera) is for the shelf bag, not {name}')
    if name == 'campus':
        if campus_dir is None:
            raise ValueError('the campus bag needs a CampusSeq1 folder (--campus-dir)')
        return campus_recipe(campus_dir)
    if name in ('shelf', 'shelf_images'):
        return shelf_recipe(dataset_dir('shelf', data_root), images_only=name == 'shelf_images', drop=drop,
                            fault=fault)
    if name == 'shelf_crowd':
        return shelf_crowd_recipe(dataset_dir('shelf', data_root))
    if name in ('shelf_rig', 'shelf_rig_raw', 'shelf_rig_turned', 'shelf_rig_lenses', 'shelf_rig_hd'):
        return shelf_rig_recipe(dataset_dir('shelf', data_root), compressed=name != 'shelf_rig_raw',
                                turned=name == 'shelf_rig_turned', lenses=name == 'shelf_rig_lenses',
                                hd=name == 'shelf_rig_hd')
    raise ValueError(f'recipe must be one of {", ".join(RECIPES)}; got {name!r}')


def _require(*paths: Path) -> None:
    for path in paths:
        if not path.is_file():
            raise FileNotFoundError(f'{path}: missing')


@dataclass(frozen=True)
class CameraFault:
    """Camera `camera` from Shelf frame `from_frame` on: turned by `degrees` about its optical
    `axis` (core.geometry.bump), or with degrees None unplugged (it sends nothing)."""

    camera: int
    from_frame: int
    degrees: float | None = None
    axis: str = 'y'

    def describe(self) -> str:
        """E.g. 'cam2 turned 2 deg about y from frame 450' (part of the bag's recipe name)."""
        what = 'unplugged' if self.degrees is None else f'turned {self.degrees:g} deg about {self.axis}'
        return f'cam{self.camera} {what} from frame {self.from_frame}'

    def default_folder(self) -> str:
        """The bag folder name under bags/ for the shelf bag with this fault."""
        what = 'unplugged' if self.degrees is None else f'rot{self.degrees:g}{self.axis}'
        return f'shelf_cam{self.camera}_{what}_from{self.from_frame}'


def _bumped(frame: OpenPoseFrame, camera: Camera, bumped: Camera) -> OpenPoseFrame:
    """The OpenPose output of `camera` as the bumped camera would have seen it: every candidate
    moved (same score; the part affinities between candidates are kept)."""
    return OpenPoseFrame([np.column_stack([bumped_pixels(camera, bumped, c[:, :2]), c[:, 2]]) if len(c) else c
                          for c in frame.candidates], frame.pafs)


def _headers(frame: int, n_cameras: int) -> tuple[int, list[Header]]:
    """Log stamp (ns) and one header per camera of `frame`."""
    stamp = stamp_of_frame(frame)
    return stamp_ns(stamp), [Header(stamp=stamp, frame_id=f'cam{c}') for c in range(n_cameras)]


def shelf_recipe(shelf: Path, images_only: bool = False, drop: FrameDrop = FrameDrop(),
                 fault: CameraFault | None = None) -> Recipe:
    """The `shelf` bag (or `shelf_images` with images_only) from the Shelf folder `shelf`, without
    the frames `drop` leaves out and with `fault` on one camera if given."""
    calibration = shelf / 'calibration' / 'calibration_shelf.json'
    _require(calibration)
    rig = dataset_cameras('shelf', calibration=calibration)
    images = {(f, c): shelf / 'frames' / f'cam{c}_{f:06d}.png'
              for f in SHELF_IMAGE_FRAMES for c in range(len(rig))}
    detections = [] if images_only else [shelf / 'openpose_body25' / f'{c}.txt' for c in range(len(rig))]
    _require(*images.values(), *detections)
    frames: Sequence[int] = SHELF_IMAGE_FRAMES if images_only else SHELF_TEST_FRAMES
    if fault is not None and not (0 <= fault.camera < len(rig) and fault.from_frame in frames):
        raise ValueError(f'camera fault: camera {fault.camera} must be in 0..{len(rig) - 1} and frame '
                         f'{fault.from_frame} in {frames[0]}..{frames[-1]}')
    bumped = (bumped_camera(rig[fault.camera], axis_rotation(fault.axis, fault.degrees))
              if fault is not None and fault.degrees is not None else None)
    frames = [frames[k] for k in drop.kept(len(frames))]

    def sends(f: int, c: int) -> bool:
        return fault is None or fault.degrees is not None or c != fault.camera or f < fault.from_frame

    def items() -> Iterator[Item]:
        openpose = [read_body25(path, cam.width, cam.height) for path, cam in zip(detections, rig)]
        for path, frames_of_camera in zip(detections, openpose):
            if len(frames_of_camera) != len(SHELF_TEST_FRAMES):
                raise ValueError(f'{path}: {len(frames_of_camera)} frames, expected '
                                 f'{len(SHELF_TEST_FRAMES)} (Shelf test frames)')
        for f in frames:
            ns, headers = _headers(f, len(rig))
            for c, cam in enumerate(rig):
                if sends(f, c):
                    yield f'/cam{c}/camera_info', camera_to_info(cam, headers[c]), ns
            if f in SHELF_IMAGE_FRAMES:
                for c, cam in enumerate(rig):
                    if sends(f, c):
                        yield f'/cam{c}/image_raw', image_to_msg(read_image(images[f, c], cam), headers[c]), ns
            for c, frames_of_camera in enumerate(openpose):
                raw = frames_of_camera[f - SHELF_TEST_FRAMES.start]
                if bumped is not None and c == fault.camera and f >= fault.from_frame:
                    raw = _bumped(raw, rig[c], bumped)
                if sends(f, c):
                    yield f'/cam{c}/openpose', openpose_to_msg(raw, headers[c]), ns

    name = 'shelf_images' if images_only else 'shelf'
    name += f' ({fault.describe()})' if fault is not None else ''
    return Recipe(name, (calibration, *images.values(), *detections), items, variant=drop.label)


def shelf_crowd_recipe(shelf: Path, people: float = CROWD_PEOPLE) -> Recipe:
    """The `shelf_crowd` bag from the Shelf folder `shelf`: the shelf bag's camera infos and
    OpenPose output, every frame with the copies that bring it to about `people` 3D people."""
    calibration = shelf / 'calibration' / 'calibration_shelf.json'
    _require(calibration)
    rig = dataset_cameras('shelf', calibration=calibration)
    detections = [shelf / 'openpose_body25' / f'{c}.txt' for c in range(len(rig))]
    _require(*detections)

    def items() -> Iterator[Item]:
        openpose = [read_body25(path, cam.width, cam.height) for path, cam in zip(detections, rig)]
        crowd = crowd_openpose(rig, list(zip(*openpose)), people)
        for f, per_camera in zip(SHELF_TEST_FRAMES, crowd.frames):
            ns, headers = _headers(f, len(rig))
            for c, cam in enumerate(rig):
                yield f'/cam{c}/camera_info', camera_to_info(cam, headers[c]), ns
            for c, frame in enumerate(per_camera):
                yield f'/cam{c}/openpose', openpose_to_msg(frame, headers[c]), ns

    return Recipe('shelf_crowd', (calibration, *detections), items, variant=f'people {people:g}')


class ForeignRig:
    """How the shelf_rig bags imitate a user's rig: camera names (Shelf camera c is NAMES[c]), the
    upscaling, and the driver's timing. Stamps: set k of camera c is captured at
    START_NS + k * PERIOD_NS + OFFSETS_MS[c] ms + uniform(-JITTER_MS, JITTER_MS) ms (seeded)."""

    NAMES = ('left', 'centre', 'right', 'back', 'door')
    SCALE = 1.5  # 1032x776 -> 1548x1164: nothing may assume Shelf's size
    SETS = 40
    PERIOD_NS = 40_000_000  # 25 Hz
    START_NS = 1_700_000_000 * 1_000_000_000  # a wall-clock capture time, as drivers stamp
    OFFSETS_MS = (0.0, 5.0, -8.0, 3.0, -6.0)
    JITTER_MS = 1.0
    SEED = 572
    LATE_CAMERA = 'back'  # its first LATE_SETS sets are missing: it starts late
    LATE_SETS = 3
    DROP_CAMERA = 'door'  # these sets of it are missing: dropped frames
    DROPPED_SETS = (11, 22, 33)
    FRAME = 572  # the Shelf frame whose five images every set shows
    JPEG_QUALITY = 90
    TURNS = (2, 2, 1, 3, 2)  # shelf_rig_turned: each image np.rot90'd this many times, its camera with it
    # shelf_rig_lenses: per camera (distortion model, D, focal length factor): fisheyes of a wider
    # view, lenses with the coefficients' magnitudes of an Azure Kinect colour camera, a webcam's barrel
    LENSES = (('equidistant', (0.1, -0.05, 0.01, -0.002), 0.9),
              ('rational_polynomial', (0.5, -2.5, 0.001, -0.0005, 1.4, 0.4, -2.3, 1.3), 1.0),
              ('plumb_bob', (-0.2, 0.05, 0.001, -0.001, 0.0), 1.0),
              ('equidistant', (0.05, 0.0, 0.0, 0.0), 0.8),
              ('rational_polynomial', (0.3, -1.5, 0.0, 0.001, 0.8, 0.25, -1.4, 0.75), 1.0))

    @staticmethod
    def image_topic(name: str, compressed: bool) -> str:
        """The driver's image topic of camera `name`."""
        return f'/rig/{name}/image_raw' + ('/compressed' if compressed else '')

    @staticmethod
    def info_topic(name: str) -> str:
        """The driver's camera_info topic of camera `name`."""
        return f'/rig/{name}/camera_info'

    @staticmethod
    def frame_id(name: str) -> str:
        """The driver's optical frame id of camera `name`."""
        return f'{name}_optical_frame'


class HdRig(ForeignRig):
    """shelf_rig_hd: the shelf_rig cameras as 30 Hz 1920 x 1080 cameras: each Shelf image scaled
    to the frame's height (1080 / 776) and centred between black bars, 60 sets."""

    SCALE = 1080 / 776
    WIDTH, HEIGHT = 1920, 1080
    SETS = 60
    PERIOD_NS = 33_333_333  # 30 Hz


def scaled_camera(camera: Camera, scale: float) -> Camera:
    """The camera of an image resized by `scale` (cv2.resize's pixel-centre mapping
    x' = scale * (x + 0.5) - 0.5); distortion acts on normalised coordinates and is unchanged."""
    K = np.array(camera.K, dtype=float)
    K[0, 0] *= scale
    K[1, 1] *= scale
    K[0, 1] *= scale
    K[:2, 2] = scale * (K[:2, 2] + 0.5) - 0.5
    return replace(camera, K=K, width=round(camera.width * scale), height=round(camera.height * scale))


def padded_camera(camera: Camera, left: int, top: int, width: int, height: int) -> Camera:
    """The camera of its image placed at (left, top) in a width x height frame (borders added)."""
    K = np.array(camera.K, dtype=float)
    K[0, 2] += left
    K[1, 2] += top
    return replace(camera, K=K, width=width, height=height)


def lensed_camera(camera: Camera, model: str, dist: Sequence[float], focal: float = 1.0) -> Camera:
    """The camera at the same pose and principal point with another lens: distortion `model` with
    coefficients `dist`, focal lengths times `focal`."""
    K = np.array(camera.K, dtype=float)
    K[:2, :2] *= focal
    return replace(camera, K=K, dist=np.asarray(dist, dtype=float), distortion_model=model)


def through_lens(image: np.ndarray, camera: Camera, lensed: Camera) -> np.ndarray:
    """The image `lensed` (at camera's pose) takes of the scene `image` of `camera` shows: each
    pixel's ray looked up in `image` (bilinear); black where `image` does not reach."""
    v, u = np.mgrid[0:lensed.height, 0:lensed.width].astype(np.float64)
    uv = camera.project(camera.centre + lensed.directions(np.stack([u, v], axis=-1))).astype(np.float32)
    return cv2.remap(image, uv[..., 0], uv[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)


def turned_camera(camera: Camera, turns: int) -> Camera:
    """The camera turned on its mount about its optical axis so that its image is
    np.rot90(image, turns) of the camera's (counterclockwise as shown): pixel (u, v) becomes
    (v, width - 1 - u) per turn, the image's size swaps, and the distortion's tangential terms
    turn with the image (p1, p2 -> -p2, p1; a fisheye's is radial only); K' = T K M^T with T that
    pixel map and M the turn of the optical frame."""
    for _ in range(turns % 4):
        T = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, camera.width - 1.0], [0.0, 0.0, 1.0]])
        M = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # x' = y, y' = -x, z' = z
        dist = camera.dist.copy()
        if camera.distortion_model != lens.EQUIDISTANT:
            dist[2:4] = -camera.dist[3], camera.dist[2]
        camera = Camera(camera.name, T @ camera.K @ M.T, M @ camera.R, M @ camera.t, dist,
                        camera.height, camera.width, camera.distortion_model)
    return camera


def shelf_rig_stamps(rig: type[ForeignRig] = ForeignRig) -> dict[str, list[int | None]]:
    """Camera name -> its stamp (ns) of every set, None where the camera has no frame."""
    rng = np.random.default_rng(rig.SEED)
    jitter = rng.uniform(-rig.JITTER_MS, rig.JITTER_MS, size=(rig.SETS, len(rig.NAMES)))
    out: dict[str, list[int | None]] = {}
    for c, name in enumerate(rig.NAMES):
        stamps: list[int | None] = []
        for k in range(rig.SETS):
            missing = (name == rig.LATE_CAMERA and k < rig.LATE_SETS) or \
                (name == rig.DROP_CAMERA and k in rig.DROPPED_SETS)
            stamps.append(None if missing else rig.START_NS + k * rig.PERIOD_NS
                          + round((rig.OFFSETS_MS[c] + jitter[k, c]) * 1e6))
        out[name] = stamps
    return out


def rig_file_text(calibration: Path, compressed: bool = True, turned: bool = False, lenses: bool = False,
                  hd: bool = False) -> str:
    """The shelf_rig bags' rig file: per camera its driver topics and extrinsics from the Shelf
    calibration (position, orientation quaternion; turned: each camera turned by ForeignRig.TURNS),
    as a user writes it: no intrinsics (those come from the bag's CameraInfo, at the upscaled size)
    and no frame ids (the driver's, ForeignRig.frame_id, come with the messages)."""
    cameras = dataset_cameras('shelf', calibration=calibration)
    if turned:
        cameras = [turned_camera(cam, k) for cam, k in zip(cameras, ForeignRig.TURNS)]
    entries = []
    for name, cam in zip(ForeignRig.NAMES, cameras):
        position = -cam.R.T @ cam.t
        entries.append({'name': name, 'image': ForeignRig.image_topic(name, compressed),
                        'camera_info': ForeignRig.info_topic(name),
                        'position': [round(float(v), 9) for v in position],
                        'orientation': [round(float(v), 12) for v in matrix_to_quaternion(cam.R.T)]})
    doc = {'world_frame': 'world', 'up': [0.0, 0.0, 1.0], 'cameras': entries}
    kind = 'sensor_msgs/CompressedImage (jpeg)' if compressed else 'sensor_msgs/Image (rgb8)'
    how = (f'# The cameras are turned {", ".join(str(90 * k) for k in ForeignRig.TURNS)} degrees on their mounts '
           f'(np.rot90 of image and camera).\n' if turned else '')
    if lenses:
        how += f'# Their lenses (CameraInfo\'s distortion_model): {", ".join(m for m, _, _ in ForeignRig.LENSES)}.\n'
    size = (f'scaled x{HdRig.SCALE:.4g} into {HdRig.WIDTH} x {HdRig.HEIGHT} frames at {1e9 / HdRig.PERIOD_NS:.0f} Hz' if hd
            else f'upscaled x{ForeignRig.SCALE:g}')
    return (f'# The rig of the shelf_rig bags (mvpose-make-bag): the five Shelf cameras under a driver\'s\n'
            f'# names, {kind} images {size}; extrinsics from\n'
            f'# {calibration.name}; intrinsics, image size and frame ids come from each camera\'s CameraInfo.\n'
            + how + yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=120))


def shelf_rig_recipe(shelf: Path, compressed: bool = True, turned: bool = False, lenses: bool = False,
                     hd: bool = False) -> Recipe:
    """The `shelf_rig` bag (CompressedImage; `shelf_rig_raw` with compressed False: Image rgb8;
    `shelf_rig_turned` with turned: its cameras turned by ForeignRig.TURNS; `shelf_rig_lenses` with
    lenses: seen through ForeignRig.LENSES; `shelf_rig_hd` with hd: HdRig's frames and timing) from
    the Shelf folder `shelf`: see ForeignRig. Each message is logged at its header stamp; every
    image goes with a CameraInfo of the same stamp (camera_info first)."""
    calibration = shelf / 'calibration' / 'calibration_shelf.json'
    _require(calibration)
    cameras = dataset_cameras('shelf', calibration=calibration)
    images = [shelf / 'frames' / f'cam{c}_{ForeignRig.FRAME:06d}.png' for c in range(len(cameras))]
    _require(*images)
    if len(cameras) != len(ForeignRig.NAMES):
        raise ValueError(f'{calibration}: {len(cameras)} cameras, expected {len(ForeignRig.NAMES)}')

    rig = HdRig if hd else ForeignRig

    def items() -> Iterator[Item]:
        scaled = [scaled_camera(cam, rig.SCALE) for cam in cameras]
        pixels = [cv2.resize(read_image(path, cam), (big.width, big.height), interpolation=cv2.INTER_LINEAR)
                  for path, cam, big in zip(images, cameras, scaled)]
        if hd:
            left = [(HdRig.WIDTH - cam.width) // 2 for cam in scaled]
            pixels = [cv2.copyMakeBorder(p, 0, HdRig.HEIGHT - p.shape[0], x, HdRig.WIDTH - p.shape[1] - x,
                                         cv2.BORDER_CONSTANT) for p, x in zip(pixels, left)]
            scaled = [padded_camera(cam, x, 0, HdRig.WIDTH, HdRig.HEIGHT) for cam, x in zip(scaled, left)]
        if turned:
            scaled = [turned_camera(cam, k) for cam, k in zip(scaled, ForeignRig.TURNS)]
            pixels = [np.ascontiguousarray(np.rot90(p, k)) for p, k in zip(pixels, ForeignRig.TURNS)]
        if lenses:
            lensed = [lensed_camera(cam, *lens_of) for cam, lens_of in zip(scaled, ForeignRig.LENSES)]
            pixels = [through_lens(p, cam, new) for p, cam, new in zip(pixels, scaled, lensed)]
            scaled = lensed
        header0 = Header()
        # One encoding per camera: every set shows the same capture, only the header changes.
        payload = ([image_to_compressed_msg(p, header0, 'jpeg', ForeignRig.JPEG_QUALITY) for p in pixels]
                   if compressed else [image_to_msg(p, header0, 'rgb8') for p in pixels])
        stamps = shelf_rig_stamps(rig)
        # (stamp, camera) in log order; messages are made as they are written (raw images are big)
        order = sorted((stamp, c) for c, name in enumerate(ForeignRig.NAMES) for stamp in stamps[name]
                       if stamp is not None)
        for stamp, c in order:
            name = ForeignRig.NAMES[c]
            header = Header(frame_id=ForeignRig.frame_id(name))
            header.stamp.sec, header.stamp.nanosec = divmod(stamp, 1_000_000_000)
            p = payload[c]
            if compressed:
                image = CompressedImage(header=header, format=p.format, data=p.data)
            else:
                image = Image(header=header, height=p.height, width=p.width, encoding=p.encoding,
                              is_bigendian=p.is_bigendian, step=p.step, data=p.data)
            yield ForeignRig.info_topic(name), camera_to_info(scaled[c], header), stamp
            yield ForeignRig.image_topic(name, compressed), image, stamp

    name = ('shelf_rig_turned' if turned else 'shelf_rig_lenses' if lenses else 'shelf_rig_hd' if hd
            else 'shelf_rig' if compressed else 'shelf_rig_raw')
    return Recipe(name, (calibration, *images), items,
                  lambda: rig_file_text(calibration, compressed, turned, lenses, hd))


def campus_image(campus_dir: Path, camera: int, frame: int) -> Path:
    """Where CampusSeq1 keeps camera `camera`'s image of `frame`."""
    return campus_dir / f'Camera{camera}' / f'campus4-c{camera}-{frame:05d}.png'


def campus_recipe(campus_dir: str | Path) -> Recipe:
    """The `campus` bag from a CampusSeq1 folder (Camera{c}/ images, actorsGT.mat,
    calibration_campus.json); test frames without any image are left out."""
    campus_dir = Path(campus_dir)
    if not campus_dir.is_dir():
        raise FileNotFoundError(f'CampusSeq1 folder not found: {campus_dir}')
    gt_path, calibration = campus_dir / 'actorsGT.mat', campus_dir / 'calibration_campus.json'
    _require(gt_path, calibration)
    rig = dataset_cameras('campus', calibration=calibration)
    present = {f: [c for c in range(len(rig)) if campus_image(campus_dir, c, f).is_file()]
               for f in CAMPUS_TEST_FRAMES}
    frames = [f for f in CAMPUS_TEST_FRAMES if present[f]]
    if not frames:
        raise FileNotFoundError(f'{campus_dir}: no test frame images (expected e.g. '
                                f'{campus_image(campus_dir, 0, CAMPUS_TEST_FRAMES[0])})')
    try:
        gt = load_actors_gt(gt_path, frames)
    except IndexError as exc:
        raise ValueError(str(exc)) from None
    inputs = (gt_path, calibration, *(campus_image(campus_dir, c, f) for f in frames for c in present[f]))

    def items() -> Iterator[Item]:
        for i, f in enumerate(frames):
            ns, headers = _headers(f, len(rig))
            for c, cam in enumerate(rig):
                yield f'/cam{c}/camera_info', camera_to_info(cam, headers[c]), ns
            for c in present[f]:
                yield f'/cam{c}/image_raw', image_to_msg(read_image(campus_image(campus_dir, c, f), rig[c]),
                                                         headers[c]), ns
            here = gt.present[i]
            yield GROUND_TRUTH_TOPIC, skeletons_to_msg(np.flatnonzero(here), gt.poses[i, here],
                                                       Header(stamp=headers[0].stamp, frame_id='world'),
                                                       confidence=np.ones((here.sum(), NUM_JOINTS))), ns  # the truth

    return Recipe('campus', inputs, items)
