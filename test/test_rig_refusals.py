"""mvpose-graph --rig on a rig file that cannot work: a driver's recording (the shelf_rig bag, its
frame ids `<camera>_optical_frame`) with a rig file giving three cameras another frame_id. The run
stops within seconds of playing with exit 1 and a line per such camera naming the cause and the
fix; the two cameras without frame_id take their driver's and are not named."""
from __future__ import annotations

import yaml

from mvpose_ros.bags.recipes import RIG_FILE
from mvpose_ros.cli import graph
from mvpose_ros.cli.make_bag import main as make_bag
from ros_harness import ros_domain

WRONG = ('right', 'back', 'door')


def test_a_rig_file_whose_frame_ids_the_driver_does_not_stamp_stops_the_run_with_the_fix(tmp_path, monkeypatch,
                                                                                         capsys):
    bag = tmp_path / 'shelf_rig'
    assert make_bag(['shelf_rig', '--output', str(bag)]) == 0
    rig = yaml.safe_load((bag / RIG_FILE).read_text())
    for camera in rig['cameras']:
        if camera['name'] in WRONG:
            camera['frame_id'] = camera['name']
    rig_file = tmp_path / 'rig.yaml'
    rig_file.write_text(yaml.safe_dump(rig))
    capsys.readouterr()
    with ros_domain(monkeypatch, profile=None) as domain:  # the runner sets the profile
        code = graph.main(['--rig', str(rig_file), '--bag', str(bag), '--rate', '1', '--loops', '10',
                           '--predictions', str(tmp_path / 'out' / 'p.jsonl'), '--domain-id', str(domain)])
    err = capsys.readouterr().err
    assert code == 1, err
    lines = [line for line in err.splitlines() if line.startswith('mvpose-graph: error: ')]
    assert lines == [f"mvpose-graph: error: {name}: every image refused: frame_id '{name}_optical_frame' is not "
                     f"'{name}'; set frame_id: {name}_optical_frame in the rig file, or leave it out"
                     for name in sorted(WRONG)], err
    # stopped by the refusals, not by the end of the bag's 20 s (ten loops) of playing
    player = (tmp_path / 'out' / 'p_logs' / 'bag_player.log').read_text()
    assert 'start signal received' in player and 'done: ' not in player, player
    assert not (tmp_path / 'out' / 'p.jsonl').exists()
