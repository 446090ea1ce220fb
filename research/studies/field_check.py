"""Field check of the calibration loop (issues 20, 35): a calibration judged on ANOTHER run of the same gyro.

``nice -n 10 .venv/bin/python research/studies/field_check.py --jobs 2`` (``--quick`` for a smoke run of three
cases into ``out/field-check-quick/``) simulates a KVH RD2100 with its own simulator (numpy only, written here from
the physics, independent of ``analysis/simulate.py``), with physics the project's simulator lacks: self-heating at
power-on (one or two time constants, or an S-shaped rise), a Gauss-Markov bias wander, a rate random walk, Shupe on
the true temperature rate, chamber phases of its own (ramps of several speeds, a sinusoid, a cold soak) and effects
of shapes no form of the loop has (heading sawtooth and bump, a temperature step, an aged polynomial). For each case
it writes fit logs (one 6 h run from power-on; and the lab protocol: two cold starts at different chamber
temperatures and a warm restart, 6 h in all) and two second runs of the same gyro (a cold one from power-on and a
warm one three hours after power-on, at another heading), fits with ``calibrate fit`` and applies with ``calibrate
apply`` exactly as the node does (static bias over the first 100 rows, bias included, ``--powered-on-at-start`` on
the cold run). It drives the package only through its command line (subprocess): it never imports
``art_gyro_calibration``.

Calibrations scored on each second run: the gyro's packaged one (``config/<SERIAL>.yaml``), the loop's (single-run
and several-run fits), and two references: **the true form through the node** (the packaged polynomial plus the true
terms with their true coefficients, written as a calibration file and run through ``calibrate apply`` like the
loop's) and **the true form on the true signals** (the same correction from the gyro's true temperature and its true
rate of change, the static bias taken as the node takes it). Score: the corrected rate against the table's true rate
over the run after the bias window, bias included, in deg/h: the mean, the rms of 60 s means and the heading error
after 1 h. Writes ``research/doc/field-check.md``, ``research/doc/figures/field-*.png`` and
``out/field-check/results.json``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

REPO = Path(__file__).resolve().parents[2]
PYTHON = os.environ.get('FIELD_CHECK_PYTHON', sys.executable)  # the interpreter with the package's CLI
SERIAL = 'NAVC3545'
ROWS, COLUMNS = 3, 4
RATE_HZ = 10.0
BIAS_SAMPLES = 100
# The filters `calibrate fit` writes into a new file (the package's SignalFilters defaults; research/tests check they
# agree): a true-form file must name them, since a file naming none keeps the old first-order filter.
FIT_FILTERS = {'temperature_rate_tau_s': 20.0, 'rate_change_tau_s': 0.5, 'temperature_rate_form': 'local_quadratic'}
# Where the robot runs, as its user tells `calibrate fit --operating-range` (issue 35 item 4): the second runs' chamber
# spans 10..49.5 degC, beyond what a 6 h fit log may have logged.
OPERATING_RANGE_C = (10.0, 50.0)
INITIAL_REST_S = 60.0            # >= 100 rows at rest at the start of every log
WARM_START_S = 3 * 3600.0        # the warm second run (and the protocol's warm restart) starts 3 h after power-on
WARM_HEADING_DEG = 137.0
COLD_SECOND_HOURS = 4.0          # the cold second run, from power-on (issue 35's table)
WARM_SECOND_HOURS = 2.0
FIT_HOURS = 6.0                  # the single-run fit log, from power-on
# The lab protocol (issue 35 item 1): (name, hours, chamber degC at power-on, or None for a warm restart).
# The guide's lab protocol (doc/calibration.md): cold starts soaked at the low end and at 40 degC, a warm restart.
PROTOCOL = (('cold1', 3.0, 10.0), ('cold2', 3.0, 40.0), ('warm', 2.0, None))
QUICK_HOURS = 2.0                # --quick: the single-run fit and the cold second run; the protocol's runs a third
LATITUDE_DEG = 42.3
EARTH_RATE_DPS = 15.041 / 3600.0 * math.sin(math.radians(LATITUDE_DEG))
ARW_DEG_RTHR = 0.1               # angle random walk: white rate noise of 0.0053 deg/s at 10 Hz
TURN_ON_BIAS_STD_DPS = 0.005     # a new turn-on bias at every power-on
CHAMBER_LAG_S = 300.0            # gyro case lagging the chamber air
CHAMBER_LOW_C, CHAMBER_TOP_C = 10.0, 49.5   # the gyro (self-heating included) stays in the calibration's 10..50 degC
TABLE_RATES_DPS = (1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0)
BLOCK_S = 60.0                   # low-pass of the score: 60 s means
DPH = 3600.0                     # deg/h per deg/s
# Issue 35's targets.
WRITTEN_VS_NODE = 1.5            # the written calibration within this times the true form through the node (median)
NODE_VS_SIGNALS = 1.5            # the true form through the node within this times the true form on the true signals
WORSE_DPH = 1.0                  # no null run worse than the packaged calibration by more than this
MULTI = 'loop_multi'             # the label of the several-run fit
REFERENCES = ('true_node', 'true_signals')
# Figure colours (a loop's single-run fit: red).
# The case (the first of these in the results) whose cold second run the time figure follows.
TIME_CASES = ('shupe2.4_warmup', 'shupe_warmup', 'shupe_k2.4_slow')
COLOURS = {'baseline': '#7f7f7f', MULTI: '#9467bd', 'true_node': '#1f77b4', 'true_signals': '#2ca02c'}


# ---------------------------------------------------------------------------------------------------------
# The gyro: the ART polynomial of one packaged gyro, read from its YAML file.

@dataclass(frozen=True)
class Gyro:
    """One RD2100: its error polynomial (deg/s; rows powers of temperature, columns powers of rate)."""

    serial: str
    rate_scale: float
    temp_scale: float
    coefficients: tuple[tuple[float, ...], ...]

    @classmethod
    def packaged(cls, serial: str) -> 'Gyro':
        """The gyro whose true polynomial is its packaged calibration's."""
        p = yaml.safe_load((REPO / 'config' / f'{serial}.yaml').read_text())['/**']['ros__parameters']
        rows, cols = int(p['polynomial']['rows']), int(p['polynomial']['columns'])
        c = [float(x) for x in p['polynomial']['coefficients']]
        return cls(serial, float(p['rate_scale_factor']), float(p['temp_scale_factor']),
                   tuple(tuple(c[i * cols:(i + 1) * cols]) for i in range(rows)))

    def comp(self, rate: np.ndarray, temp: np.ndarray) -> np.ndarray:
        """The polynomial error, deg/s: sum_ij c[i][j] temp^(rows-1-i) rate^(cols-1-j) (Horner in both)."""
        out = np.zeros_like(rate)
        for row in self.coefficients:
            inner = np.zeros_like(rate)
            for c in row:
                inner = inner * rate + c
            out = out * temp + inner
        return out


# ---------------------------------------------------------------------------------------------------------
# The physics of a case: the same gyro in every run of the case (polynomial, self-heating, effect sizes).

@dataclass(frozen=True)
class Physics:
    """What the gyro and its chamber do beyond the polynomial; sizes in deg/h unless named otherwise."""

    self_heat_c: float = 4.0              # temperature rise after power-on (degC)
    self_heat_tau_s: float = 1500.0       # its time constant
    self_heat_shape: float = 1.0          # rise c (1 - exp(-(t/tau)^shape)): 1 exponential, 2 S-shaped
    self_heat2_c: float = 0.0             # a second, slower rise (degC), exponential
    self_heat2_tau_s: float = 2400.0
    wander_dph: float = 1.5               # Gauss-Markov bias wander, stationary sigma
    wander_tau_s: float = 3600.0
    rrw_dph_rthr: float = 0.5             # rate random walk (deg/h per sqrt(h))
    ramp_c_per_min: float = 0.5           # chamber ramp rate
    chamber_start_c: float = 0.0          # chamber (and soaked gyro) at power-on; 0: an ambient 18-26 degC
    chamber_sine_c: float = 0.0           # > 0: after the first hold the chamber swings +-this (degC) ...
    chamber_sine_period_s: float = 5400.0  # ... with this period, instead of ramps and holds
    shupe_k: float = 0.0                  # deg/s per degC/s of the gyro's temperature rate
    warmup_dph: float = 0.0               # a * exp(-t_since_power_on / tau)
    warmup_tau_s: float = 1200.0
    heading_saw_dph: float = 0.0          # sawtooth over heading mod 360: -A at 0 deg rising to +A at 360
    heading_bump_dph: float = 0.0         # a bump of A at heading 90 deg, 25 deg wide (sigma)
    temp_step_dph: float = 0.0            # +A when the gyro is above temp_step_c
    temp_step_c: float = 32.0
    aged_dph_per_c: float = 0.0           # the gyro's bias slope moved since its report (about 30 degC)

    @property
    def heat_c(self) -> float:
        """The whole self-heating (degC)."""
        return self.self_heat_c + self.self_heat2_c

    def heating(self, t_po: np.ndarray) -> np.ndarray:
        """The gyro's temperature rise over its case (degC) at each time since power-on."""
        heat: np.ndarray = (self.self_heat_c * (1.0 - np.exp(-(t_po / self.self_heat_tau_s) ** self.self_heat_shape))
                            + self.self_heat2_c * (1.0 - np.exp(-t_po / self.self_heat2_tau_s)))
        return heat

    @property
    def formless(self) -> list[str]:
        """The effects no form of the loop (or no calibration file the node takes) has."""
        return [name for name, size in (('heading sawtooth', self.heading_saw_dph),
                                        ('heading bump', self.heading_bump_dph),
                                        ('temperature step', self.temp_step_dph)) if size]

    def effect_dps(self, t_po: np.ndarray, temp: np.ndarray, dtemp: np.ndarray,
                   heading: np.ndarray) -> np.ndarray:
        """The deterministic error beyond the polynomial (deg/s), at each row."""
        e: np.ndarray = self.shupe_k * dtemp
        e = e + self.warmup_dph / DPH * np.exp(-t_po / self.warmup_tau_s)
        h = np.mod(heading, 360.0)
        e = e + self.heading_saw_dph / DPH * (2.0 * h / 360.0 - 1.0)
        d = np.mod(heading - 90.0 + 180.0, 360.0) - 180.0
        e = e + self.heading_bump_dph / DPH * np.exp(-0.5 * (d / 25.0) ** 2)
        e = e + self.temp_step_dph / DPH * (temp > self.temp_step_c)
        e = e + self.aged_dph_per_c / DPH * (temp - 30.0)
        return e


