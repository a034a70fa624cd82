"""The 3D stage on two processes, split where the node graph splits it: this process turns each
camera's OpenPose output into people with heatmaps and associates them across cameras (the
detectors' and association's work); a worker process samples, scores and solves the sliding
window (bp_solver's). Frames stream through a pipe, so on two cores the halves overlap and the
throughput is that of the slower half. The worker runs the same Inference3D on the same input, so
the results equal a single process's.
"""
from __future__ import annotations

import multiprocessing as mp
import time
from dataclasses import dataclass
from multiprocessing.connection import Connection
from typing import Sequence

from mvpose_ros.core.detection.openpose import OpenPoseFrame
from mvpose_ros.core.detection.openpose_detector import OpenPoseDetectorConfig, detect_people
from mvpose_ros.core.evaluation.offline import GROUPING
from mvpose_ros.core.geometry.camera import Camera
from mvpose_ros.core.inference.solver import Inference3D, SolverConfig
from mvpose_ros.core.stage import Stage3D, StageConfig
from mvpose_ros.core.types import FrameResult


@dataclass
class PipelinedRun:
    """results: one per frame, in order; wall_s: from the first frame's grouping to the last
    result back; seconds: per stage, of both processes (they overlap in wall time)."""

    results: list[FrameResult]
    wall_s: float
    seconds: dict[str, float]


def _solver(cameras: Sequence[Camera], config: SolverConfig, inbox: Connection, outbox: Connection) -> None:
    """Worker: (frame, bundles) in, each call's results out; None flushes, sends the timer, ends."""
    solver = Inference3D(cameras, config)
    while (item := inbox.recv()) is not None:
        outbox.send(solver.push(*item))
    outbox.send(solver.flush())
    outbox.send(dict(solver.timer.seconds))


def run_two_processes(cameras: Sequence[Camera], frames: Sequence[int], raw: Sequence[Sequence[OpenPoseFrame]],
                      detector: OpenPoseDetectorConfig, config: StageConfig) -> PipelinedRun:
    """raw[k][c]: camera c's OpenPose output of frames[k]."""
    ctx = mp.get_context('fork')  # the worker starts warm, with the modules already imported
    to_solver, solver_in = ctx.Pipe()
    solver_out, from_solver = ctx.Pipe()
    worker = ctx.Process(target=_solver, args=(cameras, config.solver, solver_in, solver_out), daemon=True)
    worker.start()
    stage = Stage3D(cameras, config)  # only its association half runs here
    timer = stage.timer
    results: list[FrameResult] = []
    try:
        t_start = time.perf_counter()
        for frame, per_camera in zip(frames, raw):
            t0 = time.perf_counter()
            people = [detect_people(f, detector) for f in per_camera]
            timer.add(GROUPING, t0)
            bundles = stage.associate(frame, people)
            to_solver.send((frame, bundles))
            while from_solver.poll():  # keep the return pipe from filling up
                results += from_solver.recv()
        to_solver.send(None)
        while not isinstance(item := from_solver.recv(), dict):  # the last frames' results, the flush's
            results += item
        wall = time.perf_counter() - t_start
    finally:
        worker.join(timeout=10)
        if worker.is_alive():
            worker.kill()
    return PipelinedRun(results, wall, {**timer.seconds, **item})
