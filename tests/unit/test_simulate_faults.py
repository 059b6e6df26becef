"""`hostd simulate --fault KIND=P`: read by the settings helper, a wrong one refused saying why."""

from __future__ import annotations

import pytest

from hostd.app.cli import UsageError
from hostd.app.commands.simulate import parse_faults


def test_faults_are_probabilities_of_known_kinds() -> None:
    assert parse_faults(["drop_ok=0.01", "resend=1", "busy = 0"]) == {
        "p_drop_ok": 0.01, "p_resend": 1.0, "p_busy": 0.0}
    assert parse_faults([]) == {}


@pytest.mark.parametrize(("spec", "reason"), [
    ("gremlins=0.1", "'gremlins' is not one of corrupt_rx"),
    ("drop_ok", "expected KIND=P with KIND one of corrupt_rx"),
    ("drop_ok=often", "expected a number, got 'often'"),
    ("drop_ok=1.5", "1.5 is outside 0..1"),
    ("drop_ok=true", "expected a number, got True"),
])
def test_a_wrong_fault_is_refused_naming_it(spec: str, reason: str) -> None:
    with pytest.raises(UsageError) as caught:
        parse_faults(["resend=0.1", spec])
    assert str(caught.value).startswith(f"--fault {spec!r}: {reason}")