@dataclass(frozen=True)
class Case:
    """A named gyro and its physics; seeds fix every run. ``reps``: runs of this case (0: the study's default)."""

    name: str
    physics: Physics
    seed: int
    note: str = ''
    reps: int = 0


CASES = (
    Case('null_quiet', Physics(self_heat_c=3.0, self_heat_tau_s=900.0, wander_dph=1.0, wander_tau_s=1800.0),
         101, 'no effect; mild self-heating (3 degC, 15 min), wander 1 deg/h, 0.5 h'),
    Case('null_wander', Physics(self_heat_c=4.0, self_heat_tau_s=1500.0, wander_dph=3.6, wander_tau_s=3600.0),
         102, 'no effect; slow bias wander 3.6 deg/h, 1 h (the issue 20 null)'),
    Case('null_hot_fast', Physics(self_heat_c=6.0, self_heat_tau_s=300.0, wander_dph=2.0, wander_tau_s=7200.0,
                                  rrw_dph_rthr=1.0),
         103, 'no effect; fast strong self-heating (6 degC, 5 min), wander 2 deg/h, 2 h, RRW 1'),
    Case('null_cold_soak_two_tau', Physics(self_heat_c=2.0, self_heat_tau_s=300.0, self_heat2_c=3.0,
                                           self_heat2_tau_s=3000.0, chamber_start_c=10.0),
         119, 'no effect; powered on after a cold soak at 10 degC; self-heating in two time constants (2 degC in '
         '5 min + 3 degC in 50 min)'),
    Case('null_sine_s_curve', Physics(self_heat_c=4.0, self_heat_tau_s=900.0, self_heat_shape=2.0,
                                      chamber_sine_c=10.0, chamber_sine_period_s=3600.0, wander_dph=2.0),
         120, 'no effect; a sinusoidal chamber (+-10 degC, 60 min period); S-shaped self-heating (4 degC, '
         '1 - exp(-(t / 15 min)^2))'),
    Case('shupe_slow_heat', Physics(self_heat_c=4.0, self_heat_tau_s=1500.0, shupe_k=0.6),
         104, 'Shupe k = 0.6 deg/s per degC/s (18 deg/h on 0.5 degC/min ramps); self-heating 4 degC, 25 min'),
    Case('shupe_fast_heat', Physics(self_heat_c=5.0, self_heat_tau_s=600.0, shupe_k=0.6, wander_dph=2.0),
         105, 'Shupe k = 0.6; self-heating 5 degC, 10 min'),
    Case('shupe_k2.4_slow', Physics(self_heat_c=4.0, self_heat_tau_s=1500.0, shupe_k=2.4, ramp_c_per_min=0.1),
         106, 'issue 35\'s first row: Shupe k = 2.4, chamber ramps 0.1 degC/min (14 deg/h); self-heating 4 degC, '
         '25 min'),
    Case('shupe2.4_fast_heat', Physics(self_heat_c=5.0, self_heat_tau_s=600.0, shupe_k=2.4, ramp_c_per_min=0.1),
         113, 'issue 35\'s second row: Shupe k = 2.4, ramps 0.1 degC/min; self-heating 5 degC, 10 min'),
    Case('shupe2.4_warmup', Physics(self_heat_c=4.0, self_heat_tau_s=1500.0, shupe_k=2.4, ramp_c_per_min=0.1,
                                    warmup_dph=43.2, warmup_tau_s=1200.0),
         114, 'issue 35\'s third row: Shupe k = 2.4 and a 0.012 deg/s (43.2 deg/h) warm-up of 20 min; ramps 0.1 '
         'degC/min; self-heating 4 degC, 25 min'),
    Case('shupe_two_tau_sine', Physics(self_heat_c=2.5, self_heat_tau_s=300.0, self_heat2_c=2.5,
                                       self_heat2_tau_s=2400.0, shupe_k=0.6, chamber_sine_c=8.0,
                                       chamber_sine_period_s=5400.0),
         117, 'Shupe k = 0.6; self-heating in two time constants (2.5 degC in 5 min + 2.5 degC in 40 min); a '
         'sinusoidal chamber (+-8 degC, 90 min period)'),
    Case('shupe_s_curve_fast_ramps', Physics(self_heat_c=4.0, self_heat_tau_s=900.0, self_heat_shape=2.0,
                                             shupe_k=0.6, ramp_c_per_min=1.5),
         118, 'Shupe k = 0.6; S-shaped self-heating (4 degC, 1 - exp(-(t / 15 min)^2)); chamber ramps 1.5 degC/min'),
    Case('warmup', Physics(self_heat_c=2.0, self_heat_tau_s=600.0, warmup_dph=8.0, warmup_tau_s=1200.0),
         107, 'warm-up 8 deg/h, 20 min; self-heating 2 degC, 10 min'),
    Case('warmup_0.012', Physics(self_heat_c=4.0, self_heat_tau_s=1500.0, warmup_dph=43.2, warmup_tau_s=1200.0,
                                 ramp_c_per_min=0.1),
         115, 'issue 35\'s fourth row: the 0.012 deg/s (43.2 deg/h), 20 min warm-up alone; ramps 0.1 degC/min; '
         'self-heating 4 degC, 25 min'),
    Case('warmup_4c10m', Physics(self_heat_c=4.0, self_heat_tau_s=600.0, warmup_dph=9.0, warmup_tau_s=1200.0),
         116, 'issue 35 item 5\'s cell: warm-up 9 deg/h, 20 min; self-heating 4 degC, 10 min; ramps 0.5 degC/min; '
         'five runs', reps=5),
    Case('shupe_warmup', Physics(self_heat_c=4.0, self_heat_tau_s=1500.0, shupe_k=0.6, warmup_dph=6.0,
                                 warmup_tau_s=1200.0, wander_dph=1.0),
         108, 'Shupe k = 0.6 and warm-up 6 deg/h, 20 min; self-heating 4 degC, 25 min'),
    Case('shupe_warmup_cold_soak', Physics(self_heat_c=4.0, self_heat_tau_s=1500.0, shupe_k=0.6, warmup_dph=6.0,
                                           chamber_start_c=10.0, ramp_c_per_min=1.0),
         121, 'Shupe k = 0.6 and warm-up 6 deg/h, 20 min, powered on after a cold soak at 10 degC; ramps 1 degC/min'),
    # Added after the loop's fourth pass was tuned on the cases above (issue 35, third session): physics it was
    # not tuned on.
    Case('shupe1.2_two_tau_slow_ramps', Physics(self_heat_c=3.0, self_heat_tau_s=400.0, self_heat2_c=2.0,
                                                self_heat2_tau_s=3000.0, shupe_k=1.2, ramp_c_per_min=0.3),
         122, 'Shupe k = 1.2 on 0.3 degC/min ramps (22 deg/h); self-heating in two time constants (3 degC in '
         '7 min + 2 degC in 50 min); two runs', reps=2),
    Case('fast_warmup_shupe', Physics(self_heat_c=3.0, self_heat_tau_s=1200.0, shupe_k=0.6, warmup_dph=20.0,
                                      warmup_tau_s=400.0, ramp_c_per_min=0.25, wander_dph=2.0),
         123, 'a fast warm-up (20 deg/h, 7 min) beside Shupe k = 0.6 on 0.25 degC/min ramps; self-heating 3 degC, '
         '20 min; two runs', reps=2),
    Case('aged_poly_shupe', Physics(aged_dph_per_c=0.2, shupe_k=1.0, self_heat_c=4.0, self_heat_tau_s=900.0,
                                    ramp_c_per_min=0.3),
         124, 'bias slope moved by 0.2 deg/h per degC since the report, and Shupe k = 1.0 on 0.3 degC/min ramps; '
         'self-heating 4 degC, 15 min; two runs', reps=2),
    Case('null_s_curve_slow_ramps', Physics(self_heat_c=5.0, self_heat_tau_s=1200.0, self_heat_shape=2.0,
                                            ramp_c_per_min=0.1, wander_dph=2.5, wander_tau_s=5400.0),
         125, 'no effect; S-shaped self-heating (5 degC, 1 - exp(-(t / 20 min)^2)), ramps 0.1 degC/min, wander '
         '2.5 deg/h, 1.5 h; two runs', reps=2),
    Case('heading_saw', Physics(heading_saw_dph=6.0, wander_dph=1.0), 109,
         'sawtooth over heading mod 360, +-6 deg/h'),
    Case('heading_bump', Physics(heading_bump_dph=10.0, wander_dph=1.0), 110,
         'bump of 10 deg/h at heading 90 deg (sigma 25 deg)'),
    Case('temp_step', Physics(temp_step_dph=6.0, wander_dph=1.0), 111,
         'step of +6 deg/h above 32 degC'),
    Case('aged_poly', Physics(aged_dph_per_c=0.25, wander_dph=1.0), 112,
         'bias slope moved by 0.25 deg/h per degC since the report (+-5 deg/h over 10..50 degC); no other effect'),
)
QUICK_CASES = ('null_wander', 'shupe2.4_warmup', 'heading_bump')


# ---------------------------------------------------------------------------------------------------------
# Profiles: the rate table and the chamber.

def table_profile(rng: np.random.Generator, t: np.ndarray) -> np.ndarray:
    """Table rate (deg/s) at every t: a rest, then steps of +-1..100 deg/s, each followed by a rest."""
    edges, rates = [0.0, INITIAL_REST_S], [0.0]
    while edges[-1] < t[-1] + 1.0:
        r = float(rng.choice(TABLE_RATES_DPS)) * float(rng.choice((-1.0, 1.0)))
        hold = float(rng.uniform(30.0, 120.0)) * (2.0 if abs(r) <= 2.0 else 1.0)
        rest = float(rng.uniform(10.0, 40.0))
        rates += [r, 0.0]
        edges += [edges[-1] + hold, edges[-1] + hold + rest]
    rates.append(0.0)
    return np.asarray(rates)[np.searchsorted(np.asarray(edges), t, side='right') - 1]


