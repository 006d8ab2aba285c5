"""The robot and its world: robot model, poses, shapes, goal regions, scenes (our YAML format),
collision and voxels. No ROS.

Import from the defining module (``advocc_ros.model.robot``, ``.scene``, ``.goal``, ...): this
package re-exports nothing, so importing one of its modules loads only what that module needs.
Inverse kinematics lives in ``advocc_ros.kinematics``, file formats of other tools in
``advocc_ros.formats`` and scene variations and simulated sensing in ``advocc_ros.scenes``.
"""
