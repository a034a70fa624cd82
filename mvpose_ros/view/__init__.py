"""The live view over Foxglove's WebSocket protocol: the scene conversion (ROS-free, `scene`)."""
