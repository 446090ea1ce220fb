"""Extended terms: forms, validation, batch and per-sample agreement."""

import math

import numpy as np
import pytest

from art_gyro_calibration.terms import Term


@pytest.mark.parametrize('term, x, expected', [
    (Term('temperature_rate', 'power', (3.0, 2.0), (1, 2)), 0.5, 3.0 * 0.5 + 2.0 * 0.25),
    (Term('time', 'exp_decay', (0.04,), (), 600.0), 600.0, 0.04 * math.exp(-1.0)),
    (Term('angle', 'harmonic', (0.01, 0.02)), 90.0, 0.01),
])
def test_forms(term: Term, x: float, expected: float) -> None:
    assert term.evaluate_one(x) == pytest.approx(expected)
    assert term.evaluate(np.array([x, x]))[1] == pytest.approx(expected)
    assert term.basis(np.array([x])).shape == (1, len(term.coefficients))
    assert term.signal in term.describe()


@pytest.mark.parametrize('kwargs, message', [
    (dict(form='cubic', coefficients=(1.0,)), "form 'cubic'"),
    (dict(form='power', coefficients=(1.0,), powers=()), 'needs 0 coefficients'),
    (dict(form='power', coefficients=(1.0,), powers=(0,)), 'powers must be whole numbers >= 1'),
    (dict(form='harmonic', coefficients=(1.0,)), 'needs 2 coefficients'),
    (dict(form='exp_decay', coefficients=(1.0,), time_constant_s=-5.0), 'time_constant_s must be positive'),
    (dict(form='power', coefficients=(float('nan'),), powers=(1,)), 'must be finite'),
])
def test_invalid_terms(kwargs: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        Term(signal='x', **kwargs)
