"""MPlib planning worker: run by the MPlib venv's interpreter, never imported by advocc_ros.

MPlib 0.2.1 needs numpy < 2 (with numpy 2 it segfaults loading a URDF), so it cannot live in
our venv; this script runs in ``.venv-mplib`` (``make install`` makes it) and must not import
advocc_ros. It speaks JSON lines: requests on stdin, answers on a private duplicate of stdout
(fd 1 goes to stderr so that C++ output cannot corrupt the protocol), the first answer is
``{"ready": true, "pid": ...}``. The parent (``advocc_ros.planning.victims.mplib``) sends the
robot and the objects when they change, and kills this process when it does not answer in time.

Requests (``op``):
- ``plan``: ``q_start`` (planned joints, in ``joints`` order), ``goals`` (K, same order),
  ``time_s``, ``seed``, ``check_step_rad``; optional ``robot`` and ``objects`` (sent when they
  change). Answers ``status`` (``ok``, ``start_invalid``, ``no_valid_goal``), MPlib's
  ``ompl_status``, the raw ``path``, ``solve_s`` (wall time of ``plan``), ``goals_valid``
  (mask of the goals valid in MPlib's model) and ``first_collision`` (index of the first state
  of the path, interpolated at ``check_step_rad``, that collides in MPlib's model; -1: none).
- ``check``: ``q`` (N, planned joints) -> ``collides`` (N booleans), MPlib's verdicts, and
  ``pairs``: the colliding pairs of each (names of links or objects).
- ``stall``: sleep ``seconds`` (diagnostic: tests the parent's watchdog).

Diagnostics: ``ADVOCC_PLANNING_FAULT=kill:SEED[,SEED...]`` makes the worker SIGKILL itself
when asked to plan with one of those seeds, ``raise:...`` raise (as our planning worker does).
"""

import json
import os
import signal
import sys
import time

import numpy as np


def _pose(position, quat_xyzw):
    from mplib import Pose
    x, y, z, w = quat_xyzw
    return Pose(p=np.asarray(position, float), q=np.array([w, x, y, z], float))


def _geometry(fcl, obj: dict):
    """An FCL geometry for one shape of our scene (dims as in ``advocc_ros.model.shapes``)."""
    kind, dims = obj['kind'], obj['dims']
    if kind == 'box':
        return fcl.Box(*dims)
    if kind == 'sphere':
        return fcl.Sphere(dims[0])
    if kind == 'cylinder':  # shape_msgs: (height, radius), axis z; FCL: (radius, lz), axis z
        return fcl.Cylinder(dims[1], dims[0])
    if kind == 'mesh':
        model = fcl.BVHModel()
        model.begin_model()
        model.add_sub_model(vertices=np.asarray(obj['vertices'], float),
                            faces=np.asarray(obj['faces'], np.int32))
        model.end_model()
        return model
    raise ValueError(f'shape kind {kind!r} is not supported by the MPlib worker')


