"""gyro_node given a deeply nested YAML file (as a params file or a calibration file): one line naming it, exit 1."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest.importorskip('rclpy')

from rosproc import start_refused  # noqa: E402

from art_gyro_calibration.calibration import MAX_YAML_DEPTH  # noqa: E402

DEPTH = 10_000


@pytest.mark.parametrize('option', ['--params-file', 'calibration_file'])
def test_node_refuses_a_deep_yaml_file_in_one_line(tmp_path: Path, option: str) -> None:
    deep = tmp_path / 'deep.yaml'
    deep.write_text('/**:\n  ros__parameters:\n    a: ' + '[' * DEPTH + ']' * DEPTH + '\n')
    args = (['--params-file', str(deep)] if option == '--params-file' else
            ['-p', 'serial_number:=NAVC3545', '-p', f'calibration_file:={deep}'])
    code, text = start_refused(tmp_path / 'node.log', *args)
    assert code == 1 and text.startswith(f'gyro_node: error: {deep}: not a ') and len(text.splitlines()) == 1, text
    assert f'nested deeper than {MAX_YAML_DEPTH} levels' in text and 'Traceback' not in text
