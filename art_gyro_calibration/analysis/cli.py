"""``calibrate``: apply a calibration to a log, fit one to a rate-table log, simulate a run, record a gyro.

- ``calibrate apply LOG.csv --calibration FILE --out OUT.csv [--bias-samples N]``
- ``calibrate fit LOG.csv [LOG2.csv ...] --rows R --columns C [--serial SN] --out CAL.yaml --report REPORT.json
  [--plots DIR] [--warm-start LOG2.csv] [--validate OTHER_LOG ...] [--node-signal COLUMN ...]``
- ``calibrate replay OTHER_LOG.csv --calibration CAL.yaml [--start-s S] [--bias-samples N]``
- ``calibrate simulate --serial SN --hours H --out LOG.csv [--effect NAME ...] [--self-heating-c DT]
  [--self-heating-tau-s TAU]``
- ``calibrate record --port P --out BAG_OR_LOG.csv [--protocol binary] [--baud 9600] [--serial SN] [--duration S]``
- ``calibrate allan LOG_OR_BAG --out ALLAN.json [--plots DIR] [--serial SN] [--node-rate-hz F]``

Wherever a log is read, a rosbag2 (a directory with metadata.yaml, an .mcap or a .db3) is
read too (:mod:`.bags`); ``--rate-topic``, ``--temperature-topic``, ``--reference-topic``
and ``--extra-topic NAME=TOPIC`` say which of its topics make the log.

Errors in the input (a bad log, a bad calibration, a gyro that moved during the
static bias) are reported on stderr with a non-zero exit status. Outputs are checked
before the work starts and written whole or not at all (:mod:`.outputs`): an existing
one is replaced only with ``--force``, an input never. ``record`` alone writes in place
as frames come, so that a stop keeps what nothing can make again.
"""

from __future__ import annotations

import argparse
import ctypes
import math
import queue
import signal
import sys
import time
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path

from art_gyro_calibration.calibration import (DEFAULT_RATE_SCALE_FACTOR, PLAUSIBLE_TEMPERATURE_C, Calibration,
                                              CalibrationError, find_calibration_file, load_calibration,
                                              write_calibration)
from art_gyro_calibration.compensation import RunStart
from art_gyro_calibration.log import CutRowWarning, LogError, RawLogWriter
from art_gyro_calibration.analysis.bags import BagTopics
from art_gyro_calibration.analysis.loop import DEFAULT_MAX_EFFECTS, DEFAULT_SERIAL, LoopOptions
from art_gyro_calibration.static_bias import DEFAULT_SAMPLES, MotionError
from art_gyro_calibration.analysis.outputs import Outputs
from art_gyro_calibration.analysis.progress import Progress, Ticker, clear
from art_gyro_calibration.analysis.trace import DEFAULT_ALPHA, DEFAULT_BLOCK_S, DEFAULT_DRAWS


def _apply(args: argparse.Namespace) -> int:
    from art_gyro_calibration.analysis.replay import unapplied_warm_up
    from art_gyro_calibration.analysis.streaming import apply_to_csv
    with Outputs([args.log, args.calibration], args.force) as outputs:
        out = outputs.claim(args.out)
        calibration = load_calibration(args.calibration)
        _recorded_serial(args.log, calibration.serial_number, f'the calibration\'s ({args.calibration})')
        _warn_if(unapplied_warm_up(calibration, RunStart(args.powered_on_at_start)))
        with open(out, 'wb') as stream:
            done = apply_to_csv(args.log, calibration, args.bias_samples, stream,
                                start=RunStart(args.powered_on_at_start), topics=_topics(args))
    low, high = PLAUSIBLE_TEMPERATURE_C
    print(f'{args.out}: {done.rows - done.dropped} of {done.rows} rows; {done.dropped} dropped as the node drops '
          f'them (temperature outside {low:g}..{high:g} degC); {_outside(calibration, done.outside_range)}'
          f'{done.bias.describe()}')
    for name, (held, beyond) in done.flagged.items():   # rows the node would flag: not corrected as logged
        if held or beyond:
            low, high = calibration.signal_limits(name)
            _warn(f'{name}: {held} rows not finite (the last finite value held) and {beyond} beyond {low:g}..'
                  f'{high:g} (applied at the limit): the node flags such rates uncorrected')
    if done.beyond_unit_range:
        _warn(f'{done.beyond_unit_range} rows whose corrected rate is beyond the unit\'s range '
              f'+-{calibration.rate_range_dps:g} deg/s: written uncorrected (the log\'s rate), as the node publishes '
              'them flagged uncorrected')
    return 0


