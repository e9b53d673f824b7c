"""The ROS 2 shell: the localizer node, the simulated vehicle, the launcher, live replay; the only package that
imports rclpy."""
