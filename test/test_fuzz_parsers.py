"""Property-based tests of every file parser: any input ends in a result or our own error.

Inputs start from a valid document and are mutated at a random place (NaN/inf, huge and
negative numbers, wrong types, empty and oversized containers, unknown or missing keys), or
are the bytes of a valid file truncated and bit-flipped. A parser passes when it returns a
value or raises its documented error type (``SceneError``, ``HeatmapError``, ``RobotError``,
``ValueError`` for configs) quickly; any other exception is a bug. The number of cases run is
printed after the module's last test and written to ``$ADVOCC_FUZZ_COUNTS`` when set.
"""

import copy
import io
import time

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings, strategies as st

from case_counts import report_cases, whole_module_ran
from conftest import REPO

CASES: dict[str, int] = {}
SETTINGS = dict(max_examples=30, deadline=5000, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture,
                                       HealthCheck.data_too_large])
SCENES = REPO / 'config' / 'scenes'
MBM = REPO / 'test' / 'data' / 'mbm'


def _count(name: str) -> None:
    CASES[name] = CASES.get(name, 0) + 1


@pytest.fixture(scope='module', autouse=True)
def _case_count(request):
    """After the module's last test, in whatever order they ran: how many generated cases ran
    (hypothesis examples + fixed hostile inputs), and at least 250 when the whole module ran."""
    failed_before = request.session.testsfailed
    CASES.clear()
    yield
    total = report_cases(request, 'parsers', CASES)
    if whole_module_ran(request, failed_before):
        assert total >= 250, CASES


NAN, INF = float('nan'), float('inf')
NASTY = st.one_of(
    st.sampled_from([NAN, INF, -INF, 0, -0.0, -1, 1e308, -1e308, 10 ** 30, True, None, '', 'x',
                     [], {}, [0, 0, 0], [NAN] * 3, [-1, -1, -1], [1, 2], [1, 2, 3, 4, 5],
                     [[0, 0, 0]] * 4, {'x': 1}, '../../etc/passwd', 'world',
                     [0.0] * 300_001]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(min_value=-2 ** 70, max_value=2 ** 70),
    st.text(max_size=8),
    st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=8),
    st.dictionaries(st.text(max_size=6), st.integers(), max_size=3))


def _paths(doc, prefix=()):
    """Every (path, value) of a nested dict/list document."""
    yield prefix, doc
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(doc, list):
        for i, v in enumerate(doc[:6]):
            yield from _paths(v, prefix + (i,))


def mutate(data, doc):
    """A copy of ``doc`` with 1-3 random edits (replace, delete, add a key, duplicate)."""
    doc = copy.deepcopy(doc)
    for _ in range(data.draw(st.integers(1, 3), label='edits')):
        paths = [p for p, _ in _paths(doc)]
        path = data.draw(st.sampled_from(paths), label='path')
        action = data.draw(st.sampled_from(['replace', 'replace', 'delete', 'add', 'grow']),
                           label='action')
        if not path:
            if action == 'replace':
                doc = data.draw(NASTY, label='root')
            continue
        parent = doc
        for key in path[:-1]:
            parent = parent[key]
        key = path[-1]
        if action == 'replace':
            parent[key] = data.draw(NASTY, label='value')
        elif action == 'delete':
            del parent[key]
        elif action == 'add' and isinstance(parent[key], dict):
            parent[key][data.draw(st.sampled_from(['bogus', 'id', 'type', 'size', 'file']))] = \
                data.draw(NASTY)
        elif action == 'grow' and isinstance(parent[key], list) and parent[key]:
            parent[key] = parent[key] * data.draw(st.sampled_from([2, 100, 1001]))
    return doc


def _flip(data, raw: bytes) -> bytes:
    """``raw`` truncated and/or with a few bits flipped."""
    b = bytearray(raw)
    if data.draw(st.booleans(), label='truncate'):
        b = b[:data.draw(st.integers(0, max(len(b) - 1, 0)), label='cut')]
    for _ in range(data.draw(st.integers(0 if len(b) else 0, 6), label='flips')):
        if not b:
            break
        k = data.draw(st.integers(0, len(b) - 1))
        b[k] ^= 1 << data.draw(st.integers(0, 7))
    return bytes(b)


class _Timer:
    """Each parse must end quickly, whatever it reads (no hang, no quadratic blow-up)."""

    def __init__(self, limit_s=3.0):
        self.limit_s = limit_s

    def __enter__(self):
        self.t0 = time.perf_counter()
        return self

    def __exit__(self, *exc):
        assert time.perf_counter() - self.t0 < self.limit_s, 'parser too slow'
        return False


