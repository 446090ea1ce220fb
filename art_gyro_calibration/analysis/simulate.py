"""Simulated rate-table and thermal-chamber run of one RD2100, for testing the fit and the tracer.

The table steps through positive and negative rates up to the full scale, each step a
whole number of turns, with rests between; the chamber holds and ramps through the
calibrated temperature range and the gyro follows it with a thermal lag, warming by itself after
power-on when asked (``self_heating_c``: the gyro's temperature rises by ``dT * (1 - exp(-t / tau))``
from power-on, ``tau`` = ``self_heating_tau_s``; the sensor reads it and the polynomial sees it, and the
chamber's top set point is lowered by ``dT`` so that the warm gyro stays in the calibrated range). The gyro's
error is its report polynomial (:func:`gyro_physics.measured_from_true`) plus a turn-on bias,
the Earth's rate, a first-order Gauss-Markov bias instability, white noise and count
quantisation. Switchable effects the ART model lacks:

- ``shupe``: ``c * dT/dt`` (the causally filtered temperature rate, as the tracker computes it),
- ``warmup``: ``a * exp(-time / tau)`` after power-on,
- ``supply_voltage``: ``k * (supply_v - 24 V)``, on an extra log column ``supply_v`` that is written
  whether or not the effect is on (the tracer must find it without being told).

and effects outside those forms (:data:`WIDER_EFFECTS`), which a loop must find by a wider search
or by its lack-of-fit alarm: a coil whose temperature lags the sensor's, a scale factor in the
cube of temperature, a scale factor in the temperature rate, a linear drift, and a Shupe effect on
the true rate of change of the gyro's temperature (``shupe_true_rate``: a real coil follows its own
temperature, not the node's 120 s filtered rate that ``shupe`` follows).

Slow noise beyond the 300 s bias instability is off by default (``wander_dps``: a Gauss-Markov
bias wander of correlation time ``wander_tau_s``, 1 h; ``rate_random_walk_dph_rthr``). A second run
of the same gyro is the same settings with another seed (:func:`same_gyro`: new noise, turn-on bias
and table order, the same errors); :func:`warm_restart` is a node restart on a gyro powered on
hours before, at whatever heading the table has reached.

The log holds what a lab would record (raw counts, table rate, supply voltage); the truth
goes to a side file and never into the fit.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from art_gyro_calibration.calibration import Calibration
from art_gyro_calibration.gyro_physics import (ANN_ARBOR_LATITUDE_DEG, earth_rate_dps, measured_from_true, to_counts,
                                               white_noise_dps)
from art_gyro_calibration.log import GyroLog
from art_gyro_calibration.signals import SignalFilters, Signals, compute_signals, first_order_smooth
from art_gyro_calibration.units import DEG_PER_H_PER_DPS, SECONDS_PER_HOUR
from art_gyro_calibration.analysis.csv_writer import write_columns

FULL_SCALE_DPS = 100.0
# Table rates of one cycle (both signs of each); a cycle lasts about 27 minutes.
TABLE_RATES_DPS = (1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0)
SUPPLY_NOMINAL_V = 24.0
# Effect name -> (signal, form, default coefficient, time constant (s), signal's nominal value).
EFFECTS: dict[str, tuple[str, str, float, float, float]] = {
    # 0.24 deg/s per degC/s: 0.004 deg/s (14 deg/h) while the chamber ramps at 1 degC/min.
    'shupe': ('temperature_rate', 'power', 0.24, 0.0, 0.0),
    # 0.02 deg/s decaying over 20 minutes after power-on.
    'warmup': ('time_since_power_on', 'exp_decay', 0.02, 1200.0, 0.0),
    # 0.008 deg/s per volt away from the nominal 24 V, on a supply wandering by about +-0.5 V.
    'supply_voltage': ('supply_v', 'power', 0.008, 0.0, SUPPLY_NOMINAL_V),
}
COIL_LAG_TAU_S = 600.0
RESTART_TURN_DPS = 10.0
# Effects no single-signal term of the first loop can express: name -> default size.
WIDER_EFFECTS: dict[str, float] = {
    # Fraction of the polynomial's temperature dependence that follows a coil lagging the sensor by
    # COIL_LAG_TAU_S (first order): the polynomial is evaluated at T + size * (T_coil - T).
    'coil_lag': 1.0,
    # size * rate * u**3, u = temperature scaled to [-1, 1] over the calibrated range: 200 ppm of
    # the rate at the range's ends, 0.02 deg/s at full scale; beyond a 3-row polynomial.
    'rate_t3': 2e-4,
    # size * rate * dT/dt (filtered as the tracker does): 0.013 deg/s at 100 deg/s on a 1 degC/min ramp.
    'rate_temperature_rate': 0.008,
    # size * seconds since power-on: 1.8 deg/h more every hour.
    'drift': 5e-7,
    # size * d/dt of the gyro's true temperature (deg/s per degC/s; a central difference of the noiseless
    # temperature before quantisation, self-heating included): the default is shupe's, 0.24, 0.004 deg/s
    # (14 deg/h) on a 1 degC/min ramp, 0.0064 deg/s at power-on with 4 degC of self-heating over 10 minutes.
    'shupe_true_rate': 0.24,
}
ALL_EFFECTS = (*EFFECTS, *WIDER_EFFECTS)


@dataclass(frozen=True)
class SimulationSettings:
    """What the simulated gyro, table and chamber do; defaults are an RD2100 in a typical lab."""

    hours: float = 2.0
    rate_hz: float = 10.0
    effects: tuple[str, ...] = ()
    seed: int = 0
    latitude_deg: float = ANN_ARBOR_LATITUDE_DEG
    # Angle random walk in deg/sqrt(h); the per-sample noise is arw / 60 * sqrt(rate_hz) deg/s (white_noise_dps).
    arw_deg_rthr: float = 0.1
    turn_on_bias_std_dps: float = 0.005
    bias_instability_dps: float = 0.0003
    bias_instability_tau_s: float = 300.0
    ramp_c_per_min: float = 1.0
    hold_s: float = 900.0
    thermal_lag_s: float = 300.0
    initial_rest_s: float = 60.0
    rest_s: float = 10.0
    min_step_s: float = 30.0
    effect_sizes: dict[str, float] = field(default_factory=dict)
    # Slow bias wander (first-order Gauss-Markov, stationary std in deg/s) and rate random walk.
    wander_dps: float = 0.0
    wander_tau_s: float = 3600.0
    rate_random_walk_dph_rthr: float = 0.0
    # Times (s since power-on) after which the table, at its next step, turns by restart_turn_deg at
    # RESTART_TURN_DPS and rests for initial_rest_s: a node restarted there, on a warm gyro at
    # another heading, takes its static bias.
    restarts_s: tuple[float, ...] = ()
    restart_turn_deg: float = 0.0
    # Self-heating at power-on: the gyro's temperature rises by self_heating_c * (1 - exp(-t / self_heating_tau_s))
    # above the chamber's (lagged) profile, whose top set point is lowered by self_heating_c.
    self_heating_c: float = 0.0
    self_heating_tau_s: float = 900.0

    def __post_init__(self) -> None:
        unknown = [e for e in self.effects if e not in ALL_EFFECTS]
        if unknown:
            raise ValueError(f'unknown effect(s) {unknown}; choose from {", ".join(ALL_EFFECTS)}')
        if not (self.hours > 0 and self.rate_hz > 0):
            raise ValueError(f'hours and rate_hz must be positive, got {self.hours}, {self.rate_hz}')
        if not (math.isfinite(self.self_heating_c) and self.self_heating_c >= 0.0):
            raise ValueError(f'self_heating_c must be a finite number >= 0 (degC), got {self.self_heating_c}')
        if not (math.isfinite(self.self_heating_tau_s) and self.self_heating_tau_s > 0.0):
            raise ValueError(f'self_heating_tau_s must be a positive number of seconds, got {self.self_heating_tau_s}')


@dataclass(frozen=True)
class SimulatedRun:
    """Log columns (as written) and the truth behind them."""

    columns: dict[str, NDArray[np.float64]]
    truth: dict[str, Any]

    def log(self, calibration: Calibration) -> GyroLog:
        """The log as ``read_log`` gives it back: counts scaled by ``calibration``'s factors, ``supply_v`` an extra."""
        c = self.columns
        return GyroLog(c['t'], c['raw_rate'] * calibration.rate_scale_factor,
                       c['raw_temp'] * calibration.temp_scale_factor, c['ref_rate'], {'supply_v': c['supply_v']})


