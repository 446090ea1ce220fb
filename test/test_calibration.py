"""Calibration files: the report's digits, loading, round trips and refusals."""

import dataclasses
import os
import re
import threading
from pathlib import Path

import numpy as np
import pytest
import yaml

from art_gyro_calibration.calibration import (Calibration, CalibrationError, dump_calibration, find_calibration_file,
                                              flatten, from_parameters, load_calibration, load_packaged_calibration,
                                              write_calibration)
from art_gyro_calibration.model import Continuation
from art_gyro_calibration.terms import Term

REPO = Path(__file__).resolve().parent.parent
# The report itself lives outside the repository (beside it, or beside a directory of worktrees); where it is
# present the transcription is checked against it.
SEED = next((p for d in REPO.parents if (p := d / 'shared' / 'seeds' / '000_e616fa3fb2e01c6d.txt').is_file()),
            REPO.parent / 'shared' / 'seeds' / '000_e616fa3fb2e01c6d.txt')
TRANSCRIPTION = Path(__file__).resolve().parent / 'data' / 'art_report_coefficients.yaml'
NUMBER = r'-?\d+\.\d+'
Section = tuple[str, str, str, list[str]]


def report_sections() -> dict[str, Section]:
    """Per serial, the report's (rows, columns, scale factor, coefficient tokens) as transcribed beside this test."""
    doc = yaml.safe_load(TRANSCRIPTION.read_text(encoding='utf-8'))
    return {serial: (str(s['rows']), str(s['columns']), s['scale_factor'],
                     [t for row in s['coefficients'] for t in row]) for serial, s in doc.items()}


def seed_sections(text: str) -> dict[str, Section]:
    """Per serial, the same read from the report's own text."""
    sections = {}
    for m in re.finditer(r'# Gyro #\d, S/N: (\w+)\s+Polynomial function with ROWS = (\d+), COLUMNS = (\d+), '
                         r'Scale Factor = ([\d.]+):', text):
        rows, columns = int(m.group(2)), int(m.group(3))
        tokens = re.findall(NUMBER, text[m.end():])[:rows * columns]
        sections[m.group(1)] = (m.group(2), m.group(3), m.group(4), tokens)
    return sections


def test_the_report_has_five_gyros_transcribed_as_printed() -> None:
    sections = report_sections()
    assert sorted(sections) == ['NAVC3545', 'NAVC4058', 'NAVC4253', 'NAVC4361', 'NAVC4377']
    assert all(len(tokens) == int(rows) * int(columns) for rows, columns, _, tokens in sections.values())
    if SEED.is_file():
        assert seed_sections(SEED.read_text(encoding='utf-8')) == sections


def test_files_hold_every_printed_digit(serial: str) -> None:
    rows, columns, scale, tokens = report_sections()[serial]
    text = find_calibration_file(serial).read_text(encoding='utf-8')
    body = text[text.index('coefficients:'):]
    assert re.findall(NUMBER, body[:body.index(']')]) == tokens
    assert re.search(rf'^\s+rate_scale_factor: {re.escape(scale)}$', text, re.M)
    assert re.search(rf'^\s+rows: {rows}$', text, re.M) and re.search(rf'^\s+columns: {columns}$', text, re.M)
    cal = load_packaged_calibration(serial)
    np.testing.assert_array_equal(cal.polynomial.coefficients.ravel(), [float(t) for t in tokens])
    assert cal.serial_number == serial and cal.temp_scale_factor == 0.05


def test_files_are_ros2_parameter_files(serial: str) -> None:
    doc = yaml.safe_load(find_calibration_file(serial).read_text(encoding='utf-8'))
    assert list(doc) == ['/**'] and list(doc['/**']) == ['ros__parameters']
    coefficients = doc['/**']['ros__parameters']['polynomial']['coefficients']
    # rcl's YAML parser needs one type per array: every coefficient is written as a float.
    assert all(isinstance(c, float) for c in coefficients)


