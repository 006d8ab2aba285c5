"""Our OMPL 1.7 planners (RRTConnect, PRM*, BKPIECE1, ...) as a victim: one watched worker.

By default they sample the goal region themselves (IK inside their budget, topped up lazily
while planning: paper §V-A). With ``VictimConfig.ompl_goal_list`` they plan to the same K goal
configurations the outside victims get, computed before the clock starts, so the two compare
like for like (docs/transfer.md).
"""

from __future__ import annotations

from advocc_ros.model.collision import CollisionWorld
from advocc_ros.planning.types import PlanResult, PlanStatus, failed, planner_class_name
from advocc_ros.planning.victims.base import Task, VictimConfig
from advocc_ros.planning.worker import Planner


class OmplVictim:
    """``Victim`` over our ``Planner`` (its worker process, watchdog and statuses)."""

    def __init__(self, name: str, config: VictimConfig = VictimConfig()):
        if planner_class_name(name) is None:
            raise ValueError(f'{name!r} is not an OMPL planner id')
        self.name, self.config = name, config
        self.planner_id = name
        """The OMPL planner id sent to the worker."""
        self._planner: Planner | None = None
        self._world: tuple[str, CollisionWorld] | None = None

    def new_planner(self, scene) -> Planner:
        """A ``Planner`` over our OMPL 1.7 worker; a subclass overrides it to run another
        worker (the OMPL 2 victims run theirs in the OMPL 2 venv)."""
        return Planner(scene, self.config.planning)

    @property
    def planner(self) -> Planner | None:
        """The ``Planner`` the last ``start`` or ``plan`` used (None before, and after
        ``close``): its ``robot`` is the model the victim's paths are checked in."""
        return self._planner

    def _planner_for(self, task: Task) -> Planner:
        if self._planner is None or self._planner.robot.spec != task.scene.robot:
            if self._planner is not None:
                self._planner.close()
            self._planner = self.new_planner(task.scene)
        else:
            self._planner.set_scene(task.scene)
            self._planner.config = self.config.planning  # the shim may change its settings
        return self._planner

    def start(self, scene) -> 'OmplVictim':
        if self._planner is None or self._planner.robot.spec != scene.robot:
            self.close()
            self._planner = self.new_planner(scene)
        self._planner.start()
        return self

    def plan(self, task: Task, time_budget_s: float, seed: int) -> PlanResult:
        planner = self._planner_for(task)
        goals, stats = task.goal_configs, {}
        if self.config.ompl_goal_list and goals is None and not task.goal.is_joint:
            found = task.goal_list(planner.robot, self.world_for(task, planner.robot),
                                   self.config.goal_configs, seed)
            goals, stats = found.configs, found.stats()
        if goals is not None and not len(goals):
            return failed(PlanStatus.GOAL_IN_COLLISION, 'no goal found: our goal sampler found no '
                          'collision-free goal configuration for the goal list before the clock '
                          f'({stats.get("goal_attempts", 0)} IK attempts)', planner.robot.nq,
                          **stats)
        result = planner.plan(task.q_start, task.goal, self.planner_id, time_budget_s, seed,
                              goals)
        result.stats.update(stats, victim=self.name)
        return result

    def world_for(self, task: Task, robot) -> CollisionWorld:
        """The collision world of ``task``'s scene for ``robot``, kept while the scene's objects
        stay the same (the goal list's search and a subclass's path checks share it)."""
        key = task.scene.objects_hash()
        if self._world is None or self._world[0] != key:
            self._world = (key, CollisionWorld(robot, task.scene.shapes))
        return self._world[1]

    def close(self) -> None:
        if self._planner is not None:
            self._planner.close()
            self._planner = None
