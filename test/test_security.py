"""Nothing on an input path can execute code, and nodes read files only from allowed folders."""

import ast
import pathlib
import subprocess
import sys

import pytest

from conftest import REPO

_BANNED_MODULES = {'pickle', 'cPickle', 'dill', 'cloudpickle', 'marshal', 'shelve', 'joblib'}
_BANNED_CALLS = {'eval', 'exec', '__import__'}
_BANNED_ATTRS = {('yaml', 'load'), ('yaml', 'unsafe_load'), ('yaml', 'full_load'),
                 ('yaml', 'load_all'), ('yaml', 'unsafe_load_all'), ('os', 'system'),
                 ('os', 'popen'), ('pickle', 'load'), ('pickle', 'loads')}


def _findings(path: pathlib.Path) -> list[str]:
    tree = ast.parse(path.read_text(), str(path))
    found = []
    for node in ast.walk(tree):
        where = f'{path.relative_to(REPO)}:{getattr(node, "lineno", 0)}'
        if isinstance(node, ast.Import):
            found += [f'{where} import {a.name}' for a in node.names
                      if a.name.split('.')[0] in _BANNED_MODULES]
        elif isinstance(node, ast.ImportFrom) and node.module \
                and node.module.split('.')[0] in _BANNED_MODULES:
            found.append(f'{where} from {node.module} import')
        elif isinstance(node, ast.Call):
            f = node.func
            if isinstance(f, ast.Name) and f.id in _BANNED_CALLS:
                found.append(f'{where} {f.id}()')
            if isinstance(f, ast.Attribute) and isinstance(f.value, ast.Name) \
                    and (f.value.id, f.attr) in _BANNED_ATTRS:
                found.append(f'{where} {f.value.id}.{f.attr}()')
            for kw in node.keywords:
                if kw.arg in ('allow_pickle', 'shell') and isinstance(kw.value, ast.Constant) \
                        and kw.value.value is True:
                    found.append(f'{where} {kw.arg}=True')
    return found


def test_no_pickle_eval_or_unsafe_yaml():
    files = sorted((REPO / 'advocc_ros').rglob('*.py'))
    assert len(files) > 20
    findings = [f for path in files for f in _findings(path)]
    assert not findings, '\n'.join(findings)


def test_the_scanner_sees_what_it_bans(tmp_path):
    bad = REPO / 'advocc_ros' / '_scan_probe.py'
    source = ('import pickle\nimport yaml\nyaml.load(open("x"))\neval("1")\n'
              'import numpy as np\nnp.load("f", allow_pickle=True)\n')
    try:
        bad.write_text(source)
        assert len(_findings(bad)) == 4
    finally:
        bad.unlink()


def test_confine(tmp_path):
    from advocc_ros.paths import PathError, allowed_dirs, confine
    inside = tmp_path / 'ok' / 'h.npz'
    inside.parent.mkdir()
    inside.write_bytes(b'')
    dirs = allowed_dirs([str(tmp_path / 'ok')])
    assert confine(inside, dirs, 'f') == inside.resolve()
    for path in (tmp_path / 'ok' / '..' / 'h.npz', '/etc/passwd', tmp_path / 'okay' / 'x'):
        with pytest.raises(PathError, match='outside the allowed directories'):
            confine(path, dirs, 'f')
    link = tmp_path / 'ok' / 'link.npz'
    link.symlink_to('/etc/hostname')
    with pytest.raises(PathError):
        confine(link, dirs, 'f')  # a symlink out of an allowed folder does not escape
    assert REPO / 'config' in allowed_dirs(None) or \
        (REPO / 'config').resolve() in allowed_dirs(None)


@pytest.mark.processes
def test_nodes_refuse_files_outside_allowed_dirs(tmp_path, ros_env):
    """Both nodes exit 1 with a clear message; started together (start-up dominates)."""
    allowed = tmp_path / 'allowed'
    allowed.mkdir()
    (allowed / 'escape.yaml').symlink_to(REPO / 'config' / 'scenes' / 'table_pick.yaml')
    runs = [
        ('heatmap_server', [f'heatmap_file:={tmp_path / "h.npz"}',
                            f'allowed_dirs:=[{allowed}]'], 'heatmap_file'),
        ('planner_shim', [f'scene_file:={allowed / "escape.yaml"}',
                          f'allowed_dirs:=[{allowed}]'], 'scene_file'),
        ('planner_shim', ['scene_file:=/etc/hostname.yaml'], 'scene_file'),
    ]
    procs = []
    for module, params, _ in runs:
        args = [sys.executable, '-m', f'advocc_ros.nodes.{module}', '--ros-args']
        for p in params:
            args += ['-p', p]
        procs.append(subprocess.Popen(args, env=ros_env, stdout=subprocess.PIPE,
                                      stderr=subprocess.STDOUT, text=True))
    try:
        for proc, (_, _, what) in zip(procs, runs):
            out, _ = proc.communicate(timeout=120)
            assert proc.returncode == 1, out
            assert 'cannot start' in out and what in out and 'outside the allowed' in out, out
            assert 'Traceback' not in out
    finally:
        for proc in procs:
            if proc.poll() is None:
                proc.kill()
                proc.wait(5)


