"""Compile every numba kernel of the package once, into numba's on-disk cache.

The kernels (``@numba.njit(cache=True)`` in kinematics.batch, heatmap.build and the attack's
coverage, configurations and region modules) compile on their first call, about 30 s of one CPU;
after that every process loads them from the cache in well under a second. ``make install`` runs
``python -m advocc_ros.attack.kernels``, so a user's first heatmap or attack does not pay the
compilation. The smallest real heatmap and attack call every kernel with the types they are always
called with (the attack starts no planner and writes no disk cache), and the goal-sample cache's
check of a sample read back from disk calls the last two."""

from __future__ import annotations

import sys
import time

WARM_SCENE = 'table_pick'
WARM_SAMPLES = 100
WARM_BUDGET = 2


def warm() -> float:
    """Build a tiny heatmap and run one attack on it: every kernel compiled (or loaded from
    the cache); the seconds it took."""
    from advocc_ros.attack import attack
    from advocc_ros.heatmap import HeatmapConfig, build_heatmap
    from advocc_ros.kinematics.batch import ChainKinematics
    from advocc_ros.kinematics.ik import goal_box, start_configuration
    from advocc_ros.model.cache import disk_cache_at
    from advocc_ros.model.robot import load_robot
    from advocc_ros.model.scene import load_scene
    from advocc_ros.paths import scene_path

    t0 = time.perf_counter()
    scene = load_scene(scene_path(WARM_SCENE))
    robot = load_robot(scene.robot)
    q_init = start_configuration(scene, robot)
    heatmap = build_heatmap(scene, HeatmapConfig(samples=WARM_SAMPLES))
    with disk_cache_at('off'):  # nothing of the warm-up in the user's cache
        result = attack(heatmap, robot, scene.objects, q_init, scene.goal, WARM_BUDGET, 'task',
                        goal_policy='paper', certify=False)
    if not result.status.ok:
        raise RuntimeError(f'the warm-up attack failed: {result.message}')
    chain = ChainKinematics(robot.model, robot.model.getFrameId(scene.goal.link))
    goal_box(robot, scene.goal).contains(chain.frame(q_init[None]))
    return time.perf_counter() - t0


def main() -> int:
    print(f'advocc_ros: numba kernels compiled and cached in {warm():.1f} s', file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(main())
