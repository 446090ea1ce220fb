"""Files ``calibrate`` writes: never over an input, over an existing file only when forced, never half-written.

Every output is checked before the work starts and written into a hidden staging
directory beside it (same file system); when the command succeeds each file is renamed
into place, and when it fails (an error, Ctrl-C) the staging directory is removed and the
outputs are as they were. Only a regular file is ever replaced: a FIFO or a device given
as an output is refused, with ``--force`` too. A staging directory is named after its
process (``.calibrate-<pid>-...``): one left by a process that no longer runs (SIGKILL, a
power cut) is removed by the next command that stages in that directory (one named
``.calibrate-keep-<pid>-...``, where ``calibrate record`` once staged its rows, never is). Outputs that
hold data nothing can make again (``calibrate record``'s rows) are not staged: :meth:`Outputs.check`
checks them, and they are written in place as the data comes.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterable
from pathlib import Path
from types import TracebackType

from art_gyro_calibration.calibration import special_file_kind

StrPath = str | os.PathLike[str]


# Start of a staging directory's name; the process id that owns it follows.
STAGE_PREFIX = '.calibrate-'


class OutputError(ValueError):
    """An output that would destroy data, or that cannot be written."""


def _running(pid: int) -> bool:
    """Whether a process ``pid`` exists (one of another user's counts as running)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_stale_stages(directory: Path) -> list[Path]:
    """Remove the staging directories in ``directory`` whose process no longer runs; returns them.

    A process killed without a chance to clean up (SIGKILL) leaves its staging directory (half an
    output, hundreds of MB); its name carries its pid, so the next command knows it is nobody's.
    """
    removed = []
    for stage in directory.glob(f'{STAGE_PREFIX}*-*'):
        pid = stage.name[len(STAGE_PREFIX):].split('-', 1)[0]
        if pid.isdigit() and stage.is_dir() and not stage.is_symlink() and not _running(int(pid)):
            shutil.rmtree(stage, ignore_errors=True)
            removed.append(stage)
    return removed


class Outputs:
    """The outputs of one command; use as a context manager: they are renamed into place when it ends well."""

    def __init__(self, inputs: Iterable[StrPath | None], force: bool = False) -> None:
        self._inputs = [Path(p) for p in inputs if p is not None]
        self._force = force
        self._prefix = f'{STAGE_PREFIX}{os.getpid()}-'
        self._claimed: list[Path] = []
        self._stages: list[tuple[Path, Path]] = []   # (staging directory, directory its files go to)

    def claim(self, path: StrPath, beside: Iterable[StrPath] = ()) -> Path:
        """Check ``path`` and the files the work writes ``beside`` it; returns where to write ``path`` now."""
        target = self.check(path)
        for other in beside:
            self.check(other)
        stage = next((s for s, d in self._stages if d == target.parent), None) or self._stage(target.parent, path)
        return stage / target.name

    def claim_directory(self, directory: StrPath, pattern: str) -> Path:
        """A directory the work fills with files matching ``pattern`` (glob); returns where to write them now."""
        d = Path(directory)
        if d.exists() and not d.is_dir():
            raise OutputError(f'{d}: is not a directory')
        existing = sorted(p.name for p in d.glob(pattern)) if d.is_dir() else []
        if existing and not self._force:
            raise OutputError(f'{d}: already holds {", ".join(existing[:3])}{" ..." if len(existing) > 3 else ""}; '
                              'pass --force to replace them')
        real = Path(os.path.realpath(d))
        parent = real if real.is_dir() else real.parent
        while not parent.is_dir():
            parent = parent.parent
        stage = self._stage(parent, d)
        self._stages[-1] = (stage, real)
        return stage

    def check(self, path: StrPath) -> Path:
        """Check an output the work writes in place (not staged); returns its real path."""
        p = Path(path)
        real = Path(os.path.realpath(p))
        for given in self._inputs:
            if real == Path(os.path.realpath(given)) or p.exists() and given.exists() and os.path.samefile(p, given):
                raise OutputError(f'{p}: is the input {given}: write the output to another file')
        if real in self._claimed:
            raise OutputError(f'{p}: named as two outputs')
        if p.is_dir():
            raise OutputError(f'{p}: is a directory')
        if p.exists() and not p.is_file():
            raise OutputError(f'{p}: is {special_file_kind(p.stat().st_mode)}, not a regular file: '
                              'never replaced, --force or not')
        if p.exists() and not self._force:
            raise OutputError(f'{p}: exists; pass --force to replace it')
        if not real.parent.is_dir():
            raise OutputError(f'{p}: directory {real.parent} does not exist')
        self._claimed.append(real)
        return real

    def _stage(self, parent: Path, named: StrPath) -> Path:
        remove_stale_stages(parent)
        try:
            stage = Path(tempfile.mkdtemp(prefix=self._prefix, dir=parent))
        except OSError as e:
            raise OutputError(f'{named}: cannot write in {parent}: {e.strerror}') from None
        self._stages.append((stage, parent))
        return stage

    def commit(self) -> None:
        """Rename every staged file into place."""
        for stage, directory in self._stages:
            directory.mkdir(parents=True, exist_ok=True)
            for f in sorted(stage.iterdir()):
                os.replace(f, directory / f.name)
            stage.rmdir()
        self._stages.clear()

    def discard(self) -> None:
        """Remove what was staged; the outputs stay as they were."""
        for stage, _ in self._stages:
            shutil.rmtree(stage, ignore_errors=True)
        self._stages.clear()

    def __enter__(self) -> Outputs:
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 traceback: TracebackType | None) -> None:
        if kind is None:
            self.commit()
        else:
            self.discard()
