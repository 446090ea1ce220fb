"""``calibrate fit`` writes only what the node can run (issue 20 item 4).

The README's 24 h example wrote a ``supply_v`` term and gyro_node refused the file
("extended terms need signals ['supply_v'] that are not available here"). An effect on a
signal the node does not track is a finding, reported with what to do, never written.
"""

import json

from art_gyro_calibration.calibration import check_signals_available, load_calibration, load_packaged_calibration
from art_gyro_calibration.compensation import Compensator
from art_gyro_calibration.analysis.cli import main
from art_gyro_calibration.analysis.simulate import SimulationSettings, simulate_run, write_run


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
