"""Adapters between rclpy messages and the mvpose_ros core types: the PointCloud2 record
encodings of the ROS graph contract (raw OpenPose, 2D people, per-person view bundles, 3D
skeletons), RViz markers for skeletons, CameraInfo from calibrated cameras, BGR images and the
frame <-> header stamp timeline. Every decoder validates its message and raises ValueError
naming the first thing that is wrong; the core never sees a malformed message."""
