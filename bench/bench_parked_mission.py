"""The parked bias measured: heading error over a day-long mission with a wandering bias, and creeps refused.

``python bench/bench_parked_mission.py [--missions 20] [--seed 1] [--quick]`` simulates an RD2100 (NAVC3545's
polynomial and counts of 0.00305 deg/s, white noise of 0.1 deg/sqrt(h) at 10 Hz, a Gauss-Markov bias wander sized so
that 3 sigma of its heading error over 10 minutes is 1 degree) on a robot that drives legs with turns and stops
for 10 s to 10 min (log-uniform), a Bool topic saying "parked" one frame late. The heading error (the corrected
rate integrated, less the true heading) is reported for:

- the start-up static bias alone;
- the service called at every stop of 2 min or more (a user before each job);
- the parked bias on the Bool, and on the Bool with ``parked_bias.gyro_stillness``.

Then false updates: a robot that creeps at 0.05-0.5 deg/s while its topic says parked, and a sweep of slower
creeps for the smallest one the gyro's stillness always refuses.

The collections are the node's (:mod:`art_gyro_calibration.ros.bias_service`'s ``_Collection`` and
``_ParkedCollection``: the static bias checks, :func:`~art_gyro_calibration.parked.check_parked`), fed in the node's
order by :class:`~art_gyro_calibration.parked.ParkedBias` on the simulated clock: each frame, the topic's word,
then the parked check (start or abort), then the frame into the running collection, whose bias is in force from
the frame that completes it. The modelled error is the polynomial's, vectorised as ``calibrate apply`` computes it.
The fake gyro is not used: it runs in real time (a day would take a day); ``test/ros/test_node_parked_bias.py``
runs the node on it end to end.
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from art_gyro_calibration.calibration import Calibration, load_packaged_calibration
from art_gyro_calibration.gyro_physics import measured_from_true, to_counts, white_noise_dps
from art_gyro_calibration.parked import ParkedBias, ParkedSettings, odometry_parked
from art_gyro_calibration.ros.bias_service import _Collection, _ParkedCollection
from art_gyro_calibration.ros.parameters import PARAMETERS, Settings
from art_gyro_calibration.signals import compute_signals
from art_gyro_calibration.static_bias import NO_BIAS, MotionError, StaticBias

RATE_HZ = 10.0
ARW_DEG_RTHR = 0.1
SERIAL = 'NAVC3545'
DAY_S = 86400.0
# The bias wander: Gauss-Markov, correlation time WANDER_TAU_S; its rate random walk K (deg/s/sqrt(s)) is such that
# 3 sigma of the heading error it makes over 10 min (K 600^1.5 / sqrt(3) while 600 s << tau) is 1 degree.
WANDER_TAU_S = 7200.0
WANDER_K = (1.0 / 3.0) * math.sqrt(3.0) / 600.0 ** 1.5
WANDER_SIGMA_DPS = WANDER_K * math.sqrt(WANDER_TAU_S / 2.0)
TURN_ON_BIAS_SIGMA_DPS = 0.02
STOP_S = (10.0, 600.0)           # stops, log-uniform
LEG_S = (60.0, 1200.0)           # legs of driving, log-uniform
SERVICE_STOP_S = 120.0           # (b): the service is called at every stop this long, 2 s into it
TOPIC_LAG = 1                    # the Bool reports the robot's state one frame late
WINDOW_S = 600.0                 # the heading error's change over 10-minute windows
CREEPS_DPS = (0.05, 0.1, 0.2, 0.5)
SWEEP_DPS = (0.002, 0.004, 0.006, 0.008, 0.01, 0.012, 0.015, 0.02)


@dataclass
class Mission:
    """One simulated mission: per frame, the time, the true rate, the gyro's scaled rate and modelled error."""

    t: NDArray[np.float64]
    true_dps: NDArray[np.float64]
    rate_dps: NDArray[np.float64]
    comp_dps: NDArray[np.float64]
    parked: NDArray[np.bool_]                          # what the topic says at each frame (before its lag)
    stops: list[tuple[int, int]] = field(default_factory=list)   # frames [start, end) of each stop


def wander(n: int, rng: np.random.Generator) -> NDArray[np.float64]:
    """A Gauss-Markov bias wander of ``n`` frames, vectorised: b_k = phi^k (b_0 + sum phi^-j w_j)."""
    phi = math.exp(-1.0 / (RATE_HZ * WANDER_TAU_S))
    w = rng.normal(0.0, WANDER_SIGMA_DPS * math.sqrt(1.0 - phi * phi), n)
    w[0] = rng.normal(0.0, WANDER_SIGMA_DPS)
    growth = phi ** -np.arange(n, dtype=float)   # at most e^12 over a day: well within float range and precision
    return np.asarray(np.cumsum(w * growth) / growth, dtype=np.float64)