# ---------------------------------------------------------------------------------------------
# Our scene YAML

def _scene_docs():
    return [yaml.safe_load(p.read_text()) for p in sorted(SCENES.glob('*.yaml'))]


@settings(**SETTINGS)
@given(data=st.data())
def test_scene_data(data):
    from advocc_ros.model.scene import Scene, scene_from_data
    from advocc_ros.model.pose import SceneError
    doc = mutate(data, data.draw(st.sampled_from(_scene_docs()), label='scene'))
    _count('scene_yaml')
    with _Timer():
        try:
            assert isinstance(scene_from_data(doc, 'fuzz.yaml'), Scene)
        except SceneError as exc:
            assert str(exc)


@settings(**SETTINGS)
@given(data=st.data())
def test_scene_file_bytes(data, tmp_path):
    from advocc_ros.model.pose import SceneError
    from advocc_ros.model.scene import load_scene
    raw = data.draw(st.sampled_from(sorted(SCENES.glob('*.yaml')))).read_bytes()
    path = tmp_path / 'scene.yaml'
    path.write_bytes(_flip(data, raw))
    _count('scene_yaml_bytes')
    with _Timer():
        try:
            load_scene(path)
        except SceneError as exc:
            assert str(path) in str(exc), exc  # the error names the file


def _yaml_bomb(levels=9):
    """A few hundred bytes of YAML whose aliases expand to 10^levels numbers."""
    node = '&l0 [' + ', '.join(['0.1'] * 10) + ']'
    for i in range(1, levels):
        node = f'&l{i} [{node}, ' + ', '.join([f'*l{i - 1}'] * 9) + ']'
    return f'objects: [{{id: m, type: mesh, faces: [[0, 1, 2]], vertices: {node}}}]\n'


YAML_BOMB = _yaml_bomb()


@pytest.mark.parametrize('text', [
    YAML_BOMB,
    'objects: &o [*o]\n',                       # a list that contains itself
    'objects: ' + '[' * 5000 + ']' * 5000 + '\n',  # deep nesting
    'start: {panda_joint1: .nan}\n',
    '!!python/object/apply:os.system ["echo pwned"]\n',
])
def test_scene_file_hostile(tmp_path, text):
    """YAML aliases that expand to 10^9 numbers, cycles, deep nesting and Python tags."""
    from advocc_ros.model.pose import SceneError
    from advocc_ros.model.scene import load_scene
    path = tmp_path / 'hostile.yaml'
    path.write_text(text)
    _count('scene_yaml_hostile')
    with _Timer(5.0):
        with pytest.raises(SceneError):
            load_scene(path)


def test_scene_mesh_file_too_large(tmp_path):
    from advocc_ros.limits import MAX_FILE_BYTES
    from advocc_ros.model.pose import SceneError
    from advocc_ros.model.scene import load_scene
    big = tmp_path / 'big.stl'
    with open(big, 'wb') as handle:
        handle.truncate(MAX_FILE_BYTES + 1)  # sparse: no disk used
    (tmp_path / 's.yaml').write_text('objects: [{id: m, type: mesh, file: big.stl}]\n')
    _count('scene_yaml_hostile')
    with pytest.raises(SceneError, match='limit'):
        load_scene(tmp_path / 's.yaml')


# ---------------------------------------------------------------------------------------------
# MotionBenchMaker scene and request files

@settings(**SETTINGS)
@given(data=st.data())
def test_mbm_scene(data, tmp_path):
    from advocc_ros.formats.mbm_scene import load_mbm_scene
    from advocc_ros.model.scene import Scene
    from advocc_ros.model.pose import SceneError
    src = data.draw(st.sampled_from(sorted(MBM.glob('scene*.yaml'))), label='file')
    path = tmp_path / 'scene.yaml'
    if data.draw(st.booleans(), label='bytes'):
        path.write_bytes(_flip(data, src.read_bytes()))
    else:
        path.write_text(yaml.safe_dump(mutate(data, yaml.safe_load(src.read_text()))))
    _count('mbm_scene')
    with _Timer():
        try:
            assert isinstance(load_mbm_scene(path), Scene)
        except SceneError as exc:
            assert str(exc)


@settings(**SETTINGS)
@given(data=st.data())
def test_mbm_request(data, tmp_path, panda):
    from advocc_ros.formats.mbm_scene import load_request
    from advocc_ros.model.pose import SceneError
    src = data.draw(st.sampled_from(sorted(MBM.glob('request*.yaml'))), label='file')
    path = tmp_path / 'request.yaml'
    if data.draw(st.booleans(), label='bytes'):
        path.write_bytes(_flip(data, src.read_bytes()))
    else:
        path.write_text(yaml.safe_dump(mutate(data, yaml.safe_load(src.read_text()))))
    _count('mbm_request')
    with _Timer():
        try:
            req = load_request(path, panda)
            assert set(req.goal) == set(panda.joint_names)
        except SceneError as exc:
            assert str(exc)


