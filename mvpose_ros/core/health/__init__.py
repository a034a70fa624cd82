"""Node health, ROS-free: rolling statistics of each node's inputs and stages, the documented
thresholds that turn them into OK / WARN / ERROR, and the per-camera reprojection residual that
shows a camera moved out of its calibration. msg_adapters/diagnostics_msg.py turns the statuses
into a diagnostic_msgs/DiagnosticArray."""
