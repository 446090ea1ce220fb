"""The driver's warnings: no alarm for what every connection does, no empty parentheses, a missing port said again."""

import time

from test_driver import wait_for

from art_gyro_calibration.driver import LINK_DOWN_REPEAT_S, SerialGyroDriver
from art_gyro_calibration.fake_gyro import FakeGyro
from art_gyro_calibration.protocols.kvh_fog import KvhFogConfig


def test_a_kvh_units_start_up_rejections_are_no_baud_alarm() -> None:
    """Delta angles before the interval is measured (the first second) are rejected by design: not a wrong baud."""
    warnings: list[str] = []
    frames: list[object] = []
    with FakeGyro('KVH_DSP1760_EXAMPLE', protocol='kvh_fog', rate_hz=1000, kvh_fog=KvhFogConfig()) as fake:
        driver = SerialGyroDriver(fake.path, 921600, 'kvh_fog', frames.append, kvh_fog=fake.kvh_fog,
                                  on_warning=warnings.append)
        driver.start()
        try:
            assert wait_for(lambda: len(frames) > 100)
            time.sleep(4.5)   # two whole byte-share windows
        finally:
            driver.stop()
    assert driver.stats.rejected_by_reason['no_interval'] > 0
    assert not [w for w in warnings if 'check the baud rate' in w], warnings


def test_a_slow_kvh_units_first_frame_after_the_no_frames_warning_is_no_baud_alarm() -> None:
    """A unit at 1 Hz: its first messages are held until the interval is measured (1 s), the first frame at 3 s.

    Before: "no valid frame ... check the baud rate (921600) and the protocol (kvh_fog)".
    """
    warnings: list[str] = []
    frames: list[object] = []
    config = KvhFogConfig(output_rate_hz=1.0)
    with FakeGyro('KVH_DSP1760_EXAMPLE', protocol='kvh_fog', rate_hz=1, kvh_fog=config) as fake:
        driver = SerialGyroDriver(fake.path, 921600, 'kvh_fog', frames.append, kvh_fog=fake.kvh_fog,
                                  on_warning=warnings.append)
        driver.start()
        try:
            assert wait_for(lambda: frames, timeout_s=10.0)
        finally:
            driver.stop()
    assert len(warnings) == 1 and 'valid messages came, held as a connection\'s first' in warnings[0], warnings
    assert 'no_interval' in warnings[0] and 'baud' not in warnings[0], warnings


def test_bytes_without_a_frame_say_so_not_empty_parentheses(tmp_path) -> None:
    warnings: list[str] = []
    silent = FakeGyro('NAVC3545', link=str(tmp_path / 'rd2100'))   # not started: only what is injected
    try:
        driver = SerialGyroDriver(silent.path, 9600, 'kvh_fog', lambda f: None, on_warning=warnings.append)
        driver.start()
        try:
            assert wait_for(lambda: driver.stats.connected)
            silent.inject(b'\x10\x20\x30' * 56)
            assert wait_for(lambda: warnings)
        finally:
            driver.stop()
    finally:
        silent.stop()
    assert '()' not in warnings[0] and '168 bytes skipped so far (no frame found in them)' in warnings[0], warnings


def test_a_missing_port_is_said_again_until_it_appears(tmp_path) -> None:
    links: list[tuple[bool, str]] = []
    clock = [0]
    path = str(tmp_path / 'absent')
    driver = SerialGyroDriver(path, 9600, 'binary', lambda f: None, on_link=lambda up, why: links.append((up, why)),
                              reopen_period_s=0.01, monotonic_ns=lambda: clock[0])
    driver.start()
    try:
        assert wait_for(lambda: links)
        for k in range(1, 4):
            time.sleep(0.1)
            assert len(links) == k   # retried every 10 ms, said once per LINK_DOWN_REPEAT_S
            clock[0] += int(LINK_DOWN_REPEAT_S * 1e9)
            assert wait_for(lambda: len(links) == k + 1)
    finally:
        driver.stop()
    assert all(not up and f'cannot open {path}' in why for up, why in links), links
    assert links[1][1].endswith('(down 10 s; retried every 0.01 s)') and '(down 30 s;' in links[3][1], links
