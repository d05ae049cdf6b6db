"""soil_planner: Planner example: the deepest cut within the machine's force limits from /soil/estimate (ROS-free core and thin rclpy node)."""
