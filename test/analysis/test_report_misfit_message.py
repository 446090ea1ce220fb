"""The lack-of-fit warning says the reason its numbers give: a shape, the level beyond the budget, or both."""

from types import SimpleNamespace

from art_gyro_calibration.analysis.loop import Adequacy, SignalShape
from art_gyro_calibration.analysis.pipeline import _warn_loop
from art_gyro_calibration.analysis.report import misfit_reason


def _said(adequacy: Adequacy) -> str:
    said: list[str] = []
    _warn_loop(SimpleNamespace(findings=[], adequacy=adequacy), said.append)   # type: ignore[arg-type]
    assert len(said) == 1
    return said[0]


SUPPLY = SignalShape('supply_v', 16.65, 9.0, 3.0, True)


def test_a_shape_within_the_budget_is_named_as_the_reason() -> None:
    # The showcase fit: 6.34 deg/h held out against a budget of 7.12 deg/h, a 16.65 deg/h supply_v shape.
    said = _said(Adequacy(False, 600.0, 6.34, 7.12, 0.0, 1.0, (SUPPLY,)))
    assert said.startswith('the model does not fit: what it leaves has a shape beyond chance and the materiality '
                           'against supply_v (16.65 deg/h) (its level, held out, over 10-minute means, 6.34 deg/h, '
                           'is within 3 x the noise budget of 7.12 deg/h)'), said
    assert 'beyond the noise budget' not in said and '0.00' not in said


def test_a_level_beyond_the_budget_says_by_how_much() -> None:
    said = _said(Adequacy(False, 600.0, 40.0, 7.0, 39.4, 1.0, ()))
    assert 'is 40.00 deg/h, more than 3 x the noise budget of 7.00 deg/h (39.40 deg/h beyond it)' in said, said
    assert 'shape' not in said


def test_both_reasons_are_given() -> None:
    reason = misfit_reason(40.0, 7.0, 39.4, [('supply_v', 16.65)])
    assert reason.endswith('(39.40 deg/h beyond it); and it has a shape beyond chance and the materiality against '
                           'supply_v (16.65 deg/h)'), reason
