"""ros2 launch aoa_localizer spectrum.launch.py edges:=4.0e8,4.5e8,5.0e8 params_file:=/path/params.yaml

One localizer node per band of one receiver's spectrum: node `band<i>/aoa_localizer` takes the DF records with
edges[i] <= frequency < edges[i+1] (`frequency_band_hz`) from the shared /gps/fix and /df/bearing, and publishes
under its namespace; a consumer merges their `band<i>/emitter/channels` (docs/interface.md, "Several nodes over one
spectrum"). Needs the ROS 2 `launch` and `launch_ros` packages of a full Jazzy install."""
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from aoa_localizer.ros.bands import band_nodes
from launch import LaunchDescription


def _nodes(context):
    params_file = LaunchConfiguration("params_file").perform(context)
    shared = [params_file] if params_file else []
    return [
        Node(package="aoa_localizer", executable="aoa_localizer", name="aoa_localizer", namespace=namespace,
             output="screen", parameters=[*shared, {"frequency_band_hz": band}],
             remappings=[("gps/fix", "/gps/fix"), ("df/bearing", "/df/bearing")])
        for namespace, band in band_nodes(LaunchConfiguration("edges").perform(context))
    ]


def generate_launch_description():
    return LaunchDescription([
        DeclareLaunchArgument("edges", default_value="4.0e8,4.5e8,5.0e8",
                              description="band edges in Hz, ascending: one node per band [edges[i], edges[i+1])"),
        DeclareLaunchArgument("params_file", default_value="", description="the nodes' ROS 2 parameters file"),
        OpaqueFunction(function=_nodes),
    ])