@settings(**SETTINGS)
@given(data=st.data())
def test_mbm_trajectory(data, tmp_path):
    from advocc_ros.formats.mbm_export import load_trajectory, trajectory_data
    from advocc_ros.model.pose import SceneError
    doc = trajectory_data(['a', 'b'], np.array([[0.0, 0.1], [0.5, -0.2], [1.0, 0.3]]),
                          np.ones(2))
    path = tmp_path / 'trajectory.yaml'
    if data.draw(st.booleans(), label='bytes'):
        path.write_bytes(_flip(data, yaml.safe_dump(doc).encode()))
    else:
        path.write_text(yaml.safe_dump(mutate(data, doc)))
    _count('mbm_trajectory')
    with _Timer():
        try:
            names, points = load_trajectory(path)
            assert points.shape == (points.shape[0], len(names)) and np.isfinite(points).all()
        except SceneError as exc:
            assert str(exc)


# ---------------------------------------------------------------------------------------------
# Obstacles files

@pytest.fixture(scope='module')
def obstacles_doc():
    from advocc_ros.attack import AttackResult, AttackStatus, obstacles_data
    from advocc_ros.model.scene import make_box
    boxes = tuple(make_box(f'adv_{i}', (0.5, 0.1 * i, 0.3), (0.05,) * 3) for i in range(3))
    return obstacles_data(AttackResult(AttackStatus.SUCCESS, 'placed 3 boxes', boxes,
                                       (1.0, 0.5, 0.25), 1.75, 0.01, 'ours', 3, 0.05))


@settings(**SETTINGS)
@given(data=st.data())
def test_obstacles_file(data, tmp_path, obstacles_doc):
    from advocc_ros.attack import load_obstacles
    from advocc_ros.model.pose import SceneError
    path = tmp_path / 'obstacles.yaml'
    text = yaml.safe_dump(obstacles_doc)
    if data.draw(st.booleans(), label='bytes'):
        path.write_bytes(_flip(data, text.encode()))
    else:
        path.write_text(yaml.safe_dump(mutate(data, obstacles_doc)))
    _count('obstacles')
    with _Timer():
        try:
            objects, meta = load_obstacles(path)
            assert isinstance(meta, dict) and all(o.shapes for o in objects)
        except SceneError as exc:
            assert str(exc)


# ---------------------------------------------------------------------------------------------
# Heatmap files

@pytest.fixture(scope='module')
def heatmap_bytes(tmp_path_factory, table_scene):
    from advocc_ros.heatmap import HeatmapConfig, build_heatmap, save_heatmap
    path = tmp_path_factory.mktemp('fuzz_heatmap') / 'h.npz'
    save_heatmap(build_heatmap(table_scene, HeatmapConfig(samples=50, voxel_m=0.05), seed=3),
                 path)
    return path.read_bytes()


@settings(**dict(SETTINGS, max_examples=50))
@given(data=st.data())
def test_heatmap_bytes(data, tmp_path, heatmap_bytes):
    from advocc_ros.heatmap import Heatmap, HeatmapError, load_heatmap
    path = tmp_path / 'h.npz'
    path.write_bytes(_flip(data, heatmap_bytes))
    _count('heatmap_bytes')
    with _Timer():
        try:
            assert isinstance(load_heatmap(path), Heatmap)
        except HeatmapError as exc:
            assert str(path) in str(exc)


_ARRAYS = st.one_of(
    st.sampled_from([np.array(1), np.array([1, 2]), np.array('x'), np.array(1.5), np.array(NAN),
                     np.zeros(2), np.full(3, NAN), np.array([-2, -2, -2]), np.array([2, 2]),
                     np.zeros((2, 2, 2), np.float32), np.zeros((2, 2, 2)),
                     np.ones((2, 2, 2), bool), np.full((2, 2, 2), -1.0),
                     np.full((2, 2, 2), INF), np.frombuffer(b'[1]', np.uint8),
                     np.frombuffer(b'\xff\xfe', np.uint8), np.array([10 ** 6] * 3),
                     np.array(['a'] * 8).reshape(2, 2, 2), np.zeros(0)]),
    st.integers(-5, 5).map(np.array))


