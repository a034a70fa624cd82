"""ament_python package definition for mvpose_ros.

`colcon build` on a ROS 2 install and `pip install .` in a plain venv both use this file.
"""
from glob import glob

from setuptools import find_packages, setup

PACKAGE = 'mvpose_ros'

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(include=[PACKAGE, f'{PACKAGE}.*', 'msg_adapters', 'msg_adapters.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', [f'resource/{PACKAGE}']),
        (f'share/{PACKAGE}', ['package.xml']),
        (f'share/{PACKAGE}/config', glob('config/*.yaml') + glob('config/*.xml') + glob('config/*.rviz')
         + glob('config/*.json')),
        (f'share/{PACKAGE}/config/rigs', glob('config/rigs/*.yaml')),
        (f'share/{PACKAGE}/launch', glob('launch/*.py')),
        # Node launchers, where `ros2 run` looks for a package's executables.
        (f'lib/{PACKAGE}', glob('scripts/*')),
    ],
    # What `pip install .` needs to run (the versions requirements.txt pins). The ROS 2 wheels
    # (rclpy and the message packages) are the extra 'ros': on a ROS install they come from the
    # distribution (package.xml), where a pip requirement on them could never be met.
    install_requires=['numpy>=1.26', 'scipy>=1.11', 'opencv-python-headless>=4.8', 'onnxruntime>=1.17',
                      'rosbags~=0.11.9', 'foxglove-sdk~=0.30.3', 'PyYAML>=6', 'numba>=0.60'],
    extras_require={'ros': ['ros-jazzy-rclpy', 'ros-jazzy-common-interfaces', 'ros-jazzy-rmw-fastrtps-cpp']},
    zip_safe=True,
    maintainer='mvpose_ros developers',
    maintainer_email='mvpose-ros@example.org',
    description='Multi-view multi-person 3D pose estimation with sliding-window belief propagation.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'mvpose-bench = mvpose_ros.cli.bench:main',
            'mvpose-docs = mvpose_ros.cli.docs:main',
            'mvpose-eval = mvpose_ros.cli.evaluate:main',
            'mvpose-graph = mvpose_ros.cli.graph:main',
            'mvpose-images = mvpose_ros.cli.images:main',
            'mvpose-make-bag = mvpose_ros.cli.make_bag:main',
            'mvpose-record = mvpose_ros.graph.topic_recorder:main',
            'mvpose-render = mvpose_ros.cli.render:main',
        ],
    },
)
