"""Gain-scheduled anti-stall blade controller of Wagner et al. (Eq. 11-12): ROS-free core and thin rclpy node."""
