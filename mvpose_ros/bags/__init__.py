"""rosbag2 bags of the real data: reading and writing (io), what each bag holds (recipes) and
the replay pacing of the bag_player node (replay)."""
