"""The msd example (the mass-spring-damper of docs/plant.md): start its observer with a committed params file.

    ros2 launch fto_ros msd.launch.py [observer:=luenberger]

observer picks the tuning, share/fto_ros/config/msd_<observer>.yaml; every argument of
observer.launch.py but params_file applies too (node_name, namespace, use_sim_time, managed,
autostart). With use_sim_time:=true, drive it with the recorded bag:
ros2 bag play bags/msd --clock 1000
"""
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, IncludeLaunchDescription
from launch.launch_description_sources import PythonLaunchDescriptionSource
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.substitutions import FindPackageShare


def generate_launch_description():
    share = FindPackageShare('fto_ros')
    # one path from a list of substitutions (PathJoinSubstitution takes no nested list)
    params_file = [share, '/config/msd_', LaunchConfiguration('observer'), '.yaml']
    return LaunchDescription([
        DeclareLaunchArgument(
            'observer', default_value='single_delay',
            choices=['single_delay',
                     'luenberger',
                     'hosm',
                     'newton',
                     'prescribed_time',
                     'global_norm',
                     'high_gain',
                     'ekf',
                     'acquire_track',
                     'joint_kalman',
                     'track_joint_kalman'],
            description='the tuning: config/msd_<observer>.yaml'),
        IncludeLaunchDescription(
            PythonLaunchDescriptionSource(
                PathJoinSubstitution([share, 'launch', 'observer.launch.py'])),
            launch_arguments={'params_file': params_file}.items()),
    ])