def test_round_trip_with_extended_terms(tmp_path: Path) -> None:
    base = load_packaged_calibration('NAVC4058')
    cal = Calibration(base.serial_number, base.rate_scale_factor, base.polynomial, base.temperature_range_c,
                      terms=(Term('temperature_rate', 'power', (12.5, 0.01), (1,), rate_powers=(0, 1)),
                             Term('time_since_power_on', 'exp_decay', (0.02,), (), 900.0),
                             Term('time', 'power', (1e-7,), (1,)),
                             Term('temperature_lag', 'power', (1e-3, 2e-5), (1, 2), 600.0),
                             Term('supply_v', 'power', (0.003,), (1,))))
    path = tmp_path / 'cal.yaml'
    write_calibration(path, cal, header='fitted by a test')
    assert path.read_text().startswith('# fitted by a test\n/**:')
    again = load_calibration(path, expected_serial='NAVC4058')
    assert again.terms == cal.terms
    np.testing.assert_array_equal(again.polynomial.coefficients, cal.polynomial.coefficients)


def _params(serial: str = 'NAVC3545') -> dict:
    return load_packaged_calibration(serial).to_parameters()


@pytest.mark.parametrize('change, message', [
    ({'polynomial.coefficients': [1.0] * 11}, 'has 11 numbers'),
    ({'polynomial.coefficients': [1.0] * 11 + ['x']}, r'polynomial.coefficients\[11\] must be a finite number'),
    ({'polynomial.coefficients': [1.0] * 11 + [float('nan')]}, 'finite number'),
    ({'polynomial.rows': 0}, 'polynomial.rows must be a whole number'),
    ({'polynomial.rows': 2.5}, 'polynomial.rows must be a whole number'),
    ({'rate_scale_factor': -0.00305}, 'scale factors must be positive'),
    ({'rate_scale_factor': 'fast'}, 'rate_scale_factor must be a finite number'),
    ({'temperature_range_c': [50.0, 10.0]}, 'min < max'),
    ({'serial_number': 'NAVC 3545'}, 'serial_number must be'),
    ({'extended.signals': ['time']}, "missing parameter 'extended.time.form'"),
    ({'extended.signals': ['time_since_power_on'], 'extended.time_since_power_on.form': 'exp_decay',
      'extended.time_since_power_on.coefficients': [0.1]}, 'time_constant_s must be positive'),
    # Terms the node would apply wrongly from some start: a warm-up counted from the node's start, a heading term.
    ({'extended.signals': ['time'], 'extended.time.form': 'exp_decay', 'extended.time.coefficients': [0.1],
      'extended.time.time_constant_s': 600.0}, "extended.time.form: a warm-up decays from the gyro's power-on"),
    ({'extended.signals': ['angle'], 'extended.angle.form': 'harmonic', 'extended.angle.coefficients': [0.1, 0.2]},
     'extended.angle.form: a term of the heading needs an absolute heading'),
    ({'extended.signals': ['temperature_lag'], 'extended.temperature_lag.form': 'power',
      'extended.temperature_lag.coefficients': [0.1], 'extended.temperature_lag.powers': [1]},
     'time_constant_s must be positive'),
    ({'extended.signals': ['temperature_rate'], 'extended.temperature_rate.form': 'power',
      'extended.temperature_rate.coefficients': [0.1], 'extended.temperature_rate.powers': [1],
      'extended.temperature_rate.rate_powers': [0, 1]}, 'needs 2 coefficients'),
    ({'extended.signals': ['rate'], 'extended.rate.form': 'spline', 'extended.rate.coefficients': [0.1]},
     "form 'spline' is not one of"),
    ({'filters.temperature_rate_tau_s': 0.0}, 'temperature_rate_tau_s must be a positive'),
    ({'temperature_range_c': 25.0}, 'temperature_range_c must be a list of numbers, got 25.0'),
    ({'temperature_warn_range_c': [50.0, 10.0]}, r'temperature_warn_range_c must be \[min, max\] with min < max'),
    ({'temperature_warn_range_c': ['cold', 50.0]}, r'temperature_warn_range_c\[0\] must be a finite number'),
    ({'temperature_range_c': [10.0, 50.0]}, 'temperature_range_c .* and temperature_warn_range_c .* both given'),
    ({'extended.signals': 5}, 'extended.signals must be a list of signal names, got 5'),
    ({'extended.signals': None}, 'extended.signals must be a list of signal names, got None'),
    ({'extended.signals': ['time'], 'extended.time.form': 'power', 'extended.time.coefficients': [0.1],
      'extended.time.powers': 2}, 'extended.time.powers must be a list of whole numbers, got 2'),
])
def test_malformed_parameters_are_refused(change: dict, message: str) -> None:
    params = _params()
    params.update(change)
    with pytest.raises(CalibrationError, match=message) as info:
        from_parameters(params, 'test.yaml')
    assert str(info.value).startswith('test.yaml: ')