# --------------------------------------------------------------------------------------------
# Layering: the pipeline's stage packages are free of ROS, imports form no cycle, and nothing
# uses the CLI as a library.

_PACKAGE = REPO / 'advocc_ros'
_STAGES = ('kernels', 'model', 'kinematics', 'formats', 'scenes', 'heatmap', 'attack', 'planning',
           'evaluation', 'audit', 'view', 'bench')
_LOOSE = ('__init__', 'cli', 'fileio', 'limits', 'paths')  # top-level modules, also ROS-free
_ROS_EDGE = ('advocc_ros.ros', 'advocc_ros.nodes', 'advocc_ros.orchestrator')


def _module_name(path: pathlib.Path) -> str:
    parts = list(path.relative_to(REPO).with_suffix('').parts)
    if parts[-1] == '__init__':
        parts.pop()
    return '.'.join(parts)


def _modules() -> dict[str, pathlib.Path]:
    return {_module_name(p): p for p in sorted(_PACKAGE.rglob('*.py'))}


def _imports(name: str, path: pathlib.Path) -> list[tuple[str, int]]:
    """(imported module, line) of every import in the file, at any depth (functions too)."""
    package = name if path.name == '__init__.py' else name.rpartition('.')[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out += [(a.name, node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ''
            if node.level:
                anchor = package.split('.')[:len(package.split('.')) - node.level + 1]
                base = '.'.join(anchor + ([base] if base else []))
            out.append((base, node.lineno))
            out += [(f'{base}.{a.name}', node.lineno) for a in node.names]
    return out


def _graph() -> dict[str, dict[str, int]]:
    """Module -> {module of advocc_ros it imports: line}."""
    modules = _modules()
    return {name: {dep: line for dep, line in _imports(name, path)
                   if dep in modules and dep != name}
            for name, path in modules.items()}


def _is_ros(module: str) -> bool:
    top = module.split('.')[0]
    return top in ('rclpy', 'builtin_interfaces', 'rcl_interfaces', 'advocc_msgs') \
        or top.startswith('rosidl') or top.endswith('_msgs') or top.endswith('_interfaces')


def test_no_import_cycles():
    graph = _graph()
    state: dict[str, int] = {}  # 1: on the DFS stack, 2: done
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for dep in sorted(graph[node]):
            if state.get(dep) == 1:
                return stack[stack.index(dep):] + [dep]
            if dep not in state:
                cycle = visit(dep)
                if cycle:
                    return cycle
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state:
            cycle = visit(node)
            assert cycle is None, 'import cycle: ' + ' -> '.join(cycle)


def test_stage_packages_import_no_ros():
    modules = _modules()
    stage = [n for n in modules if n.split('.')[1:2] and n.split('.')[1] in _STAGES
             or n in {f'advocc_ros.{m}' if m != '__init__' else 'advocc_ros' for m in _LOOSE}]
    assert len(stage) > 20
    bad = [f'{modules[n].relative_to(REPO)}:{line} imports {dep}'
           for n in stage for dep, line in _imports(n, modules[n])
           if _is_ros(dep) or dep.startswith(_ROS_EDGE)]
    assert not bad, '\n'.join(bad)


def test_nothing_imports_the_cli_commands():
    modules = _modules()
    bad = [f'{modules[n].relative_to(REPO)}:{line} imports {dep}'
           for n in modules if not n.startswith('advocc_ros.commands')
           for dep, line in _imports(n, modules[n]) if dep.startswith('advocc_ros.commands')]
    assert not bad, '\n'.join(bad)


def test_the_layering_scan_sees_a_cycle_and_ros():
    probes = [_PACKAGE / 'model' / '_layer_probe_a.py', _PACKAGE / 'model' / '_layer_probe_b.py']
    try:
        probes[0].write_text('import rclpy\nfrom advocc_ros.model import _layer_probe_b\n')
        probes[1].write_text('def f():\n    from . import _layer_probe_a\n')
        with pytest.raises(AssertionError, match='_layer_probe_a -> .*_layer_probe_b'):
            test_no_import_cycles()
        with pytest.raises(AssertionError, match='imports rclpy'):
            test_stage_packages_import_no_ros()
    finally:
        for probe in probes:
            probe.unlink(missing_ok=True)


def test_module_sizes_and_the_top_level():
    sizes = {p.relative_to(REPO): len(p.read_text().splitlines()) for p in _PACKAGE.rglob('*.py')}
    big = {str(p): n for p, n in sizes.items() if n > 500}
    assert not big, f'modules over 500 lines: {big}'
    loose = sorted(p.stem for p in _PACKAGE.glob('*.py'))
    assert len(loose) <= 6, f'top-level modules (at most 6): {loose}'


@pytest.mark.processes
def test_flake8_is_clean():
    """The settings of setup.cfg's [flake8] section (max-line-length 99) over code and tests."""
    out = subprocess.run([sys.executable, '-m', 'flake8', 'advocc_ros', 'test', 'setup.py'],
                         cwd=REPO, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stdout + out.stderr
