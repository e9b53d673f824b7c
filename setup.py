"""What a ROS install needs beside the Python package, for colcon's ament_python build (the package's metadata
is in pyproject.toml): the ament index marker, package.xml and the launch files under share/aoa_localizer."""
from setuptools import setup

setup(
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/aoa_localizer"]),
        ("share/aoa_localizer", ["package.xml"]),
        ("share/aoa_localizer/launch", ["launch/localize_sim.launch.py", "launch/spectrum.launch.py"]),
    ],
)
