"""`mvpose-make-bag`: build a rosbag2 (MCAP) bag of the real data for the ROS graph.

    mvpose-make-bag shelf|shelf_images|shelf_crowd|shelf_rig|shelf_rig_raw|shelf_rig_turned|shelf_rig_lenses|
                    shelf_rig_hd
                    [--data-root DIR] [--output DIR] [--force]
    mvpose-make-bag shelf --drop-every N | --drop-fraction F [--drop-seed S]   (bags/shelf_every2, ...)
    mvpose-make-bag campus --campus-dir CampusSeq1 [--output DIR] [--force]
    mvpose-make-bag shelf --rotate-camera C --degrees D [--axis y] --from-frame F   (a bumped camera)
    mvpose-make-bag shelf --unplug-camera C --from-frame F                         (a camera that stops)

A bag that is complete and up to date is left alone (exit 0); any other existing output needs
--force. What each bag holds: docs/cli.md#the-bags."""
from __future__ import annotations

import argparse
import shutil
import sys
import time
from pathlib import Path
from typing import Sequence, TextIO

from mvpose_ros.bags.io import bag_size, bag_summary, write_bag
from mvpose_ros.bags.recipes import RECIPES, RIG_FILE, CameraFault, Recipe, make_recipe
from mvpose_ros.core.geometry.bump import AXES
from mvpose_ros.core.scenarios.frame_drops import FrameDrop

RECIPE_KEY = 'mvpose_recipe'
FINGERPRINT_KEY = 'mvpose_fingerprint'
# All a bag folder may hold before --force deletes it (storage files, their sqlite journals).
_BAG_FILE_SUFFIXES = ('.mcap', '.db3', '.db3-shm', '.db3-wal', '.db3-journal', '.zstd')


def build_parser() -> argparse.ArgumentParser:
    """The command line of `mvpose-make-bag`."""
    p = argparse.ArgumentParser(prog='mvpose-make-bag', description=__doc__.split('\n')[0])
    p.add_argument('recipe', choices=RECIPES)
    p.add_argument('--data-root', help='folder holding data/ (default: $MVPOSE_DATA_ROOT or ../shared)')
    p.add_argument('--campus-dir', help='CampusSeq1 folder (Camera0..2/, actorsGT.mat, calibration_campus.json)')
    p.add_argument('--output', help='bag folder to write (default: bags/<recipe>)')
    p.add_argument('--force', action='store_true', help='replace an existing bag folder')
    p.add_argument('--drop-every', type=int, default=0, metavar='N',
                   help='shelf: leave out every N-th frame, as sets dropped upstream (as mvpose-eval --drop-every)')
    p.add_argument('--drop-fraction', type=float, default=0.0, metavar='F',
                   help='shelf: then leave out this fraction of the rest at random (as mvpose-eval)')
    p.add_argument('--drop-seed', type=int, default=0, metavar='S', help='seed of --drop-fraction')
    fault = p.add_mutually_exclusive_group()
    fault.add_argument('--rotate-camera', type=int, metavar='C',
                       help='shelf: camera C is bumped from --from-frame on (turned by --degrees about --axis, its '
                            'calibration unchanged; default output bags/shelf_camC_rot<D><axis>_from<F>)')
    fault.add_argument('--unplug-camera', type=int, metavar='C',
                       help='shelf: camera C sends nothing from --from-frame on (default output '
                            'bags/shelf_camC_unplugged_from<F>)')
    p.add_argument('--degrees', type=float, default=2.0, help='with --rotate-camera (default 2)')
    p.add_argument('--axis', choices=AXES, default='y',
                   help="with --rotate-camera: the camera's axis (default y: a pan)")
    p.add_argument('--from-frame', type=int, help='with --rotate-camera / --unplug-camera: the first Shelf frame '
                                                  'affected (300..600)')
    return p


