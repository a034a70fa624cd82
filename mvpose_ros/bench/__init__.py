"""Benchmark helpers (ROS-free): scaled scenes (bench.scene) and OpenCV line plots (bench.plot)."""