def table_profile(t: NDArray[np.float64], settings: SimulationSettings,
                  rng: np.random.Generator) -> NDArray[np.float64]:
    """Table rate at times ``t``: an initial rest, then steps of whole turns with rests between."""
    starts, rates = [0.0], [0.0]
    clock = settings.initial_rest_s
    end = float(t[-1]) if len(t) else 0.0
    restarts = sorted(settings.restarts_s)
    while clock <= end:
        cycle = np.concatenate([TABLE_RATES_DPS, -np.asarray(TABLE_RATES_DPS)])
        for rate in rng.permutation(cycle):
            while restarts and clock >= restarts[0]:
                restarts.pop(0)
                if settings.restart_turn_deg:
                    starts += [clock, clock + abs(settings.restart_turn_deg) / RESTART_TURN_DPS]
                    rates += [math.copysign(RESTART_TURN_DPS, settings.restart_turn_deg), 0.0]
                    clock = starts[-1]
                clock += settings.initial_rest_s
            turns = math.ceil(settings.min_step_s * abs(rate) / 360.0)
            starts += [clock, clock + turns * 360.0 / abs(rate)]
            rates += [float(rate), 0.0]
            clock = starts[-1] + settings.rest_s
    return np.asarray(rates)[np.searchsorted(starts, t, side='right') - 1]