class Session:
    """One MPlib planner for one robot, and the objects of the current scene."""

    def __init__(self):
        self.planner = None
        self.names: list[str] = []

    def load_robot(self, robot: dict) -> None:
        import mplib
        self.planner = mplib.Planner(urdf=robot['urdf'], srdf=robot['srdf'],
                                     move_group=robot['move_group'])
        mp_names = list(self.planner.user_joint_names)
        missing = [j for j in robot['joints'] if j not in mp_names]
        if missing:
            raise ValueError(f'joints {missing} are not in MPlib\'s model {mp_names}')
        group = [mp_names[i] for i in self.planner.move_group_joint_indices]
        if sorted(group) != sorted(robot['joints']):
            raise ValueError(f'MPlib plans {group} for move group {robot["move_group"]!r}, '
                             f'we plan {robot["joints"]}')
        self.group_index = [group.index(j) for j in robot['joints']]  # ours -> MPlib's group
        self.full = np.zeros(len(mp_names))
        for name, value in robot['locked'].items():
            if name in mp_names:
                self.full[mp_names.index(name)] = value
        self.group_full = list(self.planner.move_group_joint_indices)
        self.names = []

    def set_objects(self, objects: list) -> None:
        from mplib.collision_detection import fcl
        world = self.planner.planning_world
        for name in self.names:
            world.remove_object(name)
        self.names = []
        for k, obj in enumerate(objects):
            name = f'obj{k}_{obj["id"]}'
            if obj['kind'] == 'cloud':
                pts = np.asarray(obj['vertices'], float)
                T = _pose(obj['position'], obj['quaternion']).to_transformation_matrix()
                world.add_point_cloud(name, pts @ T[:3, :3].T + T[:3, 3], obj['dims'][0])
            else:
                shape = fcl.CollisionObject(_geometry(fcl, obj))
                world.add_object(fcl.FCLObject(
                    name, _pose(obj['position'], obj['quaternion']), [shape], [_pose_identity()]))
            self.names.append(name)

    def _group(self, q_ours) -> np.ndarray:
        """Our joint order -> MPlib's move-group order."""
        q = np.empty(len(self.group_index))
        q[self.group_index] = np.asarray(q_ours, float)
        return q

    def collides(self, q_ours) -> bool:
        full = self.full.copy()
        full[self.group_full] = self._group(q_ours)
        self.planner.robot.set_qpos(full, True)
        return len(self.planner.planning_world.check_collision()) > 0

    def contacts(self, q_ours) -> list:
        """The colliding pairs at ``q_ours``: (link or object, link or object) names."""
        self.collides(q_ours)
        return [[c.link_name1 or c.object_name1, c.link_name2 or c.object_name2]
                for c in self.planner.planning_world.check_collision()]

    def plan(self, req: dict) -> dict:
        import mplib
        if self.collides(req['q_start']):
            return {'status': 'start_invalid'}
        goals = [np.asarray(g, float) for g in req['goals']]
        valid = [not self.collides(g) for g in goals]
        if not any(valid):
            return {'status': 'no_valid_goal', 'goals_valid': valid}
        mplib.set_global_seed(int(req['seed']) % (2 ** 31 - 2) + 1)  # MPlib replaces 0 by 1
        t0 = time.monotonic()
        status, path = self.planner.planner.plan(
            self._group(req['q_start']), [self._group(g) for g, ok in zip(goals, valid) if ok],
            time=float(req['time_s']), range=0.0, simplify=False)
        solve_s = time.monotonic() - t0
        # MPlib's move-group order -> ours
        path = np.asarray(path, float).reshape(-1, len(self.group_index))[:, self.group_index]
        answer = {'status': 'ok', 'ompl_status': str(status), 'path': path.tolist(),
                  'solve_s': solve_s, 'goals_valid': valid, 'first_collision': -1}
        if status == 'Exact solution' and len(path):
            answer['first_collision'] = self.first_collision(path, float(req['check_step_rad']))
        return answer

    def first_collision(self, path: np.ndarray, step_rad: float) -> int:
        """Index of the first colliding state of ``path`` interpolated at ``step_rad``; -1."""
        k = 0
        for a, b in zip(path[:-1], path[1:]):
            n = max(1, int(np.ceil(np.linalg.norm(b - a) / step_rad)))
            for t in np.arange(n) / n:
                if self.collides(a + (b - a) * t):
                    return k
                k += 1
        return k if self.collides(path[-1]) else -1


def _pose_identity():
    from mplib import Pose
    return Pose()


def _inject_fault(seed: int) -> None:
    kind, _, seeds = os.environ.get('ADVOCC_PLANNING_FAULT', '').partition(':')
    if kind in ('kill', 'raise') and str(seed) in seeds.split(','):
        if kind == 'kill':
            os.kill(os.getpid(), signal.SIGKILL)
        raise RuntimeError(f'fault injected by ADVOCC_PLANNING_FAULT for seed {seed}')


def _serve(session: Session, req: dict) -> dict:
    op = req.get('op')
    if op == 'stall':
        time.sleep(float(req['seconds']))
        return {'stalled': True}
    if 'robot' in req:
        session.load_robot(req['robot'])
    if session.planner is None:
        raise ValueError('no robot loaded')
    if 'objects' in req:
        session.set_objects(req['objects'])
    if op == 'plan':
        _inject_fault(int(req['seed']))
        return session.plan(req)
    if op == 'check':
        return {'collides': [session.collides(q) for q in req['q']],
                'pairs': [session.contacts(q) for q in req['q']]}
    raise ValueError(f'unknown op {op!r}')


def main() -> None:
    out = os.fdopen(os.dup(1), 'w', buffering=1)
    os.dup2(2, 1)
    sys.stdout = sys.stderr
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent decides when we stop
    session = Session()
    out.write(json.dumps({'ready': True, 'pid': os.getpid()}) + '\n')
    for line in sys.stdin:
        try:
            answer = _serve(session, json.loads(line))
        except Exception as exc:  # a bad request must not kill the worker
            answer = {'error': f'{type(exc).__name__}: {exc}'}
        out.write(json.dumps(answer) + '\n')


if __name__ == '__main__':
    main()
