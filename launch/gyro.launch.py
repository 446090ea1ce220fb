"""Launch gyro_node for one gyro: ``ros2 launch art_gyro_calibration gyro.launch.py serial_number:=NAVC3545``.

Arguments: serial_number, port, namespace, params_file (a node params file such as
config/gyro_node.params.yaml; empty for none; the calibration is still loaded by serial_number).
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition, UnlessCondition
from launch.substitutions import LaunchConfiguration, PythonExpression
from launch_ros.actions import Node

ARGUMENTS = {
    'serial_number': ('NAVC3545', 'KVH serial number: loads the packaged config/<serial_number>.yaml'),
    'port': ('/dev/ttyUSB0', 'serial port of the gyro'),
    'namespace': ('', 'namespace of the node and its topics (imu/data_raw, imu/temperature, imu/static_bias)'),
    'params_file': ('', 'a node params file (gyro_node.params.yaml form); empty for none'),
}


def generate_launch_description() -> LaunchDescription:
    """The node with its serial number and port; a params file if one is given."""
    args = [DeclareLaunchArgument(name, default_value=default, description=description)
            for name, (default, description) in ARGUMENTS.items()]
    given = {name: LaunchConfiguration(name) for name in ARGUMENTS}
    overrides = {'serial_number': given['serial_number'], 'port': given['port']}
    has_file = PythonExpression(["'", given['params_file'], "' != ''"])
    nodes = [Node(package='art_gyro_calibration', executable='gyro_node', name='gyro_node',
                  namespace=given['namespace'], output='screen', emulate_tty=True,
                  parameters=parameters, condition=condition)
             for parameters, condition in (([given['params_file'], overrides], IfCondition(has_file)),
                                           ([overrides], UnlessCondition(has_file)))]
    return LaunchDescription(args + nodes)
