"""Regenerate ``families/<family>/sceneNNNN.yaml`` + ``requestNNNN.yaml`` (see README.md).

Run from the repo root: ``.venv/bin/python test/data/mbm/make_families.py``. Deterministic.
The structure follows what MotionBenchMaker writes (MoveIt ``PlanningScene`` and
``MotionPlanRequest`` messages serialised to YAML); the geometry follows our shipped scenes of
the same families. Each goal is a grasp whose open fingers straddle the target can.
"""

import pathlib

import numpy as np
import pinocchio as pin
import yaml

from advocc_ros.model.collision import CollisionWorld
from advocc_ros.kinematics.ik import goal_configuration
from advocc_ros.model.robot import RobotSpec, load_robot
from advocc_ros.model.goal import GoalRegion
from advocc_ros.model.pose import Pose
from advocc_ros.model.scene import load_scene

HERE = pathlib.Path(__file__).parent
REPO = HERE.parents[2]
ARM = [f'panda_joint{i}' for i in range(1, 8)]
FINGERS = ['panda_finger_joint1', 'panda_finger_joint2']
READY = [0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785]
TCP = 0.1034  # panda_hand -> point between the finger pads [m]
DOWN = pin.SE3(np.diag([1.0, -1.0, -1.0]), np.zeros(3))          # hand z pointing down
FRONT = pin.SE3(np.array([[0.0, 0, 1], [0, 1, 0], [-1, 0, 0]]), np.zeros(3))  # hand z along +x
CAN = {'type': 'cylinder', 'height': 0.12, 'radius': 0.03}
FAMILIES = {  # family: (our scene, grasp, can position if the scene has none, edits)
    'table_pick': ('table_pick', DOWN, None, {}),
    'table_under_pick': ('table_under_pick', FRONT, None, {}),
    'box': ('box', DOWN, [0.56, 0.05, 0.17], {}),
    'cage': ('cage', DOWN, None, {}),
    'bookshelf_small': ('bookshelf', FRONT, None, {'height': 0.72}),
    'bookshelf_tall': ('bookshelf', FRONT, None, {}),
    'bookshelf_thin': ('bookshelf', FRONT, None, {'thin': 0.01}),
}
PROBLEMS = 3


def _header(frame='world'):
    return {'stamp': {'sec': 0, 'nanosec': 0}, 'frame_id': frame}


def _joint_state(values):
    names = ARM + FINGERS
    return {'header': _header(), 'name': names, 'position': [float(v) for v in values],
            'velocity': [], 'effort': []}


def _robot_state(values):
    return {'joint_state': _joint_state(values),
            'multi_dof_joint_state': {
                'header': _header(), 'joint_names': ['virtual_joint'],
                'transforms': [{'translation': {'x': 0.0, 'y': 0.0, 'z': 0.0},
                                'rotation': {'x': 0.0, 'y': 0.0, 'z': 0.0, 'w': 1.0}}],
                'twist': [], 'wrench': []},
            'attached_collision_objects': [], 'is_diff': False}


def _xyz(v):
    return {'x': float(v[0]), 'y': float(v[1]), 'z': float(v[2])}


def _quat(q):
    return {'x': float(q[0]), 'y': float(q[1]), 'z': float(q[2]), 'w': float(q[3])}


def _collision_object(obj):
    shape = obj.shapes[0]
    dims = (list(shape.dims) if shape.kind != 'cylinder' else [shape.dims[0], shape.dims[1]])
    kind = {'box': 1, 'sphere': 2, 'cylinder': 3}[shape.kind]
    return {'header': _header(), 'pose': {'position': _xyz([0, 0, 0]),
                                          'orientation': _quat([0, 0, 0, 1])},
            'id': obj.id, 'type': {'key': '', 'db': ''},
            'primitives': [{'type': kind, 'dimensions': [float(d) for d in dims]}],
            'primitive_poses': [{'position': _xyz(shape.pose.position_m),
                                 'orientation': _quat(shape.pose.quat_xyzw)}],
            'meshes': [], 'mesh_poses': [], 'planes': [], 'plane_poses': [],
            'subframe_names': [], 'subframe_poses': [], 'operation': 0}


def _objects(family, rng):
    name, _, can_at, edits = FAMILIES[family]
    scene = load_scene(REPO / 'config' / 'scenes' / f'{name}.yaml')
    out = []
    for obj in scene.objects:
        shape = obj.shapes[0]
        pos, dims = np.array(shape.pose.position_m), list(shape.dims)
        if 'height' in edits and (obj.id.startswith('shelf_side') or obj.id == 'shelf_back'):
            dims[2], pos[2] = edits['height'], edits['height'] / 2
        if 'height' in edits and pos[2] > edits['height']:
            continue
        if 'thin' in edits and obj.id.startswith('shelf_board'):
            dims[2] = edits['thin']
        if obj.id.startswith('target'):
            pos[:2] += rng.uniform(-0.02, 0.02, 2)
        out.append((obj.id, shape.kind, dims, pos, shape.pose.quat_xyzw))
    if can_at is not None:
        pos = np.array(can_at, float)
        pos[:2] += rng.uniform(-0.02, 0.02, 2)
        out.append(('target_can', 'cylinder', [CAN['height'], CAN['radius']], pos, (0, 0, 0, 1)))
    return out


def _grasp(objects, grasp):
    can = next(o for o in objects if o[0] == 'target_can')
    height, pos = can[2][0], can[3]
    if grasp is DOWN:
        centre = pos + [0, 0, height / 2 - 0.03]
    else:
        centre = pos + [0, 0, 0.0]
    return pin.SE3(grasp.rotation, centre)