def _lfilter(b: list[float], a: list[float], x: NDArray[np.float64], zi: list[float] | None = None) -> Any:
    """``scipy.signal.lfilter``, imported when a run is simulated.

    Every ``calibrate`` command's parser reads this module's effect names: imported with it, scipy.signal took most
    of a second of each.
    """
    from scipy.signal import lfilter  # type: ignore[import-untyped]  # scipy ships no types
    return lfilter(b, a, x) if zi is None else lfilter(b, a, x, zi=zi)


def chamber_profile(t: NDArray[np.float64], settings: SimulationSettings,
                    temperature_range_c: tuple[float, float]) -> NDArray[np.float64]:
    """Gyro temperature: chamber holds and ramps between the range's ends, seen through a thermal lag."""
    low, high = temperature_range_c
    ramp_s = (high - low) / settings.ramp_c_per_min * 60.0
    hold = settings.hold_s
    period = 2.0 * (hold + ramp_s)
    phase = np.mod(t - t[0], period)
    chamber = np.select(
        [phase < hold, phase < hold + ramp_s, phase < 2 * hold + ramp_s],
        [np.full_like(phase, low), low + (phase - hold) / ramp_s * (high - low), np.full_like(phase, high)],
        high - (phase - 2 * hold - ramp_s) / ramp_s * (high - low))
    dt = 1.0 / settings.rate_hz
    a = -math.expm1(-dt / settings.thermal_lag_s)
    lagged, _ = _lfilter([a], [1.0, a - 1.0], chamber, zi=[(1.0 - a) * low])
    return np.asarray(lagged, dtype=np.float64)


def self_heating(t: NDArray[np.float64], settings: SimulationSettings) -> NDArray[np.float64]:
    """How far the gyro has warmed itself above the chamber's profile ``t`` s after power-on (degC)."""
    if settings.self_heating_c == 0.0:
        return np.zeros(len(t))
    return settings.self_heating_c * -np.expm1(-t / settings.self_heating_tau_s)


def chamber_range_c(calibration: Calibration, settings: SimulationSettings) -> tuple[float, float]:
    """The chamber's set points: the calibration's range, its top lowered by the self-heating."""
    low, high = _chamber_range_c(calibration)
    if settings.self_heating_c >= high - low:
        raise ValueError(f'self_heating_c {settings.self_heating_c:g} degC must be smaller than the calibrated '
                         f'range {low:g}..{high:g} degC: the warm gyro is kept inside it')
    return low, high - settings.self_heating_c


