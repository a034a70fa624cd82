"""The rclpy nodes of the mvpose_ros graph; each module is one executable (`ros2 run mvpose_ros <name>`)."""
