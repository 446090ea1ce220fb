"""``analysis.pipeline``: ``calibrate fit`` writes only what the node can run.

The README's 24 h example wrote a ``supply_v`` term and gyro_node refused the file
("extended terms need signals ['supply_v'] that are not available here"). An effect on a
signal the node does not track is a finding, reported with what to do, not written, unless
``--node-signal`` says the robot feeds the node that column by topic: then it is written,
and the node loads the file where that topic's parameter is set and refuses it, naming the parameter, where not.
"""

import json

import pytest

from art_gyro_calibration.calibration import (CalibrationError, check_fed, check_signals_available, load_calibration,
                                              load_packaged_calibration)
from art_gyro_calibration.compensation import Compensator
from art_gyro_calibration.signals import SignalFeed
from art_gyro_calibration.analysis.cli import main
from art_gyro_calibration.analysis.simulate import SimulationSettings, simulate_run, write_run
from art_gyro_calibration.log import read_log


def test_a_supply_voltage_effect_is_a_finding_and_the_node_loads_the_file(tmp_path, capsys):
    cal = load_packaged_calibration('NAVC4058')
    log = tmp_path / 'LOG.csv'
    write_run(log, simulate_run(cal, SimulationSettings(hours=2.0, seed=2, effects=('supply_voltage',))))
    assert main(['fit', str(log), '--rows', '3', '--columns', '2', '--serial', 'NAVC4058',
                 '--out', str(tmp_path / 'CAL.yaml'), '--report', str(tmp_path / 'REPORT.json')]) == 0
    written = load_calibration(tmp_path / 'CAL.yaml', expected_serial='NAVC4058')
    check_signals_available(written)   # what the node checks (the signals it tracks): no supply_v
    Compensator(written)               # the node's own constructor accepts it
    report = json.loads((tmp_path / 'REPORT.json').read_text())
    findings = {f['signal']: f for f in report['findings_not_written']}
    assert 'supply_v' in findings and 'supply_v' not in report['written']['terms']
    assert 'no supply_v at run time' in findings['supply_v']['reason']
    out = capsys.readouterr()
    assert 'an effect on supply_v' in out.err and 'not written' in out.err
    assert 'no supply_v at run time' in out.out   # REPORT.md, printed


def test_with_node_signal_the_supply_term_is_written_and_the_report_names_the_node_parameters(tmp_path, capsys):
    """``--node-signal supply_v``: the robot feeds the node its supply voltage, so the term is written.

    The file loads where the node is fed supply_v, and is refused, naming the parameter to set, where not.
    """
    cal = load_packaged_calibration('NAVC4058')
    log = tmp_path / 'LOG.csv'
    write_run(log, simulate_run(cal, SimulationSettings(hours=2.0, seed=2, effects=('supply_voltage',))))
    assert main(['fit', str(log), '--rows', '3', '--columns', '2', '--serial', 'NAVC4058', '--node-signal', 'supply_v',
                 '--out', str(tmp_path / 'CAL.yaml'), '--report', str(tmp_path / 'REPORT.json')]) == 0
    written = load_calibration(tmp_path / 'CAL.yaml', expected_serial='NAVC4058')
    assert 'supply_v' in [t.signal for t in written.terms]
    supply = read_log(log, cal.rate_scale_factor, cal.temp_scale_factor).extras['supply_v']
    assert written.signal_ranges == {'supply_v': (float(supply.min()), float(supply.max()))}   # its fitted envelope
    report = json.loads((tmp_path / 'REPORT.json').read_text())
    assert 'supply_v' not in {f['signal'] for f in report['findings_not_written']}
    assert report['written']['terms'] == [t.signal for t in written.terms]
    assert list(report['written']['node_parameters']) == ['extra_signals.supply_v.topic', 'extra_signals.supply_v.type']
    out = capsys.readouterr()
    assert 'gyro_node refuses it unless extra_signals.supply_v.topic is set' in out.err
    assert '`extra_signals.supply_v.topic`' in out.out   # REPORT.md, printed
    assert 'extra_signals.supply_v.topic' in (tmp_path / 'CAL.yaml').read_text()   # the file's comment says it too
    check_fed(written, ('supply_v',), 'the node')
    Compensator(written, feeds=(SignalFeed('supply_v', 5.0),))
    with pytest.raises(CalibrationError, match='extra_signals.supply_v.topic'):
        check_fed(written, (), 'the node')
    # The node's own check of its parameters (ROS types only, no node).
    parameters = pytest.importorskip('art_gyro_calibration.ros.parameters')
    given = {'extra_signals.supply_v.topic': 'battery', 'extra_signals.supply_v.type': 'battery_state'}
    fed, unused = parameters.extra_signal_settings(given, written, 'CAL.yaml')
    assert [(f.signal, f.topic, f.type, f.max_age_s) for f in fed] == [('supply_v', 'battery', 'battery_state', 5.0)]
    assert unused == ()
    with pytest.raises(parameters.ParameterError, match='parameter extra_signals.supply_v.topic'):
        parameters.extra_signal_settings({}, written, 'CAL.yaml')


def test_a_node_signal_must_be_a_column_of_the_log(tmp_path, capsys):
    cal = load_packaged_calibration('NAVC4058')
    log = tmp_path / 'LOG.csv'
    write_run(log, simulate_run(cal, SimulationSettings(hours=0.5, seed=2)))
    for signal, more, message in (('humidity', [], 'the log has no column humidity'),
                                  ('temperature', [], 'derived from the gyro'),
                                  ('supply_v', ['--exclude', 'supply_v'], 'contradict each other')):
        assert main(['fit', str(log), '--rows', '3', '--columns', '2', '--node-signal', signal, *more,
                     '--out', str(tmp_path / 'CAL.yaml'), '--report', str(tmp_path / 'REPORT.json')]) != 0
        err = capsys.readouterr().err
        assert f'--node-signal {signal}' in err and message in err
