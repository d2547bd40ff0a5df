"""Parse the numbers and expressions of model files without ever evaluating Python code.

The text is read by Python's `ast` parser and only arithmetic, declared names, a few
constants and elementary functions are turned into SymPy; anything else is refused.
"""

from __future__ import annotations

import ast
import keyword
import math
import re

import sympy as sp

_IDENT = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
FUNCTIONS = {
    "sin": sp.sin, "cos": sp.cos, "tan": sp.tan, "asin": sp.asin, "acos": sp.acos,
    "atan": sp.atan, "atan2": sp.atan2, "sinh": sp.sinh, "cosh": sp.cosh, "tanh": sp.tanh,
    "exp": sp.exp, "log": sp.log, "sqrt": sp.sqrt, "abs": sp.Abs,
}
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
        for name, placeholder in self.aliases:
            text = re.sub(r"(?<![A-Za-z0-9_])" + re.escape(name) + r"(?![A-Za-z0-9_])",
                          placeholder, text)
        try:
            tree = ast.parse(text.strip(), mode="eval")
        except SyntaxError as exc:
            raise ExpressionError(f"syntax error ({exc.msg})") from None
        expr = self._convert(tree.body)
        if expr.has(sp.zoo, sp.oo, -sp.oo, sp.nan):
            raise ExpressionError("the value is not finite")
        if expr.has(sp.I):
            raise ExpressionError("the value is not real")
        return expr

    def _convert(self, node: ast.AST) -> sp.Expr:
        if isinstance(node, ast.Constant) and isinstance(node.value, (int, float)) \
                and not isinstance(node.value, bool):
            if isinstance(node.value, float) and not math.isfinite(node.value):
                raise ExpressionError("the value is not finite")
            return sp.sympify(node.value)
        if isinstance(node, ast.Name):
            if node.id in self.symbols:
                return self.symbols[node.id]
            if node.id in CONSTANTS:
                return CONSTANTS[node.id]
            original = {p: n for n, p in self.aliases}.get(node.id, node.id)
            raise ExpressionError(f"undeclared symbol {original} (declare it under 'parameters')")
        if isinstance(node, ast.BinOp) and type(node.op) in _BINARY:
            return _BINARY[type(node.op)](self._convert(node.left), self._convert(node.right))
        if isinstance(node, ast.BinOp) and isinstance(node.op, ast.BitXor):
            raise ExpressionError("'^' is not a power here: write a**b")
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
            value = self._convert(node.operand)
            return -value if isinstance(node.op, ast.USub) else value
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) \
                and node.func.id in FUNCTIONS and not node.keywords:
            return FUNCTIONS[node.func.id](*(self._convert(a) for a in node.args))
        what = ast.unparse(node) if hasattr(ast, "unparse") else type(node).__name__
        raise ExpressionError(f"'{what}' is not allowed: only numbers, declared parameters, "
                              f"pi, + - * / ** and {', '.join(sorted(FUNCTIONS))}")
