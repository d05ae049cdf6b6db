"""Planar soil and bladed-vehicle simulator (ROS-free core, thin rclpy node), batch dataset generator and episode plots."""