@pytest.mark.parametrize('key', ['serial_number', 'rate_scale_factor', 'temp_scale_factor', 'polynomial.rows',
                                 'polynomial.columns', 'polynomial.coefficients'])
def test_missing_keys_are_refused(key: str) -> None:
    params = _params()
    del params[key]
    with pytest.raises(CalibrationError, match=f"missing parameter '{re.escape(key)}'"):
        from_parameters(params, 'test.yaml')


def test_a_report_calibration_has_no_calibrated_range(serial: str) -> None:
    """The report prints no range: the packaged files carry none to clamp to, only a range to warn outside."""
    cal = load_packaged_calibration(serial)
    assert cal.temperature_range_c is None and cal.model.temperature_range_c is None
    assert cal.expected_range_c == cal.temperature_warn_range_c == (10.0, 50.0)
    params = cal.to_parameters()
    assert 'temperature_range_c' not in params
    again = from_parameters(params, 'again.yaml')
    assert (again.temperature_range_c, again.temperature_warn_range_c) == (None, (10.0, 50.0))


def test_a_calibration_without_any_range_is_still_checked_over_every_plausible_temperature() -> None:
    """No range: the model is evaluated at any temperature the node keeps, so it is checked over all of them."""
    params = _params()
    del params['temperature_warn_range_c']
    cal = from_parameters(params, 'test.yaml')
    assert cal.expected_range_c is None and cal.envelope_range_c == (-60.0, 130.0)
    # Finite up to 50 degC, overflowing by 130 degC: without a range it overflows in the envelope; with one that
    # stops short it does not, and is refused only as a correction beyond the unit's range within 10..50 degC.
    params['polynomial.coefficients'] = [0.0] * 3 + [3e304] + [0.0] * 8   # temp**2 rate**0: overflows by 130
    with pytest.raises(CalibrationError, match=r'test.yaml: polynomial.coefficients: .*overflows .*-60..130 degC'):
        from_parameters(params, 'test.yaml')
    with pytest.raises(CalibrationError, match=r'test.yaml: polynomial.coefficients: a correction of .* \(at 50 degC'):
        from_parameters({**params, 'temperature_range_c': [10.0, 50.0]}, 'test.yaml')


def test_bad_files_are_refused_with_their_path(tmp_path: Path) -> None:
    good = find_calibration_file('NAVC4361').read_text()
    cases = {
        'not_yaml.yaml': 'a: [b',
        'no_params.yaml': '/**:\n  other: 1\n',
        'two_nodes.yaml': good + '\nnode2:\n  ros__parameters: {}\n',
        'wrong_count.yaml': good.replace('0.00069842373067,', ''),
        'a_word.yaml': good.replace('0.00069842373067', 'zero'),
    }
    for name, text in cases.items():
        (tmp_path / name).write_text(text)
        with pytest.raises(CalibrationError, match=re.escape(str(tmp_path / name))):
            load_calibration(tmp_path / name)
    with pytest.raises(CalibrationError, match='cannot read'):
        load_calibration(tmp_path / 'absent.yaml')
    (tmp_path / 'NAVC3545.yaml').write_text(good)
    with pytest.raises(CalibrationError, match="serial_number is 'NAVC4361', expected 'NAVC3545'"):
        load_calibration(tmp_path / 'NAVC3545.yaml', expected_serial='NAVC3545')


