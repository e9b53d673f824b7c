"""The ROS-free engine: configuration, the Localizer and what it is made of, in rooms by role (ingest, track,
inference, outputs, scheduling). Nothing here imports rclpy, and nothing here imports the simulation."""
