"""ros2 launch aoa_localizer localize_sim.launch.py scenario:=urban speedup:=10.0 params_file:=/path/params.yaml

The simulated vehicle and the localizer node (needs the ROS 2 `launch` and `launch_ros` packages of a full Jazzy
install; without them, `python -m aoa_localizer.launch` does the same)."""
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from launch import LaunchDescription


def _nodes(context):
    params_file = LaunchConfiguration("params_file").perform(context)
    node_params = [params_file] if params_file else []
    return [
        Node(package="aoa_localizer", executable="aoa_localizer", name="aoa_localizer", output="screen",
             parameters=node_params),
        Node(package="aoa_localizer", executable="aoa_sim_vehicle", name="sim_vehicle", output="screen",
             parameters=[{"scenario": LaunchConfiguration("scenario").perform(context),
                          "speedup": float(LaunchConfiguration("speedup").perform(context))}]),
    ]


def generate_launch_description():
    return LaunchDescription([
        DeclareLaunchArgument("scenario", default_value="seed", description="seed, straight, urban or homing"),
        DeclareLaunchArgument("speedup", default_value="10.0", description="simulated seconds per wall second"),
        DeclareLaunchArgument("params_file", default_value="", description="the node's ROS 2 parameters file"),
        OpaqueFunction(function=_nodes),
    ])