def gyro(calibration: Calibration, true_dps: NDArray[np.float64], rng: np.random.Generator
         ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(scaled rate, modelled error) of the gyro for ``true_dps``: polynomial, bias, wander, noise, counts."""
    n = len(true_dps)
    t = np.arange(n) / RATE_HZ
    temp = 25.0 + 5.0 * np.sin(2.0 * np.pi * t / DAY_S)   # a daily swing within the calibrated range
    measured = (measured_from_true(calibration.polynomial, true_dps, temp) + rng.normal(0.0, TURN_ON_BIAS_SIGMA_DPS)
                + wander(n, rng) + rng.normal(0.0, white_noise_dps(ARW_DEG_RTHR, RATE_HZ), n))
    rate = to_counts(measured, calibration.rate_scale_factor) * calibration.rate_scale_factor
    temp_c = to_counts(temp, calibration.temp_scale_factor) * calibration.temp_scale_factor
    comp = calibration.model.error(compute_signals(t, rate, temp_c, {}, calibration.filters))
    return rate, comp


def day_mission(calibration: Calibration, rng: np.random.Generator, duration_s: float = DAY_S) -> Mission:
    """A mission: a 60 s start at rest, then legs (straight with a yaw wobble, turns of 10-45 deg/s) and stops."""
    true: list[NDArray[np.float64]] = [np.zeros(int(60 * RATE_HZ))]
    parked: list[NDArray[np.bool_]] = [np.ones(int(60 * RATE_HZ), dtype=bool)]
    stops = [(0, len(true[0]))]
    n = len(true[0])
    total = int(duration_s * RATE_HZ)
    while n < total:
        leg = int(math.exp(rng.uniform(*np.log(LEG_S))) * RATE_HZ)
        rate = rng.normal(0.0, 0.1, leg)   # the true yaw wobble of driving straight
        k = int(rng.uniform(5, 60) * RATE_HZ)
        while k < leg:
            turn = int(rng.uniform(1, 6) * RATE_HZ)
            rate[k:k + turn] += rng.choice((-1.0, 1.0)) * rng.uniform(10, 45)
            k += turn + int(rng.uniform(5, 60) * RATE_HZ)
        stop = int(math.exp(rng.uniform(*np.log(STOP_S))) * RATE_HZ)
        true += [rate, np.zeros(stop)]
        parked += [np.zeros(leg, dtype=bool), np.ones(stop, dtype=bool)]
        stops.append((n + leg, n + leg + stop))
        n += leg + stop
    true_dps = np.concatenate(true)[:total]
    rate, comp = gyro(calibration, true_dps, rng)
    return Mission(np.arange(total) / RATE_HZ, true_dps, rate, comp, np.concatenate(parked)[:total],
                   [(a, min(b, total)) for a, b in stops if a < total])


@dataclass
class Outcome:
    """The biases put in force (frame from which, bias) and the parked bias logic's counts."""

    biases: list[tuple[int, StaticBias]]
    updates: int = 0
    refused: dict[str, int] = field(default_factory=dict)


def collect(collection: _Collection, mission: Mission, first: int) -> tuple[int, StaticBias | None]:
    """Feed the service's collection from frame ``first``: (the frame that completed it, its bias or None)."""
    k = first
    while not collection.add(float(mission.rate_dps[k]), float(mission.comp_dps[k]), float(mission.t[k])):
        k += 1
    try:
        return k, collection.result()
    except (MotionError, ValueError):
        return k, None


def service_biases(mission: Mission, settings: Settings, min_stop_s: float) -> Outcome:
    """The start-up bias, and the service's at every stop of ``min_stop_s`` or more (inf: the start-up's alone)."""
    biases = []
    for n, (a, b) in enumerate(mission.stops):
        if n and b - a < min_stop_s * RATE_HZ:
            continue
        collection = _Collection(settings.bias_samples, settings.static_bias_max_mean_dps,
                                 settings.static_bias_max_std_dps, False)
        first = a if n == 0 else a + int(2 * RATE_HZ)
        k, bias = collect(collection, mission, first)
        if bias is not None:
            biases.append((k, bias))
    return Outcome(biases)


def parked_biases(mission: Mission, settings: Settings, stillness: bool, odometry_dps: float | None = None) -> Outcome:
    """The start-up bias, then the parked bias as the node runs it on the simulated clock.

    ``odometry_dps``: the topic is odometry whose twist reads this yaw rate while parked (else a Bool).
    """
    parked_settings = ParkedSettings(True, stillness, settings.parked_bias_max_age_s, settings.parked_bias_settle_s,
                                     settings.parked_bias_min_interval_s)
    logic = ParkedBias(parked_settings, 0.0)
    startup = _Collection(settings.bias_samples, settings.static_bias_max_mean_dps, settings.static_bias_max_std_dps,
                          False)
    end, bias = collect(startup, mission, 0)
    biases = [(end, bias)] if bias is not None else []
    logic.bias_taken(float(mission.t[end]))
    in_force = bias or NO_BIAS
    max_std = min(settings.static_bias_max_std_dps, settings.parked_bias_max_std_dps) if stillness else \
        settings.static_bias_max_std_dps
    words = mission.parked.tolist()
    if odometry_dps is not None:   # the odometry's twist, through the node's test of it
        word = odometry_parked((0.0, 0.0, 0.0), (0.0, 0.0, math.radians(odometry_dps)),
                               settings.parked_bias_max_linear_mps, settings.parked_bias_max_angular_dps)
        words = [w and word for w in words]
    rate, comp, t = mission.rate_dps.tolist(), mission.comp_dps.tolist(), mission.t.tolist()
    running: _ParkedCollection | None = None
    for k in range(end + 1, len(t)):
        now = t[k]
        logic.put(words[max(k - TOPIC_LAG, 0)], now)
        if running is None:
            if logic.due(now):
                logic.start(now)
                running = _ParkedCollection(settings.bias_samples, settings.static_bias_max_mean_dps, max_std, False,
                                            in_force, stillness)
        elif (broken := logic.broken(now)) is not None:
            logic.ended(now, broken)
            running = None
        if running is not None and running.add(rate[k], comp[k], now):
            try:
                if (broken := logic.broken(now)) is not None:
                    raise broken
                in_force = running.result()
            except (MotionError, ValueError) as e:
                logic.ended(now, e)
            else:
                logic.ended(now, None)
                biases.append((k, in_force))
            running = None
    return Outcome(biases, logic.updates, dict(logic.refused))


def heading_error(mission: Mission, outcome: Outcome) -> NDArray[np.float64]:
    """Heading error (deg) per frame from the start-up bias on: each bias corrects from its frame to the next's."""
    start = outcome.biases[0][0]
    error = np.empty(len(mission.t) - start)
    ends = [k for k, _ in outcome.biases[1:]] + [len(mission.t)]
    for (k, bias), end in zip(outcome.biases, ends):
        corrected = bias.correct(mission.rate_dps[k:end], mission.comp_dps[k:end])
        error[k - start:end - start] = corrected - mission.true_dps[k:end]
    return np.asarray(np.cumsum(error) / RATE_HZ, dtype=np.float64)


def window_changes(error: NDArray[np.float64]) -> NDArray[np.float64]:
    """|change| of the heading error over every 10-minute window, a minute apart."""
    w, step = int(WINDOW_S * RATE_HZ), int(60 * RATE_HZ)
    return np.asarray(np.abs(error[w::step] - error[:-w:step][:len(error[w::step])]), dtype=np.float64)


def default_settings() -> Settings:
    """The node's settings at its parameters' defaults."""
    return Settings(**{name.replace('.', '_'): entry[0] for name, entry in PARAMETERS.items()})


def ten_minute_reference(calibration: Calibration, rng: np.random.Generator, runs: int) -> NDArray[np.float64]:
    """|heading error| 10 min after a start-up bias, on ``runs`` missions at rest then driving."""
    settings = default_settings()
    out = []
    for _ in range(runs):
        mission = day_mission(calibration, rng, 60.0 + WINDOW_S + 20.0)
        error = heading_error(mission, service_biases(mission, settings, math.inf))
        out.append(abs(error[int(WINDOW_S * RATE_HZ)]))
    return np.array(out)


def creep_mission(calibration: Calibration, rng: np.random.Generator, creep_dps: float, stops: int) -> Mission:
    """A start at rest, then ``stops`` times: a 30 s leg and a 30 s stop that creeps at ``creep_dps``, "parked"."""
    leg, stop = int(30 * RATE_HZ), int(30 * RATE_HZ)
    start = int(20 * RATE_HZ)
    n = start + stops * (leg + stop)
    true = np.zeros(n)
    parked = np.zeros(n, dtype=bool)
    parked[:start] = True
    spans = [(0, start)]
    for i in range(stops):
        a = start + i * (leg + stop)
        true[a:a + leg] = rng.normal(0.0, 0.1, leg)
        true[a + int(5 * RATE_HZ):a + int(10 * RATE_HZ)] += 20.0
        true[a + leg:a + leg + stop] = creep_dps
        parked[a + leg:a + leg + stop] = True
        spans.append((a + leg, a + leg + stop))
    rate, comp = gyro(calibration, true, rng)
    return Mission(np.arange(n) / RATE_HZ, true, rate, comp, parked, spans)


def long_enough(mission: Mission, settings: Settings) -> int:
    """Stops after the start long enough for a parked bias: ``settle_s`` and the window (the lag delays both ends)."""
    need = settings.parked_bias_settle_s * RATE_HZ + settings.bias_samples
    return sum(b - a >= need for a, b in mission.stops[1:])


def creep_taken(calibration: Calibration, rng: np.random.Generator, settings: Settings, creep_dps: float,
                trials: int, stillness: bool, odometry: bool) -> int:
    """Parked biases taken on ``trials`` creep missions of 4 stops each (every one is false)."""
    return sum(parked_biases(creep_mission(calibration, rng, creep_dps, 4), settings, stillness,
                             creep_dps if odometry else None).updates for _ in range(trials))


def main(argv: Sequence[str] | None = None) -> int:
    """Run the missions and the creeps; print the tables."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--missions', type=int, default=20, help='day-long missions (default 20)')
    parser.add_argument('--seed', type=int, default=1)
    parser.add_argument('--quick', action='store_true', help='a smoke test: 2 missions of 2 h, fewer creeps')
    args = parser.parse_args(argv)
    started = time.process_time()
    rng = np.random.default_rng(args.seed)
    calibration = load_packaged_calibration(SERIAL)
    settings = default_settings()
    missions, duration = (2, 7200.0) if args.quick else (args.missions, DAY_S)
    print(f'{missions} missions of {duration / 3600:g} h at {RATE_HZ:g} Hz; wander: Gauss-Markov, tau '
          f'{WANDER_TAU_S / 3600:g} h, sigma {WANDER_SIGMA_DPS * 3600:.2f} deg/h (K {WANDER_K * 3600 * 60:.2f} '
          f'deg/h/sqrt(h)); bias_samples {settings.bias_samples}')
    strategies: dict[str, Callable[[Mission], Outcome]] = {
        'start-up bias alone': lambda m: service_biases(m, settings, math.inf),
        f'service at stops >= {SERVICE_STOP_S:g} s': lambda m: service_biases(m, settings, SERVICE_STOP_S),
        'parked bias (Bool)': lambda m: parked_biases(m, settings, False),
        'parked bias (Bool + gyro stillness)': lambda m: parked_biases(m, settings, True)}
    rows: dict[str, list[tuple[float, float, float, int, dict[str, int]]]] = {name: [] for name in strategies}
    stops = enough = 0
    for _ in range(missions):
        mission = day_mission(calibration, rng, duration)
        stops += len(mission.stops) - 1
        enough += long_enough(mission, settings)
        for name, strategy in strategies.items():
            outcome = strategy(mission)
            error = heading_error(mission, outcome)
            rows[name].append((abs(float(error[-1])), float(np.max(np.abs(error))),
                               float(np.percentile(window_changes(error), 95)), len(outcome.biases) - 1,
                               outcome.refused))
    reference = ten_minute_reference(calibration, rng, 20 if args.quick else 200)
    print(f'{stops} stops in all, {enough} long enough for a parked bias; a 10-minute mission after a start-up bias: '
          f'|heading error| median {np.median(reference):.2f}, 95th percentile {np.percentile(reference, 95):.2f} deg '
          f'({len(reference)} runs)')
    print('\n| strategy | end of mission, median (max) | largest over the mission, median (max) '
          '| 10-min change, 95th pct, median (max) | biases taken after the start-up one | parked refused |')
    print('|---|---:|---:|---:|---:|---|')
    for name, values in rows.items():
        end, peak, window, taken = (np.array([v[i] for v in values], dtype=float) for i in range(4))
        refused: dict[str, int] = {}
        for v in values:
            for reason, count in v[4].items():
                refused[reason] = refused.get(reason, 0) + count
        said = ', '.join(f'{r} {c}' for r, c in refused.items() if c) or ('none' if refused else '-')
        print(f'| {name} | {np.median(end):.2f} ({end.max():.2f}) deg | {np.median(peak):.2f} ({peak.max():.2f}) '
              f'deg | {np.median(window):.2f} ({window.max():.2f}) deg | {taken.sum():.0f} | {said} |')

    trials = 5 if args.quick else 50
    print(f'\nFalse updates: per creep rate, {trials} missions of 4 stops (30 s) creeping while the topic says parked, '
          'after a start-up bias at rest: parked biases taken (each one false)')
    configs = {'Bool + gyro stillness': (True, False), 'Bool alone': (False, False),
               'odometry (reads the creep)': (False, True)}
    print('| creep (deg/s) | ' + ' | '.join(configs) + ' |')
    print('|---:|' + '---:|' * len(configs))
    for creep in CREEPS_DPS if args.quick else sorted(CREEPS_DPS + SWEEP_DPS):
        counts = [creep_taken(calibration, rng, settings, creep, trials, stillness, odometry)
                  for stillness, odometry in configs.values()]
        print(f'| {creep:g} | ' + ' | '.join(f'{c} of {4 * trials}' for c in counts) + ' |')
    print(f'\nCPU {time.process_time() - started:.0f} s')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
