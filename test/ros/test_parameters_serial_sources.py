"""Every serial_number the user gave (-p, params files, the calibration file) must agree, whatever their order.

rcl merges its sources by node entry, not by argument order: a check of the merged value against
the files let another gyro's calibration through in one order and refused it in the other.
"""

from __future__ import annotations

import signal
from collections.abc import Callable
from pathlib import Path

import pytest

pytest.importorskip('rclpy')

from rosproc import REPO, domain_id, start_node, start_refused, stop_node, wait_until  # noqa: E402

from art_gyro_calibration.ros.parameters import given_values, params_file_values, params_files  # noqa: E402

NODE = REPO / 'config' / 'gyro_node.params.yaml'   # serial_number NAVC3545 under gyro_node:
CAL_4058 = REPO / 'config' / 'NAVC4058.yaml'   # a calibration for NAVC4058 under /**:


def _node_params(tmp_path: Path, key: str, serial: str) -> str:
    path = tmp_path / f'{serial}_{key.strip("/*") or "all"}.yaml'
    path.write_text(f'{key}:\n  ros__parameters:\n    serial_number: {serial}\n    port: /nonexistent\n')
    return str(path)


def _given(argv: list[str]) -> list[tuple[str, str]]:
    argv = ['gyro_node', '--ros-args', *argv]
    files = params_file_values(params_files(argv), '/gyro_node')
    return [(g.value, g.source) for g in given_values(argv, 'serial_number', '/gyro_node', files)]


def test_every_source_of_a_parameter_is_found_in_command_line_order(tmp_path: Path) -> None:
    """-p rules (with a node prefix that names this node or a wildcard) and params files under any matching key."""
    star = _node_params(tmp_path, '/**', 'A')
    fqn = _node_params(tmp_path, '/gyro_node', 'B')
    other = _node_params(tmp_path, 'other_node', 'C')
    assert _given(['-p', 'serial_number:=X', '--params-file', star, '-p', 'gyro_node:serial_number:=Y',
                   '--param', '*:serial_number:=Z', '-p', 'other_node:serial_number:=W', '--params-file', other,
                   '--params-file', fqn, '-p', 'port:=/dev/x']) == [
        ('X', '-p serial_number:=X on the command line'), ('A', f'the parameters in {star}'),
        ('Y', '-p gyro_node:serial_number:=Y on the command line'),
        ('Z', '--param *:serial_number:=Z on the command line'), ('B', f'the parameters in {fqn}')]
    assert _given(['--params-file', str(CAL_4058)]) == [('NAVC4058', f'the calibration in {CAL_4058}')]
    assert _given(['-p', "serial_number:='NAVC3545'"]) == [('NAVC3545', '-p serial_number:=\'NAVC3545\' on the '
                                                            'command line')]
    deep = '[' * 10_000 + ']' * 10_000   # not parsed here: rcl reads what is no string
    assert _given(['-p', f'serial_number:={deep}']) == [(deep, f'-p serial_number:={deep[:65]}... (19935 more '
                                                               'characters) on the command line')]


def _refused(tmp_path: Path, *args: str) -> str:
    code, text = start_refused(tmp_path / 'node.log', *args)
    assert code == 1 and text.startswith('gyro_node: error: ') and 'Traceback' not in text, text
    return text


