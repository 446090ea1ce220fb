"""SerializedMessage: fields written in place read back through rclpy's own deserializer; a bad field refused."""

from __future__ import annotations

import math

import pytest
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import Imu   # type: ignore[import-untyped]  # the message wheels ship no type hints
from std_msgs.msg import Float64   # type: ignore[import-untyped]  # the message wheels ship no type hints

from art_gyro_calibration.ros.node import IMU_AXES_FIELDS, IMU_FIELDS
from art_gyro_calibration.ros.rclpy_typed import SerializedMessage


def test_fields_written_in_place_deserialize_as_written_and_the_rest_as_the_template() -> None:
    """Every field the node writes, with a long frame id before them (offsets found, not assumed)."""
    template = Imu()
    template.header.frame_id = 'a_frame_id_of_odd_length'
    template.orientation_covariance[0] = -1.0
    template.orientation.w = 0.5
    message = SerializedMessage(template, IMU_FIELDS + IMU_AXES_FIELDS)
    values = {field: float(i + 1) / 7 for i, field in enumerate(IMU_FIELDS + IMU_AXES_FIELDS)}
    values.update({'header.stamp.sec': 2_000_000_001, 'header.stamp.nanosec': 999_999_999})
    for field, value in values.items():
        message.put(field, value)
    got = deserialize_message(message.data(), Imu)
    assert (got.header.stamp.sec, got.header.stamp.nanosec) == (2_000_000_001, 999_999_999)
    assert got.header.frame_id == 'a_frame_id_of_odd_length'
    assert (got.angular_velocity.x, got.angular_velocity.y, got.angular_velocity.z) == (
        values['angular_velocity.x'], values['angular_velocity.y'], values['angular_velocity.z'])
    assert list(got.angular_velocity_covariance[[0, 4, 8]]) == [values[f'angular_velocity_covariance[{i}]']
                                                                for i in (0, 4, 8)]
    assert got.linear_acceleration.z == values['linear_acceleration.z']
    assert got.linear_acceleration_covariance[8] == values['linear_acceleration_covariance[8]']
    assert got.orientation_covariance[0] == -1.0 and got.orientation.w == 0.5
    assert got.angular_velocity_covariance[1] == 0.0
    temperature = SerializedMessage(Float64(), ('data',))
    temperature.put('data', -math.pi)
    assert deserialize_message(temperature.data(), Float64).data == -math.pi


def test_a_field_that_is_not_the_messages_is_refused() -> None:
    """A misspelt field ends the construction, naming it (not a write at a wrong offset)."""
    with pytest.raises(AttributeError, match='angular_velocity_z'):
        SerializedMessage(Imu(), ('angular_velocity_z',))
