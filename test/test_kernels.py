"""``python -m advocc_ros.attack.kernels`` (run by ``make install``) compiles every numba kernel
of the package into numba's cache: run into an empty cache folder, it leaves an entry for each
``@numba.njit`` function in the source, so a user's first heatmap or attack compiles none."""

import os
import re
import subprocess
import sys

import pytest

from conftest import REPO

pytestmark = [pytest.mark.processes, pytest.mark.slow]  # ~30 s of compilation in one process

KERNEL = re.compile(r'^@numba\.njit\(.*\n(?:@.*\n)*def (\w+)\(', re.MULTILINE)


def _kernels() -> set[str]:
    """Every kernel's cache index name, ``<module>.<function>-<line of its decorator>``."""
    names = set()
    for path in sorted((REPO / 'advocc_ros').rglob('*.py')):
        text = path.read_text()
        for m in KERNEL.finditer(text):
            line = text.count('\n', 0, m.start()) + 1
            names.add(f'{path.stem}.{m.group(1)}-{line}')
    return names


def test_the_warm_up_compiles_every_kernel_of_the_package(tmp_path):
    kernels = _kernels()
    assert len(kernels) >= 15, kernels  # batch kinematics, heatmap, coverage, region, ...
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path))
    proc = subprocess.run([sys.executable, '-m', 'advocc_ros.attack.kernels'], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert 'numba kernels compiled and cached' in proc.stderr
    version = f'py{sys.version_info.major}{sys.version_info.minor}'
    cached = {p.name.removesuffix(f'.{version}.nbi') for p in tmp_path.rglob('*.nbi')}
    assert kernels - cached == set()
