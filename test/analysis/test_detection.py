"""Detection limits: what a log would have found, checked by injecting effects at its limit.

Logs are 2 h at 10 Hz. The supply voltage (an extra column, the form c * supply_v) and the
Shupe term (c * dT/dt) are injected at twice and half the limit the loop reported for the
same log without them (same seed: the same noise). Measured while this was written (seeds 0-2,
factors 0.5, 1, 2, 3, 4): the supply voltage found at 2x in 3 of 3 and at 1x in 2 of 3, the Shupe
term at 2x in 2 of 3 (seed 0 not up to 4x), a drift (c t) only from 3-4x, and none at 0.5x. With the
temperature rate's local quadratic fit (issue 35) the Shupe term is found at 2x on seed 2, at 3x on
seed 1, not up to 4x on seeds 0 and 3: the limit is a lower bound (detection.py), further below for
the Shupe form than before.
"""

import json
import math

import pytest

from art_gyro_calibration.calibration import load_packaged_calibration
from art_gyro_calibration.analysis.detection import FAR_EXTRAPOLATION, length_scaling
from art_gyro_calibration.analysis.loop import LoopOptions, close_loop
from art_gyro_calibration.analysis.report import build_report, markdown_summary
from art_gyro_calibration.analysis.simulate import SimulationSettings, simulate_run

HOURS, RATE_HZ = 2.0, 10.0


def _run(seed, effects=(), sizes=None, hours=HOURS, rate_hz=RATE_HZ, **settings):
    cal = load_packaged_calibration('NAVC3545')
    sim = simulate_run(cal, SimulationSettings(hours=hours, rate_hz=rate_hz, seed=seed, effects=effects,
                                               effect_sizes=sizes or {}, **settings))
    log = sim.log(cal)
    return log, close_loop(log, 3, 4, LoopOptions(serial_number='NAVC3545'))


def _found(result, signal):
    return any(e.signal == signal for e in (*result.effects, *result.findings))


@pytest.mark.parametrize('signal, effect, seed, factor', [
    ('supply_v', 'supply_voltage', 1, 2.0), ('supply_v', 'supply_voltage', 2, 2.0),
    ('temperature_rate', 'shupe', 1, 3.0), ('temperature_rate', 'shupe', 2, 2.0)])
def test_injected_beyond_the_limit_is_found_at_half_not(seed, signal, effect, factor):
    _, null = _run(seed)
    limit = {d.signal: d for d in null.detection}[signal]
    assert limit.limit_dph > 0.0 and math.isfinite(limit.coefficient)
    _, beyond = _run(seed, (effect,), {effect: factor * limit.coefficient})
    assert _found(beyond, signal), (limit, [e.term.describe() for e in (*beyond.effects, *beyond.findings)])
    # Its size as the loop measures it is the injected one: the limit's units are the loop's.
    size = [e.score.effect_dph for e in (*beyond.effects, *beyond.findings) if e.signal == signal][0]
    assert 0.65 * factor * limit.limit_dph < size < 1.5 * factor * limit.limit_dph
    _, half = _run(seed, (effect,), {effect: 0.5 * limit.coefficient})
    assert not _found(half, signal)


def test_length_scaling_of_a_known_power_law():
    hours = [0.5, 1.0, 2.0]
    by_length = [(h, 2.0 * math.sqrt(2.0) * h ** -0.5) for h in hours]   # 2 deg/h at 2 h
    p, needed, note = length_scaling(by_length, 1.0)
    assert p == pytest.approx(0.5)
    assert needed == pytest.approx(8.0)   # 2 deg/h * (8 h / 2 h)**-0.5 = 1 deg/h
    assert note == ''
    p, needed, note = length_scaling([(h, 3.0) for h in hours], 1.0)   # flat: no length helps
    assert p == pytest.approx(0.0, abs=1e-12) and needed is None and 'does not shrink' in note
    p, needed, note = length_scaling([(h, 100.0 * h ** -0.5) for h in hours], 1.0)
    assert needed > FAR_EXTRAPOLATION * 2.0 and 'extrapolated' in note
    assert length_scaling([(h, 0.5 * h ** -0.5) for h in hours], 1.0)[1] is None   # already below


def test_white_noise_limits_shrink_with_length():
    """Without slow noise the limits fall with the log's length: about hours**-0.5 for most forms.

    Measured on two 4 h logs: the exponents of the 17 forms spread from -0.2 to 1.1 (a part of the
    log covers less of the chamber's range, and this log's own residual enters each limit); the
    median 0.6 and 0.56.
    """
    _, result = _run(1, hours=4.0, rate_hz=2.0, bias_instability_dps=0.0)
    exponents = sorted(d.exponent for d in result.detection if math.isfinite(d.exponent))
    assert len(exponents) >= 10
    assert 0.3 < exponents[len(exponents) // 2] < 1.0


def test_report_fields():
    log, result = _run(1)
    report = build_report(log, result, 100)
    report['detection_limit_dph'] = {d.signal: d.to_dict() for d in result.detection}   # as calibrate fit adds it
    limits = json.loads(json.dumps(report['detection_limit_dph']))
    assert {'supply_v', 'temperature_rate', 'time'} <= set(limits)
    for entry in limits.values():
        assert set(entry) == {'limit_dph', 'shape', 'by_length', 'exponent', 'hours_to_materiality', 'note'}
        assert [round(h, 1) for h, _ in entry['by_length']] == [0.5, 1.0, 2.0]
    above = [name for name, d in limits.items() if d['limit_dph'] is None or d['limit_dph'] > report['materiality_dph']]
    text = markdown_summary(report)
    assert 'What this log cannot see' in text
    assert all(f'**{name}**' in text for name in above)
