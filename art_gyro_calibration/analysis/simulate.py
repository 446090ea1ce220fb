"""Simulated rate-table and thermal-chamber run of one RD2100, for testing the fit and the tracer.

The table steps through positive and negative rates up to the full scale, each step a
whole number of turns, with rests between; the chamber holds and ramps through the
calibrated temperature range and the gyro follows it with a thermal lag. The gyro's
error is its report polynomial (:func:`model.measured_from_true`) plus a turn-on bias,
the Earth's rate, a first-order Gauss-Markov bias instability, white noise and count
quantisation. Switchable effects the ART model lacks:

- ``shupe``: ``c * dT/dt`` (the causally filtered temperature rate, as the tracker computes it),
- ``warmup``: ``a * exp(-time / tau)`` after power-on,
- ``supply_voltage``: ``k * (supply_v - 24 V)``, on an extra log column ``supply_v`` that is written
  whether or not the effect is on (the tracer must find it without being told).

The log holds what a lab would record (raw counts, table rate, supply voltage); the truth
goes to a side file and never into the fit.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.signal import lfilter

from art_gyro_calibration.calibration import Calibration
from art_gyro_calibration.log import GyroLog, write_columns
from art_gyro_calibration.model import measured_from_true
from art_gyro_calibration.signals import SignalFilters, compute_signals

EARTH_RATE_DPS = 15.041 / 3600.0  # sidereal rate, deg/s
ANN_ARBOR_LATITUDE_DEG = 42.3
FULL_SCALE_DPS = 100.0
# Table rates of one cycle (both signs of each); a cycle lasts about 27 minutes.
TABLE_RATES_DPS = (1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0)
SUPPLY_NOMINAL_V = 24.0
# Effect name -> (signal, form, default coefficient, time constant (s), signal's nominal value).
EFFECTS: dict[str, tuple[str, str, float, float, float]] = {
    # 0.24 deg/s per degC/s: 0.004 deg/s (14 deg/h) while the chamber ramps at 1 degC/min.
    'shupe': ('temperature_rate', 'power', 0.24, 0.0, 0.0),
    # 0.02 deg/s decaying over 20 minutes after power-on.
    'warmup': ('time', 'exp_decay', 0.02, 1200.0, 0.0),
    # 0.008 deg/s per volt away from the nominal 24 V, on a supply wandering by about +-0.5 V.
    'supply_voltage': ('supply_v', 'power', 0.008, 0.0, SUPPLY_NOMINAL_V),
}


@dataclass(frozen=True)
class SimulationSettings:
    """What the simulated gyro, table and chamber do; defaults are an RD2100 in a typical lab."""

    hours: float = 2.0
    rate_hz: float = 10.0
    effects: tuple[str, ...] = ()
    seed: int = 0
    latitude_deg: float = ANN_ARBOR_LATITUDE_DEG
    # Angle random walk in deg/sqrt(h); the per-sample noise is arw / 60 * sqrt(rate_hz) deg/s.
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

    def __post_init__(self) -> None:
        unknown = [e for e in self.effects if e not in EFFECTS]
        if unknown:
            raise ValueError(f'unknown effect(s) {unknown}; choose from {", ".join(EFFECTS)}')
        if not (self.hours > 0 and self.rate_hz > 0):
            raise ValueError(f'hours and rate_hz must be positive, got {self.hours}, {self.rate_hz}')


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
    while clock <= end:
        cycle = np.concatenate([TABLE_RATES_DPS, -np.asarray(TABLE_RATES_DPS)])
        for rate in rng.permutation(cycle):
            turns = math.ceil(settings.min_step_s * abs(rate) / 360.0)
            starts += [clock, clock + turns * 360.0 / abs(rate)]
            rates += [float(rate), 0.0]
            clock = starts[-1] + settings.rest_s
    return np.asarray(rates)[np.searchsorted(starts, t, side='right') - 1]


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
    lagged, _ = lfilter([a], [1.0, a - 1.0], chamber, zi=[(1.0 - a) * low])
    return lagged


def simulate_run(calibration: Calibration, settings: SimulationSettings) -> SimulatedRun:
    """Simulate one run of the gyro ``calibration`` describes (its polynomial is the true error)."""
    rng = np.random.default_rng(settings.seed)
    n = int(round(settings.hours * 3600.0 * settings.rate_hz))
    t = np.arange(n) / settings.rate_hz
    table = table_profile(t, settings, rng)
    temp = chamber_profile(t, settings, calibration.temperature_range_c)
    earth = EARTH_RATE_DPS * math.sin(math.radians(settings.latitude_deg))
    turn_on = float(rng.normal(0.0, settings.turn_on_bias_std_dps))
    # Gauss-Markov bias instability: stationary from the first sample.
    phi = math.exp(-1.0 / (settings.rate_hz * settings.bias_instability_tau_s))
    drive = rng.normal(0.0, settings.bias_instability_dps * math.sqrt(1.0 - phi * phi), n)
    drive[0] = rng.normal(0.0, settings.bias_instability_dps)
    instability = lfilter([1.0], [1.0, -phi], drive)
    supply_v = _supply_voltage(t, rng)
    signals = compute_signals(t, table, temp, {'supply_v': supply_v}, SignalFilters())
    effects: dict[str, Any] = {}
    effect_error = np.zeros(n)
    for name in settings.effects:
        signal, form, size, tau, nominal = EFFECTS[name]
        size = settings.effect_sizes.get(name, size)
        x = signals.get(signal) - nominal
        effect_error += size * (np.exp(-x / tau) if form == 'exp_decay' else x)
        effects[name] = {'signal': signal, 'form': form, 'coefficients': [size],
                         **({'powers': [1]} if form == 'power' else {'time_constant_s': tau})}
    true_input = table + earth + turn_on + instability + effect_error
    measured = measured_from_true(calibration.polynomial, true_input, temp)
    noise_dps = settings.arw_deg_rthr / 60.0 * math.sqrt(settings.rate_hz)
    measured += rng.normal(0.0, noise_dps, n)
    columns = {
        't': t,
        'raw_rate': np.round(measured / calibration.rate_scale_factor),
        'raw_temp': np.round(temp / calibration.temp_scale_factor),
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
        'settings': {k: (list(v) if isinstance(v, tuple) else v) for k, v in vars(settings).items()},
    }
    return SimulatedRun(columns, truth)


def _supply_voltage(t: NDArray[np.float64], rng: np.random.Generator) -> NDArray[np.float64]:
    """A 24 V supply wandering slowly by about +-0.5 V (three slow sinusoids) with a little noise."""
    periods = rng.uniform(1200.0, 5400.0, 3)
    phases = rng.uniform(0.0, 2 * math.pi, 3)
    wander = sum(0.2 * np.sin(2 * math.pi * t / p + ph) for p, ph in zip(periods, phases))
    return SUPPLY_NOMINAL_V + wander + rng.normal(0.0, 0.005, len(t))


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
