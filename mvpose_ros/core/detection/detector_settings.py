"""The heatmap detector's settings, both backends: one table of parameters (PARAMETERS: name,
default, description, range, choices, live or read-only) and `DetectorConfig.from_params`, the one
translation from flat parameters (the heatmap_detector node's ROS parameters, mvpose-images'
options) to the backends' configurations. The defaults are the configuration dataclasses' own.
ROS-free and without onnxruntime, so that declaring the parameters loads no model."""
from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any, Mapping

from mvpose_ros.core.detection.onnx_config import HEATMAP_SOURCES, MODELS, OnnxDetectorConfig
from mvpose_ros.core.detection.openpose_detector import OpenPoseDetectorConfig
from mvpose_ros.core.detection.upright import UPRIGHT
from mvpose_ros.core.parameters import Param

BACKENDS = ('openpose', 'onnx')
# the parameters of the openpose backend alone (stride and sigma serve both)
OPENPOSE_ONLY = frozenset({'secondary_radius'})
_OPENPOSE_FIELDS = ('stride', 'sigma', 'secondary_radius')
_ONNX_FIELDS = tuple(f.name for f in fields(OnnxDetectorConfig) if f.name != 'model_dir')


@dataclass(frozen=True)
class DetectorConfig:
    """The detector: its backend and that backend's configuration; person_detector_every K: with
    the onnx backend on a whole set, MultiPose searches the whole images of every K-th set only;
    upright: each camera's image turned by quarter turns so that its people stand (upright)."""

    backend: str = 'openpose'
    openpose: OpenPoseDetectorConfig = field(default_factory=OpenPoseDetectorConfig)
    onnx: OnnxDetectorConfig = field(default_factory=lambda: OnnxDetectorConfig(model_dir=Path()))
    person_detector_every: int = 1
    upright: bool = UPRIGHT

    @classmethod
    def from_params(cls, params: Mapping[str, Any], model_dir: Path = Path()) -> DetectorConfig:
        """The configuration from flat parameters (names as in PARAMETERS; others are ignored,
        absent ones keep their defaults), the onnx models in model_dir. ValueError naming the
        problem when a value is invalid (of another type, out of its range or choices, or
        refused by the backend's configuration)."""
        d = {**cls().to_params(), **{k: v for k, v in params.items() if k in SPECS}}
        for name, value in d.items():
            SPECS[name].check(value)
        onnx = {name: d[name] for name in _ONNX_FIELDS}
        return cls(backend=d['backend'],
                   openpose=replace(OpenPoseDetectorConfig(), **{name: d[name] for name in _OPENPOSE_FIELDS}),
                   onnx=OnnxDetectorConfig(model_dir=model_dir, **{**onnx, 'providers': tuple(onnx['providers'])}),
                   person_detector_every=d['person_detector_every'], upright=d['upright'])

    def to_params(self) -> dict[str, Any]:
        """The flat parameters of this configuration (the inverse of from_params; stride and sigma
        are the openpose configuration's, which from_params gives both backends)."""
        onnx = {name: getattr(self.onnx, name) for name in _ONNX_FIELDS}
        return {'backend': self.backend, **onnx, 'providers': list(self.onnx.providers),
                **{name: getattr(self.openpose, name) for name in _OPENPOSE_FIELDS},
                'person_detector_every': self.person_detector_every, 'upright': self.upright}

    def retuned(self, changes: Mapping[str, Any]) -> DetectorConfig:
        """This configuration with the changes of live parameters (ValueError when invalid, or when
        a change names a read-only one)."""
        fixed = sorted(name for name in changes if not SPECS[name].live)
        if fixed:
            raise ValueError(f'{", ".join(fixed)}: read-only (a change needs a restart)')
        return self.from_params({**self.to_params(), **changes}, self.onnx.model_dir)


_DEFAULTS = DetectorConfig().to_params()


def _param(name: str, description: str, low: float | None = None, high: float | None = None, live: bool = False,
           choices: tuple[str, ...] = ()) -> Param:
    """A parameter of the table with its default from DetectorConfig()."""
    return Param(name, _DEFAULTS[name], description, low, high, live, choices)


