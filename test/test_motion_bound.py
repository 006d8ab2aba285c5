"""The per-robot motion bound L against finite differences on the Panda, the UR5 and the xArm7.

The points are the vertices of the link meshes read from their files by trimesh
(``RobotModel.link_meshes``), not the coal geometry the bound was computed from, so the check
is independent of the code under test. A bound is a bound: no observed displacement may exceed
it, for tiny steps (the derivative) and for long ones (the integral along a straight segment).
"""

import pathlib

import numpy as np
import pinocchio as pin
import pytest

from advocc_ros.model.robot import load_robot
from advocc_ros.model.scene import load_scene

REPO = pathlib.Path(__file__).resolve().parents[1]
SCENES = ('table_pick', 'ur5_table', 'xarm7_table')
SAMPLES = 200
STEPS_RAD = (1e-4, 0.05, 0.5)


def _points_world(robot, data, geom_data, q, meshes):
    """World points of every geometry, and every joint frame (4, 4), at ``q``."""
    pin.updateGeometryPlacements(robot.model, data, robot.collision_model, geom_data, q)
    T = [geom_data.oMg[g].homogeneous for g in range(len(meshes))]
    return [meshes[g] @ T[g][:3, :3].T + T[g][:3, 3] for g in range(len(meshes))], \
        [M.homogeneous for M in data.oMi]


def _common_joint(model, a: int, b: int) -> int:
    """The deepest joint that moves both joints ``a`` and ``b`` (0: the base)."""
    ancestors = set()
    while a > 0:
        ancestors.add(a)
        a = model.parents[a]
    while b > 0 and b not in ancestors:
        b = model.parents[b]
    return b


def _in_frame(T, points):
    return (points - T[:3, 3]) @ T[:3, :3]


@pytest.fixture(scope='module', params=SCENES)
def arm(request):
    robot = load_robot(load_scene(REPO / 'config' / 'scenes' / f'{request.param}.yaml').robot)
    meshes = [np.asarray(m.vertices, float) for m in robot.link_meshes]
    return request.param, robot, meshes


def test_bound_is_never_exceeded(arm):
    name, robot, meshes = arm
    bound = robot.motion_bound
    data, geom_data = robot.create_data(), robot.collision_model.createData()
    rng = np.random.default_rng(7)
    worst_link = np.zeros(len(meshes))
    worst_pair = {pair: 0.0 for pair in robot.self_pairs}
    for _ in range(SAMPLES):
        q = robot.sample_q(rng, 1)[0]
        u = rng.normal(size=robot.nq)
        u /= np.linalg.norm(u)
        before, T_before = _points_world(robot, data, geom_data, q, meshes)
        for step in STEPS_RAD:
            after, T_after = _points_world(robot, data, geom_data, q + step * u, meshes)
            for g in range(len(meshes)):
                moved = np.linalg.norm(after[g] - before[g], axis=1).max() / step
                worst_link[g] = max(worst_link[g], moved)
            for a, b in robot.self_pairs:
                # Both seen from the frame of the joint moving both: a shared motion moves
                # them rigidly together, so what changes their distance is what moves there.
                c = _common_joint(robot.model, *(robot.collision_model.geometryObjects[g]
                                                 .parentJoint for g in (a, b)))
                moved = sum(np.linalg.norm(_in_frame(T_after[c], after[g])
                                           - _in_frame(T_before[c], before[g]), axis=1).max()
                            for g in (a, b)) / step
                worst_pair[a, b] = max(worst_pair[a, b], moved)
    assert np.all(worst_link <= bound.link_m_per_rad * (1 + 1e-9) + 1e-12), \
        (name, worst_link, bound.link_m_per_rad)
    for (a, b), moved in worst_pair.items():
        assert moved <= bound.pair_m_per_rad(a, b) * (1 + 1e-9), (name, a, b, moved)
    # Not vacuous: the bound is within a small factor of what moving links really do.
    moving = bound.link_m_per_rad > 0
    ratio = worst_link[moving] / bound.link_m_per_rad[moving]
    assert ratio.max() > 0.4, (name, ratio)
    print(f'{name}: L = {bound.max_m_per_rad:.3f} m/rad, largest observed '
          f'{worst_link.max():.3f} m/rad, per-link observed/bound {ratio.min():.2f}-'
          f'{ratio.max():.2f}')


