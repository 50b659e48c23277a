"""Start the external-torque node for the package's 7-joint arm (urdf/arm7.urdf).

    ros2 launch fto_ros arm7_external_torque.launch.py [urdf:=FILE] [namespace:=NS]
        [use_sim_time:=true] [autostart:=false]

The node (the managed observer node, executable managed_observer_node, with observer.type
external_torque) reads the arm's JointState on joint_states (position = encoders, effort =
commanded torque) and publishes ~/external_torque, ~/contact, ~/collision and /diagnostics,
with the defaults of every other parameter (the URDF's seven joints, T = 60 ms, 1e-2 false
alarms per hour, 2 s calibration). urdf defaults to the installed
share/fto_ros/urdf/arm7.urdf. Drive it with a recorded arm bag:
fto-play bags/arm7_contact_link6 (topic /arm/joint_states: namespace:=arm). Topics and parameters: docs/ros_interface.md, docs/external_torque.md.
"""
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import LifecycleNode
from launch_ros.substitutions import FindPackageShare

BOOL = ['true', 'false']


def generate_launch_description():
    share = FindPackageShare('fto_ros')
    return LaunchDescription([
        DeclareLaunchArgument(
            'urdf', default_value=PathJoinSubstitution([share, 'urdf', 'arm7.urdf']),
            description='the arm URDF file (plant.urdf)'),
        DeclareLaunchArgument('namespace', default_value='', description='node namespace'),
        DeclareLaunchArgument(
            'use_sim_time', default_value='false', choices=BOOL,
            description='take the time from /clock (diagnostics only: the estimates use the '
                        'messages\' stamps)'),
        DeclareLaunchArgument(
            'autostart', default_value='true', choices=BOOL,
            description='configure and activate at start (false: leave it to a manager)'),
        LifecycleNode(
            package='fto_ros', executable='managed_observer_node', name='external_torque_node',
            namespace=LaunchConfiguration('namespace'),
            parameters=[{'observer.type': 'external_torque',
                         'plant.urdf': LaunchConfiguration('urdf'),
                         'use_sim_time': LaunchConfiguration('use_sim_time'),
                         'autostart': LaunchConfiguration('autostart')}],
            output='screen'),
    ])