def chamber_profile(rng: np.random.Generator, t: np.ndarray, phys: Physics, start_c: float | None = None) -> np.ndarray:
    """Chamber air (degC): a hold at the start, then ramps to set points and holds, or a sinusoid.

    The start is an ambient 18-26 degC unless the case (a cold soak) or the run (the lab protocol) sets it; set
    points are drawn in 10 degC..(49.5 degC less the self-heating), at least 8 degC apart.
    """
    top = CHAMBER_TOP_C - phys.heat_c
    start = float(rng.uniform(18.0, 26.0))
    start = start_c if start_c is not None else (phys.chamber_start_c or start)
    hold = float(rng.uniform(600.0, 1500.0))
    if phys.chamber_sine_c > 0.0:
        start = min(max(start, CHAMBER_LOW_C + phys.chamber_sine_c), top - phys.chamber_sine_c)
        swing: np.ndarray = start + phys.chamber_sine_c * np.sin(
            2.0 * math.pi * np.maximum(t - hold, 0.0) / phys.chamber_sine_period_s)
        return swing
    start = min(max(start, CHAMBER_LOW_C), top)
    knots_t, knots_c = [0.0, hold], [start, start]
    while knots_t[-1] < t[-1]:
        target = float(rng.uniform(CHAMBER_LOW_C, top))
        while abs(target - knots_c[-1]) < 8.0:
            target = float(rng.uniform(CHAMBER_LOW_C, top))
        ramp_s = abs(target - knots_c[-1]) / phys.ramp_c_per_min * 60.0
        knots_t += [knots_t[-1] + ramp_s, knots_t[-1] + ramp_s + float(rng.uniform(900.0, 2400.0))]
        knots_c += [target, target]
    profile: np.ndarray = np.interp(t, knots_t, knots_c)
    return profile


def first_order(x: np.ndarray, dt: float, tau: float) -> np.ndarray:
    """The input through a first-order lag (exact for a piecewise-linear input at this step), from equilibrium."""
    a = math.exp(-dt / tau)
    y = np.empty_like(x)
    y[0] = x[0]
    for k in range(1, len(x)):
        y[k] = a * y[k - 1] + (1.0 - a) * x[k]
    return y


def gauss_markov(rng: np.random.Generator, n: int, dt: float, sigma: float, tau: float) -> np.ndarray:
    """A first-order Gauss-Markov process (stationary from its first sample)."""
    a = math.exp(-dt / tau)
    drive = sigma * math.sqrt(1.0 - a * a) * rng.standard_normal(n)
    y = np.empty(n)
    y[0] = sigma * rng.standard_normal()
    for k in range(1, n):
        y[k] = a * y[k - 1] + drive[k]
    return y


# ---------------------------------------------------------------------------------------------------------
# One run.

def simulate(gyro: Gyro, phys: Physics, hours: float, seed: int, power_on_offset_s: float,
             heading0_deg: float, chamber_start_c: float | None = None) -> dict[str, np.ndarray]:
    """One run of the gyro: every array at RATE_HZ, truth included (never written to the log)."""
    rng = np.random.default_rng(seed)
    dt = 1.0 / RATE_HZ
    n = int(round(hours * 3600.0 * RATE_HZ))
    t = np.arange(n) * dt
    t_po = t + power_on_offset_s
    # Slow quantities on a 1 s grid, interpolated.
    ts = np.arange(0.0, t[-1] + 2.0, 1.0)
    chamber = chamber_profile(rng, ts, phys, chamber_start_c)
    case_c = first_order(chamber, 1.0, CHAMBER_LAG_S)
    temp_s = case_c + phys.heating(ts + power_on_offset_s)
    dtemp_s = np.gradient(temp_s, ts)
    wander_s = gauss_markov(rng, len(ts), 1.0, phys.wander_dph / DPH, phys.wander_tau_s)
    rrw_per_step = phys.rrw_dph_rthr / DPH * math.sqrt(1.0 / 3600.0)
    rrw_s = np.cumsum(rrw_per_step * rng.standard_normal(len(ts)))
    temp = np.interp(t, ts, temp_s)
    dtemp = np.interp(t, ts, dtemp_s)
    slow = np.interp(t, ts, wander_s + rrw_s)
    rate = table_profile(rng, t)
    heading = heading0_deg + np.concatenate(([0.0], np.cumsum(rate[:-1]) * dt))
    turn_on = TURN_ON_BIAS_STD_DPS * rng.standard_normal()
    effect = phys.effect_dps(t_po, temp, dtemp, heading)
    base = rate + EARTH_RATE_DPS + turn_on + slow + effect
    # The reading carries the polynomial at the reading itself (as the node evaluates it): a fixed point.
    reading = base.copy()
    for _ in range(4):
        reading = base + gyro.comp(reading, temp)
    white = ARW_DEG_RTHR / 60.0 * math.sqrt(RATE_HZ) * rng.standard_normal(n)
    measured = reading + white
    return {'t': t, 'raw_rate': np.round(measured / gyro.rate_scale), 'raw_temp': np.round(temp / gyro.temp_scale),
            'ref_rate': rate, 'temp': temp, 'heading': heading, 'true_error': gyro.comp(reading, temp) + effect,
            'measured': measured}


def write_log(run: dict[str, np.ndarray], path: Path) -> None:
    """The log as `calibrate` reads it (and the node's log_path writes it): t, raw_rate, raw_temp, ref_rate."""
    data = np.column_stack([run['t'], run['raw_rate'], run['raw_temp'], run['ref_rate']])
    np.savetxt(path, data, fmt=['%.1f', '%d', '%d', '%.6g'], delimiter=',', header='t,raw_rate,raw_temp,ref_rate',
               comments='')


# ---------------------------------------------------------------------------------------------------------
# Scoring.

def score(error_dps: np.ndarray) -> dict[str, float]:
    """Error after the bias window, bias included: mean, rms of 60 s means (deg/h), heading after 1 h (deg)."""
    e = error_dps[BIAS_SAMPLES:]
    per = int(BLOCK_S * RATE_HZ)
    blocks = e[:len(e) // per * per].reshape(-1, per).mean(axis=1)
    hour = e[:int(3600 * RATE_HZ)]
    return {'mean_dph': float(e.mean() * DPH), 'sys_rms_dph': float(np.sqrt(np.mean(blocks ** 2)) * DPH),
            'heading_1h_deg': float(hour.sum() / RATE_HZ)}


def true_signals_error(run: dict[str, np.ndarray]) -> np.ndarray:
    """The true form on the true signals: the true error removed, then the node's static bias."""
    corrected: np.ndarray = run['measured'] - run['true_error']
    corrected = corrected - corrected[:BIAS_SAMPLES].mean()
    error: np.ndarray = corrected - run['ref_rate']
    return error


def true_form_file(phys: Physics, path: Path) -> bool:
    """The true form as a calibration file the node takes, written to `path`; False when no such file exists.

    The packaged file (`config/<SERIAL>.yaml`: its polynomial, scale factors and warned range), its polynomial
    moved by an aged bias slope, plus the true terms with their true coefficients as `calibrate fit` writes them:
    Shupe as a linear term on `temperature_rate`, the warm-up as an exponential on `time_since_power_on`, with the
    filters `calibrate fit` writes (the package's defaults: a file that names none keeps the old first-order filter).
    A heading effect or a temperature step has no form.
    """
    if phys.formless:
        return False
    cal = yaml.safe_load((REPO / 'config' / f'{SERIAL}.yaml').read_text())
    p = cal['/**']['ros__parameters']
    if phys.aged_dph_per_c:
        c = [float(x) for x in p['polynomial']['coefficients']]
        cols = int(p['polynomial']['columns'])
        c[-1 - cols] += phys.aged_dph_per_c / DPH            # temperature^1 x rate^0
        c[-1] -= 30.0 * phys.aged_dph_per_c / DPH            # temperature^0 x rate^0
        p['polynomial']['coefficients'] = c
    terms: dict[str, Any] = {}
    if phys.shupe_k:
        terms['temperature_rate'] = {'form': 'power', 'coefficients': [phys.shupe_k], 'powers': [1]}
    if phys.warmup_dph:
        terms['time_since_power_on'] = {'form': 'exp_decay', 'coefficients': [phys.warmup_dph / DPH],
                                        'time_constant_s': phys.warmup_tau_s}
    if terms:
        p['extended'] = {'signals': list(terms), **terms}
    p['filters'] = dict(FIT_FILTERS)
    path.write_text('# The true form of the field check\'s simulated gyro (research/studies/field_check.py).\n'
                    + yaml.safe_dump(cal, sort_keys=False))
    return True


def several_runs_refusal() -> str:
    """Why the installed `calibrate fit` cannot take the lab protocol's several logs ('' when it can)."""
    done = subprocess.run([PYTHON, '-m', 'art_gyro_calibration.analysis.cli', 'fit', '--help'], cwd=REPO,
                          env=dict(os.environ, PYTHONPATH=str(REPO)), capture_output=True, text=True)
    if done.returncode != 0:
        return f'`calibrate fit --help` failed ({done.returncode}): {done.stderr.strip()[-300:]}'
    if '--warm-start' not in done.stdout:
        return ('the installed `calibrate fit` takes one log (no `--warm-start` in its `--help`): several-run fits '
                'skipped')
    return ''


def calibrate(*args: str, log: Path) -> str:
    """One `calibrate` command (nice -n 10), through the CLI only; its stdout and stderr are kept in `log`."""
    cmd = ['nice', '-n', '10', PYTHON, '-m', 'art_gyro_calibration.analysis.cli', *args]
    env = dict(os.environ, OPENBLAS_NUM_THREADS='1', OMP_NUM_THREADS='1', MKL_NUM_THREADS='1',
               PYTHONPATH=str(REPO))
    done = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True)
    with log.open('a') as f:
        f.write('$ ' + ' '.join(cmd) + f'\n{done.stdout}{done.stderr}[exit {done.returncode}]\n')
    if done.returncode != 0:
        raise RuntimeError(f'{" ".join(args[:2])} failed ({done.returncode}): {done.stderr[-2000:]}')
    return done.stdout + done.stderr


