"""Service requests to live nodes: ``heatmap_server ~/attack`` and ``planner_shim ~/plan``.

Both nodes run as real child processes on a ROS domain of their own. Each request starts from
a good one (table_pick) and gets 0-3 seeded edits: numbers to NaN/inf/extremes, joint names,
frames and links, goal tolerances, scene objects and the sensed cloud's layout. An answer with
a known code is ok (outcomes) or a clear/unclear error (by its message); ``FAILURE`` (an
exception the callback only caught), an unknown code, or a dead node is a crash; no answer
within the timeout is a hang. A node that died or hung is restarted.
"""

from __future__ import annotations

import os
import pathlib
import random
import threading
import time

import numpy as np

from fuzz.classify import MIN_MESSAGE
from fuzz.files import SCENES

NS = f'/fuzz{os.getpid()}'
NAN, INF = float('nan'), float('inf')
FLOATS = [NAN, INF, -INF, 0.0, -0.0, -1.0, 1e308, -1e308, 1e-320, 0.5, 2.0, 1e9]
OUTCOMES = ('SUCCESS', 'PARTIAL', 'PLANNING_FAILED', 'TIMED_OUT', 'INVALID_MOTION_PLAN')
"""Codes that answer the question (planning outcomes), not refuse the request."""


def _float(rng: random.Random) -> float:
    return rng.choice(FLOATS) if rng.random() < 0.7 else rng.uniform(-2.0, 2.0)


def _joint_state(rng: random.Random, js) -> None:
    names, pos = list(js.name), list(js.position)
    if not names or len(names) != len(pos):  # an earlier edit emptied or cut it: add to it
        js.name, js.position = names + ['panda_joint1'], pos + [_float(rng)]
        return
    op = rng.choice(['name', 'value', 'cut', 'dup', 'fingers', 'many', 'empty'])
    i = rng.randrange(len(names))
    if op == 'name':
        names[i] = rng.choice(['', 'joint1', 'panda_joint8', 'panda_finger_joint1', 'é' * 300])
    elif op == 'value':
        pos[i] = _float(rng)
    elif op == 'cut':
        names, pos = (names[:i], pos) if rng.random() < 0.5 else (names, pos[:i])
    elif op == 'dup':
        names[(i + 1) % len(names)] = names[i]
    elif op == 'fingers':
        names, pos = names + ['panda_finger_joint1'], pos + [_float(rng)]
    elif op == 'many':
        names, pos = names + [f'j{k}' for k in range(3000)], pos + [0.0] * 3000
    else:
        names, pos = [], []
    js.name, js.position = names, pos


def _goal(rng: random.Random, goal) -> None:
    op = rng.choice(['center', 'quat', 'tol', 'rot_tol', 'link', 'frame', 'offset', 'zero',
                     'seeds'])
    if op == 'center':
        setattr(goal.center.position, rng.choice('xyz'), _float(rng))
    elif op == 'quat':
        q = goal.center.orientation
        q.x, q.y, q.z, q.w = (_float(rng) for _ in range(4))
    elif op in ('tol', 'rot_tol'):
        size = rng.choice([3, 3, 0, 5])
        values = [rng.choice([NAN, INF, -0.1, 0.0, 1e9, 0.05]) for _ in range(size)]
        setattr(goal, 'position_tolerance' if op == 'tol' else 'orientation_tolerance', values)
    elif op == 'link':
        goal.link_name = rng.choice(['', 'tool0', 'panda_link0', 'panda_hand', 'world', 'x' * 500])
    elif op == 'frame':
        goal.header.frame_id = rng.choice(['world', 'panda_hand', '/', 'map'])
    elif op == 'offset':
        setattr(goal.tool_offset.position, rng.choice('xyz'), _float(rng))
    elif op == 'zero':
        goal.position_tolerance, goal.orientation_tolerance = [0.0] * 3, [0.0] * 3
    elif hasattr(goal, 'seed_joints'):
        goal.seed_joints = rng.choice([[], ['panda_joint1'], ['nope'] * 7])


