"""Packaging for fto_ros: one setup.py for colcon (ament_python) and for pip."""
import os
from glob import glob

from setuptools import find_packages, setup

package_name = 'fto_ros'
# realpath: `colcon build --symlink-install` runs a symlink to this file in build/.
here = os.path.dirname(os.path.realpath(__file__))


def _requirements():
    """Run-time Python libraries: requirements.txt is the single list."""
    with open(os.path.join(here, 'requirements.txt')) as f:
        lines = (line.split('#', 1)[0].strip() for line in f)
        return [line for line in lines if line]


def _share(subdir, pattern):
    """(destination, files) for data_files; nothing when there are no files."""
    files = sorted(glob(os.path.join(subdir, pattern)))
    return [(os.path.join('share', package_name, subdir), files)] if files else []


setup(
    name=package_name,
    version='0.1.0',
    description='Finite-, fixed-, prescribed-time and global state observers for ROS 2',
    license='Apache-2.0',
    maintainer='fto_ros developers',
    maintainer_email='fto_ros@example.com',
    python_requires='>=3.10',
    packages=find_packages(exclude=['test', 'test.*', 'benchmarks', 'benchmarks.*']),
    data_files=[
        # Marker that makes the package visible to ament_index / `ros2 pkg`.
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        *_share('config', '*.yaml'),
        *_share('launch', '*.py'),
        *_share('urdf', '*.urdf'),
    ],
    install_requires=_requirements(),
    extras_require={'test': ['pytest>=7', 'hypothesis>=6', 'pytest-xdist>=3.5',
                              'pytest-timeout>=2.2']},
    entry_points={
        'console_scripts': [
            'fto-observer = fto_ros.nodes.start:observer',
            # Same node under the name `ros2 run fto_ros observer_node` looks for.
            'observer_node = fto_ros.nodes.start:observer',
            'fto-observer-managed = fto_ros.nodes.start:managed',
            'managed_observer_node = fto_ros.nodes.start:managed',
            'fto-external-torque = fto_ros.nodes.start:external_torque',
            'external_torque_node = fto_ros.nodes.start:external_torque',
            'fto-replay = fto_ros.replay.cli:main',
            'fto-simulate = fto_ros.cli.simulate:main',
            'fto-play = fto_ros.nodes.start:player',
            'fto-report = fto_ros.cli.report:main',
            'fto-design = fto_ros.cli.design:main',
            'fto-tune = fto_ros.cli.tune:main',
            'fto-identify = fto_ros.cli.identify:main',
            'fto-sweep = fto_ros.sweep.cli:main',
            'fto-warm-cache = fto_ros.cli.warm_cache:main',
        ],
    },
)
