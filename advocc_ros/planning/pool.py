"""A pool of local planning workers that answers plan queries (PFA's planner in the loop)."""

from __future__ import annotations

import concurrent.futures
import queue

from advocc_ros.model.scene import Scene
from advocc_ros.planning.types import PlanningConfig, PlanResult
from advocc_ros.planning.worker import Planner


class LocalPlanners:
    """:class:`QueryPlanner` over ``workers`` local OMPL worker processes (one ``Planner``
    each); a call takes a free planner, sets the scene plus obstacles, and plans."""

    def __init__(self, scene: Scene, workers: int = 1, config: PlanningConfig = PlanningConfig()):
        if workers < 1:
            raise ValueError(f'workers must be >= 1, got {workers}')
        self.scene, self.workers = scene, int(workers)
        self._planners = [Planner(scene, config) for _ in range(self.workers)]
        self._free: queue.SimpleQueue[Planner] = queue.SimpleQueue()
        for p in self._planners:
            self._free.put(p)

    def start(self) -> 'LocalPlanners':
        """Start every worker process now (in parallel; ~2 s each otherwise on first use)."""
        with concurrent.futures.ThreadPoolExecutor(self.workers) as pool:
            list(pool.map(Planner.start, self._planners))
        return self

    def __call__(self, q_start, obstacles, goal, planner_id, time_budget_s, seed) -> PlanResult:
        planner = self._free.get()
        try:
            planner.set_scene(self.scene.with_objects(tuple(obstacles)))
            return planner.plan(q_start, goal, planner_id, time_budget_s, seed)
        finally:
            self._free.put(planner)

    def close(self) -> None:
        for p in self._planners:
            p.close()

    def __enter__(self) -> 'LocalPlanners':
        return self

    def __exit__(self, *exc) -> None:
        self.close()
