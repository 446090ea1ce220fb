"""Benchmark: causal temperature-rate estimators against the true dT/dt, on profiles of known shape.

True temperatures (power-on self-heating, chamber ramps with holds, and shapes no estimator was tuned
on) are measured as an RD2100 gives them (0.05 degC counts at 10 Hz, with 0.01 degC of noise before
the rounding) or as a KVH unit does (floats at 1 kHz, 0.01 degC of noise). Each estimator's rate is
compared with the true dT/dt: rms after the node's static bias refinement (the first 6 min are its
provisional fit's, :mod:`art_gyro_calibration.static_bias`), the mean over the static-bias window
(first 10 s), and the mean magnitude of the error in the 10 min after each change of a chamber's slope
(a slope that changes at once: every causal estimate starts that change behind); in degC/s
and as deg/h of a Shupe coefficient of 2.4 deg/s per degC/s. Then, as the node applies it (``calibrate apply``:
static bias over the first 100 rows, refined, from power-on), a gyro whose error is the packaged NAVC3545
polynomial plus that Shupe effect, corrected by a calibration holding both with the true coefficient (the
true form through the node) and by the same correction on the true rate (the true form on the true signals). Run:
``python bench/bench_temperature_rate.py [--hours 4] [--kvh-hours 1]``. A benchmark, not a test.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from art_gyro_calibration.calibration import load_packaged_calibration
from art_gyro_calibration.compensation import RunStart, apply_calibration
from art_gyro_calibration.gyro_physics import measured_from_true
from art_gyro_calibration.log import GyroLog
from art_gyro_calibration.signals import DEFAULT_TEMPERATURE_RATE_TAU_S, FIRST_ORDER_TAU_S, SignalFilters, \
    compute_signals, first_order_smooth
from art_gyro_calibration.temperature_rate import FIRST_ORDER, LOCAL_QUADRATIC
from art_gyro_calibration.terms import Term

SHUPE_DPS_PER_DEGC_PER_S = 2.4
DPH_PER_DEGC_PER_S = SHUPE_DPS_PER_DEGC_PER_S * 3600.0
COUNT_C = 0.05
NOISE_C = 0.01
WINDOW_S = 10.0
REFINED_FROM_S = 360.0
AFTER_CHANGE_S = 600.0
Array = NDArray[np.float64]
Shape = Callable[[Array], tuple[Array, Array]]   # times to the true temperature and its rate


@dataclass(frozen=True)
class Profile:
    """A true temperature, its rate and the times its slope changes abruptly."""

    name: str
    tuned: bool            # the estimators' settings were chosen on it
    temperature: Shape
    changes_s: tuple[float, ...] = ()


def self_heating(rise_c: float, tau_min: float) -> Shape:
    """``T0 + rise (1 - exp(-t / tau))`` from power-on."""
    tau = 60.0 * tau_min

    def temperature(t: Array) -> tuple[Array, Array]:
        decay = np.exp(-t / tau)
        return 20.0 + rise_c * (1.0 - decay), rise_c / tau * decay
    return temperature


def piecewise(knots_s: tuple[float, ...], rates_c_per_min: tuple[float, ...]) -> Callable[[Array], Array]:
    """Chamber temperature: a constant rate between knots (0 before the first and after the last)."""
    def chamber_rate(t: Array) -> Array:
        rate = np.zeros(len(t))
        for start, stop, r in zip(knots_s[:-1], knots_s[1:], rates_c_per_min):
            rate[(t >= start) & (t < stop)] = r / 60.0
        return rate
    return chamber_rate


def chamber(rise_c: float, tau_min: float, knots_s: tuple[float, ...], rates: tuple[float, ...],
            lag_s: float = 0.0) -> Shape:
    """Self-heating plus ramps (through a first-order lag of ``lag_s``: a chamber's air, then the case)."""
    heat = self_heating(rise_c, tau_min)
    chamber_rate = piecewise(knots_s, rates)

    def temperature(t: Array) -> tuple[Array, Array]:
        base, base_rate = heat(t)
        rate = chamber_rate(t)
        if lag_s > 0.0:   # the rate through the lag, in closed form per step (fine steps: exact enough)
            rate = first_order_smooth(np.concatenate(([0.0], rate)),
                                      np.full(len(t), -(t[1] - t[0]) / lag_s))
        level = np.concatenate(([0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(t))))
        return base + level, base_rate + rate
    return temperature


def sine(amplitude_c: float, period_min: float) -> Shape:
    """A day-night swing, speeded up."""
    w = 2.0 * np.pi / (60.0 * period_min)

    def temperature(t: Array) -> tuple[Array, Array]:
        return 20.0 + amplitude_c * np.sin(w * t), amplitude_c * w * np.cos(w * t)
    return temperature


def two_time_constants(fast: tuple[float, float], slow: tuple[float, float]) -> Shape:
    """Self-heating of electronics (fast) and housing (slow)."""
    a, b = self_heating(*fast), self_heating(*slow)

    def temperature(t: Array) -> tuple[Array, Array]:
        (x1, r1), (x2, r2) = a(t), b(t)
        return x1 + x2 - 20.0, r1 + r2
    return temperature


def profiles() -> list[Profile]:
    """The tuned ones, then the others."""
    knots = (1200.0, 3600.0, 5400.0, 7200.0, 9000.0, 10800.0, 12600.0)
    return [
        Profile('hold (counts alone)', True, lambda t: (np.full(len(t), 20.02), np.zeros(len(t)))),
        Profile('heat 2 degC / 5 min', True, self_heating(2.0, 5.0)),
        Profile('heat 4 degC / 25 min', True, self_heating(4.0, 25.0)),
        Profile('heat 6 degC / 10 min', True, self_heating(6.0, 10.0)),
        Profile('heat 4/25 + ramps 0.5, 1 degC/min', True,
                chamber(4.0, 25.0, knots, (0.5, 0.0, -1.0, 0.0, 0.25, 0.0)), knots),
        Profile('heat 5/10 + ramps 0.1 degC/min', True,
                chamber(5.0, 10.0, knots, (0.1, 0.0, -0.1, 0.0, 0.1, 0.0)), knots),
        Profile('untuned: heat 3/2 min + 3/60 min', False, two_time_constants((3.0, 2.0), (3.0, 60.0))),
        Profile('untuned: sine 5 degC, 60 min', False, sine(5.0, 60.0)),
        Profile('untuned: heat 4/15 + lagged ramps 0.7', False,
                chamber(4.0, 15.0, knots, (0.7, 0.0, -0.7, 0.0, 0.7, 0.0), lag_s=180.0), knots),
        Profile('untuned: door opened (-3 degC, 1 min lag)', False,
                chamber(2.0, 8.0, (3000.0, 3060.0), (-3.0,), lag_s=60.0), (3000.0,)),
    ]


def linear_rate(t: Array, x: Array, tau_s: float) -> Array:
    """Brown's double smoothing's slope, ``(s1 - s2) / tau`` (discounted least squares' line): lag-free on a ramp."""
    decay = np.diff(t) / -tau_s
    s1 = np.concatenate((x[:1], first_order_smooth(x, decay)))
    s2 = np.concatenate((x[:1], first_order_smooth(s1, decay)))
    return (s1 - s2) / tau_s


def candidates() -> list[tuple[str, Callable[[Array, Array], Array]]]:
    """(name, estimator of the rate from times and measured temperatures)."""
    def package(tau_s: float, form: str) -> Callable[[Array, Array], Array]:
        def rate(t: Array, x: Array) -> Array:
            return compute_signals(t, np.zeros(len(t)), x, filters=SignalFilters(tau_s, 0.5, form)).temperature_rate
        return rate

    def linear(tau_s: float) -> Callable[[Array, Array], Array]:
        return lambda t, x: linear_rate(t, x, tau_s)
    out = [(f'first order {tau:g} s', package(tau, FIRST_ORDER)) for tau in (120.0, 30.0)]
    out += [(f'local linear {tau:g} s', linear(tau)) for tau in (10.0, 20.0, 30.0, 60.0)]
    out += [(f'local quadratic {tau:g} s', package(tau, LOCAL_QUADRATIC))
            for tau in (15.0, 20.0, 25.0, 30.0, 45.0, 60.0)]
    return out


def measure(profile: Profile, hours: float, rate_hz: float, counts: bool,
            seed: int) -> dict[str, tuple[float, float, float]]:
    """Per candidate: (rms after the refinement, window mean error, worst after a change), degC/s."""
    t = np.arange(0.0, 3600.0 * hours, 1.0 / rate_hz)
    true, true_rate = profile.temperature(t)
    rng = np.random.default_rng(seed)
    measured = true + rng.normal(0.0, NOISE_C, len(t))
    if counts:
        measured = np.round(measured / COUNT_C) * COUNT_C
    after = t >= REFINED_FROM_S
    window = t < WINDOW_S
    near = np.zeros(len(t), dtype=bool)
    for change in profile.changes_s:
        near |= (t >= change) & (t < change + AFTER_CHANGE_S)
    out = {}
    for name, estimate in candidates():
        error = estimate(t, measured) - true_rate
        worst = float(np.mean(np.abs(error[near]))) if near.any() else float('nan')
        out[name] = (float(np.sqrt(np.mean(error[after] ** 2))), float(np.mean(error[window])), worst)
    return out


def through_the_node(profile: Profile, hours: float, seed: int) -> dict[str, tuple[float, float]]:
    """Per correction: (rms, mean) of the corrected rate after the bias window, deg/s (10 Hz counts)."""
    t = np.arange(0.0, 3600.0 * hours, 0.1)
    true, true_rate = profile.temperature(t)
    rng = np.random.default_rng(seed)
    counts = np.round((true + rng.normal(0.0, NOISE_C, len(t))) / COUNT_C) * COUNT_C
    packaged = load_packaged_calibration('NAVC3545')
    log = GyroLog(t, measured_from_true(packaged.polynomial, SHUPE_DPS_PER_DEGC_PER_S * true_rate, true), counts)
    shupe = (Term('temperature_rate', 'power', (SHUPE_DPS_PER_DEGC_PER_S,), (1,)),)
    out = {}
    for name, filters in (('first order 120 s (old files)', SignalFilters(FIRST_ORDER_TAU_S, 0.5, FIRST_ORDER)),
                          (f'local quadratic {DEFAULT_TEMPERATURE_RATE_TAU_S:g} s (new)', SignalFilters())):
        calibration = replace(packaged, terms=shupe, filters=filters)
        corrected = apply_calibration(log, calibration, 100, start=RunStart(powered_on_at_start=True)).corrected_dps
        out[name] = corrected[100:]
    # The same correction on the true rate (and the counts the node's polynomial sees), its static bias likewise.
    ideal = log.rate_dps - packaged.model.error(compute_signals(t, log.rate_dps, counts)) \
        - SHUPE_DPS_PER_DEGC_PER_S * true_rate
    out['on the true rate'] = (ideal - ideal[:100].mean())[100:]
    return {name: (float(np.sqrt(np.mean(c ** 2))), float(np.mean(c))) for name, c in out.items()}


def main() -> None:
    """Print one table per sampling: each profile's numbers, then each candidate's median."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--hours', type=float, default=4.0, help='length of each 10 Hz profile')
    parser.add_argument('--kvh-hours', type=float, default=1.0, help='length of each 1 kHz profile (0: none)')
    args = parser.parse_args()
    runs = [('RD2100: 0.05 degC counts, 10 Hz', args.hours, 10.0, True)]
    if args.kvh_hours > 0:
        runs.append(('KVH: floats, 1 kHz', args.kvh_hours, 1000.0, False))
    for title, hours, rate_hz, counts in runs:
        print(f'\n## {title}, {hours:g} h; error against the true dT/dt, deg/h of Shupe 2.4 deg/s per degC/s')
        print('rms: after 6 min; window: mean over the first 10 s; change: mean |error| in 10 min after a slope change')
        table: dict[str, list[tuple[float, float, float]]] = {}
        for k, profile in enumerate(profiles()):
            numbers = measure(profile, hours, rate_hz, counts, seed=k)
            print(f'\n{profile.name}' + ('' if profile.tuned else ' (not tuned on)'))
            for name, (rms, window, worst) in numbers.items():
                print(f'  {name:<22} rms {rms * DPH_PER_DEGC_PER_S:7.2f}  window {window * DPH_PER_DEGC_PER_S:8.2f}'
                      f'  change {worst * DPH_PER_DEGC_PER_S:7.2f}  (rms {rms:.2e} degC/s)')
                table.setdefault(name, []).append((rms, window, worst))
        print('\nmedian over the profiles (untuned alone in brackets), deg/h:')
        untuned = [not p.tuned for p in profiles()]
        for name, rows in table.items():
            values = np.array(rows) * DPH_PER_DEGC_PER_S
            rest = values[untuned]
            print(f'  {name:<22} rms {np.median(values[:, 0]):7.2f} ({np.median(rest[:, 0]):6.2f})'
                  f'  change {np.nanmedian(values[:, 2]):7.2f} ({np.nanmedian(rest[:, 2]):6.2f})'
                  f'  rms max {np.max(values[:, 0]):7.2f}')
    print(f'\n## Through the node (calibrate apply, cold start), 10 Hz counts, {args.hours:g} h: corrected rate, deg/h')
    for k, profile in enumerate(profiles()):
        node = through_the_node(profile, args.hours, seed=k)
        cells = (f'{name}: rms {rms * 3600:5.2f} mean {mean * 3600:+6.2f}' for name, (rms, mean) in node.items())
        print(f'{profile.name:<44}' + '  '.join(cells))


if __name__ == '__main__':
    main()
