"""The ROS-free algorithm core, grouped by stage: geometry, detection, association, inference,
evaluation; shared data types in `types`, the whole stage in `stage`."""
