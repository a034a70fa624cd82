"""The ROS-free algorithm core, grouped by stage: geometry, detection, association, inference;
the defaults every part shares in `defaults`, data types in `types`, the whole stage in `stage`;
beside it the datasets, scenarios made from them, drawing, and evaluation (which no run-time code
imports)."""
