"""The kernels' shared library: the C sources beside this file, built once by the system's C
compiler into the user's cache and loaded with ctypes.

The file is named by a digest of the sources, the compiler flags and the machine, so a changed
source builds a new library and an unchanged one is loaded as it is (``make install`` builds
it; a checkout or an install space without it builds it on first use, ~2 s). It is built for
the architecture's baseline (no ``-march``) and without floating-point contraction, so its
results do not depend on the CPU it runs on. Its calls release the GIL (ctypes.CDLL), and a
parallel kernel starts its threads for the call and joins them before it returns: nothing
stays running that a fork could break."""

from __future__ import annotations

import ctypes
import functools
import hashlib
import os
import pathlib
import platform
import shutil
import subprocess
import tempfile
import threading

from advocc_ros.model.cache import user_cache_root

HERE = pathlib.Path(__file__).resolve().parent
SOURCES = ('parallel.c', 'kinematics.c', 'voxels.c', 'grids.c')
HEADERS = ('parallel.h',)
CFLAGS = ('-O2', '-std=c11', '-D_GNU_SOURCE', '-fPIC', '-shared', '-pthread',
          '-ffp-contract=off', '-fno-strict-aliasing')
COMPILE_TIMEOUT_S = 300.0
CC_ENV = 'CC'
"""The C compiler to build with (default ``cc``, else ``gcc``)."""

_LOCK = threading.Lock()
_LIBRARY: ctypes.CDLL | None = None


class KernelBuildError(RuntimeError):
    """The kernels could not be built (no compiler, or it failed): the message says why."""


def digest() -> str:
    """What names the library: the sources, the flags and the machine."""
    h = hashlib.sha256(' '.join(CFLAGS + (platform.machine(),)).encode())
    for name in SOURCES + HEADERS:
        h.update(name.encode() + b'\0' + (HERE / name).read_bytes())
    return h.hexdigest()[:20]


def library_path() -> pathlib.Path:
    """Where the library of these sources is kept: ``<user cache>/kernels/``."""
    return user_cache_root() / 'kernels' / f'libadvocc_kernels-{digest()}.so'


def _compiler() -> str:
    cc = os.environ.get(CC_ENV) or shutil.which('cc') or shutil.which('gcc')
    if not cc:
        raise KernelBuildError('advocc_ros builds its kernels with a C compiler once, and '
                               'none was found (install gcc, or set $CC)')
    return cc


@functools.lru_cache(maxsize=1)
def compiler_version() -> str | None:
    """The first line of the C compiler's ``--version`` (None without one)."""
    try:
        done = subprocess.run([_compiler(), '--version'], capture_output=True, text=True,
                              timeout=30)
    except (KernelBuildError, OSError, subprocess.SubprocessError):
        return None
    return (done.stdout.splitlines() or [None])[0]


def build(path: pathlib.Path) -> pathlib.Path:
    """Compile the sources into ``path`` (written under a temporary name, then renamed, so a
    concurrent build or load never sees half a file); ``KernelBuildError`` on failure."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=path.name + '.', suffix='.tmp', dir=path.parent)
    os.close(fd)
    cmd = [_compiler(), *CFLAGS, '-o', tmp, *(str(HERE / s) for s in SOURCES), '-lm']
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=COMPILE_TIMEOUT_S)
        if proc.returncode != 0:
            raise KernelBuildError(f'building the kernels failed ({" ".join(cmd)}):\n'
                                   f'{proc.stderr[-4000:]}')
        os.replace(tmp, path)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise KernelBuildError(f'building the kernels failed ({" ".join(cmd)}): {exc}') \
            from None
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return path


def _located() -> pathlib.Path:
    """The library, built first if this cache has none; a private folder when the cache
    cannot be written."""
    path = library_path()
    if path.is_file():
        return path
    try:
        return build(path)
    except PermissionError:
        return build(pathlib.Path(tempfile.mkdtemp(prefix='advocc-kernels-')) / path.name)


def library() -> ctypes.CDLL:
    """The loaded library (built on first use; once per process)."""
    global _LIBRARY
    with _LOCK:
        if _LIBRARY is None:
            path = _located()
            try:
                _LIBRARY = ctypes.CDLL(str(path))
            except OSError:  # a damaged file: built again
                _LIBRARY = ctypes.CDLL(str(build(path)))
        return _LIBRARY


__all__ = ['KernelBuildError', 'build', 'compiler_version', 'digest', 'library',
           'library_path']
