"""Start one fto_ros observer node.

    ros2 launch fto_ros observer.launch.py params_file:=FILE [node_name:=NAME] [namespace:=NS]
        [use_sim_time:=true] [managed:=true [autostart:=false]]

managed:=false (the default) starts the plain node (executable observer_node), which is
configured and running as soon as it starts. managed:=true starts the lifecycle node
(executable managed_observer_node) instead; autostart:=true (the default here) has it
configure and activate itself, autostart:=false leaves it unconfigured for a lifecycle
manager or `ros2 lifecycle set`.

The params file needs a block for the node: the committed files in share/fto_ros/config name
theirs `observer_node` (the default name, root namespace); a `/**:` block fits any name.
A tuning file of a system with a plant file (config/<system>_plant.yaml) is started with that
plant file merged first, by the same rule as the replay tools (fto_ros.runner.plant_files).
Arguments and topics: docs/ros_interface.md.
"""
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.conditions import IfCondition, UnlessCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import LifecycleNode, Node

PACKAGE = 'fto_ros'
BOOL = ['true', 'false']


def _nodes(context):
    """The node, with the params file and the plant file it runs with (evaluated at launch)."""
    from fto_ros.runner.plant_files import params_files
    files = [str(p) for p in params_files(LaunchConfiguration('params_file').perform(context))]
    name = LaunchConfiguration('node_name')
    namespace = LaunchConfiguration('namespace')
    use_sim_time = LaunchConfiguration('use_sim_time')
    managed = LaunchConfiguration('managed')
    return [
        Node(
            package=PACKAGE, executable='observer_node', name=name, namespace=namespace,
            parameters=[*files, {'use_sim_time': use_sim_time}],
            output='screen', condition=UnlessCondition(managed)),
        LifecycleNode(
            package=PACKAGE, executable='managed_observer_node', name=name, namespace=namespace,
            parameters=[*files, {'use_sim_time': use_sim_time,
                                 'autostart': LaunchConfiguration('autostart')}],
            output='screen', condition=IfCondition(managed)),
    ]


def generate_launch_description():
    return LaunchDescription([
        DeclareLaunchArgument(
            'params_file',
            description='ROS 2 params file of the observer (e.g. a file of share/fto_ros/config)'),
        DeclareLaunchArgument(
            'node_name', default_value='observer_node',
            description='node name; the params file needs a block for it (or a /** block)'),
        DeclareLaunchArgument(
            'namespace', default_value='', description='node namespace'),
        DeclareLaunchArgument(
            'use_sim_time', default_value='false', choices=BOOL,
            description='take the time from /clock (a bag played with --clock)'),
        DeclareLaunchArgument(
            'managed', default_value='false', choices=BOOL,
            description='false: the plain observer_node; '
                        'true: the lifecycle node managed_observer_node'),
        DeclareLaunchArgument(
            'autostart', default_value='true', choices=BOOL,
            description='managed node only: configure and activate it at start'),
        OpaqueFunction(function=_nodes),
    ])
