"""The ROS-free engine: configuration, the Localizer and what it is made of (pairing, points, the robustness layer),
simulated scenarios and their evaluation. Nothing here imports rclpy."""
