"""Shared fixtures: the five gyros of the ART report; loopback-only DDS discovery."""

import pytest

SERIALS = ('NAVC3545', 'NAVC4361', 'NAVC4058', 'NAVC4377', 'NAVC4253')


@pytest.fixture(params=SERIALS)
def serial(request: pytest.FixtureRequest) -> str:
    """Each gyro's KVH serial number in turn."""
    return str(request.param)


@pytest.fixture
def loopback(monkeypatch: pytest.MonkeyPatch) -> None:
    """DDS discovery on loopback only, for this process's listener too."""
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