def test_unknown_serial_names_where_it_looked() -> None:
    with pytest.raises(CalibrationError, match='no calibration file NAVC0000.yaml in'):
        load_packaged_calibration('NAVC0000')


def test_flatten_matches_the_dump() -> None:
    cal = load_packaged_calibration('NAVC4377')
    doc = yaml.safe_load(dump_calibration(cal))
    assert flatten(doc['/**']['ros__parameters']) == cal.to_parameters()


def _cal_text(extra: str = '', serial: str = 'NAVC4058') -> str:
    return find_calibration_file(serial).read_text(encoding='utf-8') + extra


@pytest.mark.parametrize('extra, message', [
    ('    extnded:\n      signals: [time]\n', "unknown key 'extnded.signals' \\(did you mean 'extended.signals'\\?\\)"),
    ('    polynomial_rows: 3\n', "unknown key 'polynomial_rows' \\(did you mean 'polynomial.rows'\\?\\)"),
    ('    extended:\n      signals: [time]\n      time: {form: exp_decay, time_constant_s: 9.0, coefficients: [0.1],'
     ' time_constnt_s: 1.0}\n', "unknown key 'extended.time.time_constnt_s' \\(did you mean "
     "'extended.time.time_constant_s'\\?\\)"),
    ('    extended:\n      signals: [rate]\n      time: {form: exp_decay, time_constant_s: 9.0, coefficients: [0.1]}\n',
     "unknown key 'extended.time.form'"),
])
def test_unknown_keys_are_refused_with_the_closest_name(tmp_path: Path, extra: str, message: str) -> None:
    """A misspelt key used to drop the fitted terms silently."""
    path = tmp_path / 'cal.yaml'
    path.write_text(_cal_text(extra))
    with pytest.raises(CalibrationError, match=f'^{re.escape(str(path))}: {message}'):
        load_calibration(path)


@pytest.mark.parametrize('extended, key', [
    ('{signals: [rate], rate: {form: power, powers: [400], coefficients: [1.0e-9]}}', 'extended.rate'),
    ('{signals: [rate], rate: {form: exp_decay, time_constant_s: 0.001, coefficients: [0.01]}}', 'extended.rate'),
    ('{signals: [temperature_rate], temperature_rate: {form: exp_decay, time_constant_s: 0.0001, '
     'coefficients: [0.01]}}', 'extended.temperature_rate'),
    ('{signals: [time], time: {form: power, powers: [60], coefficients: [1.0e-9]}}', 'extended.time'),
])
def test_terms_that_overflow_in_the_envelope_are_refused(tmp_path: Path, extended: str, key: str) -> None:
    """A power [400] or an exp_decay of a signal that goes negative overflows: the node dropped every frame."""
    path = tmp_path / 'cal.yaml'
    path.write_text(_cal_text(f'    extended: {extended}\n'))
    with pytest.raises(CalibrationError, match=f'^{re.escape(str(path))}: {key}: the .* term overflows'):
        load_calibration(path)


def test_terms_finite_in_the_envelope_are_kept(tmp_path: Path) -> None:
    """A 1 ms warm-up decays to 0 (the time since power-on is never negative); a rate cross term."""
    path = tmp_path / 'cal.yaml'
    path.write_text(_cal_text('    extended: {signals: [time_since_power_on, temperature_lag], time_since_power_on: '
                              '{form: exp_decay, time_constant_s: 0.001, coefficients: [0.01]}, temperature_lag: '
                              '{form: power, powers: [2], rate_powers: [0, 3], time_constant_s: 60.0, '
                              'coefficients: [0.1, 0.2]}}\n'))
    assert [t.signal for t in load_calibration(path).terms] == ['time_since_power_on', 'temperature_lag']


