"""Shared fixtures: the five gyros of the ART report; loopback-only DDS discovery."""

import signal

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


def pytest_configure(config: pytest.Config) -> None:
    """Children the tests stop with SIGINT take it as Ctrl-C, however the suite was started.

    A shell without job control starts a background command with SIGINT ignored, its children
    too, and Python then leaves it so: ``calibrate record`` went on recording after the SIGINT
    (the suite run as ``nohup .ci/run &``).
    """
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
