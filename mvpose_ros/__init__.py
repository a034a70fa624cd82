"""mvpose_ros: multi-view multi-person 3D human pose for ROS 2 (core, nodes, graph runner, tools)."""