def _scene(rng: random.Random, objects: list) -> list:
    from advocc_msgs.msg import CollisionObject
    from shape_msgs.msg import SolidPrimitive
    if not objects or rng.random() < 0.2:
        box = CollisionObject(id=rng.choice(['b', '', 'table']), operation=CollisionObject.ADD,
                              primitives=[SolidPrimitive(type=1, dimensions=[0.05] * 3)])
        box.primitive_poses = [box.pose]
        box.pose.orientation.w = box.primitive_poses[0].orientation.w = 1.0
        return objects + [box] * rng.choice([1, 2, 300, 2000])
    obj = rng.choice(objects)
    op = rng.choice(['dims', 'type', 'pose', 'frame', 'op', 'poses', 'empty', 'id'])
    if op == 'dims' and obj.primitives:
        obj.primitives[0].dimensions = [_float(rng) for _ in range(rng.choice([0, 1, 3, 3, 9]))]
    elif op == 'type' and obj.primitives:
        obj.primitives[0].type = rng.randrange(256)
    elif op == 'pose' and obj.primitive_poses:
        setattr(obj.primitive_poses[0].position, rng.choice('xyz'), _float(rng))
    elif op == 'frame':
        obj.header.frame_id = rng.choice(['world', 'map', 'panda_hand'])
    elif op == 'op':
        obj.operation = bytes([rng.randrange(1, 256)])
    elif op == 'poses':
        obj.primitive_poses = []
    elif op == 'empty':
        obj.primitives, obj.primitive_poses = [], []
    else:
        obj.id = rng.choice(['', objects[0].id, 'ü' * 100])
    return objects


def _cloud(rng: random.Random, req) -> None:
    """A small PointCloud2 of the request's cloud field, then its layout broken."""
    from sensor_msgs.msg import PointField
    pts = np.array([[0.6, 0.0, 0.8], [0.6, 0.05, 0.8]], dtype=np.float32)
    cloud = req.cloud
    cloud.fields = [PointField(name=n, offset=4 * i, datatype=PointField.FLOAT32, count=1)
                    for i, n in enumerate('xyz')]
    cloud.height, cloud.width, cloud.point_step, cloud.row_step = 1, len(pts), 12, 12 * len(pts)
    cloud.data = pts.tobytes()
    req.cloud_resolution = rng.choice([0.0, 0.02, 0.02, -1.0, NAN, 1e-9, 10.0])
    op = rng.choice(['none', 'width', 'height', 'step', 'data', 'field', 'offset', 'type',
                     'nan', 'endian'])
    if op == 'width':
        cloud.width = rng.choice([0, 3, 2 ** 31, 2 ** 32 - 1])
    elif op == 'height':
        cloud.height = rng.choice([0, 2, 2 ** 32 - 1])
    elif op == 'step':
        cloud.point_step = rng.choice([0, 4, 11, 2 ** 32 - 1])
    elif op == 'data':
        cloud.data = cloud.data[:rng.randrange(len(cloud.data))]
    elif op == 'field':
        cloud.fields = cloud.fields[:rng.randrange(3)]
    elif op == 'offset':
        cloud.fields[rng.randrange(3)].offset = rng.choice([10, 2 ** 32 - 1])
    elif op == 'type':
        cloud.fields[rng.randrange(3)].datatype = rng.choice([0, 1, 8, 9, 255])
    elif op == 'nan':
        cloud.data = np.array([[NAN, INF, 0.0]] * 2, np.float32).tobytes()
    elif op == 'endian':
        cloud.is_bigendian = True


def attack_request(rng: random.Random, base):
    """An ``Attack.Request``: ``base`` (a good one) with 0-3 edits."""
    from advocc_msgs.srv import Attack
    req = _copy(base, Attack.Request)
    for _ in range(rng.choice([0, 1, 1, 2, 3])):
        field = rng.choice(['budget', 'method', 'box', 'seed', 'policy', 'start', 'goal',
                            'scene', 'scene', 'cloud'])
        if field == 'budget':
            req.budget = rng.choice([0, -1, 1, 3, 8, 9, 2 ** 31 - 1, -2 ** 31])
        elif field == 'method':
            req.method = rng.choice(['', 'ours', 'random', 'task', 'pfa', 'pfa++', 'OURS',
                                     '../x', 'ä', 'x' * 10_000])
        elif field == 'box':
            req.box_size = _float(rng) if rng.random() < 0.7 else rng.uniform(0.0, 0.6)
        elif field == 'seed':
            req.seed = rng.randint(-2 ** 63, 2 ** 63 - 1)
        elif field == 'policy':
            req.goal_policy = rng.choice(['', 'paper', 'reachable', 'solvable', 'nope'])
        elif field == 'start':
            _joint_state(rng, req.start_state)
        elif field == 'goal':
            _goal(rng, req.goal_region)
        elif field == 'scene':
            req.scene = _scene(rng, list(req.scene))
        else:
            _cloud(rng, req)
    if req.method in ('pfa', 'pfa++', 'task') and rng.random() < 0.8:
        req.method = 'ours'  # PFA/task take seconds per request: keep a few, not a fifth
    if req.goal_policy == 'solvable' and rng.random() < 0.5:
        req.goal_policy = ''  # a witness search per request: seconds, keep a few
    return req