def _recorded_serial(log: str, serial: str | None, whose: str) -> str | None:
    """The gyro's serial number: ``serial``, checked against the one ``calibrate record`` kept in ``log``, else that.

    A log recorded from another gyro is refused: its calibration would be nonsense.
    """
    from art_gyro_calibration.analysis.bags import recorded_serial
    recorded = recorded_serial(log)
    if recorded and serial and recorded != serial:
        raise ValueError(f'{log}: recorded from gyro {recorded}, not {serial} as {whose} says')
    if recorded and not serial:
        _stderr(f'calibrate: {log}: recorded from gyro {recorded}: taken as its serial number')
    return serial or recorded


def _outside(calibration: Calibration, rows: int) -> str:
    """The summary's words on the rows outside the calibration's range, and what was done with them."""
    if calibration.temperature_range_c is not None:
        low, high = calibration.temperature_range_c
        return f'{rows} outside the calibrated range {low:g}..{high:g} degC, {calibration.beyond_range}; '
    if calibration.temperature_warn_range_c is not None:
        low, high = calibration.temperature_warn_range_c
        return (f'{rows} outside the calibrated range {low:g}..{high:g} degC (temperature_warn_range_c, assumed: '
                'the polynomial applied as the report does, not clamped); ')
    return ''


def _fit(args: argparse.Namespace) -> int:
    from art_gyro_calibration.analysis.baseline import operating_range
    from art_gyro_calibration.analysis.pipeline import FitSettings, fit_log, scale_factors
    from art_gyro_calibration.analysis.report import write_report
    operating = None if args.operating_range is None else operating_range(*args.operating_range)
    with Outputs([*args.log, *args.validate, args.still, *([args.baseline] if args.baseline else [])],
                 args.force) as outputs:
        out = outputs.claim(args.out)
        report_path = outputs.claim(args.report, beside=[Path(args.report).with_suffix('.md')])
        plots = outputs.claim_directory(args.plots, f'{args.plot_prefix}*.png') if args.plots else None
        for log in args.log:   # every run of one gyro: a serial recorded in one holds for the others
            args.serial = _recorded_serial(log, args.serial, '--serial')
        scale = scale_factors(args.serial, args.rate_scale_factor)
        if scale.assumed:   # said whether the log is raw or not: the node scales by the factor written
            print(f'calibrate fit: no --rate-scale-factor and no packaged calibration of {args.serial or "the gyro"}: '
                  f'using the usual {scale.rate} deg/s per count', file=sys.stderr)
        loop = LoopOptions(serial_number=args.serial or DEFAULT_SERIAL, rate_scale_factor=scale.rate,
                           temp_scale_factor=scale.temp, settle_s=args.settle_s, max_effects=args.max_effects,
                           seed=args.seed, exclude=tuple(args.exclude), block_s=args.block_s,
                           materiality_dph=args.materiality, draws=args.draws, alpha=args.alpha,
                           from_power_on=not args.not_from_power_on, node_signals=tuple(args.node_signal))
        settings = FitSettings(args.rows, args.columns, loop, args.bias_samples, tuple(args.validate),
                               args.validate_powered_on_at_start, topics=_topics(args), still=args.still,
                               baseline=args.baseline, operating_range_c=operating,
                               warm_start=tuple(args.warm_start))
        with Ticker(f'calibrate fit: {", ".join(Path(log).name for log in args.log)}'):
            fitted = fit_log(args.log, settings, str(args.out),
                             lambda warning: _stderr(f'calibrate fit: warning: {warning}'))
            write_calibration(out, fitted.calibration, fitted.comment)
            summary = write_report(report_path, fitted.report).read_text(encoding='utf-8')
            if plots is not None:
                from art_gyro_calibration.analysis.plots import plot_all
                plot_all(fitted.log, fitted.loop, args.bias_samples, plots, args.plot_prefix)
    print(summary, end='')
    return 0


def _replay(args: argparse.Namespace) -> int:
    from art_gyro_calibration.analysis.replay import replay, restart, unapplied_warm_up, without_terms
    from art_gyro_calibration.analysis.report import field_table
    from art_gyro_calibration.analysis.bags import read_any_log
    calibration = load_calibration(args.calibration)
    _recorded_serial(args.log, calibration.serial_number, f'the calibration\'s ({args.calibration})')
    log = read_any_log(args.log, calibration.rate_scale_factor, calibration.temp_scale_factor, _topics(args), _warn)
    if args.start_s:
        log = restart(log, args.start_s)
    start = RunStart(powered_on_at_start=args.powered_on_at_start)
    _warn_if(unapplied_warm_up(calibration, start))
    rows = [(f'{args.log} from {args.start_s:g} s', name,
             replay(log, c, args.bias_samples, args.settle_s, start).field.to_dict())
            for name, c in (('art', without_terms(calibration)), ('extended', calibration))]
    print('\n'.join(field_table(rows)))
    return 0


