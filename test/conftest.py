"""Shared fixtures: the five gyros of the ART report."""

import pytest

SERIALS = ('NAVC3545', 'NAVC4361', 'NAVC4058', 'NAVC4377', 'NAVC4253')


@pytest.fixture(params=SERIALS)
def serial(request: pytest.FixtureRequest) -> str:
    """Each gyro's KVH serial number in turn."""
    return request.param