@settings(**SETTINGS)
@given(data=st.data())
def test_heatmap_crafted(data, tmp_path):
    """Well-formed npz files whose arrays lie about the grid: wrong shapes, types, values."""
    from advocc_ros.heatmap import Heatmap, HeatmapError, load_heatmap
    arrays = dict(format_version=np.array(1), origin_m=np.zeros(3), voxel_m=np.array(0.02),
                  shape=np.array([2, 2, 2]), values=np.zeros((2, 2, 2)),
                  free=np.ones((2, 2, 2), bool),
                  meta_json=np.frombuffer(b'{"robot_hash": "r"}', np.uint8))
    for key in data.draw(st.lists(st.sampled_from(sorted(arrays)), min_size=1, max_size=3,
                                  unique=True), label='keys'):
        if data.draw(st.integers(0, 5)) == 0:
            del arrays[key]
        else:
            arrays[key] = data.draw(_ARRAYS, label=key)
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    path = tmp_path / 'crafted.npz'
    path.write_bytes(buf.getvalue())
    _count('heatmap_crafted')
    with _Timer():
        try:
            h = load_heatmap(path, robot_hash=data.draw(st.sampled_from([None, 'r', 'other'])))
            assert isinstance(h, Heatmap) and len(h.grid.origin_m) == 3
            assert np.all(np.isfinite(h.grid.origin_m))
        except HeatmapError as exc:
            assert str(path) in str(exc)


