"""A camera's frame id: the one its rig entry gives, or else the one its first message carries.

Drivers name a camera's optical frame themselves (`hd00_optical_frame`,
`camera_color_optical_frame`), so a rig file may leave `frame_id` out: the camera's frame id is
then learned from its first CameraInfo or image (its first people2d downstream) and held to from
then on. Either way a message of that camera under another frame id is refused, with the fix.
"""
from __future__ import annotations


class CameraFrameId:
    """The frame id a camera's messages must carry.

    camera: its name in the rig; given: the rig file's `frame_id`, or None to learn it.
    """

    def __init__(self, camera: str, given: str | None) -> None:
        self.camera = camera
        self.given = given
        self.value = given
        self.learned_from: str | None = None  # what the value was learned from ('CameraInfo', ...)

    def check(self, frame_id: str, what: str) -> None:
        """Take the frame id of one of the camera's messages (`what`: 'CameraInfo', 'image', ...):
        learned when none is known yet; ValueError of one line, with the fix, when it differs."""
        if self.value is None:
            self.value, self.learned_from = frame_id, what
            return
        if frame_id == self.value:
            return
        if self.given is not None:
            raise ValueError(f'frame_id {frame_id!r} is not {self.given!r}; set frame_id: {frame_id} in the rig file, '
                             f'or leave it out')
        raise ValueError(f'frame_id {frame_id!r} is not {self.value!r} (the frame id of its first {self.learned_from})')
