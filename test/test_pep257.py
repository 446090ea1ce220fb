"""The package's docstrings pass ament_pep257."""

from pathlib import Path

import pytest
from ament_pep257.main import main

REPO = Path(__file__).resolve().parent.parent


@pytest.mark.linter
@pytest.mark.pep257
def test_pep257() -> None:
    """No pep257 errors in the package, its tests and the research, in the project's docstring style.

    The ament convention, less two checks the project's style contradicts: D213 (it puts
    the summary on the first line, D212 style, which ament also ignores) and D401 (its
    summaries may describe, "The ...", rather than command).
    """
    rc = main(argv=['--add-ignore', 'D213', 'D401', '--',
                    str(REPO / 'art_gyro_calibration'), str(REPO / 'test'), str(REPO / 'research')])
    assert rc == 0, 'Found code style errors / warnings'