def applied_error(log_csv: Path, cal: Path, run: dict[str, np.ndarray], cold: bool, out: Path,
                  cmd_log: Path) -> np.ndarray:
    """The error of the corrected rate of `calibrate apply` against the truth, row by row."""
    args = ['apply', str(log_csv), '--calibration', str(cal), '--out', str(out), '--bias-samples',
            str(BIAS_SAMPLES), '--force']
    if cold:
        args.append('--powered-on-at-start')
    calibrate(*args, log=cmd_log)
    got = np.genfromtxt(out, delimiter=',', names=True)
    if len(got) != len(run['t']) or np.max(np.abs(got['t'] - run['t'])) > 1e-3:
        raise RuntimeError(f'{out}: apply dropped rows ({len(got)} of {len(run["t"])})')
    out.unlink()
    error: np.ndarray = got['corrected_dps'] - run['ref_rate']
    return error


OUTSIDE = re.compile(r'applied-(cold|warm)-(\w+?)\.csv: (\d+) of (\d+) rows;.*?; (\d+) outside the calibrated range '
                     r'([-\d.]+)\.\.([-\d.]+) degC')


def outside_range(cmd_log: Path) -> dict[str, dict[str, Any]]:
    """Per second run and calibration, the rows `calibrate apply` compensated at the edge of its temperature range."""
    out: dict[str, dict[str, Any]] = {}
    for m in OUTSIDE.finditer(cmd_log.read_text()):
        run, label, _, rows, outside, lo, hi = m.groups()
        out.setdefault(run, {})[label] = {'fraction': int(outside) / int(rows), 'range_c': [float(lo), float(hi)]}
    return out


def report_summary(report_path: Path) -> dict[str, Any]:
    """What the loop found, from REPORT.json (kept loosely: the fields may grow)."""
    r = json.loads(report_path.read_text())
    effects = []
    for e in r.get('effects', []) or []:
        if isinstance(e, dict):
            effects.append({k: e.get(k) for k in ('signal', 'form', 'time_constant_s', 'effect_dph',
                                                  'materiality_dph', 'p_value', 'coefficients') if k in e})
    out = {'effects': effects, 'model_adequate': r.get('model_adequate'), 'written': r.get('written'),
           'warnings': r.get('warnings'), 'materiality_dph': r.get('materiality_dph')}
    sc = r.get('startup_check')
    if isinstance(sc, dict):
        out['startup_dropped'] = sc.get('dropped') or sc.get('terms_dropped')
    return out


# ---------------------------------------------------------------------------------------------------------
# A case.

def fit(logs: list[Path], label: str, d: Path, cmd_log: Path, warm: list[Path]) -> tuple[Path, dict[str, Any]]:
    """`calibrate fit` of the logs (the runs named in `warm` began warm): the calibration file and what it found."""
    cal, report = d / f'{label}.yaml', d / f'{label}-REPORT.json'
    calibrate('fit', *map(str, logs), *[a for w in warm for a in ('--warm-start', str(w))], '--rows', str(ROWS),
              '--columns', str(COLUMNS), '--serial', SERIAL, '--operating-range', *map(str, OPERATING_RANGE_C),
              '--out', str(cal), '--report', str(report), '--plots', str(d), '--plot-prefix', f'{label}-', '--force',
              log=cmd_log)
    return cal, report_summary(report)


def run_case(case: Case, rep: int, quick: bool, several: bool, work: Path) -> dict[str, Any]:
    """Fit logs, second runs, fits, applies and scores of one case, repetition `rep` (its own seeds).

    `several`: the installed `calibrate fit` takes the lab protocol's logs (else only the single-run fit).
    """
    t0 = time.time()
    gyro = Gyro.packaged(SERIAL)
    seed = case.seed + 1000 * rep
    d = work / f'{case.name}-{rep}'
    d.mkdir(parents=True, exist_ok=True)
    cmd_log = d / 'commands.log'
    cmd_log.write_text('')
    scale = QUICK_HOURS / FIT_HOURS if quick else 1.0
    fit_hours = FIT_HOURS * scale
    second = {'cold': simulate(gyro, case.physics, QUICK_HOURS if quick else COLD_SECOND_HOURS, seed * 100 + 1,
                               0.0, 0.0),
              'warm': simulate(gyro, case.physics, WARM_SECOND_HOURS, seed * 100 + 2, WARM_START_S,
                               WARM_HEADING_DEG)}
    logs = {}
    for name, run in second.items():
        logs[name] = d / f'second-{name}.csv'
        write_log(run, logs[name])
    cals = {'baseline': REPO / 'config' / f'{SERIAL}.yaml'}
    found = {}
    single = d / f'fit-{fit_hours:g}h.csv'
    write_log(simulate(gyro, case.physics, fit_hours, seed * 100 + 10, 0.0, 0.0), single)
    label = f'loop_{fit_hours:g}h'
    cals[label], found[label] = fit([single], label, d, cmd_log, [])
    single.unlink()
    if several:
        runs = []
        for k, (name, hours, chamber_c) in enumerate(PROTOCOL):
            runs.append(d / f'protocol-{name}.csv')
            write_log(simulate(gyro, case.physics, hours * scale, seed * 100 + 20 + k,
                               0.0 if chamber_c is not None else WARM_START_S, 0.0, chamber_c), runs[-1])
        warm = [log for log, (_, _, chamber_c) in zip(runs, PROTOCOL) if chamber_c is None]
        cals[MULTI], found[MULTI] = fit(runs, MULTI, d, cmd_log, warm)
        for log in runs:
            log.unlink()
    true_node = d / 'true-form.yaml'
    if true_form_file(case.physics, true_node):
        cals['true_node'] = true_node
    scores: dict[str, dict[str, Any]] = {}
    for name, run in second.items():
        scores[name] = {'true_signals': score(true_signals_error(run))}
        for label, cal in cals.items():
            err = applied_error(logs[name], cal, run, name == 'cold', d / f'applied-{name}-{label}.csv', cmd_log)
            scores[name][label] = score(err)
        logs[name].unlink()
    return {'case': case.name, 'rep': rep, 'note': case.note, 'outside_range': outside_range(cmd_log),
            'seed': seed, 'physics': asdict(case.physics), 'formless': case.physics.formless,
            'scores': scores, 'found': found, 'seconds': time.time() - t0}


def commit() -> str:
    """The commit the study and the package ran at (with a mark if the tree had changes)."""
    try:
        head = subprocess.run(['git', '-C', str(REPO), 'rev-parse', '--short', 'HEAD'], capture_output=True,
                              text=True, check=True).stdout.strip()
        # The code that runs: the package and the studies (not the documents this writes).
        dirty = subprocess.run(['git', '-C', str(REPO), 'status', '--porcelain', '--', 'art_gyro_calibration',
                                'research/studies', 'config'],
                               capture_output=True, text=True, check=True).stdout.strip()
        return head + (' + uncommitted changes' if dirty else '')
    except (OSError, subprocess.CalledProcessError):
        return 'unknown'


def _median(results: list[dict[str, Any]], name: str, label: str, key: str = 'sys_rms_dph') -> float:
    return float(np.median([r['scores'][name][label][key] for r in results]))


def _by_case(results: list[dict[str, Any]]) -> dict[str, list[dict[str, Any]]]:
    out: dict[str, list[dict[str, Any]]] = {}
    for r in results:
        out.setdefault(r['case'], []).append(r)
    return out


def loop_labels(results: list[dict[str, Any]]) -> list[str]:
    """The loop's calibrations the results hold (single-run fit first, then the several-run fit)."""
    return sorted({lab for r in results for lab in r['scores']['cold'] if lab.startswith('loop_')},
                  key=lambda lab: (lab == MULTI, lab))


def _label_text(lab: str) -> str:
    return {'baseline': 'packaged', 'true_node': 'true form through the node',
            'true_signals': 'true form on the true signals', MULTI: 'loop, several runs'}.get(
                lab, f'loop, one {lab[5:-1]} h run')


