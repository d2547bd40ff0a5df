"""Parse the numbers and expressions of model files without ever evaluating Python code.

The text is read by Python's `ast` parser and only arithmetic, declared names, a few
constants and elementary functions are turned into SymPy; anything else is refused.
Size, depth and magnitude are bounded before anything is computed, so a hostile
expression (a power tower, a sum thousands deep) is refused in milliseconds.
"""

from __future__ import annotations

import ast
import keyword
import math
import re

import sympy as sp

_IDENT = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
MAX_LENGTH = 1000  # characters of one expression
MAX_DEPTH = 100  # nesting of operations and calls (a sum of n terms nests n deep)
MAX_NODES = 400  # operations, names and numbers in one expression
MAX_EXPONENT = 64  # |b| in a**b when b is a number
MAX_MAGNITUDE = 1e300  # any number met while building the expression
FUNCTIONS = {
    "sin": sp.sin, "cos": sp.cos, "tan": sp.tan, "asin": sp.asin, "acos": sp.acos,
    "atan": sp.atan, "atan2": sp.atan2, "sinh": sp.sinh, "cosh": sp.cosh, "tanh": sp.tanh,
    "exp": sp.exp, "log": sp.log, "sqrt": sp.sqrt, "abs": sp.Abs,
}
_ARITY = {"atan2": 2}
CONSTANTS = {"pi": sp.pi}
_BINARY = {
    ast.Add: lambda a, b: a + b, ast.Sub: lambda a, b: a - b, ast.Mult: lambda a, b: a * b,
    ast.Div: lambda a, b: a / b, ast.Pow: lambda a, b: a**b,
}


class ExpressionError(ValueError):
    """The text is not an arithmetic expression in the declared names."""


class ExpressionParser:
    """Turns text into SymPy expressions in the declared parameter names."""

    def __init__(self, names: list[str]):
        self.symbols: dict[str, sp.Symbol] = {}
        self.aliases: list[tuple[str, str]] = []  # names that are not Python identifiers
        for k, name in enumerate(sorted(names, key=len, reverse=True)):
            if _IDENT.match(name) and not keyword.iskeyword(name):
                self.symbols[name] = sp.Symbol(name)
            else:
                placeholder = f"__gagen_param_{k}"
                self.aliases.append((name, placeholder))
                self.symbols[placeholder] = sp.Symbol(name)

    def parse(self, text: str) -> sp.Expr:
        """The SymPy expression for `text`, or ExpressionError saying why not."""
        if len(text) > MAX_LENGTH:
            raise ExpressionError(f"the expression has {len(text)} characters; "
                                  f"at most {MAX_LENGTH} are allowed")
        for name, placeholder in self.aliases:
            text = re.sub(r"(?<![A-Za-z0-9_])" + re.escape(name) + r"(?![A-Za-z0-9_])",
                          placeholder, text)
        try:
            tree = ast.parse(text.strip(), mode="eval")
        except SyntaxError as exc:
            raise ExpressionError(f"syntax error ({exc.msg})") from None
        except (ValueError, MemoryError, RecursionError):
            raise ExpressionError("the expression is too deeply nested to read") from None
        _check_size(tree.body)
        try:
            expr = self._convert(tree.body)
        except (TypeError, ValueError, OverflowError, ZeroDivisionError) as exc:
            if isinstance(exc, ExpressionError):
                raise
            raise ExpressionError(f"cannot be evaluated ({type(exc).__name__})") from None
        if expr.has(sp.zoo, sp.oo, -sp.oo, sp.nan):
            raise ExpressionError("the value is not finite")
        if expr.has(sp.I):
            raise ExpressionError("the value is not real")
        return expr

    def _convert(self, node: ast.AST) -> sp.Expr:
        if isinstance(node, ast.Constant) and isinstance(node.value, (int, float)) \
                and not isinstance(node.value, bool):
            return _bounded(sp.sympify(node.value))
        if isinstance(node, ast.Name):
            if node.id in self.symbols:
                return self.symbols[node.id]
            if node.id in CONSTANTS:
                return CONSTANTS[node.id]
            original = {p: n for n, p in self.aliases}.get(node.id, node.id)
            raise ExpressionError(f"undeclared symbol {original} (declare it under 'parameters')")
        if isinstance(node, ast.BinOp) and type(node.op) in _BINARY:
            left, right = self._convert(node.left), self._convert(node.right)
            if isinstance(node.op, ast.Pow):
                _check_exponent(left, right)
            return _bounded(_BINARY[type(node.op)](left, right))
        if isinstance(node, ast.BinOp) and isinstance(node.op, ast.BitXor):
            raise ExpressionError("'^' is not a power here: write a**b")
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
            value = self._convert(node.operand)
            return -value if isinstance(node.op, ast.USub) else value
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) \
                and node.func.id in FUNCTIONS and not node.keywords:
            name = node.func.id
            arity = _ARITY.get(name, 1)
            if len(node.args) != arity:
                raise ExpressionError(f"{name}() takes {arity} argument{'s' * (arity > 1)}, "
                                      f"got {len(node.args)}")
            return _bounded(FUNCTIONS[name](*(self._convert(a) for a in node.args)))
        raise ExpressionError(f"'{_shown(node)}' is not allowed: only numbers, declared "
                              f"parameters, pi, + - * / ** and {', '.join(sorted(FUNCTIONS))}")


def _shown(node: ast.AST) -> str:
    text = ast.unparse(node)
    return text if len(text) <= 60 else text[:60] + "..."


def _check_size(root: ast.AST) -> None:
    """Refuse trees too deep or too large before any of them is evaluated (no recursion)."""
    stack = [(root, 1)]
    count = 0
    while stack:
        node, depth = stack.pop()
        count += 1
        if depth > MAX_DEPTH:
            raise ExpressionError(f"the expression is nested more than {MAX_DEPTH} deep")
        if count > MAX_NODES:
            raise ExpressionError(f"the expression has more than {MAX_NODES} terms")
        grows = isinstance(node, (ast.BinOp, ast.UnaryOp, ast.Call))
        stack.extend((child, depth + grows) for child in ast.iter_child_nodes(node))


def _check_exponent(base: sp.Expr, exponent: sp.Expr) -> None:
    """Refuse a**b with a large numeric b before SymPy computes it (9**9**9 is a giant integer)."""
    if exponent.is_Number and abs(exponent) > MAX_EXPONENT:
        raise ExpressionError(f"the exponent {_number_text(exponent)} is larger than "
                              f"{MAX_EXPONENT} in magnitude")


def _bounded(value: sp.Expr) -> sp.Expr:
    """Refuse numbers past MAX_MAGNITUDE (and so past the range of a C double)."""
    if value.free_symbols or value.is_finite is False:
        return value
    number = value if value.is_Number else value.evalf(15)
    if not number.is_Number:
        raise ExpressionError(f"the value {_number_text(value)} is not a real number")
    if number.is_Number:
        try:
            magnitude = abs(float(number))
        except (OverflowError, TypeError):
            magnitude = math.inf
        if magnitude > MAX_MAGNITUDE:
            raise ExpressionError(f"the number {_number_text(value)} is larger than "
                                  f"{MAX_MAGNITUDE:g} in magnitude")
    return value


def _number_text(value: sp.Expr) -> str:
    if value.is_Integer and abs(value) > 10**20:
        return f"of {int(abs(value)).bit_length()} bits"
    text = str(value)
    return text if len(text) <= 30 else text[:30] + "..."
