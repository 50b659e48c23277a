"""The arm7 example (the 7-joint arm of config/arm7_plant.yaml, one observer per joint in one
node): start its observer with a committed params file.

    ros2 launch fto_ros arm7.launch.py [observer:=luenberger]

The node runs one observer per joint of the JointState /arm/joint_states (joints), all
joints in one compiled call per message.

observer picks the tuning, share/fto_ros/config/arm7_<observer>.yaml; every argument of
observer.launch.py but params_file applies too (node_name, namespace, use_sim_time, managed,
autostart). With use_sim_time:=true, drive it with the recorded bag:
ros2 bag play bags/arm7_contact_link6 --clock 1000
"""
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, IncludeLaunchDescription
from launch.launch_description_sources import PythonLaunchDescriptionSource
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.substitutions import FindPackageShare


def generate_launch_description():
    share = FindPackageShare('fto_ros')
    # one path from a list of substitutions (PathJoinSubstitution takes no nested list)
    params_file = [share, '/config/arm7_', LaunchConfiguration('observer'), '.yaml']
    return LaunchDescription([
        DeclareLaunchArgument(
            'observer', default_value='hosm',
            choices=['hosm',
                     'luenberger',
                     'single_delay',
                     'ekf',
                     'acquire_track',
                     'joint_kalman',
                     'track_joint_kalman'],
            description='the tuning: config/arm7_<observer>.yaml'),
        IncludeLaunchDescription(
            PythonLaunchDescriptionSource(
                PathJoinSubstitution([share, 'launch', 'observer.launch.py'])),
            launch_arguments={'params_file': params_file}.items()),
    ])
