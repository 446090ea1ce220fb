"""``calibrate --help``: every option of every command says what it is and its default; bags are named; no RST."""

import argparse
from pathlib import Path

import numpy as np
import pytest

from art_gyro_calibration.analysis.cli import build_parser, main
from art_gyro_calibration.log import GyroLog

from test_bags import write_bag


def _commands() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


@pytest.mark.parametrize('command', sorted(_commands()))
def test_every_option_has_help_and_its_default(command: str) -> None:
    for action in _commands()[command]._actions:
        if isinstance(action, argparse._HelpAction):
            continue
        name = '/'.join(action.option_strings) or action.dest
        assert action.help, f'calibrate {command} {name}: no help text'
        # A value the option takes when not given is said; a flag (False), a repeatable (empty) or a required one
        # has none to say.
        if action.option_strings and not action.required and action.default not in (False, []):
            assert 'default' in action.help, f'calibrate {command} {name}: help does not say its default'


def test_inputs_name_rosbag2_and_no_raw_rst(capsys: pytest.CaptureFixture[str]) -> None:
    for command in ('apply', 'fit', 'replay', 'allan'):
        log = next(a for a in _commands()[command]._actions if a.dest == 'log')
        assert 'rosbag2' in log.help, command
    with pytest.raises(SystemExit):
        main(['--help'])
    assert '``' not in capsys.readouterr().out


def test_a_bag_without_a_reference_names_the_option(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    n = 3000
    ns = 1_700_000_000_000_000_000 + np.arange(n, dtype=np.int64) * 100_000_000
    log = GyroLog(ns * 1e-9, np.random.default_rng(1).normal(0.0, 0.01, n), np.full(n, 25.0))
    bag = write_bag(tmp_path / 'bag', log, ns)
    assert main(['fit', str(bag), '--rows', '1', '--columns', '1', '--out', str(tmp_path / 'c.yaml'),
                 '--report', str(tmp_path / 'r.json')]) == 1
    err = capsys.readouterr().err
    assert 'no ref_rate column' in err and 'with --reference-topic TOPIC' in err, err
