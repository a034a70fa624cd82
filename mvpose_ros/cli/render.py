"""`mvpose-render`: a predictions file (JSON lines, e.g. from `mvpose-graph --predictions` or
`mvpose-eval --predictions`) rendered to a video, for machines without RViz.

    mvpose-render out/shelf_graph.jsonl --output out/shelf.mp4 [--rig config/rigs/shelf.yaml]
        [--camera 2 --images '<data root>/data/shelf/frames/cam{camera}_{frame:06d}.png']
        [--still 572 --still-output docs/shelf_skeletons.png] [--ground-truth shelf]

The virtual camera looks at where the people are from the side of the rig's cameras; with
--camera C the rig camera C's view is drawn beside it, over its image where --images has one
for that frame (a pattern with {camera} and {frame}). --still N also writes frame N as a PNG.
--ground-truth shelf draws Shelf's annotated poses of each frame (the predictions' frame numbers
are Shelf's) in both views, thin yellow and labelled `GT <actor>`, as `mvpose-images` does.
"""
from __future__ import annotations

import argparse
import sys
from functools import partial
from pathlib import Path
from typing import Callable, Sequence

import cv2
import numpy as np

from mvpose_ros.core.datasets.shelf_campus import dataset_dir, load_actors_gt
from mvpose_ros.core.defaults import data_root
from mvpose_ros.core.drawing.video import Scene, render_frame, virtual_camera, write_video
from mvpose_ros.core.evaluation.predictions import read_results
from mvpose_ros.core.geometry.rig import load_rig_file
from mvpose_ros.package_files import package_path

SHELF_RIG = 'config/rigs/shelf.yaml'


def build_parser() -> argparse.ArgumentParser:
    """The command line of `mvpose-render`."""
    p = argparse.ArgumentParser(prog='mvpose-render', description=__doc__.split('\n')[0])
    p.add_argument('predictions', type=Path, help='predictions file (JSON lines)')
    p.add_argument('--output', type=Path, default=Path('out/skeletons.mp4'), help='video file, .mp4 or .avi')
    p.add_argument('--rig', type=Path, help=f'rig file with intrinsics, or a calibration (default: {SHELF_RIG})')
    p.add_argument('--data-root', help='folder holding data/ (default: $MVPOSE_DATA_ROOT or ../shared)')
    p.add_argument('--fps', type=float, default=25.0, help='frames per second of the video (default: 25)')
    p.add_argument('--size', default='960x720', help='virtual view WIDTHxHEIGHT pixels (default: 960x720)')
    p.add_argument('--camera', type=int, help='also draw rig camera C (index) beside the view')
    p.add_argument('--images', help="with --camera: image path pattern with {camera} and {frame}, e.g. "
                                    "'frames/cam{camera}_{frame:06d}.png'")
    p.add_argument('--still', type=int, metavar='FRAME', help='also write this frame as a PNG')
    p.add_argument('--still-output', type=Path, help='where --still goes (default: beside --output)')
    p.add_argument('--ground-truth', choices=('shelf',),
                   help="also draw this dataset's annotated poses of each frame (the predictions' frames being "
                        'its frame numbers)')
    return p


def run(args: argparse.Namespace) -> int:
    """Do what the parsed command line `args` of `mvpose-render` says; returns the exit code."""
    try:
        width, height = (int(v) for v in args.size.lower().split('x'))
    except ValueError:
        raise ValueError(f'--size {args.size!r}: expected WIDTHxHEIGHT') from None
    rig = load_rig_file(args.rig or package_path(SHELF_RIG), data_root=partial(data_root, args.data_root))
    cameras = rig.calibrated_cameras()
    if args.camera is not None and not 0 <= args.camera < len(cameras):
        raise ValueError(f'--camera {args.camera}: the rig has cameras 0..{len(cameras) - 1}')
    lines = read_results(args.predictions)
    frames = [(result, extra.get('stamp')) for result, extra in lines]
    results = [r for r, _ in frames]

    def image(frame: int):
        path = Path(args.images.format(camera=args.camera, frame=frame))
        return cv2.imread(str(path)) if path.is_file() else None

    scene = Scene(virtual_camera(results, cameras, rig.up, width, height), cameras, rig.names, rig.up,
                  args.camera, image if args.images else None,
                  _annotations([r.frame for r in results], args.data_root) if args.ground_truth else None)
    n = write_video(args.output, frames, scene, args.fps)
    print(f'wrote {n} frames to {args.output}')
    if args.still is not None:
        match = [f for f in frames if f[0].frame == args.still]
        if not match:
            raise ValueError(f'--still {args.still}: no such frame in {args.predictions}')
        still = args.still_output or args.output.with_name(f'{args.output.stem}_{args.still}.png')
        still.parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(still), render_frame(scene, *match[0]))
        print(f'wrote {still}')
    return 0


def _annotations(frames: Sequence[int], root: str | None) -> Callable[[int], tuple[np.ndarray, np.ndarray]]:
    """frame -> the actors Shelf annotates in that frame of `frames` (A,) and their poses (A, 14, 3)."""
    try:
        gt = load_actors_gt(dataset_dir('shelf', root) / 'actorsGT.mat', sorted(set(frames)))
    except IndexError as exc:
        raise ValueError(f"--ground-truth shelf: the predictions' frames are not all Shelf frames ({exc})") from None
    index = {int(f): i for i, f in enumerate(gt.frames)}

    return lambda frame: gt.annotated(index[frame])


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of `mvpose-render`; returns the exit code."""
    args = build_parser().parse_args(argv)
    try:
        return run(args)
    except (FileNotFoundError, ValueError) as exc:
        print(f'mvpose-render: error: {exc}', file=sys.stderr)
        return 2


if __name__ == '__main__':
    sys.exit(main())