def plan_request(rng: random.Random, base):
    """A ``Plan.Request``: ``base`` (a good one) with 0-2 edits."""
    from advocc_msgs.srv import Plan
    req = _copy(base, Plan.Request)
    for _ in range(rng.choice([0, 1, 1, 2])):
        field = rng.choice(['planner', 'budget', 'seed', 'start', 'start', 'goal', 'goal'])
        if field == 'planner':
            req.planner_id = rng.choice(['', 'RRTConnectkConfigDefault', 'prmstar', 'bkpiece1',
                                         'nope', 'geometric::', 'x' * 10_000, 'rrtstar'])
        elif field == 'budget':
            req.time_budget_s = _float(rng) if rng.random() < 0.7 else rng.uniform(0.01, 0.4)
        elif field == 'seed':
            req.seed = rng.randint(-2 ** 63, 2 ** 63 - 1)
        elif field == 'start':
            _joint_state(rng, req.start_state)
        else:
            _goal(rng, req.goal_region)
    return req


def _copy(msg, cls):
    """A deep copy of a message (serialise, deserialise: no shared sub-messages)."""
    from rclpy.serialization import deserialize_message, serialize_message
    return deserialize_message(serialize_message(msg), cls)


# --------------------------------------------------------------------------------------------
# Live nodes

class _Node:
    """One node process under test, restarted when it dies or hangs."""

    def __init__(self, module: str, params: dict, env: dict, log_dir: pathlib.Path):
        self.module, self.params, self.env = module, params, env
        log_dir.mkdir(parents=True, exist_ok=True)
        self.log_path = log_dir / f'{module}.log'
        self.log_path.write_text('')
        self.proc = None
        self.restarts = -1

    def start(self) -> None:
        from advocc_ros.ros.spawn import start_node, stop
        if self.proc is not None:
            stop(self.proc, grace_s=2.0)
        with open(self.log_path, 'a') as log:
            self.proc = start_node(self.module, self.params, {'__ns': NS}, self.env, log)
        self.restarts += 1

    def stop(self) -> None:
        from advocc_ros.ros.spawn import stop
        if self.proc is not None:
            stop(self.proc)

    def tail(self) -> str:
        text = self.log_path.read_text(errors='replace')
        return text[-1500:]


def _classify(res, codes: dict[int, str], check) -> tuple[str, str]:
    name = codes.get(res.error_code.val)
    detail = f'{name or res.error_code.val}: {res.message[:250]}'
    if name is None or name in ('FAILURE', 'CRASH', 'UNDEFINED'):
        return 'crash', detail
    if name in OUTCOMES:
        problem = check(res) if name in ('SUCCESS', 'PARTIAL') else None
        return ('accepted_bad', f'{detail} ({problem})') if problem else ('ok', detail)
    return ('clear_error' if len(res.message) >= MIN_MESSAGE else 'unclear_error'), detail


def _check_attack(req):
    def check(res):
        if len(res.obstacles) > max(req.budget, 0):
            return f'{len(res.obstacles)} boxes for budget {req.budget}'
        for o in res.obstacles:
            p = o.pose.position
            if not (np.all(np.isfinite([p.x, p.y, p.z, *o.size])) and min(o.size) > 0):
                return 'a box with non-finite or non-positive numbers'
        return None
    return check


def _check_plan(res):
    return None if len(res.trajectory.points) >= 2 else 'success without a trajectory'


