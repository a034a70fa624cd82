"""The benchmark (ROS-free): runs (bench.runs), their report (bench.report), scenes multiplied by
shifted copies (core.evaluation.crowd), the two-process run (bench.pipelined); plots by
core.evaluation.plot."""