def gyro_temperature(t: NDArray[np.float64], calibration: Calibration,
                     settings: SimulationSettings) -> NDArray[np.float64]:
    """The gyro's true temperature (before quantisation): the chamber through its lag, plus the self-heating."""
    return chamber_profile(t, settings, chamber_range_c(calibration, settings)) + self_heating(t, settings)


def simulate_run(calibration: Calibration, settings: SimulationSettings) -> SimulatedRun:
    """Simulate one run of the gyro ``calibration`` describes (its polynomial is the true error)."""
    rng = np.random.default_rng(settings.seed)
    n = int(round(settings.hours * SECONDS_PER_HOUR * settings.rate_hz))
    t = np.arange(n) / settings.rate_hz
    table = table_profile(t, settings, rng)
    temp = gyro_temperature(t, calibration, settings)
    earth = earth_rate_dps(settings.latitude_deg)
    turn_on = float(rng.normal(0.0, settings.turn_on_bias_std_dps))
    # Gauss-Markov bias instability: stationary from the first sample.
    phi = math.exp(-1.0 / (settings.rate_hz * settings.bias_instability_tau_s))
    drive = rng.normal(0.0, settings.bias_instability_dps * math.sqrt(1.0 - phi * phi), n)
    drive[0] = rng.normal(0.0, settings.bias_instability_dps)
    instability = _lfilter([1.0], [1.0, -phi], drive)
    supply_v = _supply_voltage(t, rng)
    signals = compute_signals(t, table, temp, {'supply_v': supply_v}, SignalFilters())
    effects: dict[str, Any] = {}
    effect_error = np.zeros(n)
    for name in settings.effects:
        if name not in EFFECTS:
            continue
        signal, form, size, tau, nominal = EFFECTS[name]
        size = settings.effect_sizes.get(name, size)
        x = signals.get(signal) - nominal
        effect_error += size * (np.exp(-x / tau) if form == 'exp_decay' else x)
        effects[name] = {'signal': signal, 'form': form, 'coefficients': [size],
                         **({'powers': [1]} if form == 'power' else {'time_constant_s': tau})}
    wider, polynomial_temp = _wider_effects(signals, settings, _chamber_range_c(calibration))
    for name, (error, entry) in wider.items():
        effect_error += error
        effects[name] = entry
    true_input = table + earth + turn_on + instability + _slow_noise(n, settings) + effect_error
    measured = measured_from_true(calibration.polynomial, true_input, polynomial_temp)
    noise_dps = white_noise_dps(settings.arw_deg_rthr, settings.rate_hz)
    measured += rng.normal(0.0, noise_dps, n)
    columns = {
        't': t,
        'raw_rate': to_counts(measured, calibration.rate_scale_factor),
        'raw_temp': to_counts(temp, calibration.temp_scale_factor),
        'ref_rate': table,
        'supply_v': np.round(supply_v, 3),
    }
    truth = {
        'serial_number': calibration.serial_number,
        'rate_scale_factor': calibration.rate_scale_factor,
        'polynomial': calibration.polynomial.coefficients.tolist(),
        'turn_on_bias_dps': turn_on,
        'earth_rate_dps': earth,
        'white_noise_dps': noise_dps,
        'bias_instability_dps': settings.bias_instability_dps,
        'effects': effects,
        # The node's view of the run's start: power-on, at the table's heading 0.
        'start_s': 0.0,
        'powered_on_at_start': True,
        'heading_at_start_deg': 0.0,
        'settings': {k: (list(v) if isinstance(v, tuple) else v) for k, v in vars(settings).items()
                     if k not in _SELF_HEATING or settings.self_heating_c},   # without it, as before it existed
    }
    if settings.self_heating_c:
        truth['self_heating'] = {'c': settings.self_heating_c, 'time_constant_s': settings.self_heating_tau_s,
                                 'chamber_range_c': list(chamber_range_c(calibration, settings))}
    return SimulatedRun(columns, truth)


_SELF_HEATING = ('self_heating_c', 'self_heating_tau_s')


