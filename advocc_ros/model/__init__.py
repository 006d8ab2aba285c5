"""The robot and its world: robot model, scenes and their file formats, collision, voxels."""

from advocc_ros.model.robot import (example_robot_data_share, load_robot, resolve_path, RobotError,
                                    RobotModel, RobotSpec)
from advocc_ros.model.scene import (apply_operation, finite_array, GoalRegion, load_scene,
                                    make_box, make_mesh_shape, objects_from_data, objects_to_data,
                                    Operation, Pose, read_yaml, save_yaml_atomic, Scene,
                                    scene_from_data, SceneError, SceneObject, Shape, SHAPES)
from advocc_ros.model.mbm import (apply_request, base_frame, goal_region_at, GoalTolerance,
                                  is_mbm_scene, load_any_scene, load_mbm_scene, load_request,
                                  MbmRequest, objects_from_planning_scene, parse_goal_tolerance)
from advocc_ros.model.collision import (coal_geometry, CollisionWorld)
from advocc_ros.model.voxels import (occupied_mask, points_in_shape, SolidLUT, VoxelGrid)
from advocc_ros.model.scenegen import (Variation, VariationConfig, vary_scene)

__all__ = [
    'apply_operation', 'apply_request', 'base_frame', 'coal_geometry', 'CollisionWorld',
    'example_robot_data_share', 'finite_array', 'goal_region_at', 'GoalRegion',
    'GoalTolerance', 'is_mbm_scene', 'load_any_scene', 'load_mbm_scene', 'load_request',
    'load_robot', 'load_scene', 'make_box', 'make_mesh_shape', 'MbmRequest',
    'objects_from_data', 'objects_from_planning_scene', 'objects_to_data', 'occupied_mask',
    'Operation', 'parse_goal_tolerance', 'points_in_shape', 'Pose', 'read_yaml',
    'resolve_path', 'RobotError', 'RobotModel', 'RobotSpec', 'save_yaml_atomic', 'Scene',
    'scene_from_data', 'SceneError', 'SceneObject', 'Shape', 'SHAPES', 'SolidLUT', 'Variation',
    'VariationConfig', 'vary_scene', 'VoxelGrid']
