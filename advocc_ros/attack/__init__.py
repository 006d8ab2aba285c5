"""The online phase: the attack's pipeline, one module per step (docs/design.md, "The attack,
step by step"), its methods and the obstacles file. No ROS.

Methods are listed once, in ``advocc_ros.attack.methods.REGISTRY``; a method's module is
imported on first use (``load_method``). Names here are loaded from their module on first use
too: ``from advocc_ros.attack.types import AttackConfig`` (the nodes' message conversions)
loads no compiled kernel.
"""

from advocc_ros import lazy_exports

__getattr__, __all__ = lazy_exports(__name__, {
    'types': ('AttackConfig', 'AttackError', 'AttackResult', 'AttackStatus'),
    'coverage': ('Accept', 'box_distance', 'box_half_voxels', 'box_sum', 'greedy_cover',
                 'random_cover'),
    'region': ('SearchRegion', 'robot_occupancy', 'search_region'),
    'methods': ('CONTEXT_METHODS', 'KNOWN_METHODS', 'METHODS', 'MethodContext', 'MethodSpec',
                'REGISTRY', 'Selector', 'available_methods', 'load_method', 'register_method'),
    'api': ('attack',),
    'request': ('validate_request',),
    'obstacles': ('OBSTACLES_FORMAT', 'OBSTACLES_VERSION', 'load_obstacles', 'obstacles_data',
                  'obstacles_file_data', 'obstacles_meta', 'save_obstacles'),
})