def _simulate(args: argparse.Namespace) -> int:
    from art_gyro_calibration.calibration import load_packaged_calibration
    from art_gyro_calibration.analysis.simulate import SimulationSettings, simulate_run, truth_path, write_run
    with Outputs([], args.force) as outputs:
        out = outputs.claim(args.out, beside=[truth_path(args.out)])
        calibration = load_packaged_calibration(args.serial)
        settings = SimulationSettings(hours=args.hours, rate_hz=args.rate_hz, effects=tuple(args.effect),
                                      seed=args.seed, self_heating_c=args.self_heating_c,
                                      self_heating_tau_s=args.self_heating_tau_s)
        with Ticker(f'calibrate simulate: {args.hours:g} h at {args.rate_hz:g} Hz'):
            try:
                run = simulate_run(calibration, settings)
            except ValueError as e:   # a self-heating as wide as the calibrated range
                raise ValueError(f'--self-heating-c: {e}') from None
            write_run(out, run)
    print(f'{args.out}: {len(run.columns["t"])} rows of {args.serial} '
          f'(effects: {", ".join(args.effect) or "none"}); truth in {truth_path(args.out)}')
    return 0


def _allan(args: argparse.Namespace) -> int:
    import json
    from art_gyro_calibration.analysis.bags import csv_rate_chunks, is_bag, rate_chunks
    from art_gyro_calibration.analysis.noise import allan_of_record, check_node_rate, plot_allan, table_at_rest
    from art_gyro_calibration.analysis.pipeline import scale_factors
    from art_gyro_calibration.log import read_log_chunks
    if args.node_rate_hz is not None:
        check_node_rate(args.node_rate_hz)
    with Outputs([args.log], args.force) as outputs:
        out = outputs.claim(args.out)
        plots = outputs.claim_directory(args.plots, 'allan*.png') if args.plots else None
        total: float   # a bag's messages, or the rows a CSV's size gives
        if is_bag(args.log):
            total, chunks = rate_chunks(args.log, args.rate_topic)
        else:
            args.serial = _recorded_serial(args.log, args.serial, '--serial')
            given = args.serial or args.rate_scale_factor is not None
            scale = scale_factors(args.serial, args.rate_scale_factor) if given else None
            rate_scale, temp_scale = (scale.rate, scale.temp) if scale else (None, None)
            total = csv_rate_chunks(args.log, rate_scale, temp_scale)[0]   # its size; the rows read with ref_rate
            chunks = table_at_rest(read_log_chunks(args.log, rate_scale, temp_scale), str(args.log))
        try:
            result = allan_of_record(chunks, str(args.log), args.node_rate_hz, total)
        except LogError as e:
            if 'raw counts need' in str(e):
                raise LogError(f'{e}: give --serial or --rate-scale-factor') from None
            raise
        out.write_text(json.dumps(result.to_dict(), indent=1) + '\n', encoding='utf-8')
        if plots is not None:
            plot_allan(result, plots / 'allan.png')
    if result.stats.gaps:
        _warn(f'{result.stats.gaps} gaps in the record (the longest {result.stats.longest_gap_s:.3g} s): the Allan '
              'deviation takes the samples as equally spaced')
    named = result.terms.to_dict()
    print(f'{args.out}: {result.stats.samples} samples at {result.stats.sample_rate_hz:.6g} Hz; '
          f'ARW {named["arw_deg_per_sqrt_h"]:.4g} deg/sqrt(h), bias instability '
          f'{named["bias_instability_deg_per_h"]:.4g} deg/h, rate random walk '
          f'{named["rate_random_walk_deg_per_h_per_sqrt_h"]:.4g} deg/h/sqrt(h)')
    if result.node.limited_by:
        _warn(f'bias_samples: {result.node.limited_by}')
    print(result.node.snippet(), end='')
    return 0


def _warn(message: str) -> None:
    _stderr(f'calibrate: warning: {message}')


def _stderr(line: str) -> None:
    """A line on stderr, on its own line whatever progress is shown."""
    clear()
    print(line, file=sys.stderr, flush=True)


def _warn_if(message: str) -> None:
    """:func:`_warn` a message that may be empty (nothing to say)."""
    if message:
        _warn(message)


def _topics(args: argparse.Namespace) -> BagTopics:
    """The bag topics the options name (only a bag reads them)."""
    return BagTopics(args.rate_topic, args.temperature_topic, args.reference_topic, dict(args.extra_topic))