def test_fixed_geometry_has_no_motion(arm):
    _, robot, _ = arm
    for g, geom in enumerate(robot.collision_model.geometryObjects):
        assert (robot.motion_bound.link_m_per_rad[g] == 0) == (geom.parentJoint == 0)


def test_pair_bound_counts_only_joints_between_the_links(panda):
    bound = panda.motion_bound
    names = list(panda.link_names)
    link1, link2 = names.index('panda_link1_0'), names.index('panda_link2_0')
    hand = names.index('panda_hand_0')
    finger = names.index('panda_leftfinger_0')
    # link1 and link2 differ by joint 2 only: its lever arm for link2, nothing of joint 1.
    assert bound.pair_m_per_rad(link1, link2) == pytest.approx(bound.lever_m[1, link2])
    assert bound.pair_m_per_rad(hand, finger) == 0.0  # both on joint 7
    assert bound.pair_m_per_rad(link1, hand) < bound.link_m_per_rad[hand]


def test_planner_motion_step_cannot_step_over_a_box(arm):
    """What ``PlanningConfig.motion_step_rad`` claims: between two checked states no point of
    any shipped arm moves as far as the default box edge."""
    from advocc_ros.attack.types import AttackConfig
    from advocc_ros.planning.types import PlanningConfig

    _, robot, _ = arm
    step = PlanningConfig().motion_step_rad
    assert robot.motion_bound.max_m_per_rad * step < AttackConfig().box_size_m


def _toy_arm():
    """A revolute joint (z) carrying a sphere, then a prismatic joint (x, travel -0.2..0.3 m,
    0.5 m out) carrying a box: the bound is computable by hand."""
    import coal

    model = pin.Model()
    j1 = model.addJoint(0, pin.JointModelRZ(), pin.SE3.Identity(), 'turn')
    j2 = model.addJoint(j1, pin.JointModelPX(), pin.SE3(np.eye(3), np.array([0.5, 0, 0])),
                        'slide', np.array([1e3]), np.array([1e3]), np.array([-0.2]),
                        np.array([0.3]))
    model.lowerPositionLimit[0], model.upperPositionLimit[0] = -3.0, 3.0
    geom = pin.GeometryModel()
    geom.addGeometryObject(pin.GeometryObject(
        'ball', j1, j1, pin.SE3(np.eye(3), np.array([0.25, 0, 0])), coal.Sphere(0.05)))
    geom.addGeometryObject(pin.GeometryObject(
        'block', j2, j2, pin.SE3(np.eye(3), np.array([0.1, 0, 0])), coal.Box(0.2, 0.1, 0.1)))
    return model, geom


def test_toy_arm_bound_by_hand():
    from advocc_ros.model.motion_bound import motion_bound

    model, geom = _toy_arm()
    bound = motion_bound(model, geom)
    # ball: 0.25 m from the axis + 0.05 m radius; block: 1 m/m along the slide, and for the
    # turn 0.5 m out + 0.3 m of travel + its farthest corner sqrt(0.2^2 + 0.05^2 + 0.05^2).
    assert bound.lever_m[:, 0] == pytest.approx([0.30, 0.0])
    corner = np.sqrt(0.2 ** 2 + 0.05 ** 2 + 0.05 ** 2)
    assert bound.lever_m[:, 1] == pytest.approx([0.8 + corner, 1.0])
    assert bound.link_m_per_rad[1] == pytest.approx(np.hypot(0.8 + corner, 1.0))
    assert bound.pair_m_per_rad(0, 1) == pytest.approx(1.0)  # only the slide moves them apart
    # and finite differences stay below it
    rng = np.random.default_rng(0)
    data, geom_data = model.createData(), geom.createData()
    corners = np.array([[x, y, z] for x in (-0.1, 0.1) for y in (-0.05, 0.05)
                        for z in (-0.05, 0.05)])
    for _ in range(300):
        q = rng.uniform(model.lowerPositionLimit + 0.01, model.upperPositionLimit - 0.01)
        u = rng.normal(size=2)  # a 0.01 step stays within the limits the bound assumes
        u /= np.linalg.norm(u)
        moved = []
        for step in (0.0, 0.01):
            pin.updateGeometryPlacements(model, data, geom, geom_data, q + step * u)
            T = geom_data.oMg[1]
            moved.append(corners @ T.rotation.T + T.translation)
        assert np.linalg.norm(moved[1] - moved[0], axis=1).max() / 0.01 <= \
            bound.link_m_per_rad[1] + 1e-9
