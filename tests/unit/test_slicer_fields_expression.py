"""The restricted formula evaluator: what it computes and what it refuses, with reasons."""

from __future__ import annotations

import numpy as np
import pytest

from slicer.expression import compile_formula
from slicer.settings import SettingsError

VARS = ("x", "y", "z", "layer", "d")


def evaluate(text: str, **values: object) -> np.ndarray:
    return compile_formula(text, VARS)(values)


def test_arithmetic_functions_and_constants_are_vectorised() -> None:
    x = np.array([0.0, 1.0, 2.0, 3.0])
    got = evaluate("2 * sin(pi * x / 2) + x ** 2 - 7 % 3 + -abs(-x) / 2", x=x)
    want = 2 * np.sin(np.pi * x / 2) + x**2 - 1 - x / 2
    assert np.allclose(got, want)


def test_min_max_take_several_arguments_and_broadcast() -> None:
    x = np.array([0.0, 5.0, 10.0])
    assert np.allclose(evaluate("max(x, 3, layer)", x=x, layer=4.0), [4.0, 5.0, 10.0])
    assert np.allclose(evaluate("min(x, 3)", x=x), [0.0, 3.0, 3.0])


def test_comparisons_give_zero_or_one_and_chain() -> None:
    x = np.array([0.0, 5.0, 10.0])
    assert np.allclose(evaluate("(x > 2) * 10 + (1 < x <= 5)", x=x), [0.0, 11.0, 10.0])


def test_remaining_functions_match_numpy() -> None:
    x = np.array([0.3, 1.7])
    got = evaluate("cos(x) + tan(x) + sqrt(x) + exp(x) + log(x) + floor(x) + ceil(x) + e", x=x)
    want = (
        np.cos(x) + np.tan(x) + np.sqrt(x) + np.exp(x) + np.log(x) + np.floor(x) + np.ceil(x) + np.e
    )
    assert np.allclose(got, want)


def test_names_used_are_reported() -> None:
    assert compile_formula("x + d * 2", VARS).names == {"x", "d"}


def test_overflow_gives_infinity_not_a_hang() -> None:
    assert np.isinf(evaluate("9 ** 9 ** 9"))


@pytest.mark.parametrize(
    ("text", "reason"),
    [
        ("__import__('os')", "unknown function '__import__'"),
        ("x.real", "attribute access"),
        ("(lambda: 1)()", "lambda"),
        ("x[0]", "subscripts"),
        ("foo + 1", "unknown name 'foo'"),
        ("open('f')", "unknown function 'open'"),
        ("sin(x, y)", "sin() takes 1 argument"),
        ("sin(x=1)", "keyword"),
        ("'text'", "only numbers"),
        ("x // 2", "'//'"),
        ("x if y else z", "conditional"),
        ("x and y", "'and'/'or'"),
        ("[x, y]", "lists"),
        ("x +", "syntax error"),
        ("   ", "empty formula"),
        ("(x := 1)", "assignment"),
        ("x.__class__.__bases__", "attribute access"),
        ("True + x", "only numbers"),
    ],
)
def test_refused_constructs_name_the_reason(text: str, reason: str) -> None:
    with pytest.raises(SettingsError) as err:
        compile_formula(text, VARS)
    assert err.value.key == "infill.expression"
    assert reason in err.value.reason


def test_deep_nesting_is_refused_cleanly() -> None:
    with pytest.raises(SettingsError):
        compile_formula("-" * 5000 + "x", VARS)
