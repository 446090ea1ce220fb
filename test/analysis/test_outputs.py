"""``analysis.outputs``: outputs staged beside their target and renamed into place only when the work ends well."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from art_gyro_calibration.analysis.outputs import STAGE_PREFIX, OutputError, Outputs, remove_stale_stages


def _stages(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.iterdir() if p.name.startswith(STAGE_PREFIX))


def test_a_claimed_file_appears_only_when_the_work_ends_well(tmp_path: Path) -> None:
    target = tmp_path / 'out.csv'
    with Outputs([]) as outputs:
        staged = outputs.claim(target)
        assert staged.parent != tmp_path and staged.parent.parent == tmp_path and staged.name == 'out.csv'
        staged.write_text('result\n')
        assert not target.exists()
    assert target.read_text() == 'result\n' and _stages(tmp_path) == []


def test_a_failure_leaves_the_outputs_as_they_were(tmp_path: Path) -> None:
    target = tmp_path / 'out.csv'
    target.write_text('previous\n')
    with pytest.raises(RuntimeError), Outputs([], force=True) as outputs:
        outputs.claim(target).write_text('half\n')
        raise RuntimeError('the work failed')
    assert target.read_text() == 'previous\n' and _stages(tmp_path) == []


def test_an_input_is_never_an_output_by_any_path(tmp_path: Path) -> None:
    log = tmp_path / 'log.csv'
    log.write_text('t\n')
    (tmp_path / 'link.csv').symlink_to(log)
    os.link(log, tmp_path / 'hard.csv')
    for path in (log, tmp_path / 'link.csv', tmp_path / 'hard.csv', tmp_path / '.' / 'log.csv'):
        with pytest.raises(OutputError, match='is the input'):
            Outputs([log], force=True).claim(path)
    assert log.read_text() == 't\n'


@pytest.mark.parametrize('force, message', [(False, 'exists; pass --force to replace it'), (True, '')])
def test_an_existing_file_is_replaced_only_when_forced(tmp_path: Path, force: bool, message: str) -> None:
    target = tmp_path / 'out.csv'
    target.write_text('precious\n')
    if message:
        with pytest.raises(OutputError, match=message):
            Outputs([], force=force).claim(target)
        assert target.read_text() == 'precious\n'
        return
    with Outputs([], force=force) as outputs:
        outputs.claim(target).write_text('new\n')
    assert target.read_text() == 'new\n'


def test_special_files_directories_and_missing_directories_are_refused(tmp_path: Path) -> None:
    fifo = tmp_path / 'fifo'
    os.mkfifo(fifo)
    with pytest.raises(OutputError, match='is a FIFO, not a regular file: never replaced'):
        Outputs([], force=True).claim(fifo)
    with pytest.raises(OutputError, match='is a directory'):
        Outputs([], force=True).claim(tmp_path)
    with pytest.raises(OutputError, match='does not exist'):
        Outputs([]).claim(tmp_path / 'missing' / 'out.csv')


def test_one_path_named_twice_is_refused(tmp_path: Path) -> None:
    outputs = Outputs([])
    outputs.claim(tmp_path / 'a.csv')
    with pytest.raises(OutputError, match='named as two outputs'):
        outputs.claim(tmp_path / 'a.csv', beside=[tmp_path / 'b.csv'])
    outputs.discard()


def test_a_directory_of_outputs_is_refused_when_it_holds_matching_files(tmp_path: Path) -> None:
    plots = tmp_path / 'plots'
    plots.mkdir()
    (plots / 'old.png').write_bytes(b'png')
    with pytest.raises(OutputError, match='already holds old.png; pass --force'):
        Outputs([]).claim_directory(plots, '*.png')
    with Outputs([], force=True) as outputs:
        (outputs.claim_directory(plots, '*.png') / 'new.png').write_bytes(b'png')
    assert sorted(p.name for p in plots.iterdir()) == ['new.png', 'old.png']


def test_stale_stages_of_dead_processes_are_removed_and_kept_ones_are_not(tmp_path: Path) -> None:
    dead = subprocess.run([sys.executable, '-c', 'import os; print(os.getpid())'], capture_output=True, text=True,
                          check=True)
    pid = int(dead.stdout)
    stale = tmp_path / f'{STAGE_PREFIX}{pid}-abc'
    stale.mkdir()
    (stale / 'half.csv').write_text('half\n')
    kept = tmp_path / f'{STAGE_PREFIX}keep-{pid}-abc'   # rows nothing can make again
    kept.mkdir()
    mine = tmp_path / f'{STAGE_PREFIX}{os.getpid()}-abc'
    mine.mkdir()
    assert remove_stale_stages(tmp_path) == [stale]
    assert _stages(tmp_path) == sorted([kept.name, mine.name])
