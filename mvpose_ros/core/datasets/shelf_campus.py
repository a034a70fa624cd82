"""The Shelf and Campus datasets: where their files live, their fixed facts, and ground-truth loading.

Ground truth comes from the datasets' `actorsGT.mat` (MATLAB cell arrays): `actor3D{p}{f}` is a
(14, 3) array in metres, `actor2D{p}{f}{c}` a (14, 2) array in pixels, and an absent actor is an
empty (1, 0) array. Here absence becomes NaN so that frames stack into dense arrays.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from mvpose_ros.core.defaults import data_root
from mvpose_ros.core.geometry.body import NUM_JOINTS
from mvpose_ros.core.geometry.camera import Camera
from mvpose_ros.core.geometry.rig import Rig, load_rig_file
from mvpose_ros.package_files import package_path

SHELF_TEST_FRAMES = range(300, 601)
CAMPUS_TEST_FRAMES = [*range(350, 471), *range(650, 751)]
SHELF_ACTORS = (0, 1, 2)
CAMPUS_ACTORS = (0, 1, 2)


def dataset_dir(name: str, root: str | None = None) -> Path:
    """`<data root>/data/<name>`, e.g. dataset_dir('shelf')."""
    return data_root(root) / 'data' / name


def calibration_path(name: str) -> Path:
    """The calibration json of dataset `name` ('shelf' or 'campus'), relative to the data root."""
    return Path('data') / name / 'calibration' / f'calibration_{name}.json'


def calibration_file(name: str, root: str | None = None) -> Path:
    """The calibration json of dataset `name` in the shared data."""
    return data_root(root) / calibration_path(name)


def dataset_rig(name: str, root: str | None = None) -> Rig:
    """The rig of dataset `name` ('shelf', 'campus'): the package's config/rigs/<name>.yaml, which
    gives the image size the calibration json does not record."""
    return load_rig_file(package_path(f'config/rigs/{name}.yaml'), data_root=data_root(root))


def dataset_cameras(name: str, root: str | None = None, calibration: str | Path | None = None) -> list[Camera]:
    """The cameras of dataset `name`, from its shared calibration or from `calibration` (e.g. a
    CampusSeq1 folder's copy), at the image size of its rig file."""
    cameras = dataset_rig(name, root).calibrated_cameras()
    if calibration is None:
        return cameras
    return load_rig_file(calibration, cameras[0].width, cameras[0].height).calibrated_cameras()


def shelf_cameras(root: str | None = None) -> list[Camera]:
    """The five Shelf cameras."""
    return dataset_cameras('shelf', root)


@dataclass
class GroundTruth:
    """3D ground truth of a clip.

    frames: (F,) actorsGT frame indices (0-based).
    poses: (F, A, 14, 3) metres, NaN where the actor is absent.
    """

    frames: np.ndarray
    poses: np.ndarray

    @property
    def present(self) -> np.ndarray:
        """(F, A) bool: the actor is annotated in that frame."""
        return np.isfinite(self.poses).all(axis=(-2, -1))

    def annotated(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """The actors (A,) annotated in the i-th frame, as actorsGT indices, and their poses (A, 14, 3)."""
        actors = np.flatnonzero(self.present[i])
        return actors, self.poses[i, actors]


def _cells(mat_path: str | Path, key: str, frames: Sequence[int] | None) -> tuple[np.ndarray, list]:
    """Frame indices (F,) and per-actor lists of the selected cells of `key`."""
    import scipy.io  # the one reader of MATLAB files, loaded only where ground truth is read
    actors = scipy.io.loadmat(str(mat_path), variable_names=[key])[key][0]
    n_frames = actors[0].shape[0]
    idx = np.arange(n_frames) if frames is None else np.asarray(list(frames), dtype=int)
    if idx.size and (idx.min() < 0 or idx.max() >= n_frames):
        raise IndexError(f'{mat_path}: frames must lie in 0..{n_frames - 1}')
    return idx, [actor[idx, 0] for actor in actors]


def load_actors_gt(mat_path: str | Path, frames: Sequence[int] | None = None) -> GroundTruth:
    """3D ground truth of every actor in `mat_path` at `frames` (all frames when None)."""
    idx, actors = _cells(mat_path, 'actor3D', frames)
    poses = np.full((idx.size, len(actors), NUM_JOINTS, 3), np.nan)
    for a, cells in enumerate(actors):
        here = np.array([c.size > 0 for c in cells], dtype=bool)
        if here.any():
            poses[here, a] = np.stack(cells[here])
    return GroundTruth(frames=idx, poses=poses)


def load_actors_gt_2d(mat_path: str | Path, frames: Sequence[int] | None = None) -> np.ndarray:
    """(F, A, C, 14, 2) annotated pixels of every actor in every camera, NaN where absent.

    An absent actor's cell holds one empty array per camera. Campus stores some cameras'
    annotations as integers; they are returned as float.
    """
    idx, actors = _cells(mat_path, 'actor2D', frames)
    n_cams = max((cell.size for cells in actors for cell in cells), default=0)
    uv = np.full((idx.size, len(actors), n_cams, NUM_JOINTS, 2), np.nan)
    for a, cells in enumerate(actors):
        for c in range(n_cams):
            views = [cell.ravel()[c] if cell.size > c else np.empty(0) for cell in cells]
            here = np.array([v.size > 0 for v in views], dtype=bool)
            if here.any():
                uv[here, a, c] = np.stack([v for v, h in zip(views, here) if h])
    return uv
