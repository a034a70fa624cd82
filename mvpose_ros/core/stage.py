"""The whole 3D stage as one streaming object, and its configuration from flat parameters.

`Stage3D` is "associate, bundle, solve": each frame's 2D people of every camera go in, decoded
frames come out `lag` frames later. The offline evaluator, the benchmarks (one and two processes)
and `mvpose-images` run it; the node graph runs the same two halves in the association and
bp_solver nodes.

`StageConfig.from_params` is the one translation from flat parameters (the nodes' ROS parameters,
the command lines' options, a parameter file's section) to the configuration dataclasses; the
defaults are the dataclasses' own and validation happens in their constructors. `parameter_specs`
gives the nodes each parameter with its default, description, range and whether it may change
while the node runs (LIVE_PARAMETERS).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Any, Mapping, Sequence

import numpy as np

from mvpose_ros.core.association.associator import AssociationConfig, Associator
from mvpose_ros.core.association.matching import MatchingConfig
from mvpose_ros.core.geometry.body import HEAD_MODELS, UP
from mvpose_ros.core.geometry.camera import Camera
from mvpose_ros.core.inference.factors import FactorConfig
from mvpose_ros.core.inference.hypotheses import SINGLE_VIEW_DEPTHS, UNSEEN_JOINTS, SamplingConfig
from mvpose_ros.core.inference.solver import Inference3D, SolverConfig
from mvpose_ros.core.inference.window import TERMS, InferenceConfig
from mvpose_ros.core.parameters import Param
from mvpose_ros.core.timing import StageTimer
from mvpose_ros.core.types import Bundle, FrameResult, Person2D

# Flat parameter name -> description. 0 stands for None where a setting can be off, since ROS
# parameters have no None.
SOLVER_PARAMETERS = {
    'window': 'frames in the sliding window (0: the whole clip at once, offline only)',
    'lag': 'frames between a frame arriving and its output (< window)',
    'iterations': 'BP iterations when a window is solved from scratch (paper: 5)',
    'slide_iterations': 'iterations per new frame, warm-started from the last slide (0: re-solve every window)',
    'hypotheses': 'hypotheses M per joint (paper: 64)',
    'bp_hypotheses': 'hypotheses kept per joint inside BP, best data term first (0: all M)',
    'single_view_depth': f'depth of a joint seen by one camera on its rays, from {", ".join(SINGLE_VIEW_DEPTHS)}: '
                         'nearest the person\'s centre, or at the bone\'s typical adult length from the parent '
                         'joint, or at the person\'s own (measured in the same frame)',
    'hanging_legs': 'a knee or ankle seen by one camera where its ray meets the sphere of its bone around the '
                    'parent joint lower along up (legs hang from hips and knees), not nearer the person\'s centre',
    'unseen_joints': f'where a joint no camera sees is put, from {", ".join(UNSEEN_JOINTS)}: the person\'s centre, '
                     'or on the body (legs and arms hang from their parents, the neck between the shoulders, the '
                     'head above the neck, a shoulder above a seen hip); with body, a joint seen by one camera '
                     'without a parent to hang from also takes the depth nearest where the body puts it',
    'terms': f'CRF terms, from {", ".join(TERMS)}',
    'head_model': f'head and neck from the detected face: {", ".join(HEAD_MODELS)}',
    'seed': 'seed of the hypothesis sampling',
    'collision_centre': 'collision factor: sigmoid centre, metres between two joints',
    'collision_width': 'collision factor: sigmoid width, metres',
    'frame_rate': 'nominal frames per second: the temporal factor is defined for one such period and widens '
                  'with the real time between frames',
    'max_gap': 's between two successive frames beyond which every temporal chain breaks',
    'threads': 'threads solving people\'s BP chains and temporal tables side by side (the results do not depend on '
               'it; 1: none besides the caller\'s)',
}
ASSOCIATION_PARAMETERS = {
    'track_iou': 'per-camera tracking: minimum box IoU (paper: 0.7)',
    'match_distance': 'cross-view matching: maximum mean ray-to-ray distance between two views of a person, metres',
    'max_view_residual': 'a matched view whose keypoints lie further from the joints the other views triangulate '
                         'than this share of its size (median) is left out (0: every view kept)',
    'single_view_people': 'a person one camera alone sees keeps the id his track had and is placed from where he '
                          'was in the frame before, while his id is remembered after two cameras last saw him '
                          '(false: dropped)',
}
# (low, high) inclusive of every numeric parameter (None: unbounded on that side)
PARAMETER_RANGES: dict[str, tuple[float | None, float | None]] = {
    'window': (0, None), 'lag': (0, None), 'iterations': (1, None), 'slide_iterations': (0, None),
    'hypotheses': (1, None), 'bp_hypotheses': (0, None), 'seed': (0, None),
    'collision_centre': (0.0, 10.0), 'collision_width': (0.001, 10.0), 'frame_rate': (0.1, 1000.0),
    'max_gap': (0.0, 3600.0), 'track_iou': (0.0, 1.0), 'match_distance': (0.0, 10.0),
    'max_view_residual': (0.0, 10.0), 'threads': (1, 64),
}
# Thresholds and distances a running node applies to the frames after the change; every other
# parameter sizes or seeds state made at start-up (read-only: a change needs a restart).
LIVE_PARAMETERS = frozenset({'collision_centre', 'collision_width', 'max_gap', 'track_iou', 'match_distance',
                             'max_view_residual', 'single_view_people'})


@dataclass(frozen=True)
class StageConfig:
    """The 3D stage: association, then the solver."""

    association: AssociationConfig = field(default_factory=AssociationConfig)
    solver: SolverConfig = field(default_factory=SolverConfig)

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> StageConfig:
        """The configuration from flat parameters (names as in SOLVER_PARAMETERS and
        ASSOCIATION_PARAMETERS; others are ignored, absent ones keep their defaults). ValueError
        naming the problem when a value is invalid."""
        d = {**cls().to_params(), **{k: v for k, v in params.items() if k in ALL_PARAMETERS}}
        for name in ('hanging_legs', 'single_view_people'):
            if not isinstance(d[name], (bool, np.bool_)):  # bool('false') would be True
                raise ValueError(f'{name} must be true or false, got {d[name]!r}')
        window = int(d['window']) or None
        factors = replace(FactorConfig(), collision_centre=float(d['collision_centre']),
                          collision_width=float(d['collision_width']))
        inference = InferenceConfig(terms=tuple(d['terms']), window=window, lag=int(d['lag']),
                                    iterations=int(d['iterations']), bp_hypotheses=int(d['bp_hypotheses']) or None,
                                    slide_iterations=int(d['slide_iterations']) or None, factors=factors,
                                    frame_rate=float(d['frame_rate']), max_gap=float(d['max_gap']),
                                    threads=int(d['threads']))
        sampling = replace(SamplingConfig(), hypotheses=int(d['hypotheses']),
                           single_view_depth=str(d['single_view_depth']), hanging_legs=bool(d['hanging_legs']),
                           unseen_joints=str(d['unseen_joints']))
        solver = SolverConfig(sampling=sampling,
                              inference=inference, head_model=str(d['head_model']), seed=int(d['seed']))
        association = replace(AssociationConfig(), track_iou=float(d['track_iou']),
                              matching=replace(MatchingConfig(), max_distance=float(d['match_distance'])),
                              max_view_residual=float(d['max_view_residual']),
                              single_view_people=bool(d['single_view_people']))
        return cls(association, solver)

    def to_params(self) -> dict[str, Any]:
        """The flat parameters of this configuration (the inverse of from_params)."""
        inference, solver = self.solver.inference, self.solver
        return {
            'window': inference.window or 0, 'lag': inference.lag, 'iterations': inference.iterations,
            'slide_iterations': inference.slide_iterations or 0, 'hypotheses': solver.sampling.hypotheses,
            'bp_hypotheses': inference.bp_hypotheses or 0, 'single_view_depth': solver.sampling.single_view_depth,
            'hanging_legs': solver.sampling.hanging_legs, 'unseen_joints': solver.sampling.unseen_joints,
            'terms': list(inference.terms),
            'head_model': solver.head_model, 'seed': solver.seed,
            'collision_centre': inference.factors.collision_centre,
            'collision_width': inference.factors.collision_width,
            'frame_rate': inference.frame_rate, 'max_gap': inference.max_gap, 'threads': inference.threads,
            'track_iou': self.association.track_iou, 'match_distance': self.association.matching.max_distance,
            'max_view_residual': self.association.max_view_residual,
            'single_view_people': self.association.single_view_people,
        }


ALL_PARAMETERS = {**SOLVER_PARAMETERS, **ASSOCIATION_PARAMETERS}


def parameter_specs(names: Mapping[str, str]) -> list[Param]:
    """Each named parameter (name -> description) with its default from StageConfig(), its range
    (PARAMETER_RANGES) and whether it is live (LIVE_PARAMETERS)."""
    defaults = StageConfig().to_params()
    return [Param(name, defaults[name], description, *PARAMETER_RANGES.get(name, (None, None)),
                  live=name in LIVE_PARAMETERS) for name, description in names.items()]


class LiveStageParameters:
    """A node's parameter values as they change while it runs, through the one route of every
    node that runs part of the stage: the values with a change must give a StageConfig
    (from_params), or the change is refused with from_params' reason."""

    def __init__(self, values: Mapping[str, Any]) -> None:
        self.values = dict(values)

    def refusal(self, changes: Mapping[str, Any]) -> str | None:
        """Why `changes` cannot be taken (None: they can)."""
        try:
            StageConfig.from_params({**self.values, **changes})
        except ValueError as exc:
            return str(exc)
        return None

    def apply(self, changes: Mapping[str, Any]) -> StageConfig:
        """Take `changes` (checked by refusal) and return the configuration they give."""
        self.values = {**self.values, **changes}
        return StageConfig.from_params(self.values)


