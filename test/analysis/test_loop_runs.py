"""Several runs of one gyro in one loop: a warm-up that one power-on cannot pin down, pinned by three runs."""

import numpy as np
import pytest

from art_gyro_calibration.analysis.loop import LoopOptions, close_loop
from art_gyro_calibration.analysis.replay import COLD_START_NAME, startup_check
from art_gyro_calibration.analysis.report import stage_error
from art_gyro_calibration.analysis.runs import joined
from art_gyro_calibration.analysis.simulate import (EFFECTS, SimulatedRun, SimulationSettings, same_gyro,
                                                    simulate_run, warm_restart)
from art_gyro_calibration.calibration import load_packaged_calibration
from art_gyro_calibration.log import GyroLog
from art_gyro_calibration.signals import POWER_ON_SIGNAL

CAL = load_packaged_calibration('NAVC3545')
# A 0.02 deg/s, 20 min warm-up, the gyro warming itself by 4 degC over 10 min after power-on and its bias
# wandering (0.0005 deg/s over 30 min): in one hour from one power-on the wander and the self-heating's
# temperature terms take the warm-up's place.
SETTINGS = SimulationSettings(hours=1.0, effects=('warmup',), self_heating_c=4.0, self_heating_tau_s=600.0,
                              wander_dps=0.0005, wander_tau_s=1800.0, seed=1)
_, _, AMPLITUDE_DPS, TAU_S, _ = EFFECTS['warmup']


@pytest.fixture(scope='module')
def simulated() -> list[SimulatedRun]:
    """Two cold starts of the gyro (their own turn-on bias, wander and table order) and a warm restart."""
    return [simulate_run(CAL, SETTINGS), simulate_run(CAL, same_gyro(SETTINGS, 2)),
            warm_restart(CAL, same_gyro(SETTINGS, 3), 1.5 * 3600.0)]


@pytest.fixture(scope='module')
def runs(simulated: list[SimulatedRun]) -> list[tuple[str, GyroLog, bool]]:
    """The runs as a several-run fit takes them: (name, log, began at power-on)."""
    names = ('cold1.csv', 'cold2.csv', 'warm.csv')
    return [(name, run.log(CAL), cold) for name, run, cold in zip(names, simulated, (True, True, False))]


def _warm_up(logs: list[tuple[str, GyroLog, bool]]) -> tuple[float, float]:
    """The loop's warm-up on ``logs`` fitted together: amplitude (deg/s) and time constant (s); 0, 0 if none."""
    log, runs = joined(logs)
    result = close_loop(log, CAL.polynomial.rows, CAL.polynomial.columns, LoopOptions(draws=100), runs)
    term = next((t for t in result.extended.terms if t.signal == POWER_ON_SIGNAL), None)
    return (0.0, 0.0) if term is None else (term.coefficients[0], term.time_constant_s)


def test_three_runs_pin_the_warm_up_that_one_power_on_cannot(runs: list[tuple[str, GyroLog, bool]]) -> None:
    amplitude, tau = _warm_up(runs)
    assert amplitude == pytest.approx(AMPLITUDE_DPS, rel=0.1) and tau == pytest.approx(TAU_S, rel=0.2)
    alone, _ = _warm_up(runs[:1])
    assert abs(alone - AMPLITUDE_DPS) > 0.5 * AMPLITUDE_DPS   # measured: 0.0034 deg/s with a 145 s time constant


def test_each_run_keeps_its_turn_on_bias_and_every_start_is_judged(
        simulated: list[SimulatedRun], runs: list[tuple[str, GyroLog, bool]]) -> None:
    log, fitted = joined(runs)
    result = close_loop(log, CAL.polynomial.rows, CAL.polynomial.columns, LoopOptions(draws=100), fitted)
    assert result.runs == fitted and len(result.signals) == len(result.error) == len(log)
    # Each run's turn-on bias less the first's, as the simulator drew them (0.005 deg/s apart, one sigma), to
    # within what the bias wander (0.0005 deg/s) moves a run's mean.
    true = np.array([run.truth['turn_on_bias_dps'] for run in simulated])
    assert result.run_offsets_dps[0] == 0.0
    assert np.array(result.run_offsets_dps) == pytest.approx(true - true[0], abs=0.0015)
    assert np.ptp(true) > 0.003   # they differ by more than that
    # The report's errors: each run started as the node starts it, its own static bias taking its turn-on bias out
    # (as one run, the later runs carried their turn-on bias less the first's).
    error = stage_error(log, result, 100, 'extended')
    steady = result.segments.rows()
    for run in fitted:
        assert abs(np.mean(error[steady[(steady >= run.first_row) & (steady < run.stop)]])) < 0.001
    _, check, names = startup_check(result, log)
    assert check is not None
    assert names[:2] == [f'cold1.csv: {COLD_START_NAME}', f'cold2.csv: {COLD_START_NAME}']
    assert 'warm.csv: from its start (warm)' in names
    assert {name.split(':')[0] for name in names} == {'cold1.csv', 'cold2.csv', 'warm.csv'}


def test_runs_must_lie_end_to_end(runs: list[tuple[str, GyroLog, bool]]) -> None:
    """Runs given with their own clocks (overlapping) are refused: the folds and bins need one clock."""
    log, fitted = joined(runs[:2])
    first = fitted[1].first_row
    overlapping = GyroLog(np.concatenate([log.t[:first], log.t[first:] - log.t[first] + log.t[0]]), log.rate_dps,
                          log.temp_c, log.ref_rate, log.extras)
    with pytest.raises(ValueError, match='run cold2.csv begins before the run before it ended'):
        close_loop(overlapping, CAL.polynomial.rows, CAL.polynomial.columns, LoopOptions(draws=10), fitted)
    with pytest.raises(ValueError, match='do not cover'):
        close_loop(log, CAL.polynomial.rows, CAL.polynomial.columns, LoopOptions(draws=10), fitted[:1])
