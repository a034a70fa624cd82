"""Running the ROS graph as separate processes without `ros2 launch`: the process supervisor and
the runner's configuration (ROS-free, so both are testable without a ROS context)."""