def test_heatmap_zip_bomb(tmp_path):
    """8 MB on disk that would inflate to 1.7 GB is refused from the zip header, unread."""
    import zipfile
    from advocc_ros.heatmap import HeatmapError, load_heatmap
    path = tmp_path / 'bomb.npz'
    header = np.lib.format.header_data_from_array_1_0(np.zeros((2, 2, 2)))
    header['shape'] = (600, 600, 600)
    with zipfile.ZipFile(path, 'w', zipfile.ZIP_DEFLATED, compresslevel=1) as zf:
        with zf.open('values.npy', 'w', force_zip64=True) as handle:
            np.lib.format.write_array_header_1_0(handle, header)
            chunk = bytes(1 << 24)
            for _ in range(1728 // 16 + 1):
                handle.write(chunk)
    assert path.stat().st_size < 20e6
    _count('heatmap_crafted')
    with _Timer(1.0):
        with pytest.raises(HeatmapError, match='limit'):
            load_heatmap(path)


# ---------------------------------------------------------------------------------------------
# Configuration (node parameter files become these dataclasses; robot specs; goal tolerance)

_CONFIG_VALUES = st.one_of(st.floats(allow_nan=True, allow_infinity=True),
                           st.integers(-10 ** 12, 10 ** 12), st.booleans(), st.none(),
                           st.text(max_size=5))


@settings(**SETTINGS)
@given(data=st.data())
def test_config_dataclasses(data):
    from advocc_ros.attack import AttackConfig
    from advocc_ros.heatmap import HeatmapConfig
    from advocc_ros.planning.types import PlanningConfig
    import dataclasses
    cls = data.draw(st.sampled_from([AttackConfig, HeatmapConfig, PlanningConfig]))
    names = [f.name for f in dataclasses.fields(cls)]
    values = data.draw(st.dictionaries(st.sampled_from(names), _CONFIG_VALUES, max_size=3))
    _count('config')
    try:
        cfg = cls(**values)
    except (ValueError, TypeError) as exc:
        assert str(exc)
        return
    for f in dataclasses.fields(cfg):
        value = getattr(cfg, f.name)
        if isinstance(value, float):
            assert np.isfinite(value), f.name


def _node_config(node: str, params: dict):
    """The core config a node builds from its parameters (what start-up validates)."""
    import dataclasses

    from advocc_ros.attack import AttackConfig
    from advocc_ros.planning.types import PlanningConfig
    cls = {'/heatmap_server': AttackConfig, '/planner_shim': PlanningConfig}.get(node)
    if cls is None:
        return None
    names = {f.name for f in dataclasses.fields(cls)}
    return cls(**{k: v for k, v in params.items() if k in names})


@settings(**SETTINGS)
@given(data=st.data())
def test_node_params_files(data, tmp_path):
    """The shipped params YAML files, mutated: read (bounded) and validated like the nodes do."""
    from advocc_ros.model.pose import SceneError
    from advocc_ros.model.scene import read_yaml
    src = data.draw(st.sampled_from(sorted((REPO / 'config').glob('*.yaml'))), label='file')
    path = tmp_path / src.name
    if data.draw(st.booleans(), label='bytes'):
        path.write_bytes(_flip(data, src.read_bytes()))
    else:
        path.write_text(yaml.safe_dump(mutate(data, yaml.safe_load(src.read_text()))))
    _count('config')
    with _Timer():
        try:
            doc = read_yaml(path)
        except SceneError:
            return
        if not isinstance(doc, dict):
            return
        for node, body in doc.items():
            params = body.get('ros__parameters') if isinstance(body, dict) else None
            if isinstance(params, dict):
                try:
                    _node_config(node, params)
                except (ValueError, TypeError) as exc:
                    assert str(exc)


@settings(**SETTINGS)
@given(robot=st.dictionaries(st.sampled_from(['urdf', 'srdf', 'group', 'ee_link', 'bogus']),
                             NASTY, max_size=3),
       tol=st.text(alphabet='posrt=;,.0123456789-einfa ', max_size=30))
def test_robot_spec_and_goal_tolerance(robot, tol):
    from advocc_ros.formats.mbm_scene import parse_goal_tolerance
    from advocc_ros.model.robot import RobotError, RobotSpec
    from advocc_ros.model.pose import SceneError
    _count('config')
    try:
        RobotSpec.from_dict(robot)
    except RobotError:
        pass
    try:
        t = parse_goal_tolerance(tol)
        assert all(np.isfinite(t.position_m)) and min(t.position_m) >= 0
    except SceneError:
        pass


# ---------------------------------------------------------------------------------------------
# Collision-object messages (what a node converts before anything else)

@settings(**SETTINGS)
@given(data=st.data())
def test_collision_object_messages(data):
    from advocc_msgs.msg import CollisionObject
    from geometry_msgs.msg import Point, Pose
    from shape_msgs.msg import Mesh, MeshTriangle, SolidPrimitive

    from advocc_ros.ros.conversions import collision_object_from_msg, scene_from_msgs
    from advocc_ros.model.robot import RobotError
    from advocc_ros.model.pose import SceneError

    floats = st.floats(allow_nan=True, allow_infinity=True)

    def pose():
        p = Pose()
        p.position.x, p.position.y, p.position.z = (data.draw(floats) for _ in range(3))
        p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w = \
            (data.draw(floats) for _ in range(4))
        return p

    msg = CollisionObject(id=data.draw(st.text(max_size=5)),
                          operation=bytes([data.draw(st.integers(0, 255))]))
    msg.header.frame_id = data.draw(st.sampled_from(['', 'panda_link0', 'world']))
    msg.pose = pose()
    for _ in range(data.draw(st.integers(0, 3))):
        msg.primitives.append(SolidPrimitive(type=data.draw(st.integers(0, 255)), dimensions=[
            data.draw(floats) for _ in range(data.draw(st.integers(0, 4)))]))
    for _ in range(data.draw(st.integers(0, 4))):
        msg.primitive_poses.append(pose())
    if data.draw(st.booleans()):
        n = data.draw(st.sampled_from([0, 3, 8]))
        mesh = Mesh(vertices=[Point(x=data.draw(floats), y=float(i), z=float(i % 3))
                              for i in range(n)],
                    triangles=[MeshTriangle(vertex_indices=[data.draw(st.integers(0, 2 ** 32 - 1))
                                                            for _ in range(3)])
                               for _ in range(data.draw(st.integers(0, 6)))])
        msg.meshes.append(mesh)
        msg.mesh_poses.append(pose())
    _count('collision_object_msg')
    with _Timer():
        for parse in (collision_object_from_msg, lambda m: scene_from_msgs([m])):
            try:
                parse(msg)
            except (SceneError, RobotError) as exc:
                assert str(exc)


def test_huge_mesh_message_is_refused_quickly():
    """10^6 vertices: refused from the array sizes, before any per-vertex conversion."""
    from advocc_msgs.msg import CollisionObject
    from geometry_msgs.msg import Point
    from shape_msgs.msg import Mesh, MeshTriangle

    from advocc_ros.ros.conversions import collision_object_from_msg
    from advocc_ros.model.pose import SceneError
    point = Point(x=1.0, y=2.0, z=3.0)
    msg = CollisionObject(id='big', operation=CollisionObject.ADD)
    msg.pose.orientation.w = 1.0
    msg.meshes = [Mesh(vertices=[point] * 1_000_000,
                       triangles=[MeshTriangle(vertex_indices=[0, 1, 2])] * 4)]
    msg.mesh_poses = [msg.pose]
    _count('collision_object_msg')
    t0 = time.perf_counter()
    with pytest.raises(SceneError, match='limit'):
        collision_object_from_msg(msg)
    assert time.perf_counter() - t0 < 0.1
