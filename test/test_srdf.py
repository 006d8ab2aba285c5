"""The SRDF generator (``advocc robot srdf``): MoveIt Setup Assistant's disabled pairs."""

import pathlib
import xml.etree.ElementTree as ET

import pinocchio as pin

from advocc_ros.cli import main
from advocc_ros.model.robot import example_robot_data_share, resolve_path
from advocc_ros.formats.srdf import disabled_collision_pairs

DATA = pathlib.Path(__file__).parent / 'data'
PANDA = 'example-robot-data://panda_description/'


def _pairs(result):
    return {frozenset((d.link1, d.link2)): d.reason for d in result.disabled}


def test_small_fixture_is_exact():
    """srdf_bot.urdf's pairs, worked out by hand (see the comment in the URDF)."""
    result = disabled_collision_pairs(DATA / 'srdf_bot.urdf', samples=500)
    got = _pairs(result)
    expected = {
        'Adjacent': ['arm1 base', 'arm1 arm2', 'arm2 tip',  # tip: through geometry-less ghost
                     'base shell', 'base flag', 'base flag2', 'base plunger', 'anvil base'],
        'Default': ['arm1 shell', 'arm2 flag', 'flag tip'],
        'Always': ['anvil plunger'],
    }
    for reason, pairs in expected.items():
        assert {p for p, r in got.items() if r == reason} == {
            frozenset(p.split()) for p in pairs}, reason
    assert set(result.enabled) == {('arm2', 'flag2'), ('flag', 'flag2'), ('flag2', 'tip')}
    n_links = len(result.links)
    assert n_links == 9 and len(got) + len(result.enabled) == n_links * (n_links - 1) // 2
    assert {r for r in got.values()} == {'Adjacent', 'Default', 'Always', 'Never'}


def test_panda_finds_the_shipped_srdf_pairs():
    result = disabled_collision_pairs(resolve_path(PANDA + 'urdf/panda.urdf'),
                                      [str(example_robot_data_share())], samples=300)
    got = _pairs(result)
    shipped = {frozenset((e.get('link1'), e.get('link2'))): e.get('reason') for e in
               ET.parse(resolve_path(PANDA + 'srdf/panda.srdf')).getroot()
               .iter('disable_collisions')}
    adjacent = {p for p, r in shipped.items() if r == 'Adjacent'}
    assert len(adjacent) == 10
    assert {p for p, r in got.items() if r == 'Adjacent'} == adjacent
    assert set(shipped) <= set(got)  # with 300 samples, Never may still cover a few more


def test_cli_writes_an_srdf_pinocchio_reads(tmp_path, capsys):
    out = tmp_path / 'bot.srdf'
    assert main(['robot', 'srdf', '--urdf', str(DATA / 'srdf_bot.urdf'), '--samples', '200',
                 '--group-joints', 'j1', 'j2', '--out', str(out)]) == 0
    assert 'Adjacent 8' in capsys.readouterr().out
    root = ET.parse(out).getroot()
    assert [j.get('name') for j in root.find('group')] == ['j1', 'j2']
    model = pin.buildModelFromUrdf(str(DATA / 'srdf_bot.urdf'))
    geom = pin.buildGeomFromUrdf(model, str(DATA / 'srdf_bot.urdf'), pin.GeometryType.COLLISION)
    geom.addAllCollisionPairs()
    pin.removeCollisionPairs(model, geom, str(out))
    names = {frozenset((model.frames[geom.geometryObjects[p.first].parentFrame].name,
                        model.frames[geom.geometryObjects[p.second].parentFrame].name))
             for p in geom.collisionPairs}
    assert names == {frozenset(p) for p in (('arm2', 'flag2'), ('flag', 'flag2'),
                                            ('flag2', 'tip'))}


def test_cli_extends_kinova_srdf_that_ships_without_pairs(tmp_path):
    base = PANDA.replace('panda', 'kinova') + 'srdf/kinova.srdf'
    assert not list(ET.parse(resolve_path(base)).getroot().iter('disable_collisions'))
    out = tmp_path / 'kinova.srdf'
    assert main(['robot', 'srdf', '--urdf', 'example-robot-data://kinova_description/robots/'
                 'kinova.urdf', '--srdf', base, '--samples', '200', '--out', str(out)]) == 0
    root = ET.parse(out).getroot()
    assert root.find('group_state') is not None  # the shipped SRDF's content is kept
    reasons = [e.get('reason') for e in root.iter('disable_collisions')]
    assert reasons.count('Adjacent') >= 6 and 'Never' in reasons


def test_cli_refuses_unknown_group_joints(tmp_path, capsys):
    assert main(['robot', 'srdf', '--urdf', str(DATA / 'srdf_bot.urdf'), '--group-joints',
                 'nope', '--out', str(tmp_path / 'x.srdf')]) == 2
    assert 'nope' in capsys.readouterr().err
