"""The check every diagnosis test on another simulator's run makes: the right name, or none.

Imported by name by ``test_diagnosis_foreign.py`` and ``test_diagnosis_independent.py`` (pytest puts
``tests/`` on ``sys.path``).
"""

from __future__ import annotations

import pytest

from tankode.diagnosis.verdict import AUDIT_HYPOTHESIS, INVENTORY

# The audit's hypothesis that measures each inventory mechanism.
INVENTORY_HYPOTHESIS = {m: AUDIT_HYPOTHESIS[m] for m in INVENTORY}


def assert_right_or_silent(d, mechanism: str | None, value: float) -> None:
    """``d`` (a ``Diagnosis`` of a run with ``mechanism`` hidden at ``value``, or nothing) names
    nothing wrong; an inventory signature of 5 sigma or more is named or listed among the places
    the data cannot separate, with its estimate within 25 %. The model's form (the tank's own
    physics, such as a dry wall heating the ullage) is no cause: it may be named anywhere."""
    v = d.verdict
    assert d.cause is None or v.kind == "cause"
    if mechanism is None:
        assert v.kind in ("none", "model_form"), v.sentence
        return
    assert v.kind in ("none", "model_form") or mechanism in v.candidates, v.sentence
    hyp = INVENTORY_HYPOTHESIS.get(mechanism)
    if hyp is not None and abs(d.audits[0].hypotheses[hyp].z) >= 5:
        assert mechanism in v.candidates, v.sentence
        assert v.estimate.value == pytest.approx(value, rel=0.25), v.sentence