def _serve(family: str, n: int, node: _Node, ctx, srv_type, make, check_of, timeout_s: float,
           record, seed: int) -> None:
    import rclpy
    from advocc_msgs.msg import ErrorCodes
    codes = {getattr(ErrorCodes, k): k for k in dir(ErrorCodes)
             if k.isupper() and isinstance(getattr(ErrorCodes, k), int)}
    client_node = rclpy.create_node(f'fuzz_{family}', context=ctx['context'])
    executor = rclpy.executors.SingleThreadedExecutor(context=ctx['context'])
    executor.add_node(client_node)
    service = f'{NS}/{node.module}/{"attack" if family == "srv_attack" else "plan"}'
    client = client_node.create_client(srv_type, service)

    def wait_ready() -> None:
        deadline = time.monotonic() + 180
        while not client.service_is_ready():
            if node.proc.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f'{node.module} does not start:\n{node.tail()}')
            executor.spin_once(timeout_sec=0.1)

    try:
        wait_ready()
        base = ctx['base'][family]
        for index in range(ctx['first'], ctx['first'] + n):
            try:
                req = make(random.Random(f'{seed}:{family}:{index}'), base)
            except Exception as exc:  # a bug of the generator, not of the node: say so
                record((family, index), 'crash', f'fuzz generator: {exc!r}', 0.0)
                continue
            t0 = time.monotonic()
            future = client.call_async(req)
            while not future.done() and node.proc.poll() is None \
                    and time.monotonic() - t0 < timeout_s:
                executor.spin_once(timeout_sec=0.1)
            seconds = time.monotonic() - t0
            if node.proc.poll() is not None:
                record((family, index), 'crash', f'node died (exit {node.proc.returncode}): '
                       f'{node.tail()}', seconds)
            elif not future.done():
                future.cancel()
                record((family, index), 'hang', f'no answer within {timeout_s:.0f} s', seconds)
            else:
                category, detail = _classify(future.result(), codes, check_of(req))
                record((family, index), category, detail, seconds)
                continue
            node.start()
            wait_ready()
    finally:
        executor.shutdown()
        client_node.destroy_node()


def run_all(counts: dict[str, int], context: dict, timeout_s: float, record) -> None:
    """Start the nodes, send ``counts[family]`` requests to each service (one thread per
    service), stop the nodes."""
    import rclpy
    from sensor_msgs.msg import JointState

    from advocc_msgs.srv import Attack, Plan
    from advocc_ros.model.scene import load_scene
    from advocc_ros.ros.conversions import attack_request as good_attack, goal_region_to_msg
    tmp, logs = pathlib.Path(context['tmp']), pathlib.Path(context['logs'])
    domain = 1 + os.getpid() % 99  # the pytest fixtures use 100..229
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_LOCALHOST_ONLY='1',
               PYTHONUNBUFFERED='1', PYTHONFAULTHANDLER='1')  # a segfault's stack in the log
    scene = load_scene(SCENES / 'table_pick.yaml')
    plan = Plan.Request(planner_id='rrtconnect', time_budget_s=0.3, seed=0)
    plan.start_state = JointState(name=list(scene.start), position=list(scene.start.values()))
    plan.goal_region = goal_region_to_msg(scene.goal, scene.frame)
    nodes = {
        'srv_attack': _Node('heatmap_server', {'heatmap_file': context['heatmap'],
                                               'max_budget': 8, 'allowed_dirs': [str(tmp)]},
                            env, logs),
        'srv_plan': _Node('planner_shim', {'scene_file': str(SCENES / 'table_pick.yaml'),
                                           'time_budget_s': 0.3, 'max_time_budget_s': 0.5,
                                           'watchdog_margin_s': 3.0}, env, logs),
    }
    rcl_context = rclpy.Context()
    rclpy.init(context=rcl_context, domain_id=domain)
    ctx = {'context': rcl_context, 'first': context['first'],
           'base': {'srv_attack': good_attack(scene, 2), 'srv_plan': plan}}
    kinds = {'srv_attack': (Attack, attack_request, _check_attack),
             'srv_plan': (Plan, plan_request, lambda req: _check_plan)}
    threads = []
    try:
        for family, n in counts.items():
            nodes[family].start()
            srv_type, make, check_of = kinds[family]
            threads.append(threading.Thread(target=_serve, args=(
                family, n, nodes[family], ctx, srv_type, make, check_of, timeout_s, record,
                context['seed'])))
            threads[-1].start()
        for thread in threads:
            thread.join()
    finally:
        for node in nodes.values():
            node.stop()
        rclpy.try_shutdown(context=rcl_context)