ORDERS: dict[str, tuple[Callable[[Path], list[str]], tuple[str, ...]]] = {
    'p_then_calibration_params_file': (
        lambda p: ['-p', 'serial_number:=NAVC3545', '--params-file', str(CAL_4058)],
        ('-p serial_number:=NAVC3545 on the command line', f'the calibration in {CAL_4058}')),
    'calibration_params_file_then_p': (
        lambda p: ['--params-file', str(CAL_4058), '-p', 'serial_number:=NAVC3545'],
        ('-p serial_number:=NAVC3545 on the command line', f'the calibration in {CAL_4058}')),
    'node_params_file_then_p': (
        lambda p: ['--params-file', str(NODE), '-p', 'serial_number:=NAVC4058', '-p', 'port:=/nonexistent'],
        (f'the parameters in {NODE}', '-p serial_number:=NAVC4058 on the command line')),
    'p_then_node_params_file': (
        lambda p: ['-p', 'serial_number:=NAVC4058', '--params-file', str(NODE), '-p', 'port:=/nonexistent'],
        (f'the parameters in {NODE}', '-p serial_number:=NAVC4058 on the command line')),
    'prefixed_p_then_p': (
        lambda p: ['-p', 'gyro_node:serial_number:=NAVC4058', '-p', 'serial_number:=NAVC3545'],
        ('-p gyro_node:serial_number:=NAVC4058', '-p serial_number:=NAVC3545')),
    'two_params_files': (
        lambda p: ['--params-file', str(CAL_4058), '--params-file', _node_params(p, '/**', 'NAVC3545')],
        (f'the calibration in {CAL_4058}', 'NAVC3545_all.yaml')),
    'two_params_files_reversed': (
        lambda p: ['--params-file', _node_params(p, '/**', 'NAVC3545'), '--params-file', str(CAL_4058)],
        (f'the calibration in {CAL_4058}', 'NAVC3545_all.yaml')),
    'node_params_file_then_calibration_file': (
        lambda p: ['--params-file', _node_params(p, 'gyro_node', 'NAVC3545'), '-p', f'calibration_file:={CAL_4058}'],
        (f'{CAL_4058}: serial_number is \'NAVC4058\', expected \'NAVC3545\'', 'NAVC3545_gyro_node.yaml')),
    'calibration_file_then_node_params_file': (
        lambda p: ['-p', f'calibration_file:={CAL_4058}', '--params-file', _node_params(p, 'gyro_node', 'NAVC3545')],
        (f'{CAL_4058}: serial_number is \'NAVC4058\', expected \'NAVC3545\'', 'NAVC3545_gyro_node.yaml')),
    'deep_p_then_p': (
        lambda p: ['-p', 'serial_number:=' + '[' * 10_000 + ']' * 10_000, '-p', 'serial_number:=NAVC3545',
                   '-p', 'port:=/nonexistent'],
        ("parameter serial_number is '[[[[", '-p serial_number:=NAVC3545 on the command line')),
    'two_calibration_files': (
        lambda p: ['-p', f'calibration_file:={CAL_4058}', '--params-file', _calibration_file_params(p)],
        (f'-p calibration_file:={CAL_4058} on the command line', 'calibration_file.yaml')),
}


def _calibration_file_params(tmp_path: Path) -> str:
    path = tmp_path / 'calibration_file.yaml'
    path.write_text(f'/**:\n  ros__parameters:\n    calibration_file: {REPO}/config/NAVC3545.yaml\n')
    return str(path)


@pytest.mark.parametrize('name', ORDERS)
def test_a_conflict_in_any_order_is_refused_naming_both_sources(tmp_path: Path, name: str) -> None:
    """Another gyro's serial, by any of -p, params file or calibration file, in either order: exit 1, both named."""
    args, sources = ORDERS[name]
    text = _refused(tmp_path, *args(tmp_path))
    for source in sources:
        assert source in text, text


def test_sources_that_agree_start_the_node(tmp_path: Path, loopback: None) -> None:
    """The same serial by -p, a node params file and a calibration params file: the calibration loads."""
    output = tmp_path / 'node.log'
    proc = start_node(domain_id(), output, '-p', 'serial_number:=NAVC4058',
                      '--params-file', _node_params(tmp_path, 'gyro_node', 'NAVC4058'), '--params-file', str(CAL_4058),
                      '-p', 'static_bias_on_startup:=false')
    try:
        wait_until(lambda: 'calibration loaded: NAVC4058' in output.read_text(), 'the calibration', proc, output)
    finally:
        stop_node(proc, signal.SIGINT, output)
