"""A camera's frame id: given by the rig file and held to, or learned from its first message."""
import pytest

from mvpose_ros.core.geometry.frame_id import CameraFrameId


def test_learned_from_the_first_message_then_held():
    frame_id = CameraFrameId('hd00', None)
    frame_id.check('hd00_optical_frame', 'CameraInfo')
    assert (frame_id.value, frame_id.learned_from) == ('hd00_optical_frame', 'CameraInfo')
    frame_id.check('hd00_optical_frame', 'image')
    with pytest.raises(ValueError, match=r"^frame_id 'hd01_optical_frame' is not 'hd00_optical_frame' \(the frame id "
                                         r"of its first CameraInfo\)$"):
        frame_id.check('hd01_optical_frame', 'image')
    assert frame_id.value == 'hd00_optical_frame'


def test_given_is_held_and_the_refusal_says_the_fix():
    frame_id = CameraFrameId('hd00', 'hd00')
    frame_id.check('hd00', 'image')
    with pytest.raises(ValueError) as refused:
        frame_id.check('hd00_optical_frame', 'image')
    assert str(refused.value) == ("frame_id 'hd00_optical_frame' is not 'hd00'; set frame_id: hd00_optical_frame in "
                                  "the rig file, or leave it out")
    assert frame_id.learned_from is None
