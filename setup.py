"""What a ROS install needs beside the Python package, for colcon's ament_python build (the package's metadata
is in pyproject.toml): the ament index marker, package.xml, the launch files and the RViz and Foxglove layouts under
share/aoa_localizer."""
from setuptools import setup

setup(
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/aoa_localizer"]),
        ("share/aoa_localizer", ["package.xml"]),
        ("share/aoa_localizer/launch", ["launch/localize_sim.launch.py", "launch/spectrum.launch.py"]),
        ("share/aoa_localizer/config", ["config/aoa_localizer.rviz", "config/aoa_localizer.foxglove.json"]),
    ],
)
