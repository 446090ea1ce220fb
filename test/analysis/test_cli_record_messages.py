"""``calibrate record`` keeps saying that nothing arrives while nothing does, rate-limited."""

from pathlib import Path

import pytest

import art_gyro_calibration.driver as driver
from art_gyro_calibration.analysis.cli import main


def test_a_missing_port_is_said_until_the_end(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(driver, 'LINK_DOWN_REPEAT_S', 0.5)
    port = tmp_path / 'nothing'
    assert main(['record', '--port', str(port), '--out', str(tmp_path / 'x.csv'), '--duration', '2.4']) == 1
    said = [line for line in capsys.readouterr().err.splitlines() if line.startswith('calibrate record: nothing')]
    assert len(said) == 3, said   # at 1 s, 1.5 s and 2 s
    assert all(f'nothing from {port} for' in line and 'cannot open' in line for line in said), said
