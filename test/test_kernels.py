"""The compiled kernels' library (advocc_ros/kernels): built once from the C sources into the
user's cache (``python -m advocc_ros.kernels``, which ``make install`` runs), loaded as it is
afterwards, built again when a source changes or the file is damaged, and a clear error when it
cannot be built. Its parallel kernels give the same result on one thread and on several, and
its entry points refuse arrays they would misread."""

import os
import pathlib
import shutil
import subprocess
import sys

import numpy as np
import pytest

from conftest import REPO
from advocc_ros import kernels
from advocc_ros.kernels import loader as lib


def _run(code: str, cache: pathlib.Path, **env) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, '-c', code], cwd=REPO, capture_output=True,
                          text=True, timeout=300,
                          env=dict(os.environ, XDG_CACHE_HOME=str(cache), **env))


@pytest.mark.processes
def test_the_library_is_built_once_into_the_cache_and_loaded_after(tmp_path):
    proc = subprocess.run([sys.executable, '-m', 'advocc_ros.kernels'], cwd=REPO,
                          capture_output=True, text=True, timeout=300,
                          env=dict(os.environ, XDG_CACHE_HOME=str(tmp_path)))
    assert proc.returncode == 0, proc.stderr
    built = sorted((tmp_path / 'advocc_ros' / 'kernels').iterdir())
    assert [p.name for p in built] == [f'libadvocc_kernels-{lib.digest()}.so'], built
    stamp = built[0].stat().st_mtime_ns
    again = _run('from advocc_ros.kernels import line_sums; import numpy as np;'
                 'print(line_sums(np.arange(4.0), 1).tolist())', tmp_path)
    assert again.returncode == 0, again.stderr
    assert again.stdout.strip() == '[1.0, 3.0, 6.0, 5.0]'
    assert built[0].stat().st_mtime_ns == stamp  # loaded, not built again
    built[0].write_bytes(b'not a library')  # damaged: built again
    damaged = _run('from advocc_ros.kernels import line_sums; import numpy as np;'
                   'print(line_sums(np.ones(3), 1).tolist())', tmp_path)
    assert damaged.returncode == 0, damaged.stderr
    assert damaged.stdout.strip() == '[2.0, 3.0, 2.0]'


def test_a_changed_source_names_another_library(tmp_path, monkeypatch):
    before = lib.digest()
    for name in lib.SOURCES + lib.HEADERS:
        shutil.copy(lib.HERE / name, tmp_path / name)
    monkeypatch.setattr(lib, 'HERE', tmp_path)
    assert lib.digest() == before
    with open(tmp_path / 'grids.c', 'a') as handle:
        handle.write('\n/* changed */\n')
    assert lib.digest() != before


def test_a_missing_or_failing_compiler_is_a_clear_error(tmp_path, monkeypatch):
    monkeypatch.setenv('CC', '/bin/false')
    with pytest.raises(lib.KernelBuildError, match='building the kernels failed'):
        lib.build(tmp_path / 'k.so')
    monkeypatch.setenv('CC', str(tmp_path / 'no-such-compiler'))
    with pytest.raises(lib.KernelBuildError, match='no-such-compiler'):
        lib.build(tmp_path / 'k.so')
    assert list(tmp_path.iterdir()) == []  # no half-written library left


def _cover_case(rng):
    """A small window with random candidates and random link placements of the Panda's
    tables (as the attack's lattice passes them)."""
    from advocc_ros.heatmap.build import link_tables
    from advocc_ros.model.robot import load_robot

    robot = load_robot()
    tables = link_tables(robot, 0.005).kernel_tables()
    L, n, k = tables.n_links, 40, 1
    shape = (30, 30, 30)
    cand_id = np.full(shape, -1, np.int64)
    picks = rng.choice(cand_id.size, 300, replace=False)
    cand_id.ravel()[picks] = np.arange(300)
    padded = tuple(s + 2 * k for s in shape)
    near = np.ones(padded, np.bool_)
    near_z = np.zeros(padded[:2] + (2,), np.int64)
    near_z[..., 1] = padded[2] - 1
    R = np.array([[np.linalg.qr(rng.normal(size=(3, 3)))[0] for _ in range(L)]
                  for _ in range(n)])
    R *= np.sign(np.linalg.det(R))[..., None, None]  # rotations
    t = rng.uniform(0.05, 0.55, size=(n, L, 3))
    return dict(starts=np.arange(0, n + 1, 4), cand_id=cand_id, near=near, near_z=near_z,
                origin_m=np.zeros(3), voxel_m=0.02, k=k, R=R, t=t, tables=tables)


def _cover(case, threads: int, monkeypatch) -> tuple[np.ndarray, np.ndarray]:
    monkeypatch.setenv('ADVOCC_THREADS', str(threads))
    rows = len(case['starts']) - 1
    cover = np.zeros((rows, 300), np.bool_)
    stamp = np.full(case['near'].shape, -1, np.int64)
    kernels.cover(cover, stamp=stamp, union=False, **case)
    union = np.full(case['near'].shape, -1, np.int64)
    kernels.cover(np.zeros((0, 0), np.bool_), stamp=union, union=True, **case)
    return cover, union >= 0


def test_parallel_kernels_give_one_threads_result(monkeypatch):
    case = _cover_case(np.random.default_rng(3))
    one, union_one = _cover(case, 1, monkeypatch)
    two, union_two = _cover(case, 2, monkeypatch)
    assert one.any() and union_one.any()  # the links met candidates
    assert np.array_equal(one, two) and np.array_equal(union_one, union_two)
    dense = np.random.default_rng(4).random((500, 70)) < 0.1
    indptr, indices = kernels.dense_to_csr(dense)
    rows, cols = np.nonzero(dense)
    assert np.array_equal(indptr, np.searchsorted(rows, np.arange(501)))
    assert np.array_equal(indices, cols)


def test_entry_points_refuse_arrays_they_would_misread():
    chain = kernels.Chain(np.tile(np.eye(4), (2, 1, 1)), np.eye(3)[:2], [True, True], [0, 1],
                          np.eye(4), nq=2)
    with pytest.raises(ValueError, match='kernel output'):
        kernels.frames(chain, np.zeros((3, 2)), np.zeros((3, 4, 4), np.float32))
    with pytest.raises(ValueError, match='shape'):
        kernels.frames(chain, np.zeros((3, 5)), np.zeros((3, 4, 4)))
    with pytest.raises(ValueError, match='joint index'):
        kernels.Chain(np.tile(np.eye(4), (2, 1, 1)), np.eye(3)[:2], [True, True], [0, 7],
                      np.eye(4), nq=2)
    n = kernels.MAX_JOINTS + 1  # beyond the kernels' scratch: pinocchio's (kinematics.batch)
    with pytest.raises(ValueError, match='at most'):
        kernels.Chain(np.tile(np.eye(4), (n, 1, 1)), np.tile([1.0, 0, 0], (n, 1)), [True] * n,
                      np.arange(n), np.eye(4), nq=n)
    with pytest.raises(ValueError, match='outside'):
        kernels.min_plus(np.zeros((2, 5)), np.zeros(2), 3, 9)
    out = np.zeros((3, 4, 4))
    kernels.frames(chain, np.zeros((3, 2)), out)
    assert np.allclose(out, np.eye(4))