class Stage3D:
    """Associate and solve, streaming: push each frame's 2D people of every camera, get the
    decoded frames that are due. `timer` holds the time of every step ('association', then the
    solver's)."""

    def __init__(self, cameras: Sequence[Camera], config: StageConfig, up: np.ndarray = UP) -> None:
        """up (3,): the world's up, a unit vector (Inference3D)."""
        self.cameras = list(cameras)
        self.config = config
        self.associator = Associator(self.cameras, config.association)
        self.solver = Inference3D(self.cameras, config.solver, up)
        self.timer: StageTimer = self.solver.timer

    def associate(self, frame: int, people: Sequence[Sequence[Person2D] | None],
                  time_s: float | None = None) -> list[Bundle]:
        """The people seen by >= 2 cameras, each with its id and views; people[c] is camera c's 2D
        people (None: no data from it), taken at time_s seconds (None: frame / the nominal frame rate)."""
        t0 = time.perf_counter()
        time_s = frame / self.config.solver.inference.frame_rate if time_s is None else time_s
        bundles = [(o.person_id, o.views) for o in self.associator.update(time_s, people)]
        self.timer.add('association', t0)
        return bundles

    def push(self, frame: int, people: Sequence[Sequence[Person2D] | None],
             time_s: float | None = None) -> list[FrameResult]:
        """Associate and solve one frame, taken at time_s seconds (None: frame / the nominal frame
        rate); returns the frames whose output is due."""
        return self.solver.push(frame, self.associate(frame, people, time_s), time_s)

    def flush(self) -> list[FrameResult]:
        """Every frame not yet output (end of stream)."""
        return self.solver.flush()
