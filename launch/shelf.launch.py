"""The Shelf graph under `ros2 launch mvpose_ros shelf.launch.py [bag:=DIR] [rate:=R]`.

The same nodes as `mvpose-graph --config config/shelf.yaml`: a heatmap_detector per camera in
namespace cam{c}, association, bp_solver and bag_player, all with the package's
config/shelf.yaml and its Fast DDS profile config/fastdds.xml (large heatmap messages). The
player itself waits (wait_subscribers) until every camera's detector has subscribed, so start
order does not matter here. A node that dies is started again after RESPAWN_DELAY_S (launch has
no cap on restarts), association keeping its person ids in `state_dir`; not the player, which
would play the bag from its start again.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, SetEnvironmentVariable
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

from mvpose_ros.graph.respawn import RESPAWN_DELAY_S

PACKAGE = 'mvpose_ros'
CAMERAS = 5


def generate_launch_description():
    config = os.path.join(get_package_share_directory(PACKAGE), 'config')
    params = os.path.join(config, 'shelf.yaml')
    ros_home = os.environ.get('ROS_HOME', os.path.join(os.path.expanduser('~'), '.ros'))
    bag = LaunchConfiguration('bag')
    rate = LaunchConfiguration('rate')
    state_dir = LaunchConfiguration('state_dir')
    detectors = [Node(package=PACKAGE, executable='heatmap_detector', name='heatmap_detector',
                      namespace=f'cam{c}', parameters=[params, {'camera': c}], output='screen',
                      respawn=True, respawn_delay=RESPAWN_DELAY_S)
                 for c in range(CAMERAS)]
    return LaunchDescription([
        DeclareLaunchArgument('bag', default_value='bags/shelf',
                              description='rosbag2 folder to play (mvpose-make-bag shelf makes bags/shelf)'),
        DeclareLaunchArgument('rate', default_value='1.0',
                              description='playback speed, x recorded; 0.0 = as fast as the graph keeps up'),
        DeclareLaunchArgument('state_dir', default_value=os.path.join(ros_home, 'mvpose_ros'),
                              description="folder where association keeps the person ids' state (restarts)"),
        SetEnvironmentVariable('FASTRTPS_DEFAULT_PROFILES_FILE', os.path.join(config, 'fastdds.xml')),
        SetEnvironmentVariable('RMW_FASTRTPS_USE_QOS_FROM_XML', '1'),
        *detectors,
        Node(package=PACKAGE, executable='association', name='association',
             parameters=[params, {'state_dir': state_dir}], output='screen', respawn=True,
             respawn_delay=RESPAWN_DELAY_S),
        Node(package=PACKAGE, executable='bp_solver', name='bp_solver', parameters=[params], output='screen',
             respawn=True, respawn_delay=RESPAWN_DELAY_S),
        Node(package=PACKAGE, executable='bag_player', name='bag_player', output='screen',
             parameters=[params, {'bag': bag, 'rate': ParameterValue(rate, value_type=float)}]),
    ])