def _bag_options(p: argparse.ArgumentParser, reference: bool = True) -> None:
    """Which topics of a rosbag2 input make the log."""
    p.add_argument('--rate-topic', default=BagTopics.rate,
                   help='rosbag2 input: sensor_msgs/Imu topic of the rate (angular_velocity.z, rad/s; '
                        'default %(default)s, the node\'s rate with only the scale factor applied)')
    if not reference:
        return
    p.add_argument('--temperature-topic', default=BagTopics.temperature,
                   help='rosbag2 input: std_msgs/Float64 topic of the temperature, degC (default %(default)s)')
    p.add_argument('--reference-topic',
                   help='rosbag2 input: the rate table\'s true rate (ref_rate): std_msgs/Float64 in deg/s, or '
                        'geometry_msgs/TwistStamped or sensor_msgs/Imu angular z in rad/s (default: none)')
    p.add_argument('--extra-topic', action='append', default=[], type=_extra_topic, metavar='NAME=TOPIC',
                   help='rosbag2 input: a numeric topic (std_msgs/Float64, ...) as the log column NAME; repeat')


def _extra_topic(text: str) -> tuple[str, str]:
    name, sep, topic = text.partition('=')
    if not sep or not name.strip() or not topic.strip():
        raise argparse.ArgumentTypeError(f'must be NAME=TOPIC, got {text!r}')
    return name.strip(), topic.strip()


# Silence after which ``calibrate record`` says that nothing arrives (and why, as far as the driver knows).
RECORD_SILENCE_S = 1.0


def _record(args: argparse.Namespace) -> int:
    from art_gyro_calibration.driver import SerialGyroDriver
    from art_gyro_calibration.analysis.outputs import OutputError
    from art_gyro_calibration.analysis.pipeline import scale_factors
    if args.serial:
        load_calibration(find_calibration_file(args.serial), expected_serial=args.serial)
    bag = (args.format or ('csv' if Path(args.out).suffix.lower() == '.csv' else 'bag')) == 'bag'
    if bag and Path(args.out).suffix.lower() in ('.mcap', '.db3'):
        raise OutputError(f'{args.out}: a bag is written as a directory (metadata.yaml and an .mcap file in it): '
                          'name it without .mcap')
    if bag and Path(args.out).exists():
        raise OutputError(f'{args.out}: exists; a bag is never replaced (--force or not): name another')
    out = Outputs([args.port], args.force).check(args.out)   # written in place: what came is kept if stopped
    scale = scale_factors(args.serial, args.rate_scale_factor)
    if bag and scale.assumed:
        _warn(f'no --rate-scale-factor and no --serial: the bag\'s rates use the usual {scale.rate} deg/s per count')
    frames: queue.SimpleQueue[tuple[int, float, float]] = queue.SimpleQueue()
    driver = SerialGyroDriver(args.port, args.baud, args.protocol,
                              lambda f: frames.put((f.stamp_ns, f.sample.raw_rate, f.sample.raw_temp)))
    previous = signal.signal(signal.SIGTERM, _interrupt)   # end as on Ctrl-C: keep what was recorded
    driver.start()   # opens the port on its thread; the log is created at the first frame
    try:
        sink = _BagRecord(out, args.serial, scale.rate, scale.temp) if bag else _CsvRecord(out, args.serial, args.force)
        count = _record_frames(frames, sink, args.port, args.duration, lambda: driver.stats.last_error)
    finally:
        driver.stop()
        signal.signal(signal.SIGTERM, previous)
    stats = driver.stats
    if not count:
        raise OSError(f'no frames from {args.port} ({stats.last_error or "nothing received"}); '
                      f'{args.out} not written')
    print(f'{args.out}: {count} frames from {args.port} ({stats.rejected} rejected, {stats.reopens} reopens)'
          f'{"; serial number " + args.serial + " kept in it" if args.serial else ""}')
    return 0


class _CsvRecord:
    """A raw CSV log (t, raw_rate, raw_temp) created at the first frame, rows flushed in batches as they come."""

    def __init__(self, out: Path, serial: str | None, replace: bool) -> None:
        self._out, self._serial, self._mode = out, serial, 'w' if replace else 'x'
        self._writer: RawLogWriter | None = None

    def write(self, stamp_ns: int, raw_rate: float, raw_temp: float) -> None:
        if self._writer is None:
            from art_gyro_calibration.analysis.bags import SERIAL_COMMENT
            stream = open(self._out, self._mode, encoding='utf-8')
            self._writer = RawLogWriter(stream)
            if self._serial:
                stream.write(f'{SERIAL_COMMENT}{self._serial}\n')   # a comment line: the readers skip it
        self._writer.write(stamp_ns * 1e-9, raw_rate, raw_temp)

    def close(self) -> None:
        if self._writer is not None:
            self._writer.close()


