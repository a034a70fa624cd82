"""Running the ROS graph as separate processes without `ros2 launch`: the process supervisor
(`processes`) and the runner's configuration (`config`), both ROS-free; the runner (`runner`: start,
wait, play, collect), the skeleton recorder node (`recorder`, also a program of its own), what the
runner prints (`report`) and resident memory (`memory`)."""
