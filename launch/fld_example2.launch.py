"""The fld_example2 example: start its observer with a committed params file.

    ros2 launch fto_ros fld_example2.launch.py [observer:=hosm]

observer picks the tuning, share/fto_ros/config/fld_example2_<observer>.yaml; every argument of
observer.launch.py but params_file applies too (node_name, namespace, use_sim_time, managed,
autostart). With use_sim_time:=true, drive it with the recorded bag:
ros2 bag play bags/fld_example2 --clock 1000
"""
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, IncludeLaunchDescription
from launch.launch_description_sources import PythonLaunchDescriptionSource
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.substitutions import FindPackageShare


def generate_launch_description():
    share = FindPackageShare('fto_ros')
    # one path from a list of substitutions (PathJoinSubstitution takes no nested list)
    params_file = [share, '/config/fld_example2_', LaunchConfiguration('observer'), '.yaml']
    return LaunchDescription([
        DeclareLaunchArgument(
            'observer', default_value='hosm',
            choices=['hosm',
                     'ekf'],
            description='the tuning: config/fld_example2_<observer>.yaml'),
        IncludeLaunchDescription(
            PythonLaunchDescriptionSource(
                PathJoinSubstitution([share, 'launch', 'observer.launch.py'])),
            launch_arguments={'params_file': params_file}.items()),
    ])
