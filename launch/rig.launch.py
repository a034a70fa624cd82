"""Your own live cameras: `ros2 launch mvpose_ros rig.launch.py rig:=FILE [params:=FILE] [namespace:=NS]`.

Starts the graph for N cameras that are already publishing (their drivers, or a played bag): ONE
heatmap_detector for the whole rig, association and bp_solver, each with the parameter file
(default: the package's config/rig_template.yaml), the rig file and the package's Fast DDS
profile (large heatmap messages). Outputs are relative to `namespace`. A node that dies is
started again after RESPAWN_DELAY_S. `tf:=true` also puts each camera's pose on /tf_static;
`overlay:=true` also starts the overlay node. Step by step: docs/own_cameras.md#steps."""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction, SetEnvironmentVariable
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from mvpose_ros.core.defaults import data_root
from mvpose_ros.core.geometry.rig import load_rig_file
from mvpose_ros.graph.respawn import RESPAWN_DELAY_S
from mvpose_ros.graph.static_tf import static_transform_nodes

PACKAGE = 'mvpose_ros'
NODES = ('heatmap_detector', 'association', 'bp_solver')


def camera_frames(context, namespace):
    """The rig file's camera poses as TF, read when the launch runs (the file is an argument)."""
    rig = load_rig_file(LaunchConfiguration('rig').perform(context), data_root=data_root)
    return [Node(**node, namespace=namespace, output='screen', respawn=True, respawn_delay=RESPAWN_DELAY_S)
            for node in static_transform_nodes(rig)]


def generate_launch_description():
    config = os.path.join(get_package_share_directory(PACKAGE), 'config')
    rig = LaunchConfiguration('rig')
    params = LaunchConfiguration('params')
    namespace = LaunchConfiguration('namespace')
    state_dir = LaunchConfiguration('state_dir')
    overrides = {'heatmap_detector': {'rig': rig, 'camera': 'all'}, 'association': {'rig': rig, 'state_dir': state_dir},
                 'bp_solver': {'rig': rig}}
    nodes = [Node(package=PACKAGE, executable=name, name=name, namespace=namespace,
                  parameters=[params, overrides[name]], output='screen', respawn=True, respawn_delay=RESPAWN_DELAY_S)
             for name in NODES]
    overlay = Node(package=PACKAGE, executable='overlay', name='overlay', namespace=namespace,
                   parameters=[params, {'rig': rig}], output='screen', respawn=True, respawn_delay=RESPAWN_DELAY_S,
                   condition=IfCondition(LaunchConfiguration('overlay')))
    ros_home = os.environ.get('ROS_HOME', os.path.join(os.path.expanduser('~'), '.ros'))
    return LaunchDescription([
        DeclareLaunchArgument('rig', description='rig file (YAML): cameras, topics, extrinsics; '
                                                 'see docs/own_cameras.md'),
        DeclareLaunchArgument('params', default_value=os.path.join(config, 'rig_template.yaml'),
                              description='parameter file (a copy of config/rig_template.yaml)'),
        DeclareLaunchArgument('namespace', default_value='',
                              description="the graph's namespace (relative topics of the rig move with it)"),
        DeclareLaunchArgument('state_dir', default_value=os.path.join(ros_home, 'mvpose_ros'),
                              description="folder where association keeps the person ids' state (restarts)"),
        DeclareLaunchArgument('tf', default_value='false',
                              description="publish each camera's pose from the rig file on /tf_static"),
        DeclareLaunchArgument('overlay', default_value='false',
                              description="draw each camera's people and skeletons on <camera>/overlay/compressed"),
        SetEnvironmentVariable('FASTRTPS_DEFAULT_PROFILES_FILE', os.path.join(config, 'fastdds.xml')),
        SetEnvironmentVariable('RMW_FASTRTPS_USE_QOS_FROM_XML', '1'),
        *nodes,
        overlay,
        OpaqueFunction(function=camera_frames, args=[namespace], condition=IfCondition(LaunchConfiguration('tf'))),
    ])