def main():
    from advocc_ros.model.scene import SceneObject
    from advocc_ros.model.shapes import Shape
    robot_closed = load_robot(RobotSpec())
    open_spec = RobotSpec(locked=(('panda_finger_joint1', 0.04), ('panda_finger_joint2', 0.04)))
    robot_open = load_robot(open_spec)
    for family, (_, grasp, _, _) in FAMILIES.items():
        folder = HERE / 'families' / family
        folder.mkdir(parents=True, exist_ok=True)
        rng = np.random.default_rng(sum(map(ord, family)))
        made = 0
        while made < PROBLEMS:
            objects = _objects(family, rng)
            shapes = [Shape(k, tuple(d), Pose(tuple(p), tuple(q))) for _, k, d, p, q in objects]
            goal = GoalRegion(center=Pose.from_se3(_grasp(objects, grasp)),
                              position_tolerance_m=(1e-4,) * 3,
                              orientation_tolerance_rad=(1e-3,) * 3,
                              tool_offset=Pose((0.0, 0.0, TCP)))
            world_open = CollisionWorld(robot_open, shapes)
            world_closed = CollisionWorld(robot_closed, shapes)
            q_goal = None
            for _ in range(60):
                seed = np.clip(np.array(READY) + rng.normal(0, 0.6, 7), robot_open.lower,
                               robot_open.upper)
                q = goal_configuration(robot_open, goal, seed, iterations=300)
                if q is not None and world_open.is_valid(q):
                    q_goal = q
                    break
            start = np.array(READY)
            if q_goal is None or not world_open.is_valid(start):
                continue
            made += 1
            scene = {'name': '(noname)+', 'robot_state': _robot_state(READY + [0.065, 0.065]),
                     'robot_model_name': 'panda',
                     'fixed_frame_transforms': [{
                         'header': _header('world'), 'child_frame_id': 'panda_link0',
                         'transform': {'translation': _xyz([0, 0, 0]),
                                       'rotation': _quat([0, 0, 0, 1])}}],
                     'allowed_collision_matrix': {'entry_names': [], 'entry_values': [],
                                                  'default_entry_names': [],
                                                  'default_entry_values': []},
                     'link_padding': [], 'link_scale': [], 'object_colors': [],
                     'world': {'collision_objects': [
                         _collision_object(SceneObject(i, (s,)))
                         for (i, *_), s in zip(objects, shapes)],
                         'octomap': {'header': _header(), 'origin': {
                             'position': _xyz([0, 0, 0]), 'orientation': _quat([0, 0, 0, 1])},
                             'octomap': {'header': _header(), 'binary': True, 'id': 'OcTree',
                                         'resolution': 0.1, 'data': []}}},
                     'is_diff': False}
            request = {
                'workspace_parameters': {'header': _header(), 'min_corner': _xyz([-1, -1, -1]),
                                         'max_corner': _xyz([1, 1, 1])},
                'start_state': _robot_state(READY + [0.065, 0.065]),
                'goal_constraints': [{'name': '', 'joint_constraints': [
                    {'joint_name': j, 'position': float(v), 'tolerance_above': 0.001,
                     'tolerance_below': 0.001, 'weight': 1.0} for j, v in zip(ARM, q_goal)],
                    'position_constraints': [], 'orientation_constraints': [],
                    'visibility_constraints': []}],
                'path_constraints': {'name': '', 'joint_constraints': [],
                                     'position_constraints': [], 'orientation_constraints': [],
                                     'visibility_constraints': []},
                'trajectory_constraints': {'constraints': []}, 'reference_trajectories': [],
                'pipeline_id': '', 'planner_id': 'RRTConnectkConfigDefault',
                'group_name': 'panda_arm', 'num_planning_attempts': 1,
                'allowed_planning_time': 60.0, 'max_velocity_scaling_factor': 1.0,
                'max_acceleration_scaling_factor': 1.0, 'cartesian_speed_end_effector_link': '',
                'max_cartesian_speed': 0.0}
            if made == PROBLEMS and family in ('box', 'bookshelf_tall'):
                T = robot_open.ee_pose(q_goal) * pin.SE3(np.eye(3), np.array([0, 0, TCP]))
                request['goal_constraints'][0]['joint_constraints'] = []
                request['goal_constraints'][0]['position_constraints'] = [{
                    'header': _header('panda_link0'), 'link_name': 'panda_hand',
                    'target_point_offset': _xyz([0, 0, TCP]),
                    'constraint_region': {
                        'primitives': [{'type': 1, 'dimensions': [0.01, 0.01, 0.01]}],
                        'primitive_poses': [{'position': _xyz(T.translation), 'orientation':
                                             _quat(pin.Quaternion(T.rotation).coeffs())}],
                        'meshes': [], 'mesh_poses': []}, 'weight': 1.0}]
                request['goal_constraints'][0]['orientation_constraints'] = [{
                    'header': _header('panda_link0'),
                    'orientation': _quat(pin.Quaternion(T.rotation).coeffs()),
                    'link_name': 'panda_hand', 'absolute_x_axis_tolerance': 0.01,
                    'absolute_y_axis_tolerance': 0.01, 'absolute_z_axis_tolerance': 0.01,
                    'parameterization': 1, 'weight': 1.0}]
            tag = f'{made:04d}'
            (folder / f'scene{tag}.yaml').write_text(yaml.safe_dump(scene, sort_keys=False))
            (folder / f'request{tag}.yaml').write_text(yaml.safe_dump(request, sort_keys=False))
            print(family, tag, 'goal in collision with closed fingers:',
                  not world_closed.is_valid(q_goal))


if __name__ == '__main__':
    main()
