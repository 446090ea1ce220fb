"""Progress of long work: a line on stderr when it is a terminal, rewritten in place; nothing in a pipe."""

import io
import sys
from pathlib import Path

import pytest

import art_gyro_calibration.analysis.progress as progress
from art_gyro_calibration.analysis.cli import main
from art_gyro_calibration.fake_gyro import FakeGyro


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


@pytest.fixture
def fast(monkeypatch: pytest.MonkeyPatch) -> None:
    """A ticker from the start, rewritten every 10 ms: short work shows it too."""
    monkeypatch.setattr(progress, 'TICKER_AFTER_S', 0.0)
    monkeypatch.setattr(progress, 'UPDATE_S', 0.01)


def _run_on(stream: io.StringIO, monkeypatch: pytest.MonkeyPatch, argv: list[str]) -> int:
    monkeypatch.setattr(sys, 'stderr', stream)
    return main(argv)


@pytest.mark.usefixtures('fast')
def test_simulate_and_fit_tick_on_a_terminal_only(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    log = tmp_path / 'sim.csv'
    simulate = ['simulate', '--serial', 'NAVC4058', '--hours', '0.3', '--out', str(log)]
    terminal, pipe = Terminal(), io.StringIO()
    assert _run_on(terminal, monkeypatch, simulate) == 0
    assert _run_on(pipe, monkeypatch, simulate + ['--force']) == 0
    assert '\r\x1b[Kcalibrate simulate: 0.3 h at 10 Hz: working, 0 s' in terminal.getvalue()
    assert terminal.getvalue().endswith('\n') and pipe.getvalue() == ''
    terminal = Terminal()
    fit = ['fit', str(log), '--rows', '1', '--columns', '2', '--serial', 'NAVC4058', '--out', str(tmp_path / 'c.yaml'),
           '--report', str(tmp_path / 'r.json'), '--draws', '19', '--max-effects', '0']
    assert _run_on(terminal, monkeypatch, fit) == 0
    assert 'calibrate fit: sim.csv: working, ' in terminal.getvalue()


@pytest.mark.usefixtures('fast')
def test_record_shows_its_frames_and_the_time_left(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    terminal = Terminal()
    with FakeGyro('NAVC3545', rate_hz=50, seed=1) as fake:
        assert _run_on(terminal, monkeypatch, ['record', '--port', fake.path, '--out', str(tmp_path / 'r.csv'),
                                               '--duration', '1.5']) == 0
    text = terminal.getvalue()
    assert f'calibrate record: {fake.path} [' in text and ' s left ' in text and ' frames' in text, text
    assert text.endswith('\n')


def test_a_ticker_waits_while_a_bar_is_shown(monkeypatch: pytest.MonkeyPatch) -> None:
    terminal = Terminal()
    bar = progress.Progress(terminal, 10, 'bar')
    monkeypatch.setattr(progress, 'UPDATE_S', 0.0)
    bar.update(5)
    shown = terminal.getvalue()
    progress._show(terminal, 'tick', object(), yields=True)
    assert terminal.getvalue() == shown   # the bar's line is not overwritten
    bar.done()
    progress.clear()
    assert terminal.getvalue() == shown + '\n'


def test_a_message_takes_the_lines_place_without_a_blank_line(monkeypatch: pytest.MonkeyPatch) -> None:
    terminal = Terminal()
    monkeypatch.setattr(progress, 'UPDATE_S', 0.0)
    bar = progress.Progress(terminal, 10, 'bar')
    bar.update(5)
    progress.clear()
    terminal.write('a warning\n')
    bar.done()   # the line was wiped for the message: nothing to end
    assert terminal.getvalue().endswith('\r\x1b[Ka warning\n')
