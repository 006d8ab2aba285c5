"""The robot and its world: robot model, scenes and their file formats (ours, MotionBenchMaker),
collision, voxels, inverse kinematics, scene variations. No ROS.
"""

from advocc_ros.model.robot import (RobotError, RobotModel, RobotSpec, example_robot_data_share,
                                    load_robot, resolve_path)
from advocc_ros.model.scene import (GoalRegion, Operation, Pose, SHAPES, Scene, SceneError,
                                    SceneObject, Shape, apply_operation, finite_array, load_scene,
                                    make_box, objects_from_data, objects_to_data, read_yaml,
                                    save_yaml_atomic, scene_from_data)
from advocc_ros.model.shapes import make_mesh_shape
from advocc_ros.model.mbm import (apply_request, is_mbm_scene, load_any_scene, load_mbm_scene,
                                  objects_from_planning_scene)
from advocc_ros.model.mbm_fields import base_frame
from advocc_ros.model.mbm_request import (GoalTolerance, MbmRequest, goal_region_at, load_request,
                                          parse_goal_tolerance)
from advocc_ros.model.collision import CollisionWorld, coal_geometry
from advocc_ros.model.voxels import SolidLUT, VoxelGrid, occupied_mask, points_in_shape
from advocc_ros.model.ik import (GoalSampler, IkConfig, dls_ik, goal_configuration, goal_set,
                                 start_configuration)
from advocc_ros.model.scenegen import Variation, VariationConfig, vary_scene, write_variation

__all__ = [
    'CollisionWorld', 'GoalRegion', 'GoalSampler', 'GoalTolerance', 'IkConfig', 'MbmRequest',
    'Operation', 'Pose', 'RobotError', 'RobotModel', 'RobotSpec', 'SHAPES', 'Scene',
    'SceneError', 'SceneObject', 'Shape', 'SolidLUT', 'Variation', 'VariationConfig',
    'VoxelGrid', 'apply_operation', 'apply_request', 'base_frame', 'coal_geometry', 'dls_ik',
    'example_robot_data_share', 'finite_array', 'goal_configuration', 'goal_region_at', 'goal_set',
    'is_mbm_scene', 'load_any_scene', 'load_mbm_scene', 'load_request', 'load_robot',
    'load_scene', 'make_box', 'make_mesh_shape', 'objects_from_data',
    'objects_from_planning_scene', 'objects_to_data', 'occupied_mask', 'parse_goal_tolerance',
    'points_in_shape', 'read_yaml', 'resolve_path', 'save_yaml_atomic', 'scene_from_data',
    'start_configuration', 'vary_scene', 'write_variation']
