"""The shared defaults: the data root's resolution, max_skew's default and what a 0 means, and that
the 3D stage's nominal frame rate is the nodes' default."""
from __future__ import annotations

import pytest

from mvpose_ros.core import defaults
from mvpose_ros.core.defaults import FRAME_RATE, data_root, default_max_skew, max_skew_or_default
from mvpose_ros.core.inference.window import InferenceConfig


def test_max_skew_is_half_a_period_and_zero_means_that():
    assert default_max_skew(25.0) == pytest.approx(0.02)
    assert max_skew_or_default(0.0, 10.0) == pytest.approx(0.05)
    assert max_skew_or_default(0.003, 10.0) == 0.003  # a value given is kept


def test_the_stage_steps_at_the_nodes_default_rate():
    assert InferenceConfig().frame_rate == FRAME_RATE


def test_data_root_default_finds_shared(monkeypatch):
    monkeypatch.delenv(defaults.DATA_ROOT_ENV, raising=False)
    root = data_root()
    assert (root / 'data' / 'shelf' / 'actorsGT.mat').is_file()


def test_data_root_override_and_env(monkeypatch, tmp_path):
    env_root, flag_root = tmp_path / 'env', tmp_path / 'flag'
    env_root.mkdir()
    flag_root.mkdir()
    monkeypatch.setenv(defaults.DATA_ROOT_ENV, str(env_root))
    assert data_root() == env_root
    assert data_root(str(flag_root)) == flag_root  # the flag beats the environment


def test_data_root_missing_names_what_was_tried(monkeypatch, tmp_path):
    monkeypatch.delenv(defaults.DATA_ROOT_ENV, raising=False)
    with pytest.raises(FileNotFoundError, match='nowhere'):
        data_root(str(tmp_path / 'nowhere'))
    monkeypatch.setenv(defaults.DATA_ROOT_ENV, str(tmp_path / 'unset_env'))
    with pytest.raises(FileNotFoundError, match='unset_env'):
        data_root()
    # Neither beside a (fake) checkout nor beside the cwd.
    monkeypatch.delenv(defaults.DATA_ROOT_ENV)
    checkout = tmp_path / 'checkout'
    monkeypatch.setattr(defaults, '__file__', str(checkout / 'mvpose_ros' / 'core' / 'defaults.py'))
    (tmp_path / 'a' / 'cwd').mkdir(parents=True)
    monkeypatch.chdir(tmp_path / 'a' / 'cwd')
    with pytest.raises(FileNotFoundError) as info:
        data_root()
    assert str(tmp_path / 'shared') in str(info.value)
    assert str(tmp_path / 'a' / 'shared') in str(info.value)