def targets(results: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Issue 35's targets on the cold second runs (and, for the null cases, the warm ones): one row per check.

    Ratios are the median over a case's runs of each run's ratio of rms of 60 s means (bias included).
    """
    rows: list[dict[str, Any]] = []
    for case, group in _by_case(results).items():
        if all('true_node' in r['scores']['cold'] for r in group):
            for lab in loop_labels(group):
                ratio = float(np.median([r['scores']['cold'][lab]['sys_rms_dph']
                                         / r['scores']['cold']['true_node']['sys_rms_dph'] for r in group]))
                rows.append({'target': f'written within {WRITTEN_VS_NODE:g}x the true form through the node',
                             'case': case, 'calibration': lab, 'value': ratio, 'limit': WRITTEN_VS_NODE,
                             'passed': ratio <= WRITTEN_VS_NODE})
            ratio = float(np.median([r['scores']['cold']['true_node']['sys_rms_dph']
                                     / r['scores']['cold']['true_signals']['sys_rms_dph'] for r in group]))
            rows.append({'target': f'true form through the node within {NODE_VS_SIGNALS:g}x the true signals',
                         'case': case, 'calibration': 'true_node', 'value': ratio, 'limit': NODE_VS_SIGNALS,
                         'passed': ratio <= NODE_VS_SIGNALS})
        if case.startswith('null'):
            for lab in loop_labels(group):
                worst = max(s[lab]['sys_rms_dph'] - s['baseline']['sys_rms_dph']
                            for r in group for s in r['scores'].values())
                rows.append({'target': f'no null run worse than the packaged calibration by > {WORSE_DPH:g} deg/h',
                             'case': case, 'calibration': lab, 'value': worst, 'limit': WORSE_DPH,
                             'passed': worst <= WORSE_DPH})
    return rows


def figure(results: list[dict[str, Any]], path: Path, cold_hours: float) -> None:
    """Every calibration's field error per case, cold and warm second runs: medians and each run."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    groups = _by_case(results)
    names = list(groups)
    series = ['baseline', *loop_labels(results), *REFERENCES]
    fig, axes = plt.subplots(2, 1, figsize=(16, 10), sharex=True)
    x = np.arange(len(names))
    width = 0.8 / len(series)
    hours = {'cold': cold_hours, 'warm': WARM_SECOND_HOURS}
    for ax, name in zip(axes, ('cold', 'warm')):
        top = 0.0
        for k, lab in enumerate(series):
            xs = x + (k - (len(series) - 1) / 2) * width
            have = [i for i, c in enumerate(names) if all(lab in r['scores'][name] for r in groups[c])]
            med = [_median(groups[names[i]], name, lab) for i in have]
            ax.bar(xs[have], med, width, label=f'{_label_text(lab)} (median)', color=COLOURS.get(lab, '#d62728'),
                   alpha=0.85)
            for i in have:
                v = [r['scores'][name][lab]['sys_rms_dph'] for r in groups[names[i]]]
                top = max(top, *v)
                ax.plot(np.full(len(v), xs[i]), v, 'k.', ms=3, label='each run' if (k == 0 and i == 0) else None)
        ax.set_ylabel('field error on the second run:\nrms of 60 s means, bias included (deg/h)')
        ax.set_title(f'cold second run: {hours["cold"]:g} h from power-on (node told powered_on_at_start)'
                     if name == 'cold' else f'warm second run: {hours["warm"]:g} h starting 3 h after power-on, at '
                     'another heading')
        ax.set_ylim(0, min(top * 1.05, 25.0))
        ax.grid(axis='y', alpha=0.3)
    axes[0].legend(fontsize=8, loc='upper left', ncol=2)
    axes[1].set_xticks(x)
    axes[1].set_xticklabels(names, rotation=30, ha='right')
    axes[1].set_xlabel('simulated gyro physics (case)')
    fig.suptitle(f'Does the loop\'s calibration make another run of the same gyro ({SERIAL}) better? '
                 '(bars above 25 deg/h are cut; no bar: no such calibration)')
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


# The history of this document's runs, by hand (the numbers each entry quotes are from that run's results).
HISTORY = '''## History

- Issue 35, three sessions on (this run, a06d7da, 23.1 min): one change since dc21506, a06d7da: a fit of several runs
  judges the baseline's bias column once more where the round-robin blocks did not show it better by the
  materiality (`baseline.PairedCheck`): the bias column alone (the loop's terms on top of both files), each run cut
  into 4 contiguous parts fitted without, every start replayed to its run's end, the two files paired by steady
  segment; refitted when they differ by more than the residual materiality, the change lowers the segments' mean
  square by at least half its own square and t >= 2 over the run parts. (b084768, after this run, changes no
  number: a three-run fit's REPORT.json and file equal to the byte.) Single-run fits are untouched: every one
  equal to dc21506's.
  Several-run fits changed in 4 of 73 runs, cold (warm) second run in deg/h, dc21506 -> this run: aged_poly_shupe
  run 0 4.23 -> 2.80 (4.50 -> 2.18; true form through the node 1.79, 1.81), run 1 4.89 -> 4.05 (2.29 -> 5.87;
  true form 4.00, 4.33: worse warm, within 1.36x of the true form); shupe1.2_two_tau_slow_ramps run 1 1.37 -> 1.63
  (1.40 -> 1.48; true form 1.70, 1.41); shupe_s_curve_fast_ramps run 2 3.39 -> 3.51 (1.83 -> 1.72; true form 3.39,
  1.93). No null file changed. Within 1.5x: one 6 h run 19 of 22 as before (shupe2.4_fast_heat 1.70, shupe_warmup
  1.50, aged_poly_shupe 1.94), the lab protocol 22 of 22 (aged_poly_shupe 1.79 -> 1.29); the true form through the
  node within 1.5x the true signals 22 of 22; no null run worse than the packaged file. A first form of the rule
  (judged against the bar as it would be written, the terms only where they helped the baseline alone; the session
  before, the several-run fits alone) met aged_poly_shupe on this check too (1.79 -> 1.29, warmup run 1 7.45 ->
  2.57), but on the package's simulator it wrote the bias column of an unaged Shupe gyro fitted over the same
  protocol (the refitted column won by the temperature rate's share: 7.29 deg/h on a cold second run where the
  baseline gives 5.04): the bias column is judged alone (`test_baseline.py`).
- Issue 35, ninth session (dc21506, 26.7 min): two changes since 664b4b0. (1) 1176383, the window cost's
  implied bias: its noise is a white part and a Gauss-Markov wander fitted to what the fit leaves as the fit would
  leave them (the fit and a run's constant take much of a wander as long as a run out of its residual), and over
  several runs at least that beside the runs-left-out spread. (2) dc21506, the fit's temperature smoothed both ways
  over 20 s (the local quadratic rate of 0.05 degC counts regressed the true rate at 0.94), and a linear term's
  square written only when it beats chance. Measured apart, (1) alone (a run at 1176383, 35.3 min): the implied
  bias covers the written Shupe coefficient's window error (`window_coverage.py`: one 6 h run 3 of 31 fits beyond
  2x, rms z 1.01; the lab protocol 2 of 31, 1.09; at 664b4b0 7 of 31 and 7 of 31, rms z 1.97 and 2.60); one
  decision moved: shupe2.4_fast_heat run 2, one run, wrote its temperature rate (with a square, 2.30 + 44 r^2)
  alone instead of beside an 81 min warm-up (the stand-in rule on the larger implied bias): 2.06 -> 6.19 deg/h.
  Both, this run: coverage one 6 h run 2 of 32 beyond 2x (rms z 0.93), the lab protocol 2 of 32 (1.03). Ratios
  (written / true form through the node, median) 664b4b0 -> this run: one 6 h run shupe2.4_fast_heat 1.60 -> 1.70,
  shupe2.4_warmup 1.54 -> 1.16 (run 2 25.06 -> 4.29 deg/h), shupe_warmup 1.49 -> 1.50 (run 0 4.21 -> 4.25),
  shupe_warmup_cold_soak 0.50 -> 0.96; the lab protocol shupe2.4_fast_heat 1.33 -> 1.17 (4.10/2.64/4.14 ->
  2.73/2.32/3.55 deg/h), shupe2.4_warmup 1.28 -> 1.41, fast_warmup_shupe 1.27 -> 0.97, shupe_warmup_cold_soak
  1.30 -> 1.03. Within 1.5x: one 6 h run 19 of 22 (fails: shupe2.4_fast_heat 1.70, shupe_warmup 1.50,
  aged_poly_shupe 1.94), the lab protocol 21 of 22 (aged_poly_shupe 1.79); the true form through the node within
  1.5x the true signals 22 of 22; no null run worse than the packaged file. Still a square: shupe2.4_fast_heat
  run 2, one run (2.32 + 40.4 r^2, 6.15 deg/h) and shupe_k2.4_slow run 2, the lab protocol (2.74 - 182 r^2): both
  beat chance on their fit logs.
- Issue 35, seventh session (664b4b0, 46.4 min, the machine shared with the loop study for its first
  17 min): the fit reads the temperature rate over each run's first 6 min as the node's static-bias refinement
  takes it (a cubic over the first 6 min), not from the causal filter's rise from 0, which the loop had fitted as
  a 30 s warm-up the node's refined bias never needs (beside a lag and the temperature rate at 0.77 for 1.0 on a
  three-run protocol of the package simulator); the start-up check also judges the cold starts apart (a term
  that shifts their static bias was diluted by the restarts); the window cost takes a temperature rate's window
  as the node refines it (it had cut the run before the refinement). One 6 h run: shupe_k2.4_slow 1.42 -> 1.14,
  shupe2.4_fast_heat 1.86 -> 1.60, shupe2.4_warmup 1.62 -> 1.54, shupe_warmup 1.51 -> 1.49,
  shupe_warmup_cold_soak 1.01 -> 0.50, shupe1.2_two_tau_slow_ramps 1.29 -> 0.99, fast_warmup_shupe 0.75 -> 0.86;
  several runs: shupe2.4_fast_heat 1.17 -> 1.33, shupe2.4_warmup 1.24 -> 1.28, shupe1.2_two_tau_slow_ramps
  0.86 -> 0.77. The written file within 1.5x the true form through the node: one 6 h run 19 of 22 (fails:
  shupe2.4_fast_heat 1.60, shupe2.4_warmup 1.54, aged_poly_shupe 1.93), the lab protocol 21 of 22
  (aged_poly_shupe 1.78); the true form through the node within 1.5x the true signals 22 of 22; no null run worse
  than the packaged file. Outside this run: aged_poly_shupe run 0 with the protocol given twice (six runs) gave
  11.29 deg/h on its cold second run before these changes (three runs 4.18; a 30 s warm-up and an eight-coefficient
  lag written), 3.64 after (true form through the node 1.79).
- Issue 35, sixth session (ed6889c, 32.9 min, the machine shared with other fits for part of it): the
  baseline comparison fits the time constants of the terms kept on top of the baseline again against it (a
  warm-up tuned beside the refit's polynomial had kept 1505 s for 1200 s, and its amplitude traded for it); when
  the start-up check drops a term, the loop is asked again without it and, apart, without each other term of
  several coefficients. shupe2.4_warmup: one 6 h run 10.38 -> 1.62 (run 0's cold second run 56.05 -> 2.31 deg/h:
  an eight-coefficient lag had pushed the warm-up to 5529 s, the check dropped the warm-up; without the lag, the
  warm-up and the temperature rate), the lab protocol 2.44 -> 1.24 (runs 0 and 1: 6.13 -> 2.13, 5.21 -> 1.63;
  run 2 2.96 -> 6.35: the warm-up retuned to 1659 s beside a 127 s lag). Moved otherwise: shupe_warmup 1.66 ->
  1.51 one run, 1.23 -> 1.18 several; warmup several 1.23 -> 0.98; warmup_0.012 1.09 -> 1.21 and 1.05 -> 1.32;
  warmup_4c10m 1.03 -> 1.39 and 1.43 -> 1.31; fast_warmup_shupe 0.63 -> 0.75 and 1.49 -> 1.30. aged_poly_shupe
  unchanged (1.93, 1.77): on the lab protocol's logs the baseline with its bias column refitted scores 3.55 deg/h
  held out against 3.42 with the Shupe term on top (materiality 2.30), though on run 0's second run it gives
  2.99 against 4.27 (true form through the node 2.09): each node run on a fit log ends where the next restart
  begins (45-90 min), too short for the aged slope's 0.2 deg/h per degC to show. The written file within 1.5x the
  true form through the node: one 6 h run 18 of 22 (fails: shupe2.4_fast_heat 1.86, shupe2.4_warmup 1.62,
  shupe_warmup 1.51, aged_poly_shupe 1.93), the lab protocol 21 of 22 (aged_poly_shupe 1.77); the true form
  through the node within 1.5x the true signals 22 of 22; no null run worse than the packaged file (6 of 6); no
  second run worse than it by more than 1 deg/h (medians).
- Issue 35, fourth session (a5b53c6, 21.1 min): a written refit is continued beyond the logged
  temperatures by the baseline's temperature dependence (it was held at the log's edge), and the baseline
  comparison gains a middle candidate, the baseline with its bias column refitted and the loop's terms on top
  (written in 13 of 146 fits: every aged_poly fit, temp_step, and four fits of warm-up cases). aged_poly: one 6 h
  run 4.19 -> 1.06, the lab protocol 1.95 -> 0.97 (run 2's cold second run 22.04 -> 1.90 deg/h: 27 % of its rows
  lay below the fit log's 19 degC); temp_step's second runs, worse than the packaged file after the 6 h fit
  before, now better. shupe2.4_warmup one run 22.65 -> 10.38 (run 2: 54.67 -> 25.05, a bias column refitted on a
  warm-up it could not name). aged_poly_shupe unchanged (1.93, 1.77): on its fit logs the bias-refitted baseline
  scores within 0.3 deg/h of the baseline with the Shupe term, under a materiality of 2.2-3.0 deg/h. The written
  file within 1.5x the true form through the node: one 6 h run 18 of 22, the lab protocol 20 of 22; the true form
  through the node within 1.5x the true signals 22 of 22; no null run worse than the packaged file (6 of 6);
  second runs worse than it by more than 1 deg/h (medians): shupe2.4_warmup warm after the 6 h fit (1.02).
- Issue 35, third session (16aa3c2, 22.8 min): `calibrate fit` judges the refit against the baseline
  with the same terms fitted on top of it (the polynomial judged, not the terms), fits a term on the temperature
  rate with its columns instrumented by their 60 s means (the causal rate's noise had pulled a Shupe coefficient
  of 2.4 to about 2.2), lets a lagged temperature's eight columns give way to the temperature rate when that
  explains half of what they fit, and asks the loop again without a term the start-up check dropped. The lab
  protocol is now the guide's (cold starts at 10 and 40 degC, 3 h each, and a 2 h warm restart: 8 h), and four
  cases the pass was not tuned on joined (two runs each). The written file within 1.5x the true form through the
  node: one 6 h run 17 of 22 cases (10 of 18 before), the lab protocol 19 of 22 (11 of 18); fails: shupe2.4_warmup
  (22.65 one run, 2.44 several: a Shupe self-heating and a warm-up of nearly one time constant, which one cold
  start cannot part), shupe2.4_fast_heat one run 1.86, shupe_warmup one run 1.66, aged_poly (4.19, 1.95) and the
  new aged_poly_shupe (1.93, 1.77): an aged polynomial refitted over the fit log's temperatures is held at its edge
  on the second run. Issue 35's rows, cold, median deg/h, one run / several / through the node / true signals:
  shupe_k2.4_slow 4.23 / 1.74 / 2.26 / 1.65, shupe2.4_fast_heat 4.39 / 2.73 / 1.99 / 1.55, shupe2.4_warmup 54.67 /
  5.21 / 2.13 / 1.99, warmup_0.012 1.66 / 2.68 / 1.32 / 1.38. No null run worse than the packaged file (6 of 6);
  second runs worse than it by more than 1 deg/h (medians): temp_step and aged_poly cold after the 6 h fit only.
- Issue 35, after (5d71f2c, 19.4 min): the package with several-run fits (`calibrate fit LOG [LOG ...]
  --warm-start`), the window terms' cost, the temperature rate's local quadratic fit (tau 20 s; the true form's file
  names it); fits told `--operating-range 10 50`. The true form through the node is within 1.5x the true signals in
  18 of 18 cases (14 at f87be58, on the first-order 120 s filter); issue 35's rows, through the node / true signals
  (deg/h): shupe_k2.4_slow 2.26 / 1.65, shupe2.4_fast_heat 1.99 / 1.55, shupe2.4_warmup 2.13 / 1.99, warmup_0.012
  1.32 / 1.38. The loop's file is not: one 6 h run within 1.5x in 10 of 18 cases, the lab protocol's three 2 h runs
  in 11 of 18. The Shupe k = 2.4 cases on 0.1 degC/min ramps are the worst (one run / several: 4.66 / 11.72,
  6.75 / 12.53, 37.28 / 14.23 deg/h against about 2 through the node); the lab protocol wins on shupe_fast_heat,
  shupe_two_tau_sine, shupe_warmup and shupe2.4_warmup and loses on shupe_k2.4_slow, shupe2.4_fast_heat,
  warmup_4c10m and shupe_warmup_cold_soak (31.37 against 20.78 packaged). No null run is worse than the packaged
  file; second runs that are, by more than 1 deg/h (medians): shupe_warmup_cold_soak, warmup_4c10m and warmup
  (warm) after the several-run fit, temp_step and aged_poly (cold) after the 6 h fit.
- Issue 35, before (f87be58): the study gains the two references of every cold second run (the true form through
  the node, and on the true signals; issue 20's "best" was the latter), 4 h cold second runs (2 h before), the lab
  protocol's several-run fit (skipped while `calibrate fit` takes one log), nine cases (issue 35's four rows and
  its item 5 cell, self-heating in two time constants and S-shaped, ramps of 1 and 1.5 degC/min, a sinusoidal
  chamber, a cold soak), and drops the 2 h single-run fit and issue 20's diagnostics (`--widen`,
  `--without-warmup`). Run at f87be58 (today's package: single-run fits only), 37.7 min on two cores shared with
  other runs (load average 5-9). Targets: the written file within 1.5x the true form through the node in 11 of 18
  cases (fails: shupe_fast_heat 3.47, shupe_k2.4_slow 1.53, shupe2.4_fast_heat 1.62, shupe2.4_warmup 4.13,
  shupe_two_tau_sine 3.25, shupe_warmup 2.66, aged_poly 4.19); the true form through the node within 1.5x the true
  signals in 14 of 18 (fails: shupe2.4_fast_heat 1.52, shupe_s_curve_fast_ramps 2.96, shupe_warmup 1.57,
  shupe_warmup_cold_soak 1.62); no null run worse than the packaged file (5 of 5 null cases, 0.00 deg/h at
  worst). Issue 35's four rows, cold 4 h second run, median field error (deg/h) loop / through the node / true
  signals: shupe_k2.4_slow 3.83 / 2.53 / 1.65, shupe2.4_fast_heat 3.48 / 2.51 / 1.55, shupe2.4_warmup 8.17 / 1.98 /
  1.99, warmup_0.012 2.47 / 1.32 / 1.38 (packaged 18.7, 69.8, 57.4, 40.3). Seven of 130 second runs are worse than
  the packaged file by more than 1 deg/h, none of them null: temp_step runs 0 and 1, aged_poly runs 0 and 2 (22.04
  against 1.86 deg/h), shupe_two_tau_sine runs 1 and 2: each fit wrote a refit polynomial clamped to the log's
  temperatures (`temperature_range_c`; at 117f8c9 every fit kept the packaged polynomial), and 12-37 % of the
  second run's rows lie outside that range.
- 117f8c9 (issue 20, seventh pass; 2 h second runs, 6 h and 2 h single-run fits): no second run worse than the
  packaged calibration by more than 1 deg/h (0 of 144); more than 2x the true signals' error in 9 of 36 cold runs
  after a 6 h fit and 11 after a 2 h fit. The provisional static-bias fit moved shupe_fast_heat's cold runs by
  -0.2 to -0.4 deg/h.
- 708a18b (sixth pass): the static-bias refinement's cubic: shupe_fast_heat cold 3.46 -> 3.15 deg/h, shupe_warmup
  cold 6.09 -> 3.39 (6 h fits).
- daaddde: a refit is no longer written where it would be clamped and the packaged file is calibrated, and terms on
  top of the kept polynomial must beat it by the materiality: 0 of 144 second runs worse than the packaged file by
  more than 1 deg/h (4 + 1 after 6 h fits and 8 + 10 after 2 h fits at d5e7267, up to 53 deg/h worse).

'''


def figure_targets(results: list[dict[str, Any]], path: Path) -> None:
    """The two ratios of issue 35's targets per case, each run and the median, on the cold second runs."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    groups = {c: g for c, g in _by_case(results).items() if all('true_node' in r['scores']['cold'] for r in g)}
    names = list(groups)
    pairs = [*[(lab, 'true_node', f'{_label_text(lab)} / true form through the node') for lab in loop_labels(results)],
             ('true_node', 'true_signals', 'true form through the node / true form on the true signals')]
    fig, ax = plt.subplots(figsize=(14, 6))
    x = np.arange(len(names))
    for k, (num, den, text) in enumerate(pairs):
        colour = COLOURS.get(num, '#d62728')
        dx = (k - (len(pairs) - 1) / 2) * 0.25
        for i, c in enumerate(names):
            v = [r['scores']['cold'][num]['sys_rms_dph'] / r['scores']['cold'][den]['sys_rms_dph']
                 for r in groups[c] if num in r['scores']['cold']]
            if v:
                ax.plot(np.full(len(v), x[i] + dx), v, '.', color=colour, ms=4, alpha=0.6)
                ax.plot([x[i] + dx], [np.median(v)], 'D', color=colour, ms=7, mec='k',
                        label=f'{text} (median of the runs; dots: each run)' if i == 0 else None)
    ax.axhline(WRITTEN_VS_NODE, color='k', ls='--', lw=0.8, label=f'target: {WRITTEN_VS_NODE:g}x')
    ax.axhline(1.0, color='k', lw=0.5)
    ax.set_yscale('log')
    ax.set_ylabel('ratio of field errors on the cold second run\n(rms of 60 s means, bias included: deg/h / deg/h)')
    ax.set_xticks(x)
    ax.set_xticklabels(names, rotation=30, ha='right')
    ax.set_xlabel('simulated gyro physics (case; cases of a shape no form has are left out)')
    ax.set_title('Issue 35 targets on the cold second runs: written against the true form through the node, '
                 'and the node against the true signals')
    ax.grid(alpha=0.3, which='both')
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _found_text(f: dict[str, Any]) -> str:
    parts = []
    for e in f['effects']:
        tc = e.get('time_constant_s')
        size = e.get('effect_dph')
        coef = e.get('coefficients') or []
        text = f"{e.get('signal')}"
        if e.get('signal') == 'temperature_rate' and len(coef) == 1:
            text += f' k {coef[0]:.3g}'
        if isinstance(tc, (int, float)):
            text += f' tau {tc:.0f} s'
        if isinstance(size, (int, float)):
            text += f' ({size:.1f} deg/h)'
        parts.append(text)
    written = f.get('written')
    out = ', '.join(parts) or 'nothing'
    if isinstance(written, dict) and written.get('terms') is not None:
        out += f"; written: {', '.join(written['terms']) or 'polynomial only'}"
    return out + f"; model_adequate: {f.get('model_adequate')}"


def _cell(s: dict[str, Any], lab: str) -> str:
    return f"{s[lab]['sys_rms_dph']:.2f} ({s[lab]['mean_dph']:+.1f})" if lab in s else 'no file'


def _med_cell(group: list[dict[str, Any]], name: str, lab: str) -> str:
    if not all(lab in r['scores'][name] for r in group):
        return 'no file' if lab == 'true_node' else '-'
    return f'{_median(group, name, lab):.2f} ({_median(group, name, lab, "mean_dph"):+.1f})'


def document(results: list[dict[str, Any]], meta: dict[str, Any]) -> str:
    """research/doc/field-check.md."""
    labels = loop_labels(results)
    series = ['baseline', *labels, *REFERENCES]
    groups = _by_case(results)
    reps = sorted({len(g) for g in groups.values()})
    cold_h, out = meta['cold_hours'], meta.get('out', 'out/field-check')
    lines = ['# Field check: does the loop\'s calibration make another run of the same gyro better?', '',
             f'Generated by `{meta["command"]}` at commit {meta["commit"]} ({meta["minutes"]:.1f} min wall, '
             f'{meta["jobs"]} runs at a time); the package ran from the same tree, driven only through its CLI '
             f'(`calibrate fit` / `calibrate apply`, subprocess). Raw results: `{out}/results.json`; each '
             'run\'s calibrations (the true form\'s file `true-form.yaml` included), REPORT.json/REPORT.md and '
             f'commands: `{out}/<case>-<run>/` (not committed: rerun the command).'
             + (f' This document was rewritten from those results at {meta["document_commit"]} '
                '(`--document-only`).' if meta.get('document_commit') else ''), '']
    if meta.get('several_runs_skipped'):
        lines += [f'**Several-run fits not run:** {meta["several_runs_skipped"]}. The study writes them as soon as '
                  '`calibrate fit` takes several logs with `--warm-start` (issue 35 item 1); rerun the command.', '']
    lines += ['## What it does', '',
              f'`research/studies/field_check.py` has its own simulator of an RD2100 (numpy, independent of '
              f'`analysis/simulate.py`). The gyro is {SERIAL}: its true error polynomial is its packaged calibration '
              f'({ROWS} x {COLUMNS}, `config/{SERIAL}.yaml`), evaluated at the reading (a fixed point, as the node '
              'evaluates it at the measured rate). The reading is the table rate + Earth rate '
              f'({EARTH_RATE_DPS * DPH:.2f} deg/h at {LATITUDE_DEG} deg N) + a turn-on bias (new at every power-on, '
              f'sigma {TURN_ON_BIAS_STD_DPS * DPH:.0f} deg/h) + comp(reading, T) + the case\'s effects + a '
              'Gauss-Markov bias wander + a rate random walk + white noise '
              f'({ARW_DEG_RTHR} deg/sqrt(h)), quantised to counts (0.00305 deg/s, 0.05 degC), {RATE_HZ:g} Hz, '
              'logged as `t,raw_rate,raw_temp,ref_rate` (the columns `calibrate simulate` writes, less `supply_v`).',
              '',
              f'- Rate table: {INITIAL_REST_S:.0f} s at rest, then steps of +-1, 2, 5, 10, 20, 50, 100 deg/s '
              '(random order and sign, 30-120 s, twice as long at 1-2 deg/s), each followed by 10-40 s at rest.',
              '- Chamber: 10-25 min at the start temperature (an ambient 18-26 degC, or a cold soak at 10 degC, or '
              'the lab protocol\'s), then either ramps (0.5 degC/min unless the case says: 0.1, 1 or 1.5) to set '
              'points drawn in 10 degC..(49.5 degC less the self-heating), at least 8 degC apart, held 15-40 min, '
              'or a sinusoid (the case\'s swing and period); the gyro case lags the air by '
              f'{CHAMBER_LAG_S:.0f} s, so the gyro stays inside the calibration\'s 10..50 degC.',
              '- Self-heating at power-on (absent from `calibrate simulate`): the gyro\'s temperature rises by dT '
              '(2-6 degC) with time constant tau (5-25 min), in some cases in two time constants or S-shaped '
              '(1 - exp(-(t/tau)^2)); the sensor reads it, the polynomial sees it, and a Shupe effect sees its rate.',
              '- Effects: Shupe (k x dT/dt of the gyro\'s own temperature, instantaneous), a warm-up (a exp(-t/tau) '
              'from power-on), both, none, and shapes no form of the loop has: a sawtooth over heading mod 360, a '
              'bump at a heading, a step at a temperature threshold; and an aged gyro whose bias slope moved since '
              'its report (there the packaged file is not the truth). Shupe k = 2.4 deg/s per degC/s (issue 35\'s '
              'cases) runs on 0.1 degC/min ramps (14 deg/h); k = 0.6 elsewhere (18 deg/h on 0.5 degC/min ramps).',
              f'- Per case and run (seed set), the same gyro (polynomial, effect size, self-heating) with other seeds '
              f'(turn-on bias, wander, table, chamber): **one fit log** of {meta["fit_hours"]:g} h from power-on; '
              '**the lab protocol** (issue 35 item 1): ' + ', '.join(
                  f'{name} {h * meta["protocol_scale"]:.2g} h '
                  + (f'from power-on, chamber at {c:g} degC' if c is not None
                     else f'a restart {WARM_START_S / 3600:g} h after power-on') for name, h, c in PROTOCOL)
              + f' ({sum(h for _, h, _ in PROTOCOL) * meta["protocol_scale"]:g} h in all, as `doc/calibration.md` '
              f'asks, against the single log\'s {meta["fit_hours"]:g} h); '
              f'a **cold second run** ({cold_h:g} h from power-on, heading 0) and a **warm** one '
              f'({WARM_SECOND_HOURS:g} h, starting {WARM_START_S / 3600:g} h after power-on, heading '
              f'{WARM_HEADING_DEG:g} deg). Every log starts with {INITIAL_REST_S:.0f} s at rest. Runs per case: '
              + ' or '.join(map(str, reps)) + '.',
              f'- Fits: `calibrate fit FIT.csv --rows {ROWS} --columns {COLUMNS} --serial {SERIAL} --operating-range '
              f'{OPERATING_RANGE_C[0]:g} {OPERATING_RANGE_C[1]:g} --out CAL.yaml --report REPORT.json` (defaults '
              'otherwise; the log starts at power-on; the operating range is where the second runs go), and '
              '`calibrate fit COLD1.csv COLD2.csv WARM.csv --warm-start WARM.csv ...`. Apply: `calibrate apply '
              f'SECOND.csv --calibration CAL --bias-samples {BIAS_SAMPLES}` (+ `--powered-on-at-start` on the cold '
              'run), as the node does.',
              '- Calibrations: **packaged** = `config/NAVC3545.yaml` (what the gyro already has); the loop\'s '
              '**one run** and **several runs** fits; **true form through the node** = the packaged file (its '
              'polynomial moved by the aged slope in aged_poly) plus the true terms with their true coefficients '
              '(Shupe: a power term [1] on `temperature_rate`; warm-up: `exp_decay` on `time_since_power_on` with '
              'its true time constant; the filters `calibrate fit` writes), applied with `calibrate apply` exactly as '
              'the loop\'s file: what a perfect fit gives this node; **true form on the true signals** = the true '
              'error (polynomial and effects at the true temperature and its true rate) removed, the static bias '
              'then taken as the node takes it: what a perfect node could give (what is left is wander, random walk '
              'and noise). For a heading sawtooth, a heading bump or a temperature step there is no file the node '
              'takes ("no file" below): no form has them.',
              f'- Score: corrected rate minus the true table rate over the second run after the {BIAS_SAMPLES}-row '
              f'bias window, **bias included**, in deg/h: the rms of {BLOCK_S:.0f} s means (the "field error") and, '
              'in brackets, the mean.', '']
    rows = targets(results)
    lines += ['## Issue 35 targets', '',
              'On the cold second runs; ratios are medians over the case\'s runs of each run\'s ratio of field errors; '
              'the null target takes the worst run, cold or warm. Cases with a shape no form has have no true form '
              'through the node and are left out of the ratios.', '',
              '| target | met | cases | failing (value) |', '|---|---|---:|---|']
    by_target: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for row in rows:
        by_target.setdefault((row['target'], row['calibration']), []).append(row)
    for (target, lab), group in by_target.items():
        bad = [f"{row['case']} ({row['value']:.2f})" for row in group if not row['passed']]
        lines.append(f'| {target}: {_label_text(lab)} | {"**fail**" if bad else "pass"} | '
                     f'{len(group) - len(bad)} of {len(group)} | {", ".join(bad) or "-"} |')
    lines += ['', '| target | case | calibration | value | limit | pass/fail |', '|---|---|---|---:|---:|---|']
    lines += [f"| {row['target']} | {row['case']} | {_label_text(row['calibration'])} | {row['value']:.2f} | "
              f"{row['limit']:g} | {'pass' if row['passed'] else '**fail**'} |" for row in rows]
    issue = [c for c in ('shupe_k2.4_slow', 'shupe2.4_fast_heat', 'shupe2.4_warmup', 'warmup_0.012') if c in groups]
    if issue:
        lines += ['', '## Issue 35\'s table, this simulator', '',
                  f'Cold second run of {cold_h:g} h; median over the runs of the field error, deg/h (median mean).',
                  '', '| case | ' + ' | '.join(_label_text(lab) for lab in series) + ' |',
                  '|---|' + '---:|' * len(series)]
        lines += [f'| {c} | ' + ' | '.join(_med_cell(groups[c], 'cold', lab) for lab in series) + ' |'
                  for c in issue]
    lines += ['', '## Field error, median over the runs (deg/h; in brackets the median mean)', '',
              '| case | second run | ' + ' | '.join(_label_text(lab) for lab in series) + ' |',
              '|---|---|' + '---:|' * len(series)]
    for case, group in groups.items():
        for name in ('cold', 'warm'):
            lines.append(f'| {case} | {name} | ' + ' | '.join(_med_cell(group, name, lab) for lab in series) + ' |')
    lines += ['', '![field-errors.png](figures/field-errors.png)', '',
              '![field-targets.png](figures/field-targets.png)', '',
              *([f'Over time, {meta["time_figure"]} (simulated again from its seed, the calibrations applied again; '
                 'the lower panel is the true rate of the gyro\'s temperature, which the node\'s causal filter '
                 'follows):', '', '![field-time.png](figures/field-time.png)', ''] if meta.get('time_figure') else []),
              HISTORY, '## Per case and run', '']
    for case, group in groups.items():
        r0 = group[0]
        lines += [f'### {case}', '', f"{r0['note']}. Physics: "
                  + ', '.join(f'{k} {v:g}' for k, v in r0['physics'].items() if v) + '.', '',
                  'Field error, deg/h (mean in brackets):', '',
                  '| run (seed) | second run | ' + ' | '.join(_label_text(lab) for lab in series) + ' |',
                  '|---|---|' + '---:|' * len(series)]
        for r in group:
            for name in ('cold', 'warm'):
                lines.append(f"| {r['rep']} ({r['seed']}) | {name} | "
                             + ' | '.join(_cell(r['scores'][name], lab) for lab in series) + ' |')
        lines += ['', 'What the loop found (REPORT.json effects, the terms written after its checks, '
                  '`model_adequate`):', '']
        for r in group:
            for lab, f in r['found'].items():
                lines.append(f"- run {r['rep']}, {_label_text(lab)}: {_found_text(f)}")
        lines += ['']
    lines += ['## Limits', '',
              f'- {" or ".join(map(str, reps))} runs per case: medians of few realisations of the wander and the '
              'profiles. Differences of about 1 deg/h between calibrations are within what another seed gives.',
              '- The packaged polynomial is the gyro\'s true one here (except in `aged_poly`): a refit can only match '
              'it on the polynomial part and gains only by the effects it adds.',
              '- Only NAVC3545 (3 x 4), one sample rate (10 Hz), the table and chamber profiles above. To bound the '
              'run time: 3 runs per case (5 for the item 5 cell), the protocol\'s runs 2 h each (6 h in all, as the '
              'single log), no 2 h single-run fit (issue 20\'s runs had one). Even so the full study took '
              f'{meta["minutes"]:.0f} min on two cores shared with other work; the several-run fits will add about '
              'as much CPU as the 6 h fits (`--reps 2` to shorten it).', '']
    return '\n'.join(lines)


def figure_time(results: list[dict[str, Any]], meta: dict[str, Any], work: Path, path: Path) -> str:
    """Over a cold second run of a Shupe and warm-up case: each calibration's error and the true temperature rate.

    The run is simulated again from its seed and the calibrations written by the run (its directory under `work`)
    applied again. Returns the run's name ('' when no such run is in the results).
    """
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    r = next((r for name in TIME_CASES for r in results if r['case'] == name and r['rep'] == 0), None)
    if r is None:
        return ''
    case = next(c for c in CASES if c.name == r['case'])
    d = work / f"{r['case']}-{r['rep']}"
    run = simulate(Gyro.packaged(SERIAL), case.physics, meta['cold_hours'], r['seed'] * 100 + 1, 0.0, 0.0)
    log, cmd_log = d / 'second-cold.csv', d / 'commands-time.log'
    write_log(run, log)
    cals = {'baseline': REPO / 'config' / f'{SERIAL}.yaml', **{lab: d / f'{lab}.yaml' for lab in r['found']},
            'true_node': d / 'true-form.yaml'}
    errors = {lab: applied_error(log, cal, run, True, d / f'applied-time-{lab}.csv', cmd_log)
              for lab, cal in cals.items()}
    errors['true_signals'] = true_signals_error(run)
    log.unlink()
    per = int(BLOCK_S * RATE_HZ)
    n = (len(run['t']) - BIAS_SAMPLES) // per * per
    minutes = run['t'][BIAS_SAMPLES:BIAS_SAMPLES + n].reshape(-1, per).mean(axis=1) / 60.0
    fig, (ax, ax2) = plt.subplots(2, 1, figsize=(12, 8), sharex=True, gridspec_kw={'height_ratios': (2, 1)})
    for lab, e in errors.items():
        blocks = e[BIAS_SAMPLES:BIAS_SAMPLES + n].reshape(-1, per).mean(axis=1) * DPH
        ax.plot(minutes, blocks, color=COLOURS.get(lab, '#d62728'), lw=1.2,
                label=f'{_label_text(lab)} (rms {r["scores"]["cold"][lab]["sys_rms_dph"]:.2f} deg/h)')
    ax.axhline(0.0, color='k', lw=0.5)
    ax.set_ylabel('error of the corrected rate,\n60 s means, bias included (deg/h)')
    ax.set_ylim(-25.0, 25.0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(f"{r['case']}, run 0: the cold second run ({meta['cold_hours']:g} h from power-on); "
                 'curves beyond +-25 deg/h are cut')
    ax2.plot(run['t'] / 60.0, np.gradient(run['temp'], run['t']) * 60.0, 'k', lw=1.0)
    ax2.set_ylabel('true rate of the gyro\'s\ntemperature (degC/min)')
    ax2.set_xlabel('time since power-on (min)')
    ax2.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return f"{r['case']} run 0"


def write_outputs(results: list[dict[str, Any]], meta: dict[str, Any], quick: bool, out: Path) -> tuple[Path, Path]:
    """The figures and the document (into out/ for --quick, doc/ otherwise)."""
    fig_dir = out if quick else REPO / 'research' / 'doc' / 'figures'
    figure(results, fig_dir / 'field-errors.png', meta['cold_hours'])
    figure_targets(results, fig_dir / 'field-targets.png')
    meta['time_figure'] = figure_time(results, meta, out, fig_dir / 'field-time.png')
    doc_dir = out if quick else REPO / 'research' / 'doc'
    (doc_dir / 'field-check.md').write_text(document(results, meta))
    return fig_dir, doc_dir


def document_only(args: argparse.Namespace) -> int:
    """Rewrite the outputs from a finished run's results.json."""
    out = REPO / 'out' / ('field-check-quick' if args.quick else 'field-check')
    data = json.loads((out / 'results.json').read_text())
    results, meta = data['results'], data['meta']
    meta['document_commit'] = commit()
    (out / 'results.json').write_text(json.dumps({'meta': meta, 'results': results}, indent=1))
    fig_dir, doc_dir = write_outputs(results, meta, args.quick, out)
    print(f'wrote {out / "results.json"}, {fig_dir}/field-*.png, {doc_dir / "field-check.md"}')
    return 0


def main() -> int:
    """Run the cases (two runs at a time) and write the document, the figures and the raw results."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--quick', action='store_true',
                        help=f'three cases, one run, {QUICK_HOURS:g} h fit logs and cold second runs; everything into '
                             'out/field-check-quick/')
    parser.add_argument('--jobs', type=int, default=2, help='runs at a time (default 2; the machine is shared)')
    parser.add_argument('--reps', type=int, help='runs (seed sets) per case (default 3 or the case\'s, quick 1)')
    parser.add_argument('--cases', nargs='*', help='only these cases')
    parser.add_argument('--document-only', action='store_true',
                        help='rewrite the document and figures from results.json')
    args = parser.parse_args()
    if args.document_only:
        return document_only(args)
    names = args.cases or (QUICK_CASES if args.quick else [c.name for c in CASES])
    unknown = set(names) - {c.name for c in CASES}
    if unknown:
        parser.error(f'--cases: no case {", ".join(sorted(unknown))} (cases: {", ".join(c.name for c in CASES)})')
    cases = [c for c in CASES if c.name in names]
    out = REPO / 'out' / ('field-check-quick' if args.quick else 'field-check')
    out.mkdir(parents=True, exist_ok=True)
    refusal = several_runs_refusal()
    if refusal:
        print(f'field_check: {refusal}', file=sys.stderr)
    head = commit()
    t0 = time.time()
    jobs = [(c, rep) for c in cases for rep in range(args.reps or (1 if args.quick else c.reps or 3))]
    with ThreadPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        results = list(pool.map(lambda j: run_case(j[0], j[1], args.quick, not refusal, out), jobs))
    scale = QUICK_HOURS / FIT_HOURS if args.quick else 1.0
    meta = {'command': 'nice -n 10 ' + ' '.join(['python', 'research/studies/field_check.py', *sys.argv[1:]]),
            'commit': head, 'minutes': (time.time() - t0) / 60.0, 'jobs': args.jobs, 'out': str(out.relative_to(REPO)),
            'fit_hours': FIT_HOURS * scale, 'protocol_scale': scale,
            'cold_hours': QUICK_HOURS if args.quick else COLD_SECOND_HOURS, 'several_runs_skipped': refusal}
    (out / 'results.json').write_text(json.dumps({'meta': meta, 'results': results}, indent=1))
    fig_dir, doc_dir = write_outputs(results, meta, args.quick, out)
    for r in results:
        s = r['scores']
        print(f"{r['case']:>24} {r['rep']} ({r['seconds']:.0f} s): " + '  '.join(
            f"{n}: " + ' '.join(f"{lab}={v['sys_rms_dph']:.2f}" for lab, v in s[n].items()) for n in s))
    for row in targets(results):
        print(f"{'pass' if row['passed'] else 'FAIL'} {row['target']}: {row['case']} {row['calibration']} "
              f"{row['value']:.2f}")
    print(f'wrote {out / "results.json"}, {fig_dir}/field-*.png, {doc_dir / "field-check.md"} '
          f'in {meta["minutes"]:.1f} min')
    return 0


if __name__ == '__main__':
    sys.exit(main())
