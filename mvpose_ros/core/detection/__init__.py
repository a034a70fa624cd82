"""The 2D side: OpenPose input and grouping, the ONNX models, per-person heatmaps from detections."""