def _chamber_range_c(calibration: Calibration) -> tuple[float, float]:
    """The chamber's span: the calibration's range (calibrated, or the report's assumed warn range)."""
    span = calibration.expected_range_c
    if span is None:
        raise ValueError(f'calibration {calibration.serial_number} has neither temperature_range_c nor '
                         'temperature_warn_range_c: the simulated chamber needs one of them')
    return span


def effect_size(name: str, settings: SimulationSettings) -> float:
    """Size of effect ``name`` in ``settings``: its ``effect_sizes`` entry, else the default."""
    default = EFFECTS[name][2] if name in EFFECTS else WIDER_EFFECTS[name]
    return settings.effect_sizes.get(name, default)


def _wider_effects(signals: Signals, settings: SimulationSettings, temperature_range_c: tuple[float, float]
                   ) -> tuple[dict[str, tuple[NDArray[np.float64], dict[str, Any]]], NDArray[np.float64]]:
    """Errors (deg/s) and truth entries of the wider effects on, and the temperature the polynomial sees."""
    low, high = temperature_range_c
    u = (signals.temperature - 0.5 * (low + high)) / (0.5 * (high - low))
    out: dict[str, tuple[NDArray[np.float64], dict[str, Any]]] = {}
    polynomial_temp = signals.temperature
    for name in settings.effects:
        if name not in WIDER_EFFECTS:
            continue
        size = effect_size(name, settings)
        error = np.zeros(len(signals))
        if name == 'coil_lag':
            coil = lagged(signals.t, signals.temperature, COIL_LAG_TAU_S)
            polynomial_temp = signals.temperature + size * (coil - signals.temperature)
            entry = {'signal': 'temperature', 'form': 'lagged_polynomial', 'fraction': size,
                     'time_constant_s': COIL_LAG_TAU_S}
        elif name == 'rate_t3':
            error = size * signals.rate * u ** 3
            entry = {'signal': 'rate * u**3', 'form': 'product', 'coefficients': [size],
                     'temperature_range_c': [low, high]}
        elif name == 'shupe_true_rate':
            error = size * true_temperature_rate(signals.t, signals.temperature)
            entry = {'signal': 'true temperature rate', 'form': 'power', 'powers': [1], 'coefficients': [size],
                     'derivative': 'central difference of the noiseless temperature'}
        elif name == 'rate_temperature_rate':
            error = size * signals.rate * signals.temperature_rate
            entry = {'signal': 'rate * temperature_rate', 'form': 'product', 'coefficients': [size]}
        else:  # drift
            error = size * signals.time
            entry = {'signal': 'time', 'form': 'power', 'powers': [1], 'coefficients': [size]}
        out[name] = (error, entry)
    return out, polynomial_temp


def true_temperature_rate(t: NDArray[np.float64], temp: NDArray[np.float64]) -> NDArray[np.float64]:
    """d/dt of the gyro's noiseless temperature (degC/s): central differences, one-sided at the ends."""
    if len(t) < 2:
        return np.zeros(len(t))
    return np.gradient(temp, t)


def lagged(t: NDArray[np.float64], x: NDArray[np.float64], tau_s: float) -> NDArray[np.float64]:
    """``x`` through a first-order lag of ``tau_s`` starting level with it (a coil at the sensor's temperature)."""
    decay = -np.maximum(np.diff(t), 0.0) / tau_s
    out = np.empty(len(x))
    out[0] = x[0]
    if len(x) > 1:
        out[1:] = first_order_smooth(x, decay)
    return out


def _slow_noise(n: int, settings: SimulationSettings) -> NDArray[np.float64]:
    """Bias wander (Gauss-Markov, stationary) plus rate random walk from 0 at power-on, deg/s.

    Drawn from a stream of its own so that runs without them are what they always were.
    """
    out = np.zeros(n)
    if settings.wander_dps <= 0.0 and settings.rate_random_walk_dph_rthr <= 0.0:
        return out
    rng = np.random.default_rng([settings.seed, 1])
    dt = 1.0 / settings.rate_hz
    if settings.wander_dps > 0.0:
        phi = math.exp(-dt / settings.wander_tau_s)
        drive = rng.normal(0.0, settings.wander_dps * math.sqrt(1.0 - phi * phi), n)
        drive[0] = rng.normal(0.0, settings.wander_dps)
        out += _lfilter([1.0], [1.0, -phi], drive)
    if settings.rate_random_walk_dph_rthr > 0.0:
        # K deg/h/sqrt(h) = K / 3600 deg/s per sqrt(3600 s): steps of K / 3600 / 60 * sqrt(dt) deg/s.
        step = settings.rate_random_walk_dph_rthr / DEG_PER_H_PER_DPS / math.sqrt(SECONDS_PER_HOUR) * math.sqrt(dt)
        out += np.cumsum(rng.normal(0.0, step, n))
    return out


