"""``python -m advocc_ros.attack.kernels`` (run by ``make install``) compiles every numba kernel
of the package into numba's cache: after the warm-up, each ``@numba.njit`` function in the
source is compiled in that process, or reached from one that is (a kernel called only inside
kernels is loaded from the cache with its callers), and its cache index is on disk, so a user's
first heatmap or attack compiles none. After ``make install`` the warm-up loads them all from
the cache (a few seconds); on a checkout whose cache is empty it compiles them (~30 s)."""

import ast
import json
import pathlib
import subprocess
import sys

import pytest

from conftest import REPO

pytestmark = pytest.mark.processes

REPORT = '''
import json, sys
from numba.core.dispatcher import Dispatcher
from advocc_ros.attack.kernels import warm
warm()
found = {}
for name, module in list(sys.modules.items()):
    if name.startswith('advocc_ros'):
        for obj in list(vars(module).values()):
            if isinstance(obj, Dispatcher) and obj.py_func.__module__ == name:
                found[f'{name}.{obj.py_func.__name__}'] = [len(obj.signatures),
                                                          obj._cache.cache_path]
print(json.dumps(found))
'''
"""Warm up, then name every kernel of the package this process holds: its compiled signatures
and its cache folder."""


def _is_kernel(node: ast.AST) -> bool:
    return isinstance(node, ast.FunctionDef) and any(
        ast.unparse(d).startswith('numba.njit(') for d in node.decorator_list)


def _kernels() -> dict[str, tuple[str, set[str]]]:
    """Every kernel in the source: ``module.function`` -> its cache index's file name
    (``<file stem>.<function>-<line of its decorator>.py3X.nbi``) and the names it calls."""
    version = f'py{sys.version_info.major}{sys.version_info.minor}'
    kernels = {}
    for path in sorted((REPO / 'advocc_ros').rglob('*.py')):
        module = '.'.join(path.relative_to(REPO).with_suffix('').parts)
        for node in ast.parse(path.read_text()).body:
            if _is_kernel(node):
                line = min(d.lineno for d in node.decorator_list)
                calls = {c.func.id for c in ast.walk(node)
                         if isinstance(c, ast.Call) and isinstance(c.func, ast.Name)}
                kernels[f'{module}.{node.name}'] = (
                    f'{path.stem}.{node.name}-{line}.{version}.nbi', calls)
    return kernels


def test_the_warm_up_compiles_and_caches_every_kernel_of_the_package():
    kernels = _kernels()
    assert len(kernels) >= 15, kernels  # batch kinematics, heatmap, coverage, region, ...
    proc = subprocess.run([sys.executable, '-c', REPORT], cwd=REPO, capture_output=True,
                          text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    found = json.loads(proc.stdout.splitlines()[-1])
    assert set(kernels) - set(found) == set()  # a kernel whose module the warm-up never loads
    reached = {k for k in kernels if found[k][0]}  # and what they call, transitively
    while True:
        called = {name for k in reached for name in kernels[k][1]}
        more = {k for k in kernels if k.rsplit('.', 1)[1] in called} - reached
        if not more:
            break
        reached |= more
    for name, (index, _) in kernels.items():
        folder = found[name][1]
        # A kernel called only inside other kernels is compiled and cached with its callers,
        # and loaded from the cache with them: it gets no signature of its own then.
        assert name in reached, \
            f'the warm-up does not call {name}'
        assert (pathlib.Path(folder) / index).is_file(), \
            f'{name}: no cache index {index} in {folder}'
