"""Shared fixtures: seeded RNGs, the Panda model, a small scene, a unique ROS domain per test."""

import os
import pathlib
import random

import numpy as np
import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]


@pytest.fixture(autouse=True)
def _seed():
    random.seed(0)
    np.random.seed(0)


@pytest.fixture(scope='session')
def panda():
    from advocc_ros.model.robot import load_robot
    return load_robot()


@pytest.fixture(scope='session')
def table_scene():
    from advocc_ros.model.scene import load_scene
    return load_scene(REPO / 'config' / 'scenes' / 'table_pick.yaml')


_domain = [100 + os.getpid() % 50]


@pytest.fixture
def ros_env():
    """Environment for child ROS processes, isolated on a ROS_DOMAIN_ID of its own."""
    _domain[0] = 100 + (_domain[0] - 99) % 130
    env = dict(os.environ)
    env['ROS_DOMAIN_ID'] = str(_domain[0])
    env['ROS_LOCALHOST_ONLY'] = '1'
    env['PYTHONUNBUFFERED'] = '1'
    return env