def same_gyro(settings: SimulationSettings, seed: int) -> SimulationSettings:
    """Another run of the same gyro: the same errors and effects, new noise, turn-on bias and table order."""
    return replace(settings, seed=seed)


def warm_restart(calibration: Calibration, settings: SimulationSettings, start_s: float,
                 heading_deg: float = 137.0) -> SimulatedRun:
    """A node started ``start_s`` after power-on, for ``settings.hours``: a slice of one longer run.

    At its first step after ``start_s`` the table turns by ``heading_deg`` and rests for
    ``initial_rest_s`` (where the node takes its static bias); the slice begins with that rest.
    The gyro is warm, its slow effects are where power-on left them, the node's filters start
    afresh, and the table stands at ``heading_deg`` (``heading_at_start_deg`` in the truth; the
    samples of a step resolve it to ``rate / rate_hz``). Times stay counted from power-on.
    """
    # Room for the step running at start_s (up to a turn at 1 deg/s), the turn and the rest.
    margin_s = 360.0 / min(TABLE_RATES_DPS) + settings.rest_s + abs(heading_deg) / RESTART_TURN_DPS \
        + settings.initial_rest_s
    long = replace(settings, hours=settings.hours + (start_s + margin_s) / SECONDS_PER_HOUR,
                   restarts_s=(*settings.restarts_s, start_s), restart_turn_deg=heading_deg)
    run = simulate_run(calibration, long)
    t, ref = run.columns['t'], run.columns['ref_rate']
    still = ref == 0.0
    first = int(np.searchsorted(t, start_s))
    # The lengthened rest: the first run of still rows from start_s on lasting initial_rest_s.
    change = np.flatnonzero(np.diff(still[first:].astype(np.int8))) + first + 1
    bounds = np.concatenate([[first], change, [len(t)]])
    begin = next(int(a) for a, b in zip(bounds[:-1], bounds[1:])
                 if still[a] and t[b - 1] - t[a] >= settings.initial_rest_s - 1.5 / settings.rate_hz)
    stop = begin + int(round(settings.hours * SECONDS_PER_HOUR * settings.rate_hz))
    truth = {**run.truth, 'start_s': float(t[begin]), 'powered_on_at_start': False,
             'heading_at_start_deg': heading_deg % 360.0}  # every other step is whole turns; settings: the long run's
    return SimulatedRun({k: v[begin:stop] for k, v in run.columns.items()}, truth)


def _supply_voltage(t: NDArray[np.float64], rng: np.random.Generator) -> NDArray[np.float64]:
    """A 24 V supply wandering slowly by about +-0.5 V (three slow sinusoids) with a little noise."""
    periods = rng.uniform(1200.0, 5400.0, 3)
    phases = rng.uniform(0.0, 2 * math.pi, 3)
    wander = sum(0.2 * np.sin(2 * math.pi * t / p + ph) for p, ph in zip(periods, phases))
    return np.asarray(SUPPLY_NOMINAL_V + wander + rng.normal(0.0, 0.005, len(t)), dtype=np.float64)


def truth_path(log_path: str | os.PathLike[str]) -> Path:
    """Side file of a simulated log: ``LOG.csv`` -> ``LOG.truth.json``."""
    p = Path(log_path)
    return p.with_name(p.stem + '.truth.json')


def write_run(log_path: str | os.PathLike[str], run: SimulatedRun) -> Path:
    """Write the log and its truth side file; returns the side file's path."""
    write_columns(log_path, run.columns, precision=10)
    side = truth_path(log_path)
    side.write_text(json.dumps(run.truth, indent=2) + '\n', encoding='utf-8')
    return side
