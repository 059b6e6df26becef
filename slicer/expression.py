"""A restricted formula evaluator: numpy arithmetic from a whitelist of syntax, never eval."""

from __future__ import annotations

import ast
import math
import operator
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from slicer.settings import SettingsError

MAX_LENGTH = 2000

CONSTANTS: dict[str, float] = {"pi": math.pi, "e": math.e}

# a value while evaluating: an array of floats, or a float64 scalar for a constant
Value = np.ndarray | np.float64

FUNCTIONS: dict[str, tuple[Callable[..., Value], int, int | None]] = {
    # name: (function, least arguments, most arguments or None for any)
    "sin": (np.sin, 1, 1),
    "cos": (np.cos, 1, 1),
    "tan": (np.tan, 1, 1),
    "sqrt": (np.sqrt, 1, 1),
    "abs": (np.abs, 1, 1),
    "exp": (np.exp, 1, 1),
    "log": (np.log, 1, 1),
    "floor": (np.floor, 1, 1),
    "ceil": (np.ceil, 1, 1),
    "min": (lambda *a: _reduce(np.minimum, a), 2, None),
    "max": (lambda *a: _reduce(np.maximum, a), 2, None),
}

BINARY: dict[type, Callable[[Value, Value], Value]] = {
    ast.Add: operator.add,
    ast.Sub: operator.sub,
    ast.Mult: operator.mul,
    ast.Div: operator.truediv,
    ast.Pow: operator.pow,
    ast.Mod: operator.mod,
}

COMPARE: dict[type, Callable[[Value, Value], np.ndarray | np.bool_]] = {
    ast.Lt: operator.lt,
    ast.LtE: operator.le,
    ast.Gt: operator.gt,
    ast.GtE: operator.ge,
    ast.Eq: operator.eq,
    ast.NotEq: operator.ne,
}

_DESCRIBE: dict[type, str] = {
    ast.Attribute: "attribute access (a.b)",
    ast.Subscript: "subscripts (a[i])",
    ast.Lambda: "lambda",
    ast.Call: "calls",
    ast.IfExp: "conditional expressions (a if b else c)",
    ast.BoolOp: "'and'/'or' (use comparisons, which give 0 or 1, and * or max)",
    ast.List: "lists",
    ast.Tuple: "tuples",
    ast.Dict: "dicts",
    ast.Set: "sets",
    ast.ListComp: "comprehensions",
    ast.GeneratorExp: "comprehensions",
    ast.Starred: "starred arguments",
    ast.NamedExpr: "assignment (:=)",
    ast.JoinedStr: "strings",
    ast.Await: "await",
}


def _reduce(func: Callable[[Value, Value], Value], args: tuple[Value, ...]) -> Value:
    result = args[0]
    for arg in args[1:]:
        result = func(result, arg)
    return result


@dataclass(frozen=True)
class Formula:
    """A checked formula; call it with arrays for its variables to get an array."""

    text: str
    tree: ast.Expression
    names: frozenset[str]

    def __call__(self, variables: Mapping[str, np.ndarray | float]) -> np.ndarray:
        """Evaluate element-wise; ``variables`` maps every name the formula uses to an array
        or a number (arrays broadcast). Comparisons give 1.0 or 0.0. Returns float64."""
        missing = self.names - set(variables) - set(CONSTANTS)
        if missing:
            raise KeyError(f"no value for {', '.join(sorted(missing))}")
        with np.errstate(all="ignore"):
            return np.asarray(_evaluate(self.tree.body, variables), dtype=float)


def compile_formula(
    text: str, variables: tuple[str, ...], key: str = "infill.expression"
) -> Formula:
    """Parse ``text`` and check every node against the whitelist.

    Allowed: numbers, the names in ``variables`` and ``pi``, ``e``; ``+ - * / ** %``,
    unary minus and plus, comparisons, and calls of the functions in
    :data:`FUNCTIONS`. Anything else raises ``SettingsError(key, reason)`` with
    the offending construct named.
    """
    if not isinstance(text, str) or not text.strip():
        raise SettingsError(key, "empty formula: give an expression such as 'sin(x) + y'")
    if len(text) > MAX_LENGTH:
        raise SettingsError(key, f"formula longer than {MAX_LENGTH} characters")
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError as exc:
        raise SettingsError(key, f"syntax error at column {exc.offset}: {exc.msg}") from None
    except (RecursionError, MemoryError):
        raise SettingsError(key, "formula nested too deeply") from None
    allowed = set(variables) | set(CONSTANTS)
    names: set[str] = set()
    try:
        _check(tree.body, allowed, names, key)
    except RecursionError:
        raise SettingsError(key, "formula nested too deeply") from None
    return Formula(text=text, tree=tree, names=frozenset(names))


