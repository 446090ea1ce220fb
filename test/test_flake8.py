"""The package's code passes ament_flake8 (with the project's 120-character lines)."""

import os
from pathlib import Path

import pytest
from ament_flake8.main import main_with_errors

REPO = Path(__file__).resolve().parent.parent


@pytest.mark.flake8
@pytest.mark.linter
def test_flake8(monkeypatch: pytest.MonkeyPatch) -> None:
    """No flake8 errors in the repository's Python files."""
    # ament_flake8 skips folders starting with '.' or '_' (such as .venv) found under the working directory.
    monkeypatch.chdir(REPO)
    rc, errors = main_with_errors(argv=['--linelength', '120', os.curdir])
    assert rc == 0, f'Found {len(errors)} code style errors / warnings:\n' + '\n'.join(errors)