class _BagRecord:
    """A rosbag2 of the node's topics (:class:`.bags.BagWriter`) created at the first frame, scaled as the node does."""

    def __init__(self, out: Path, serial: str | None, rate_scale: float, temp_scale: float) -> None:
        from art_gyro_calibration.analysis.bags import BagWriter
        self._out, self._serial = out, serial
        self._scale = rate_scale, temp_scale
        self._writer: BagWriter | None = None

    def write(self, stamp_ns: int, raw_rate: float, raw_temp: float) -> None:
        if self._writer is None:
            from art_gyro_calibration.analysis.bags import BagWriter
            self._writer = BagWriter(self._out, self._serial)
        self._writer.write_frame(stamp_ns, raw_rate * self._scale[0], raw_temp * self._scale[1])

    def close(self) -> None:
        if self._writer is not None:
            self._writer.close()


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def _record_frames(frames: queue.SimpleQueue[tuple[int, float, float]], sink: _CsvRecord | _BagRecord, port: str,
                   duration_s: float | None, last_error: Callable[[], str]) -> int:
    """Write frames to ``sink`` until ``duration_s`` or Ctrl-C (or SIGTERM); it is closed, whole, either way.

    Says on stderr when none arrive for a second, and again every LINK_DOWN_REPEAT_S while none do.
    """
    from art_gyro_calibration.driver import LINK_DOWN_REPEAT_S
    last = started = time.monotonic()
    end = math.inf if duration_s is None else last + duration_s
    bar = Progress(None, duration_s, f'calibrate record: {port}')
    silent = False
    said = -math.inf
    count = 0
    try:
        while (now := time.monotonic()) < end:
            # With --duration, the time recorded (the time left is known); else the frames so far.
            bar.update(now - started if duration_s else count, 'frames', f'{count} frames' if duration_s else '')
            try:
                stamp_ns, raw_rate, raw_temp = frames.get(timeout=max(0.0, min(end, last + RECORD_SILENCE_S) - now))
            except queue.Empty:
                now = time.monotonic()
                if now - last >= RECORD_SILENCE_S and now - said >= LINK_DOWN_REPEAT_S:
                    silent, said = True, now
                    _stderr(f'calibrate record: nothing from {port} for {now - last:.0f} s '
                            f'({last_error() or "port open, no frames"}); still waiting')
                continue
            sink.write(stamp_ns, raw_rate, raw_temp)
            count += 1
            last = time.monotonic()
            if silent:
                silent, said = False, -math.inf
                _stderr(f'calibrate record: frames from {port} again')
    except KeyboardInterrupt:
        pass
    finally:
        bar.done()
        sink.close()
    return count


