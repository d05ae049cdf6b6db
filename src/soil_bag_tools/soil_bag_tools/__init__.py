"""soil_bag_tools: rosbag2 MCAP episode bags: reading and writing, the crash-safe recorder (journal + repair) and the player."""
