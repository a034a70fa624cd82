"""Frames dropped upstream, imitated: the same frames offline (mvpose-eval) and in a bag (mvpose-make-bag)."""
import pytest

from msg_adapters.stamp import stamp_ns, stamp_of_frame
from mvpose_ros.bags.io import bag_summary, write_bag
from mvpose_ros.bags.recipes import make_recipe, shelf_recipe
from mvpose_ros.core.datasets.shelf_campus import SHELF_TEST_FRAMES, dataset_dir
from mvpose_ros.core.scenarios.frame_drops import FrameDrop


def test_every_nth_position_is_left_out():
    assert FrameDrop(every=2).kept(7) == [0, 2, 4, 6]
    assert FrameDrop(every=3).kept(7) == [0, 1, 3, 4, 6]
    assert FrameDrop().kept(4) == [0, 1, 2, 3] and not FrameDrop()


def test_a_fraction_is_left_out_at_random_and_seeded():
    kept = FrameDrop(fraction=0.3, seed=1).kept(301)
    assert len(kept) == 301 - round(0.3 * 301) and kept == sorted(set(kept))
    assert kept == FrameDrop(fraction=0.3, seed=1).kept(301)
    assert kept != FrameDrop(fraction=0.3, seed=2).kept(301)
    both = FrameDrop(every=2, fraction=0.5).kept(100)
    assert len(both) == 25 and all(k % 2 == 0 for k in both)


@pytest.mark.parametrize('every, fraction', [(-1, 0.0), (0, 1.0), (0, -0.1)])
def test_bad_drops_are_refused(every, fraction):
    with pytest.raises(ValueError, match='drop every N'):
        FrameDrop(every, fraction)


def test_labels_name_the_drop():
    assert FrameDrop(every=2).label == 'every2'
    assert FrameDrop(fraction=0.3, seed=1).label == 'fraction0.3-seed1'
    assert FrameDrop().label == ''


def test_shelf_bag_without_dropped_frames(tmp_path):
    drop = FrameDrop(fraction=0.3, seed=0)
    path = tmp_path / 'thinned'
    write_bag(path, shelf_recipe(dataset_dir('shelf'), drop=drop).items())
    topics = bag_summary(path).topics
    kept = [SHELF_TEST_FRAMES[k] for k in drop.kept(len(SHELF_TEST_FRAMES))]
    assert topics['/cam0/openpose'][1] == topics['/cam4/camera_info'][1] == len(kept)
    whole = shelf_recipe(dataset_dir('shelf'))
    assert shelf_recipe(dataset_dir('shelf'), drop=drop).fingerprint() != whole.fingerprint()
    assert bag_summary(path).first_ns == stamp_ns(stamp_of_frame(kept[0]))


def test_only_the_shelf_bag_drops_frames():
    with pytest.raises(ValueError, match='not shelf_rig'):
        make_recipe('shelf_rig', drop=FrameDrop(every=2))