def build_parser() -> argparse.ArgumentParser:
    """The ``calibrate`` command line."""
    from art_gyro_calibration.protocols import PROTOCOLS
    from art_gyro_calibration.analysis.metrics import DEFAULT_SETTLE_S
    from art_gyro_calibration.analysis.simulate import ALL_EFFECTS
    parser = argparse.ArgumentParser(prog='calibrate', description=__doc__.splitlines()[0].replace('``', ''))
    sub = parser.add_subparsers(dest='command', required=True)

    p = sub.add_parser('apply', help='static bias and compensation over a log')
    p.add_argument('log', help='CSV log (t, raw_rate, raw_temp or rate_dps, temp_c, ...) or rosbag2 (directory, '
                               '.mcap or .db3)')
    p.add_argument('--calibration', required=True, help='calibration file (config/<SERIAL>.yaml form)')
    p.add_argument('--out', required=True, help='CSV to write: t,rate_dps,temp_c,comp_dps,corrected_dps')
    p.add_argument('--bias-samples', type=int, default=DEFAULT_SAMPLES,
                   help='rows at rest at the start of the log for the static bias (default %(default)s)')
    p.add_argument('--powered-on-at-start', action='store_true',
                   help='the log starts at the gyro\'s power-on, as the node\'s parameter of that name: a warm-up '
                        'term decays from its first row (otherwise it counts as decayed)')
    _bag_options(p)
    _force_option(p)
    p.set_defaults(run=_apply)

    p = sub.add_parser('fit', help='fit the ART polynomial to a rate-table log and trace what it leaves')
    p.add_argument('log', nargs='+', help='CSV log with ref_rate (the table\'s true rate, deg/s), or rosbag2 '
                                          '(directory, .mcap or .db3) with --reference-topic; several: runs of the '
                                          'same gyro, one calibration for all, each run with its own turn-on bias')
    p.add_argument('--rows', type=_positive_int, required=True, help='powers of temperature (the report\'s ROWS)')
    p.add_argument('--columns', type=_positive_int, required=True, help='powers of rate (the report\'s COLUMNS)')
    p.add_argument('--serial', help=f'KVH serial number written into the calibration (default {DEFAULT_SERIAL}); '
                                    'its packaged calibration gives the scale factor and the baseline')
    p.add_argument('--out', required=True, help='calibration file to write (CAL.yaml)')
    p.add_argument('--report', required=True, help='REPORT.json to write (and REPORT.md beside it)')
    p.add_argument('--plots', help='directory for the figures (PNG); created, with its parents, if missing '
                                   '(default: no figures)')
    p.add_argument('--plot-prefix', default='', help='start of the figures\' file names (e.g. sim-; default none)')
    p.add_argument('--bias-samples', type=int, default=DEFAULT_SAMPLES,
                   help='rows at rest at the start of the log for the static bias (default %(default)s)')
    p.add_argument('--rate-scale-factor', type=float,
                   help='deg/s per count of raw_rate (default: the packaged calibration of --serial, '
                        f'else {DEFAULT_RATE_SCALE_FACTOR})')
    p.add_argument('--settle-s', type=float, default=DEFAULT_SETTLE_S,
                   help='seconds skipped after each change of table rate (default %(default)s)')
    p.add_argument('--max-effects', type=int, default=DEFAULT_MAX_EFFECTS,
                   help='most effects to add (default %(default)s)')
    p.add_argument('--seed', type=int, default=0,
                   help='seed of the chance scores (phase-randomised residuals; default %(default)s)')
    p.add_argument('--draws', type=_positive_int, default=DEFAULT_DRAWS,
                   help='chance draws per screen (default %(default)s)')
    p.add_argument('--alpha', type=_level, default=DEFAULT_ALPHA,
                   help='level of each screen\'s test: the chance of claiming an effect on a log without one '
                        '(default %(default)s)')
    p.add_argument('--materiality', type=float, metavar='DEG_PER_H',
                   help='smallest effect worth adding, worst case over the logged envelope, deg/h '
                        '(default: the bias instability of what the ART polynomial leaves)')
    p.add_argument('--exclude', action='append', default=[], metavar='SIGNAL',
                   help='never use this signal or log column as an effect (e.g. one the node will not have); repeat')
    p.add_argument('--node-signal', action='append', default=[], metavar='COLUMN',
                   help='a log column (e.g. supply_v) the robot will feed gyro_node by topic: an effect on it is '
                        'written, not only reported, and the report names the node parameters to set '
                        '(extra_signals.COLUMN.topic, .type); repeat')
    p.add_argument('--block-s', type=float, default=DEFAULT_BLOCK_S,
                   help='shortest held-out block of time (s); each screen lengthens it to the correlation time '
                        'of what the model leaves (default %(default)s)')
    p.add_argument('--validate', nargs='+', action='extend', default=[], metavar='OTHER_LOG',
                   help='other runs of the same gyro (with ref_rate, at rest over their first --bias-samples rows): '
                        'replay the calibrations on them as the node would, report the field errors, and drop '
                        'a term they are better without')
    p.add_argument('--still', metavar='LOG_OR_BAG',
                   help='a record of the gyro at rest (as calibrate allan reads it): its bias instability, not the '
                        'residual\'s, sets the materiality and the noise budget (default: the residual\'s)')
    p.add_argument('--not-from-power-on', action='store_true',
                   help='the log (every log given) does not start at the gyro\'s power-on: no warm-up is sought')
    p.add_argument('--warm-start', action='append', default=[], metavar='LOG',
                   help='one of the logs fitted began with the gyro already warm (a restart): no warm-up there, '
                        'its start judges the terms as a warm restart; the others began at power-on; repeat')
    p.add_argument('--validate-powered-on-at-start', action='store_true',
                   help='the --validate runs began at the gyro\'s power-on (default: unknown, a warm-up term '
                        'is not applied, as the node does by default)')
    p.add_argument('--baseline', metavar='FILE',
                   help='the gyro\'s current calibration (default: the packaged file of --serial): the refit is '
                        'judged against it held out, as the node applies both, and where its polynomial is not '
                        'better by the materiality the written file keeps the baseline\'s polynomial')
    p.add_argument('--operating-range', nargs=2, type=float, metavar=('LO', 'HI'),
                   help='temperatures (degC) the robot will run in (default: the log\'s): beyond the log the refit '
                        'is judged against the baseline only where the baseline was calibrated (temperature_range_c); '
                        'elsewhere the report says how far the two disagree, unjudged')
    _bag_options(p)
    _force_option(p)
    p.set_defaults(run=_fit)

    p = sub.add_parser('replay', help='a calibration on another run, as the node applies it: field errors')
    p.add_argument('log', help='CSV log or rosbag2 (with --reference-topic) with ref_rate, at rest over its first '
                               '--bias-samples rows (after --start-s)')
    p.add_argument('--calibration', required=True, help='calibration file; also replayed without its extended terms')
    p.add_argument('--start-s', type=float, default=0.0,
                   help='start the node this many seconds into the log (a warm restart; default %(default)s)')
    p.add_argument('--powered-on-at-start', action='store_true',
                   help='the gyro was powered on when the replayed run began: a warm-up term applies from there '
                        '(default: unknown, it is not applied, as the node does by default)')
    p.add_argument('--bias-samples', type=int, default=DEFAULT_SAMPLES,
                   help='rows at rest at the start for the static bias (default %(default)s)')
    p.add_argument('--settle-s', type=float, default=DEFAULT_SETTLE_S,
                   help='seconds skipped after each change of table rate (default %(default)s)')
    _bag_options(p)
    p.set_defaults(run=_replay)

    p = sub.add_parser('allan', help='noise of a gyro at rest: Allan deviation, IEEE 952 terms, node parameters')
    p.add_argument('log', help='record at rest: CSV log or rosbag2 (directory, .mcap or .db3)')
    p.add_argument('--out', required=True, help='ALLAN.json to write')
    p.add_argument('--plots', help='directory for allan.png; created, with its parents, if missing '
                                   '(default: no figure)')
    p.add_argument('--serial', help='gyro whose packaged calibration scales a raw log\'s counts (default: none; a '
                                    'raw log needs it or --rate-scale-factor)')
    p.add_argument('--rate-scale-factor', type=float,
                   help='deg/s per count of a raw log\'s raw_rate (default: the packaged calibration\'s of --serial)')
    p.add_argument('--node-rate-hz', type=_positive_float,
                   help='the node\'s frame rate for yaw_rate_stddev and bias_samples, 0.01..100000 Hz (default: the '
                        'record\'s)')
    _bag_options(p, reference=False)
    _force_option(p)
    p.set_defaults(run=_allan)

    p = sub.add_parser('simulate', help='write a simulated rate-table and thermal-chamber run')
    p.add_argument('--serial', required=True, help='gyro whose packaged calibration is the true error')
    p.add_argument('--hours', type=_positive_float, required=True, help='length of the run, hours (required)')
    p.add_argument('--out', required=True, help='CSV log to write; the truth goes to LOG.truth.json')
    p.add_argument('--effect', action='append', default=[], choices=sorted(ALL_EFFECTS),
                   help='switch an effect on (repeat for several; default none; doc/calibration.md says what each '
                        'one is)')
    p.add_argument('--rate-hz', type=_positive_float, default=10.0, help='samples per second (default %(default)s)')
    p.add_argument('--seed', type=int, default=0,
                   help='seed of the noise, turn-on bias and table order: another seed is another run of the same '
                        'gyro (default %(default)s)')
    p.add_argument('--self-heating-c', type=_nonnegative_float, default=0.0, metavar='DEG_C',
                   help='the gyro warms itself by this much after power-on, above the chamber (whose top set point '
                        'is lowered by as much); the sensor reads it, the polynomial and effects see it '
                        '(default %(default)s)')
    p.add_argument('--self-heating-tau-s', type=_positive_float, default=900.0, metavar='SECONDS',
                   help='time constant of the self-heating (default %(default)s)')
    _force_option(p)
    p.set_defaults(run=_simulate)

    p = sub.add_parser('record', help='record a gyro through the node\'s driver into a rosbag2 or a raw CSV log')
    p.add_argument('--port', required=True, help='serial port, e.g. /dev/ttyUSB0')
    p.add_argument('--out', required=True,
                   help='where to write: a name ending in .csv is a raw CSV log (t, raw_rate, raw_temp), any other '
                        'a rosbag2 directory (MCAP) with the node\'s imu/uncalibrated and imu/temperature, as '
                        'fit, apply and allan read it; written as frames come, kept if stopped (Ctrl-C, SIGTERM)')
    p.add_argument('--format', choices=('bag', 'csv'),
                   help='bag or csv whatever --out is named (default: from --out\'s name)')
    p.add_argument('--protocol', choices=PROTOCOLS, default=PROTOCOLS[0],
                   help='frame format on the wire, as the node\'s parameter (default %(default)s)')
    p.add_argument('--baud', type=int, default=9600, help='serial baud rate (default %(default)s)')
    p.add_argument('--serial', help='the gyro recorded: its packaged calibration must exist and gives a bag\'s scale '
                                    'factors; kept in the output (bag metadata, CSV comment line) for fit and apply '
                                    'to check (default: none)')
    p.add_argument('--rate-scale-factor', type=float,
                   help='bag: deg/s per count (default: the packaged calibration\'s of --serial, '
                        f'else {DEFAULT_RATE_SCALE_FACTOR})')
    p.add_argument('--duration', type=float, help='seconds to record (default: until Ctrl-C)')
    _force_option(p)
    p.set_defaults(run=_record)
    p = sub.add_parser('record-topics', help='record the running node\'s imu/uncalibrated and imu/temperature into '
                                             'a rosbag2, without ros2cli (needs rclpy: run it where the node runs)')
    p.add_argument('out', metavar='BAG', help='the rosbag2 directory (MCAP) to write; never replaced')
    p.add_argument('--namespace', default='/', help='the node\'s namespace (default %(default)s)')
    p.add_argument('--duration', type=float, help='seconds to record (default: until Ctrl-C)')
    p.add_argument('--quiet-s', type=float, default=5.0,
                   help='after this many seconds without a message, say once what to check (default %(default)s)')
    p.set_defaults(run=_record_topics)
    return parser