def test_polynomial_that_overflows_is_refused() -> None:
    params = _params()
    params.update({'polynomial.rows': 200, 'polynomial.columns': 1, 'polynomial.coefficients': [1.0] * 200})
    with pytest.raises(CalibrationError, match='^x.yaml: polynomial.coefficients: the polynomial overflows'):
        from_parameters(params, 'x.yaml')


def test_yaml_alias_bomb_fails_fast_naming_the_file(tmp_path: Path) -> None:
    """600 bytes of nested aliases: refused at the first alias, not expanded."""
    lines = ['a0: &a0 [x, x, x, x, x, x, x, x, x]']
    lines += [f'a{i}: &a{i} [' + ', '.join([f'*a{i - 1}'] * 9) + ']' for i in range(1, 12)]
    bomb = tmp_path / 'bomb.yaml'
    bomb.write_text('/**:\n  ros__parameters:\n' + ''.join(f'    {line}\n' for line in lines))
    assert 500 < bomb.stat().st_size < 800
    with pytest.raises(CalibrationError, match=f'^{re.escape(str(bomb))}: not valid YAML: found alias \\*a0') as info:
        load_calibration(bomb)
    assert len(str(info.value)) < 600


def test_large_and_binary_files_are_refused_briefly(tmp_path: Path) -> None:
    big = tmp_path / 'big.yaml'
    big.write_text('/**:\n  ros__parameters:\n    serial_number: "' + 'x' * (2 << 20) + '"\n')
    with pytest.raises(CalibrationError, match='larger than 1048576 bytes'):
        load_calibration(big)
    binary = tmp_path / 'binary.yaml'
    binary.write_bytes(b'\xd0\xff' * 100)
    with pytest.raises(CalibrationError, match=f'^{re.escape(str(binary))}: not UTF-8'):
        load_calibration(binary)
    long_line = tmp_path / 'long.yaml'
    long_line.write_text('a: [' + 'b' * 100_000 + ']]\n')
    with pytest.raises(CalibrationError) as info:
        load_calibration(long_line)
    assert str(info.value).startswith(str(long_line)) and len(str(info.value)) < 600


def test_known_keys_follow_to_parameters() -> None:
    """The known keys are what to_parameters writes, for terms of every form."""
    from art_gyro_calibration.calibration import CALIBRATION_KEYS, TERM_FIELDS, is_calibration_key
    assert set(_params()) <= CALIBRATION_KEYS
    assert TERM_FIELDS == {'form', 'coefficients', 'powers', 'rate_powers', 'time_constant_s', 'fitted_range'}
    assert is_calibration_key('extended.supply_v.powers') and not is_calibration_key('extnded.signals')


def test_calibration_urls_resolve(tmp_path: Path) -> None:
    from art_gyro_calibration.calibration import resolve_calibration_url
    assert resolve_calibration_url('package://art_gyro_calibration/config/NAVC3545.yaml').read_text() == \
        find_calibration_file('NAVC3545').read_text()
    assert resolve_calibration_url(f'file://{tmp_path}/x.yaml') == tmp_path / 'x.yaml'
    assert resolve_calibration_url(str(tmp_path / 'y.yaml')) == tmp_path / 'y.yaml'
    with pytest.raises(CalibrationError, match='no config/NAVC0000.yaml in'):
        resolve_calibration_url('package://art_gyro_calibration/config/NAVC0000.yaml')


