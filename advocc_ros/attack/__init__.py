"""The online phase: search region, coverage, attack methods and the obstacles file.

PFA (``advocc_ros.attack.pfa``) is a plugin: ``load_method('pfa')`` imports it on demand.
"""

from advocc_ros.attack.api import (attack, AttackConfig, AttackError, AttackResult, AttackStatus,
                                   box_distance, box_sum, CONTEXT_METHODS, goal_configuration,
                                   greedy_cover, KNOWN_METHODS, load_method, load_obstacles,
                                   MethodContext, METHODS, obstacles_data, random_cover,
                                   register_method, save_obstacles, search_region, SearchRegion,
                                   validate_request)

__all__ = [
    'attack', 'AttackConfig', 'AttackError', 'AttackResult', 'AttackStatus', 'box_distance',
    'box_sum', 'CONTEXT_METHODS', 'goal_configuration', 'greedy_cover', 'KNOWN_METHODS',
    'load_method', 'load_obstacles', 'MethodContext', 'METHODS', 'obstacles_data',
    'random_cover', 'register_method', 'save_obstacles', 'search_region', 'SearchRegion',
    'validate_request']
