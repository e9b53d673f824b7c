"""ROS-free programs and their helpers: offline replay, simulation runs, command-line options, the README parameter
tables."""
