"""QoS profiles and topic names shared by every advocc node (publisher and subscriber alike)."""

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

# Latched topics: a late joiner still gets the last messages (like tf2's static broadcaster).
# depth 100, not 1: collision objects are a stream of ADD/REMOVE operations, all of which count.
LATCHED_QOS = QoSProfile(depth=100, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                         history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE)

COLLISION_OBJECT_TOPIC = '/advocc/collision_object'
"""advocc_msgs/CollisionObject operations (ADD/REMOVE/APPEND/MOVE) for the planning scene."""
SCENE_TOPIC = '/advocc/scene'
"""advocc_msgs/Scene: the whole static scene and the start state."""
GOAL_REGION_TOPIC = '/advocc/goal_region'
"""advocc_msgs/GoalRegion: the current task's goal region."""