def test_calibrate_apply_refuses_what_the_node_refuses(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The same check in calibrate apply: a misspelt key and an overflowing term, file and key named."""
    pytest.importorskip('scipy')
    from art_gyro_calibration.analysis.cli import main
    log = tmp_path / 'LOG.csv'
    log.write_text('t,raw_rate,raw_temp\n' + ''.join(f'{i * 0.1:.6f},3,500\n' for i in range(200)))
    for name, extra, message in (
            ('misspelt.yaml', '    extnded:\n      signals: [time]\n', "unknown key 'extnded.signals'"),
            ('overflow.yaml', '    extended: {signals: [rate], rate: {form: power, powers: [400], '
                              'coefficients: [1.0e-9]}}\n', 'extended.rate: the power term overflows')):
        path = tmp_path / name
        path.write_text(_cal_text(extra))
        assert main(['apply', str(log), '--calibration', str(path), '--out', str(tmp_path / f'{name}.csv')]) == 1
        err = capsys.readouterr().err
        assert f'{path}: {message}' in err, err
        assert not (tmp_path / f'{name}.csv').exists()


def test_a_key_given_twice_is_refused_with_both_lines(tmp_path: Path) -> None:
    """The last of two polynomials won silently: here an all-zero one, the rate uncompensated."""
    text = (REPO / 'config' / 'NAVC3545.yaml').read_text(encoding='utf-8')
    first = next(i for i, line in enumerate(text.splitlines(), 1) if line.strip() == 'polynomial:')
    path = tmp_path / 'twice.yaml'
    path.write_text(text + '    polynomial: {rows: 1, columns: 1, coefficients: [0.0]}\n', encoding='utf-8')
    last = len(text.splitlines()) + 1
    with pytest.raises(CalibrationError, match=f"^{re.escape(str(path))}: .*key 'polynomial' given twice, "
                                               f'on lines {first} and {last}'):
        load_calibration(path)


def test_numbers_in_every_spelling_rcl_reads(tmp_path: Path) -> None:
    """``1e-300`` is a string to YAML 1.1 and a double to rcl: it was refused as "got '1e-300'"."""
    text = (REPO / 'config' / 'NAVC3545.yaml').read_text(encoding='utf-8')
    assert 'filters' not in text
    for spelling, value in (('1e-300', 1e-300), ('2E3', 2e3), ('2.5e3', 2.5e3), ('.5e+1', 5.0), ('30.0', 30.0)):
        path = tmp_path / 'cal.yaml'
        path.write_text(text + f'    filters: {{temperature_rate_tau_s: {spelling}}}\n', encoding='utf-8')
        assert load_calibration(path).filters.temperature_rate_tau_s == value, spelling
    path.write_text(text + "    filters: {temperature_rate_tau_s: '1e3'}\n", encoding='utf-8')
    with pytest.raises(CalibrationError, match="must be a finite number, got '1e3'"):   # quoted: a string to both
        load_calibration(path)


def test_special_files_are_refused_unread(tmp_path: Path) -> None:
    """A FIFO as calibration file blocked the reader for ever (the node's start-up, ignoring SIGINT)."""
    fifo = tmp_path / 'cal.yaml'
    os.mkfifo(fifo)
    errors: list[BaseException] = []

    def load() -> None:
        try:
            load_calibration(fifo)
        except BaseException as e:   # noqa: B036 - handed to the test's thread
            errors.append(e)

    reader = threading.Thread(target=load, daemon=True)
    reader.start()
    reader.join(10.0)
    if reader.is_alive():   # release the blocked reader before failing
        os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
        reader.join(10.0)
        pytest.fail('reading a FIFO blocked')
    assert len(errors) == 1 and str(errors[0]) == f'{fifo}: is a FIFO, not a regular file'
    with pytest.raises(CalibrationError, match='^/dev/null: is a character device, not a regular file$'):
        load_calibration('/dev/null')
    with pytest.raises(CalibrationError, match=f'^{re.escape(str(tmp_path))}: .*(?i:is a directory)'):
        load_calibration(tmp_path)


@pytest.mark.parametrize('change, message', [
    # 3 x 4, row-major, temperature powers 2..0 by rate powers 3..0: index 8 multiplies rate^3 alone.
    ({'polynomial.coefficients': [0.0] * 8 + [1e300, 0.0, 0.0, 0.0]},
     r'polynomial.coefficients: a correction of 9.983e\+305 deg/s \(at -60 degC, -99.9424 deg/s\) exceeds the unit\'s '
     r'range of \+-99.9424 deg/s'),
    ({'polynomial.coefficients': [0.0] * 8 + [1e-3, 0.0, 0.0, 0.0]},
     'polynomial.coefficients: a correction of 998.3 deg/s'),
    ({'rate_scale_factor': 1e300}, r'rate_scale_factor must be in 3.05176e-05..1, got 1e\+300 \(deg/s per count: '
                                   r'a full scale of 3.2768e\+304 deg/s\): no gyro this package reads'),
    ({'rate_scale_factor': 5e-324}, r'rate_scale_factor must be in 3.05176e-05..1, got 4.94066e-324'),
    ({'temp_scale_factor': 1e-9}, 'temp_scale_factor must be in 0.001..1, got 1e-09'),
], ids=['coefficient_1e300', 'coefficient_1e-3', 'rate_scale_huge', 'rate_scale_denormal', 'temp_scale_tiny'])
def test_a_calibration_beyond_the_units_range_is_refused(change: dict, message: str) -> None:
    """Loaded and published 1e303 deg/s, or 0.0017 deg/s for a gyro turning at 10 deg/s."""
    params = _params()
    params.update(change)
    with pytest.raises(CalibrationError, match='^x.yaml: ' + message):
        from_parameters(params, 'x.yaml')


def test_every_packaged_calibration_is_within_its_units_range(serial: str) -> None:
    cal = load_packaged_calibration(serial)
    assert cal.rate_range_dps == pytest.approx(32768 * cal.rate_scale_factor)
    assert load_calibration(REPO / 'config' / 'KVH_DSP1760_EXAMPLE.yaml').rate_range_dps == 490.0


def test_a_continuation_beyond_the_calibrated_range_round_trips_and_is_checked(tmp_path: Path) -> None:
    report = load_packaged_calibration('NAVC3545')
    cal = dataclasses.replace(report, temperature_range_c=(19.0, 46.0), temperature_warn_range_c=None,
                              continuation=Continuation(report.polynomial, None, 'config/NAVC3545.yaml'))
    path = tmp_path / 'cal.yaml'
    write_calibration(path, cal)
    again = load_calibration(path, expected_serial='NAVC3545')
    assert again.continuation is not None and again.model.continuation is again.continuation
    np.testing.assert_array_equal(again.continuation.polynomial.coefficients, report.polynomial.coefficients)
    assert (again.continuation.temperature_range_c, again.continuation.source) == (None, 'config/NAVC3545.yaml')
    assert 'continued by the temperature dependence of the baseline (config/NAVC3545.yaml)' in again.beyond_range
    params = cal.to_parameters()
    assert params['beyond_range.rows'] == 3 and 'beyond_range.temperature_range_c' not in params
    # Only a calibrated range has a beyond.
    no_range = {k: v for k, v in params.items() if k != 'temperature_range_c'}
    with pytest.raises(CalibrationError, match=r"^x.yaml: beyond_range.rows continues the polynomial beyond "
                                               r"temperature_range_c, which is not given"):
        from_parameters(no_range, 'x.yaml')
    # Checked as the polynomial is, over every plausible temperature (it is applied beyond the range).
    for change, message in (({'beyond_range.coefficients': [1.0] * 11}, 'beyond_range.coefficients has 11 numbers'),
                            ({'beyond_range.coefficients': [0.0] * 8 + [1e-3, 0.0, 0.0, 0.0]},
                             'beyond_range.coefficients: a correction of 998.3 deg/s'),
                            ({'beyond_range.source': 3}, 'beyond_range.source must be a string'),
                            ({'beyond_range.temperature_range_c': [40.0, 10.0]},
                             r'beyond_range.temperature_range_c must be \[min, max\]'),
                            ({'beyond_range.colums': 4}, "unknown key 'beyond_range.colums'")):
        with pytest.raises(CalibrationError, match='^x.yaml: ' + message):
            from_parameters({**params, **change}, 'x.yaml')
