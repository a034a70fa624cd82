"""The benchmark (ROS-free): runs (bench.runs), their report (bench.report), scenes multiplied by
shifted copies (core.scenarios.crowd), the two-process run (bench.pipelined), one set of images
through the onnx detector and the 3D stage (bench.still_sets, mvpose-images); plots by
core.drawing.plot."""