def _record_topics(args: argparse.Namespace) -> int:
    from art_gyro_calibration.analysis.record_topics import record_topics
    return record_topics(args.out, args.namespace, args.duration, args.quiet_s)


def _force_option(p: argparse.ArgumentParser) -> None:
    p.add_argument('--force', action='store_true',
                   help='replace outputs that exist (an input is never overwritten)')


def _level(text: str) -> float:
    value = float(text)
    if not 0.0 < value < 1.0:
        raise argparse.ArgumentTypeError(f'must be between 0 and 1, got {text}')
    return value


def _positive_float(text: str) -> float:
    value = float(text)
    if not value > 0.0 or not math.isfinite(value):
        raise argparse.ArgumentTypeError(f'must be a positive number, got {text}')
    return value


def _nonnegative_float(text: str) -> float:
    value = float(text)
    if not value >= 0.0 or not math.isfinite(value):
        raise argparse.ArgumentTypeError(f'must be a number >= 0, got {text}')
    return value


def _positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f'must be a whole number >= 1, got {text}')
    return value


# What the offline tools need beyond the node's runtime: the pip extra "analysis".
ANALYSIS_EXTRA = ('scipy', 'matplotlib', 'threadpoolctl', 'rosbags')


# glibc's mallopt parameter, and the size from which a block is mapped on its own (returned when freed).
_M_MMAP_THRESHOLD = -3
_MMAP_THRESHOLD_BYTES = 32 << 20