def camera_fault(args: argparse.Namespace) -> CameraFault | None:
    """The camera fault the options ask for, if any."""
    camera = args.rotate_camera if args.rotate_camera is not None else args.unplug_camera
    if camera is None:
        return None
    if args.from_frame is None:
        raise ValueError('--rotate-camera and --unplug-camera need --from-frame')
    return CameraFault(camera, args.from_frame, args.degrees if args.rotate_camera is not None else None, args.axis)


def _stale_reason(output: Path, recipe: Recipe, fingerprint: str) -> str | None:
    """Why the existing `output` is not the bag `recipe` would make now (None: it is)."""
    try:
        custom = bag_summary(output).custom_data
    except (FileNotFoundError, ValueError) as exc:
        return f'is not a complete bag ({exc})'
    if custom.get(RECIPE_KEY) != recipe.name:
        return f'holds recipe {custom.get(RECIPE_KEY) or "unknown"!r}, not {recipe.name!r}'
    if custom.get(FINGERPRINT_KEY) != fingerprint:
        return 'is out of date (its inputs or the recipe changed)'
    return None


def _remove_bag(output: Path) -> None:
    """Delete a bag folder, refusing anything that holds other files (a mistyped --output)."""
    if not output.is_dir():
        raise FileExistsError(f'{output}: exists and is not a folder; not replacing it')
    foreign = [f.name for f in output.iterdir()
               if f.name not in ('metadata.yaml', RIG_FILE) and not f.name.endswith(_BAG_FILE_SUFFIXES)]
    if foreign:
        raise FileExistsError(f'{output}: holds non-bag files ({", ".join(sorted(foreign)[:3])}); '
                              f'not deleting it')
    shutil.rmtree(output)


def _write_rig(output: Path, recipe: Recipe, out: TextIO) -> None:
    """The recipe's rig file inside the bag folder (rewritten: it is cheap and follows the code)."""
    if recipe.rig_text is not None:
        path = output / RIG_FILE
        text = recipe.rig_text()
        if not path.is_file() or path.read_text(encoding='utf-8') != text:
            path.write_text(text, encoding='utf-8')
        print(f'{path}: its rig file (intrinsics from the CameraInfo messages)', file=out)


def run(args: argparse.Namespace, out: TextIO | None = None) -> int:
    """Do what the parsed command line `args` of `mvpose-make-bag` says; returns the exit code."""
    """Make the bag `args` name; returns the exit code."""
    out = out or sys.stdout
    drop = FrameDrop(args.drop_every, args.drop_fraction, args.drop_seed)
    fault = camera_fault(args)
    recipe = make_recipe(args.recipe, args.data_root, args.campus_dir, drop, fault)
    default = fault.default_folder() if fault else '_'.join(filter(None, (args.recipe, drop.label)))
    output = Path(args.output or Path('bags') / default)
    fingerprint = recipe.fingerprint()
    if output.exists():
        reason = _stale_reason(output, recipe, fingerprint)
        if reason is None and not args.force:
            print(f'{output}: {recipe.name} bag already made and up to date', file=out)
            _write_rig(output, recipe, out)
            return 0
        if not args.force:
            raise FileExistsError(f'{output}: exists and {reason}; pass --force to replace it')
        _remove_bag(output)
    start = time.perf_counter()
    write_bag(output, recipe.items(), custom_data={RECIPE_KEY: recipe.name, FINGERPRINT_KEY: fingerprint})
    seconds = time.perf_counter() - start
    summary = bag_summary(output)
    print(f'{output}: {recipe.name} bag, {summary.message_count} messages on {len(summary.topics)} '
          f'topics, stamps {summary.first_ns / 1e9:.2f}..{summary.last_ns / 1e9:.2f} s, '
          f'{bag_size(output) / 1e6:.1f} MB, made in {seconds:.1f} s', file=out)
    _write_rig(output, recipe, out)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of `mvpose-make-bag`; returns the exit code."""
    args = build_parser().parse_args(argv)
    try:
        return run(args)
    except (OSError, ValueError) as exc:
        print(f'mvpose-make-bag: error: {exc}', file=sys.stderr)
        return 2


if __name__ == '__main__':
    sys.exit(main())
