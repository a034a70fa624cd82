"""The detector's settings: one table (core.detection.detector_settings) whose defaults are the
configuration dataclasses' own, one `DetectorConfig.from_params`, and mvpose-images' options made
from that table (the node's parameters: test_detector_inputs)."""
from __future__ import annotations

import dataclasses

import pytest

from mvpose_ros.cli import images
from mvpose_ros.cli.parameter_options import option
from mvpose_ros.core.detection.detector_settings import ONNX_PARAMETERS, PARAMETERS, DetectorConfig
from mvpose_ros.core.detection.onnx_config import OnnxDetectorConfig
from mvpose_ros.core.detection.openpose_detector import OpenPoseDetectorConfig


def test_the_defaults_are_the_configurations_own_and_from_params_inverts_to_params():
    onnx = {f.name: f.default for f in dataclasses.fields(OnnxDetectorConfig) if f.name != 'model_dir'}
    openpose = {f.name: f.default for f in dataclasses.fields(OpenPoseDetectorConfig)}
    for p in PARAMETERS:
        want = onnx.get(p.name, openpose.get(p.name, getattr(DetectorConfig, p.name, None)))
        assert p.default == (list(want) if isinstance(want, tuple) else want), p.name
    config = DetectorConfig.from_params({'backend': 'onnx', 'box_margin': 0.3, 'stride': 8.0, 'providers': ['A']})
    assert (config.onnx.box_margin, config.onnx.stride, config.openpose.stride, config.onnx.providers) == \
        (0.3, 8.0, 8.0, ('A',))
    assert DetectorConfig.from_params(config.to_params()) == config
    assert DetectorConfig.from_params({}) == DetectorConfig()


@pytest.mark.parametrize('params, message', [
    ({'backend': 'trt'}, "backend 'trt' is not one of openpose, onnx"),
    ({'heatmaps': 'mpii'}, "heatmaps 'mpii' is not one of efficientpose, multipose, fused"),
    ({'threads': -1}, 'threads -1 is not in 0..1024'),
    ({'ears': 'false'}, "ears must be true or false, got 'false'"),
    ({'input_size': 100}, 'input_size 100 is not a positive multiple of 32'),  # the configuration's own check
])
def test_from_params_refuses_a_bad_value_by_name(params, message):
    with pytest.raises(ValueError, match=message):
        DetectorConfig.from_params(params)


def test_live_changes_go_through_the_table():
    config = DetectorConfig.from_params({'backend': 'onnx'})
    changed = config.retuned({'min_person_score': 0.5, 'secondary_radius': 0.1})
    assert (changed.onnx.min_person_score, changed.openpose.secondary_radius) == (0.5, 0.1)
    assert changed.onnx.input_size == config.onnx.input_size
    with pytest.raises(ValueError, match='input_size: read-only'):
        config.retuned({'input_size': 256})
    with pytest.raises(ValueError, match='min_person_score 2.0 is not in 0.0..1.0'):
        config.retuned({'min_person_score': 2.0})


def test_mvpose_images_takes_its_detector_options_from_the_table():
    parser = images.build_parser()
    actions = {a.dest: a for a in parser._actions}
    for p in ONNX_PARAMETERS:
        action = actions[p.name]
        assert action.default == p.default, p.name
        assert p.description in action.help, p.name
        if not isinstance(p.default, bool):
            assert option(p.name) in action.option_strings and action.help.endswith(')'), p.name
    assert 'backend' not in actions and 'secondary_radius' not in actions  # the openpose backend's
    args = parser.parse_args(['--calibration', 'c.json', '--images', 'a', 'b', '--box-margin', '0.2', '--no-ears',
                              '--heatmaps', 'fused', '--providers', 'X', 'Y'])
    config = DetectorConfig.from_params({p.name: getattr(args, p.name) for p in ONNX_PARAMETERS})
    assert (config.onnx.box_margin, config.onnx.ears, config.onnx.heatmaps, config.onnx.providers) == \
        (0.2, False, 'fused', ('X', 'Y'))