PARAMETERS: tuple[Param, ...] = (
    _param('backend', f'2D detector: one of {", ".join(BACKENDS)} (input: openpose: <camera>/openpose; onnx: the '
           "rig camera's image topic)", choices=BACKENDS),
    _param('stride', 'heatmap cell size, pixels', 0.5, 256.0),
    _param('sigma', 'std of the Gaussian rendered at each candidate (onnx: at each COCO ear), pixels', 0.1, 1000.0),
    _param('secondary_radius', "openpose: other candidates within this fraction of the person's box diagonal also "
           'enter its map', 0.0, 10.0, live=True),
    _param('heatmaps', f'onnx: heatmap source, {" or ".join(HEATMAP_SOURCES)}: EfficientPose on each person\'s crop, '
           "MultiPose's own keypoints as Gaussians (EfficientPose not loaded), or both fused per limb joint",
           choices=HEATMAP_SOURCES),
    _param('keypoint_sigma', "onnx, heatmaps multipose or fused: std of the Gaussians of MultiPose's keypoints, as a "
           "fraction of the person's box diagonal", 0.001, 1.0),
    _param('model', f'onnx: the model on each person crop, {" or ".join(MODELS)}: EfficientPose (rt, i: heatmaps) or '
           'a single-person keypoint model (MoveNet, BlazePose; docs/crop_models.md)', choices=MODELS),
    _param('crop_workers', 'onnx, single-person keypoint models: crops run at once, each with `threads` intra-op '
           'threads', 1, 64),
    _param('providers', 'onnx: onnxruntime execution providers, in order of preference'),
    _param('threads', 'onnx: intra-op threads per model (0 = one per core)', 0, 1024),
    _param('max_batch', 'onnx: EfficientPose crops per run (0 = all crops of a set in one run, for a GPU)', 0, 4096),
    _param('multipose_workers', 'onnx, whole rig: images of a set MultiPose runs on at once, each with `threads` '
           'intra-op threads (two cores: 2 with threads 1 was faster)', 1, 64),
    _param('input_size', 'onnx: MultiPose square input side, pixels, a multiple of 32', 32, 4096),
    _param('person_detector_every', 'onnx, whole rig: MultiPose searches the whole image of every K-th set only; '
           'between, where the newest skeletons (the node: on skeletons/live) project: MultiPose on that region '
           '(heatmaps multipose) or EfficientPose on those crops (MultiPose does not run)', 1, 1000),
    _param('region_margin', "onnx, person_detector_every > 1, heatmaps multipose: each person's projected box grows "
           'by this fraction of its size into the region MultiPose searches', 0.0, 10.0),
    _param('box_margin', "onnx: each side of a person's box grows by this fraction of its size before the "
           'EfficientPose crop', 0.0, 10.0, live=True),
    _param('min_person_score', 'onnx: MultiPose people scoring less are dropped', 0.0, 1.0, live=True),
    _param('min_joint_score', 'onnx: a joint whose heatmap peak is lower is not detected (empty map)', 0.0, 1.0,
           live=True),
    _param('heatmap_floor', "onnx: heatmap cells below this fraction of their map's peak are 0", 0.0, 0.999,
           live=True),
    _param('ears', "onnx: fill the ear joints from MultiPose's COCO ears (the anatomical head model needs them)"),
    _param('tile_levels', 'onnx: a MultiPose run that comes back full (6 people) is repeated on two overlapping '
           'halves of what it searched, at most this many levels deep (crowds; 0: never)', 0, 4),
    _param('upright', 'onnx: turn the image of a camera mounted on its side or upside down by quarter turns (from '
           "its orientation and the rig's up) so that the networks see people standing"),
)
SPECS = {p.name: p for p in PARAMETERS}
ONNX_PARAMETERS = tuple(p for p in PARAMETERS if p.name != 'backend' and p.name not in OPENPOSE_ONLY)
