"""The online phase: the attack's pipeline, one module per step (docs/design.md, "The attack,
step by step"), its methods and the obstacles file. No ROS.

Methods are listed once, in ``advocc_ros.attack.methods.REGISTRY``; a method's module is
imported on first use (``load_method``), so PFA (``advocc_ros.attack.pfa``) is not imported here.
"""

from advocc_ros.attack.types import AttackConfig, AttackError, AttackResult, AttackStatus
from advocc_ros.attack.coverage import (Accept, box_distance, box_half_voxels, box_sum,
                                        greedy_cover, random_cover)
from advocc_ros.attack.region import SearchRegion, robot_occupancy, search_region
from advocc_ros.attack.methods import (CONTEXT_METHODS, KNOWN_METHODS, METHODS, MethodContext,
                                       MethodSpec, REGISTRY, Selector, available_methods,
                                       load_method, register_method)
from advocc_ros.attack.api import attack
from advocc_ros.attack.request import validate_request
from advocc_ros.attack.obstacles import (OBSTACLES_FORMAT, OBSTACLES_VERSION, load_obstacles,
                                         obstacles_data, obstacles_file_data, obstacles_meta,
                                         save_obstacles)

__all__ = [
    'Accept', 'AttackConfig', 'AttackError', 'AttackResult', 'AttackStatus', 'CONTEXT_METHODS',
    'KNOWN_METHODS', 'METHODS', 'MethodContext', 'MethodSpec', 'OBSTACLES_FORMAT',
    'OBSTACLES_VERSION', 'REGISTRY', 'SearchRegion', 'Selector', 'attack', 'available_methods',
    'box_distance', 'box_half_voxels', 'box_sum', 'greedy_cover', 'load_method',
    'load_obstacles', 'obstacles_data', 'obstacles_file_data', 'obstacles_meta',
    'random_cover', 'register_method', 'robot_occupancy', 'save_obstacles', 'search_region',
    'validate_request']
