"""The Foxglove scene of the skeletons (mvpose_ros.view.scene), decoded with protobuf from the
schema the SDK advertises: one entity per person in its colour, a sphere per joint and a bone
line list as opaque as they are sure, the id above the head, people who left deleted."""
from __future__ import annotations

import numpy as np
import pytest
from foxglove.messages import SceneUpdate

from mvpose_ros.core.drawing.colours import MIN_ALPHA, person_colour
from mvpose_ros.core.geometry.body import BONES, TOP_HEAD
from mvpose_ros.view.scene import LABEL_CLEARANCE_M, skeleton_scene
from foxglove_decode import decode

STAMP = 1_234_567_890_123


def _decoded(update: SceneUpdate):
    schema = SceneUpdate.get_schema()
    assert (schema.name, schema.encoding) == ('foxglove.SceneUpdate', 'protobuf')
    return decode(schema.name, schema.data, update.encode())


def _people(seed: int = 0, n: int = 2):
    rng = np.random.default_rng(seed)
    joints = rng.uniform(-1.0, 1.0, (n, 14, 3))
    joints[:, TOP_HEAD, 2] = 3.0  # the top of the head highest: the label goes above it
    return np.array([4, 11][:n]), joints, rng.uniform(0.0, 1.0, (n, 14))


def test_each_person_is_one_entity_with_its_joints_bones_and_label():
    ids, joints, confidence = _people()
    scene = _decoded(skeleton_scene(ids, joints, confidence, STAMP, frame_id='world', lifetime_s=0.5))
    # people who left disappear: everything older than this frame goes first
    kind = scene.deletions[0].DESCRIPTOR.fields_by_name['type'].enum_type.values_by_number
    assert [(kind[d.type].name, d.timestamp.seconds, d.timestamp.nanos) for d in scene.deletions] == [
        ('ALL', 1234, 567_890_123)]
    assert [e.id for e in scene.entities] == ['person 4', 'person 11']
    for k, entity in enumerate(scene.entities):
        assert entity.frame_id == 'world' and (entity.lifetime.seconds, entity.lifetime.nanos) == (0, 500_000_000)
        r, g, b = person_colour(ids[k])
        centres = np.array([[s.pose.position.x, s.pose.position.y, s.pose.position.z] for s in entity.spheres])
        np.testing.assert_allclose(centres, joints[k])
        np.testing.assert_allclose([s.color.a for s in entity.spheres], MIN_ALPHA + (1 - MIN_ALPHA) * confidence[k])
        assert all(np.allclose([s.color.r, s.color.g, s.color.b], [r, g, b]) for s in entity.spheres)
        line, = entity.lines
        ends = np.array([[p.x, p.y, p.z] for p in line.points]).reshape(-1, 2, 3)
        np.testing.assert_allclose(ends, joints[k][np.array(BONES)])
        bone_conf = confidence[k][np.array(BONES)].min(axis=1)
        np.testing.assert_allclose([c.a for c in line.colors], np.repeat(MIN_ALPHA + (1 - MIN_ALPHA) * bone_conf, 2))
        label, = entity.texts
        assert label.text == str(ids[k]) and label.billboard
        np.testing.assert_allclose([label.pose.position.x, label.pose.position.y, label.pose.position.z],
                                   joints[k, TOP_HEAD] + [0, 0, LABEL_CLEARANCE_M])


def test_a_frame_without_people_clears_the_scene():
    scene = _decoded(skeleton_scene(np.zeros(0, int), np.zeros((0, 14, 3)), np.zeros((0, 14)), STAMP))
    assert len(scene.deletions) == 1 and len(scene.entities) == 0


def test_the_label_goes_above_along_the_worlds_up():
    ids, joints, confidence = _people(n=1)
    joints[0, 3, 1] = 5.0  # the highest joint along +y
    scene = _decoded(skeleton_scene(ids, joints, confidence, STAMP, up=np.array([0.0, 1.0, 0.0])))
    label = scene.entities[0].texts[0].pose.position
    np.testing.assert_allclose([label.x, label.y, label.z], joints[0, 3] + [0, LABEL_CLEARANCE_M, 0])


def test_shapes_that_do_not_fit_are_a_clear_error():
    ids, joints, confidence = _people()
    with pytest.raises(ValueError, match=r'expected joints \(2, 14, 3\)'):
        skeleton_scene(ids, joints[:, :13], confidence, STAMP)
