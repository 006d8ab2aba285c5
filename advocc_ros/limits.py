"""Size limits on everything advocc reads, in one place, so one input cannot exhaust memory.

Each limit is enforced where the input enters (file loader or message conversion), before the
expensive work, and the error names the limit. Per-request budgets that users tune live in the
node configs instead (``AttackConfig.max_budget``, ``max_box_m``,
``PlanningConfig.max_time_budget_s``). ``worker_threads`` bounds what one process may use of the
machine's CPUs.
"""

from __future__ import annotations

import os

import numpy as np

MAX_FILE_BYTES = 64 * 1024 * 1024
"""Scene, request, obstacles and mesh files [bytes] (a 200k-vertex mesh in YAML is ~10 MB)."""
MAX_YAML_NODES = 2_000_000
"""Values in one YAML document after expanding aliases (stops "billion laughs" files)."""
MAX_YAML_FLOW_DEPTH = 1000
"""Open ``[``/``{`` at any point of a YAML file, checked before parsing: libyaml's composer
recurses in C and overflows the stack near 100,000 levels (a segfault, not an error)."""
MAX_OBJECTS = 1000
"""Collision objects in one scene file, obstacles file or request."""
MAX_SHAPES = 10_000
"""Primitives + meshes over all objects of one scene or request."""
MAX_MESH_VERTICES = 200_000
"""Vertices of one mesh."""
MAX_MESH_TRIANGLES = 400_000
"""Triangles of one mesh."""
MAX_SCENE_VERTICES = 1_000_000
"""Mesh vertices over a whole scene or request."""
MAX_CLOUD_POINTS = 2_000_000
"""Points of one sensed cloud (file or ``PointCloud2``), before the octree is built."""
MIN_CLOUD_RESOLUTION_M = 0.002
"""Smallest octree leaf edge of a cloud [m]."""
MAX_CLOUD_RESOLUTION_M = 0.5
"""Largest octree leaf edge of a cloud [m]."""
MAX_JOINTS = 1024
"""Names in one joint state."""
MAX_HEATMAP_VOXELS = 128 * 1024 * 1024
"""Voxels of a heatmap grid (1 GiB of float64 H); checked on the zip header before inflating."""
MAX_HEATMAP_BYTES = MAX_HEATMAP_VOXELS * 9 + (64 << 20)
"""Uncompressed size of all arrays of a heatmap file (H, free mask, metadata)."""
MAX_TRIALS = 100_000
"""Trials of one evaluation or benchmark cell."""
MAX_GOAL_DISTANCE_M = 100.0
"""Goal region centre and tool offset [m, per axis]: no arm has a task farther away, and goal IK
towards 1e308 m spends every budget it has (a minute per attack request) on overflow."""
MAX_PLANNER_QUERIES = 10_000
"""Planner queries of one planner-in-the-loop attack (PFA, PFA++)."""


THREADS_ENV = 'ADVOCC_THREADS'
"""Threads one process may run at once (its C++ thread pools, the kernels' parallel loops): set
by the data set build to the CPUs each of its Ray tasks holds, so that a task does not take the
CPUs of another (whose victims are being timed)."""


def available_cpus() -> int:
    """The CPUs this process may run on (its affinity mask, which ``taskset``, a container or
    a cluster scheduler narrows; ``os.cpu_count`` counts the machine's)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def worker_threads() -> int:
    """Threads this process may run at once: ``$ADVOCC_THREADS`` (a positive integer), else
    ``available_cpus``. ``ValueError`` for any other value."""
    value = os.environ.get(THREADS_ENV, '').strip()
    if not value:
        return available_cpus()
    if not value.isdigit() or int(value) < 1:
        raise ValueError(f'${THREADS_ENV}={value!r}: expected a positive integer')
    return int(value)


def yaml_flow_depth(raw: bytes, limit: int = MAX_YAML_FLOW_DEPTH) -> None:
    """``ValueError`` if more than ``limit`` brackets (``[``, ``{``) are open at some point of
    ``raw``; brackets inside quotes count too (an over-estimate, never an under-estimate)."""
    brackets = raw.translate(None, bytes(b for b in range(256) if b not in b'[]{}'))
    depth = 0
    for start in range(0, len(brackets), 1 << 22):  # bounded memory for any file
        chunk = np.frombuffer(brackets[start:start + (1 << 22)], np.uint8)
        steps = np.where((chunk == ord('[')) | (chunk == ord('{')), 1, -1)
        levels = depth + np.cumsum(steps)
        if levels.max(initial=0) > limit:
            raise ValueError(f'YAML nesting: more than {limit:,} open brackets '
                             '(limit MAX_YAML_FLOW_DEPTH)')
        depth = int(levels[-1]) if len(levels) else depth


def yaml_size(data, limit: int = MAX_YAML_NODES, max_depth: int = 200) -> int:
    """Values in ``data`` counting shared (aliased) sub-trees once per use; raises
    ``ValueError`` past ``limit``, ``max_depth`` levels, or on a cycle."""
    memo: dict[int, int] = {}

    def size(node, depth: int, path: set) -> int:
        if not isinstance(node, (list, dict)):
            return 1
        key = id(node)
        if key in path:
            raise ValueError('YAML document contains itself (recursive alias)')
        if key in memo:
            return memo[key]
        if depth > max_depth:
            raise ValueError(f'YAML nesting deeper than {max_depth} levels')
        path.add(key)
        items = list(node.keys()) + list(node.values()) if isinstance(node, dict) else node
        total = 1
        for item in items:
            total += size(item, depth + 1, path)
            if total > limit:
                raise ValueError(f'YAML document expands to more than {limit:,} values '
                                 '(limit MAX_YAML_NODES)')
        path.discard(key)
        memo[key] = total
        return total

    return size(data, 0, set())
