"""The benchmark (ROS-free): runs (bench.runs), their report (bench.report), scenes multiplied by
shifted copies (core.scenarios.crowd), the two-process run (bench.pipelined); plots by
core.drawing.plot."""