def _check(node: ast.AST, allowed: set[str], names: set[str], key: str) -> None:
    if isinstance(node, ast.Constant):
        if isinstance(node.value, bool) or not isinstance(node.value, int | float):
            raise SettingsError(key, f"only numbers are allowed as constants, not {node.value!r}")
    elif isinstance(node, ast.Name):
        if node.id not in allowed:
            raise SettingsError(
                key, f"unknown name {node.id!r} (allowed: {', '.join(sorted(allowed))})"
            )
        names.add(node.id)
    elif isinstance(node, ast.BinOp):
        if type(node.op) not in BINARY:
            raise SettingsError(key, f"operator {_symbol(node.op)} is not allowed")
        _check(node.left, allowed, names, key)
        _check(node.right, allowed, names, key)
    elif isinstance(node, ast.UnaryOp):
        if not isinstance(node.op, ast.USub | ast.UAdd):
            raise SettingsError(key, f"operator {_symbol(node.op)} is not allowed")
        _check(node.operand, allowed, names, key)
    elif isinstance(node, ast.Compare):
        for op in node.ops:
            if type(op) not in COMPARE:
                raise SettingsError(key, f"comparison {_symbol(op)} is not allowed")
        for part in (node.left, *node.comparators):
            _check(part, allowed, names, key)
    elif isinstance(node, ast.Call):
        _check_call(node, allowed, names, key)
    else:
        what = _DESCRIBE.get(type(node), type(node).__name__)
        raise SettingsError(key, f"{what} not allowed in a formula")


def _check_call(node: ast.Call, allowed: set[str], names: set[str], key: str) -> None:
    if not isinstance(node.func, ast.Name):
        what = _DESCRIBE.get(type(node.func), "this kind of call")
        raise SettingsError(key, f"{what} not allowed in a formula")
    name = node.func.id
    if name not in FUNCTIONS:
        raise SettingsError(
            key, f"unknown function {name!r} (allowed: {', '.join(sorted(FUNCTIONS))})"
        )
    if node.keywords:
        raise SettingsError(key, f"{name}() takes no keyword arguments")
    _, least, most = FUNCTIONS[name]
    count = len(node.args)
    if count < least or (most is not None and count > most):
        wanted = f"{least}" if least == most else f"at least {least}"
        raise SettingsError(key, f"{name}() takes {wanted} argument(s), got {count}")
    for arg in node.args:
        _check(arg, allowed, names, key)


def _symbol(op: ast.AST) -> str:
    return {
        ast.FloorDiv: "'//'",
        ast.BitAnd: "'&'",
        ast.BitOr: "'|'",
        ast.BitXor: "'^'",
        ast.LShift: "'<<'",
        ast.RShift: "'>>'",
        ast.MatMult: "'@'",
        ast.Invert: "'~'",
        ast.Not: "'not'",
        ast.Is: "'is'",
        ast.IsNot: "'is not'",
        ast.In: "'in'",
        ast.NotIn: "'not in'",
    }.get(type(op), type(op).__name__)


def _evaluate(node: ast.AST, variables: Mapping[str, np.ndarray | float]) -> Value:
    """Walk a checked tree; every node type here was admitted by :func:`_check`."""
    if isinstance(node, ast.Constant) and isinstance(node.value, int | float):
        return np.float64(node.value)
    if isinstance(node, ast.Name):
        if node.id in CONSTANTS:
            return np.float64(CONSTANTS[node.id])
        return np.asarray(variables[node.id], dtype=float)
    if isinstance(node, ast.BinOp):
        return BINARY[type(node.op)](
            _evaluate(node.left, variables), _evaluate(node.right, variables)
        )
    if isinstance(node, ast.UnaryOp):
        value = _evaluate(node.operand, variables)
        return -value if isinstance(node.op, ast.USub) else +value
    if isinstance(node, ast.Compare):
        left = _evaluate(node.left, variables)
        result: np.ndarray | np.bool_ = np.True_
        for op, comparator in zip(node.ops, node.comparators, strict=True):
            right = _evaluate(comparator, variables)
            result = result & COMPARE[type(op)](left, right)
            left = right
        return np.asarray(result, dtype=float)
    if isinstance(node, ast.Call):
        func = FUNCTIONS[node.func.id][0]  # type: ignore[attr-defined]
        return func(*(_evaluate(arg, variables) for arg in node.args))
    raise TypeError(f"unchecked node {type(node).__name__}")