def _return_freed_arrays() -> None:
    """Have glibc map blocks of 32 MiB and more on their own, and trim the heap as it frees (a fixed threshold).

    By default glibc raises its threshold as large blocks are freed and its trim threshold with it
    (to 64 MiB): freed heap pages then stay resident (``calibrate fit`` of 24 h at 100 Hz once held
    1.0 GiB after its loop for 0.6 GiB of live arrays). Fixed, the trim threshold stays at its
    128 KiB. Not lower than 32 MiB: a chunk's columns (2 MiB) and design matrices (25 MiB), made and
    dropped thousands of times a fit, would each be mapped afresh, and their pages faulted in and
    zeroed every time: a large share of the fit's CPU for little less memory (doc/benchmark.md). Elsewhere (no
    glibc) nothing is done.
    """
    try:
        ctypes.CDLL(None).mallopt(_M_MMAP_THRESHOLD, _MMAP_THRESHOLD_BYTES)
    except (OSError, AttributeError):
        pass


def _say_warning(message: Warning | str, category: type[Warning], filename: str, lineno: int,
                 file: object = None, line: str | None = None) -> None:
    """A warning about the input (a cut last row) as one line on stderr, not Python's source location."""
    _warn(str(message))


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``calibrate``; returns the exit status."""
    _return_freed_arrays()
    args = None
    # SIGTERM stops as Ctrl-C does: the outputs' staging is removed on the way out (SIGKILL's by the next run).
    previous = signal.signal(signal.SIGTERM, _interrupt)
    try:
        args = build_parser().parse_args(argv)
        with warnings.catch_warnings():
            warnings.simplefilter('always', CutRowWarning)
            warnings.showwarning = _say_warning
            status: int = args.run(args)
            return status
    except KeyboardInterrupt:
        # Ctrl-C is a stop as asked, not a failure to show a traceback for; what was staged is gone.
        _stderr(f'calibrate{"" if args is None else " " + args.command}: interrupted: no output written')
        return 130
    except ModuleNotFoundError as e:
        if e.name not in ANALYSIS_EXTRA:
            raise
        # A robot's install has the node's runtime only: say what to add instead of a traceback.
        print(f'calibrate: error: the offline tools need {e.name}, which this installation lacks: '
              'from the repository, pip install ".[analysis]" (scipy, matplotlib, threadpoolctl, rosbags; the '
              'package is not on PyPI), or scripts/setup.sh',
              file=sys.stderr)
        return 1
    except (LogError, CalibrationError, MotionError, ValueError, OSError) as e:
        hint = ''
        if 'no ref_rate column' in str(e) and getattr(args, 'reference_topic', '') is None:
            hint = ' (a rosbag2 input gives it with --reference-topic TOPIC)'
        _stderr(f'calibrate{"" if args is None else " " + args.command}: error: {e}{hint}')
        return 1
    finally:
        signal.signal(signal.SIGTERM, previous)


if __name__ == '__main__':
    sys.exit(main())
