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
