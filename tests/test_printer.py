"""GagenCPrinter's fast path: its C computes what SymPy's printer's C computes.

Random expressions of the kinds gagen's equations are made of (sums with negative terms,
nested products, Rationals, Floats, powers 2..4 and -1..-4, sin and cos of coordinates and
of other expressions, sign, in the exact and the smooth-sign stage) are printed by both
paths (`doprint`, `sympy_doprint`), compiled with gcc into one program with gagen_math.h
and evaluated at random points. Each value must match the expression's exact value (mpmath,
200 bits) to within a rounding-error bound for any order of evaluation (a few ulps of the
magnitudes involved: about 1e-15 relative where the expression is well conditioned). A
wrong parenthesis, sign or number misses it by far, as the canary below shows.
"""

from __future__ import annotations

import random
import shutil
import subprocess
from pathlib import Path

import pytest
import sympy as sp

from gagen.codegen.render import GagenCPrinter, _balanced_sum
from gagen.symbolic.symbols import Coordinate, Internal

mpmath = pytest.importorskip("mpmath")

TEMPLATES = Path(__file__).resolve().parents[1] / "src" / "gagen" / "codegen" / "templates" / "c"
U = 2.0**-53  # unit roundoff of a double
SLACK = 16  # the bound is first order: a margin for the rest
WIDTH = 0.3  # the smooth sign's width, the C variable `w`

V = [Internal(f"_x{k}") for k in range(6)]
Q = [Coordinate(f"j{k}") for k in range(3)]
NAMES = {**{s: f"v[{k}]" for k, s in enumerate(V)}, **{s: f"q[{k}]" for k, s in enumerate(Q)}}


def printer() -> GagenCPrinter:
    return GagenCPrinter(dict(NAMES), list(Q))


class IllConditioned(Exception):
    """The point is too close to a singularity (or a sign's switch) for a fair test."""


def _leaf(rng: random.Random) -> sp.Expr:
    r = rng.random()
    if r < 0.5:
        return rng.choice(V)
    if r < 0.62:
        return rng.choice(Q)
    if r < 0.72:
        return sp.Integer(rng.choice([-3, -2, 2, 3, 5]))
    if r < 0.86:
        return sp.Rational(rng.choice([-7, -5, -1, 1, 3, 5]), rng.choice([2, 3, 4, 7, 12]))
    return sp.Float(rng.uniform(-3.0, 3.0))


def _random_expr(rng: random.Random, depth: int) -> sp.Expr:
    if depth == 0:
        return _leaf(rng)
    r = rng.random()
    sub = lambda: _random_expr(rng, depth - 1)
    if r < 0.3:
        n = rng.choice([2, 3, 4, 5, 9, 12]) if depth > 1 else rng.choice([2, 3, 9])
        return sp.Add(*[rng.choice([1, -1]) * sub() for _ in range(n)])
    if r < 0.55:
        return sp.Mul(*[sub() for _ in range(rng.randint(2, 4))])
    if r < 0.7:
        return sp.Pow(sub(), rng.choice([2, 3, 4, -1, -1, -2, -3, -4]))
    if r < 0.8:
        return rng.choice([sp.sin, sp.cos])(rng.choice(Q))
    if r < 0.86:
        return rng.choice([sp.sin, sp.cos])(sub())
    if r < 0.93:
        return sp.sign(sub())
    return _leaf(rng)


def random_exprs(seed: int, count: int) -> list[sp.Expr]:
    rng = random.Random(seed)
    out = []
    while len(out) < count:
        e = _random_expr(rng, rng.choice([2, 3, 3, 4]))
        if e.is_number or e.has(sp.zoo, sp.oo, -sp.oo, sp.nan):
            continue
        out.append(e)
    return out


def exact(expr: sp.Expr, point: dict, smooth: bool) -> tuple:
    """The exact value of `expr` at `point` and a bound on the rounding error of its C, in
    units of U, whatever the order of its sums and products (first order)."""
    if expr in point:
        return point[expr], 0.0
    if expr.is_Integer:
        return mpmath.mpf(int(expr)), 0.0
    if expr.is_Rational:  # p.0/q.0: one division
        v = mpmath.mpf(expr.p) / expr.q
        return v, abs(v)
    if expr.is_Float:  # printed to 17 digits: the same double
        return mpmath.mpf(float(expr)), 0.0
    if isinstance(expr, (sp.sin, sp.cos)):
        f = mpmath.sin if isinstance(expr, sp.sin) else mpmath.cos
        df = mpmath.cos if isinstance(expr, sp.sin) else mpmath.sin
        a, ea = exact(expr.args[0], point, smooth)
        v = f(a)
        return v, ea * abs(df(a)) + 2 * abs(v)  # gagen_sin, libm's sin: within 1 ulp
    if isinstance(expr, sp.sign):
        a, ea = exact(expr.args[0], point, smooth)
        if not smooth:
            if abs(a) <= 1e6 * ea * U:
                raise IllConditioned
            return mpmath.sign(a), 0.0
        y = a / WIDTH
        v = mpmath.tanh(y)
        return v, (ea / WIDTH + abs(y)) * (1 - v**2) + 4 * abs(v) + 4
    if expr.is_Add or expr.is_Mul or expr.is_Pow:
        if expr.is_Pow:
            (b, eb), k = exact(expr.base, point, smooth), int(expr.exp)
            parts, ops = [(b, eb)] * abs(k), abs(k) + (k < 0)
        else:
            parts, ops = [exact(a, point, smooth) for a in expr.args], len(expr.args)
        if expr.is_Add:
            return mpmath.fsum(v for v, _ in parts), (sum(e for _, e in parts)
                                                      + ops * sum(abs(v) for v, _ in parts))
        if any(v == 0 or e * U > 1e-8 * abs(v) for v, e in parts):
            raise IllConditioned
        v = mpmath.fprod(v for v, _ in parts)
        v = 1 / v if expr.is_Pow and k < 0 else v
        return v, abs(v) * (sum(e / abs(p) for p, e in parts) + ops)
    raise AssertionError(f"unexpected node {expr!r}")


def agrees(value: float, expected, bound: float) -> bool:
    return abs(mpmath.mpf(value) - expected) <= SLACK * bound * U + 1e-300


def evaluate_c(texts: list[str], points: list[dict], tmp_path: Path) -> list[list[float]]:
    """The C expressions `texts` evaluated at each point by gcc's program (values[point][k])."""
    rows = []
    for point in points:
        values = [point[s] for s in V] + [point[s] for s in Q]
        rows.append("{" + ", ".join(repr(float(x)) for x in values) + "}")
    prints = "\n".join(f'        printf("%a\\n", (double)({t}));' for t in texts)
    trig = ", ".join(f"sn{k} = sin(q[{k}]), cs{k} = cos(q[{k}])" for k in range(len(Q)))
    source = f"""
#include <math.h>
#include <stdio.h>
#include "gagen_math.h"

static const double points[{len(points)}][{len(V) + len(Q)}] = {{{", ".join(rows)}}};

int main(void)
{{
    const double w = {WIDTH!r};
    double v[{len(V)}], q[{len(Q)}];
    for (int k = 0; k < {len(points)}; k++) {{
        for (int i = 0; i < {len(V)}; i++) v[i] = points[k][i];
        for (int i = 0; i < {len(Q)}; i++) q[i] = points[k][{len(V)} + i];
        double {trig};
{prints}
    }}
    return 0;
}}
"""
    src, exe = tmp_path / "exprs.c", tmp_path / "exprs"
    src.write_text(source)
    subprocess.run(["gcc", "-std=c99", "-O0", "-ffp-contract=off", f"-I{TEMPLATES}", str(src),
                    "-o", str(exe), "-lm"], check=True)
    out = subprocess.run([str(exe)], check=True, capture_output=True, text=True).stdout.split()
    values = [float.fromhex(x) for x in out]
    return [values[k * len(texts):(k + 1) * len(texts)] for k in range(len(points))]


def random_points(seed: int, count: int) -> list[dict]:
    rng = random.Random(seed)
    points = []
    for _ in range(count):
        point = {s: rng.choice([1, -1]) * rng.uniform(0.5, 2.0) for s in V}
        point.update({s: rng.uniform(-3.0, 3.0) for s in Q})
        points.append({s: mpmath.mpf(x) for s, x in point.items()})
    return points


@pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")
def test_fast_printer_computes_what_sympys_printer_computes(tmp_path):
    mpmath.mp.prec = 200
    exprs = random_exprs(seed=20240531, count=240)
    points = random_points(seed=7, count=4)
    p = printer()
    cases = []  # (expr, smooth, text) for both paths
    for k, e in enumerate(exprs):
        smooth = e.has(sp.sign) and k % 2 == 1
        p.smooth_sign_width = "w" if smooth else None
        fast, old = p.doprint(e), p.sympy_doprint(e)
        cases += [(e, smooth, fast), (e, smooth, old)]
    p.smooth_sign_width = None
    # the canary: y/x**2 as the old printer's x*x under a division wrote it, a/x*x
    canary = (V[1] / V[0] ** 2, False, "v[1]/v[0]*v[0]")
    values = evaluate_c([t for _, _, t in cases] + [canary[2]], points, tmp_path)
    compared = 0
    caught = 0
    for point, row in zip(points, values):
        for (e, smooth, text), value in zip(cases + [canary], row):
            try:
                expected, bound = exact(e, point, smooth)
            except IllConditioned:
                continue
            ok = agrees(value, expected, bound)
            if text is canary[2]:
                caught += not ok
                continue
            compared += 1
            assert ok, (f"{e} at {point}: C {text!r} gives {value!r}, exact "
                        f"{mpmath.nstr(expected, 20)} (bound {float(SLACK * bound * U):.3g})")
    assert caught == len(points)  # the check can fail
    assert compared > 0.8 * len(cases) * len(points)  # few points were ill-conditioned


def test_fast_printer_texts():
    p = printer()
    x, y = V[0], V[1]
    assert p.doprint(x / 4) == "(1.0/4.0)*v[0]"
    assert p.doprint(-x / 4) == "-1.0/4.0*v[0]"
    assert p.doprint(sp.Float(0.1) * x) == "0.10000000000000001*v[0]"
    assert p.doprint(sp.Float(-2.5) * x) == "-2.5*v[0]"
    assert p.doprint(x**2) == "v[0]*v[0]"
    assert p.doprint(1 / x) == "1.0/v[0]"
    assert p.doprint(x**-3) == "1.0/(v[0]*v[0]*v[0])"
    assert p.doprint(y / x**2) == p.sympy_doprint(y / x**2) == "v[1]/(v[0]*v[0])"
    assert p.doprint(-y / (x + 1)) == "-v[1]/(1 + v[0])"
    assert p.doprint(sp.sin(Q[1]) * sp.cos(Q[2])) in ("sn1*cs2", "cs2*sn1")
    assert p.doprint(sp.sin(x)) == "gagen_sin(v[0])"
    assert p.doprint(y * sp.sign(x)) == "v[1]*gagen_sign(v[0])"
    p.smooth_sign_width = "p[9]"
    assert p.doprint(sp.sign(x)) == "gagen_smooth_sign(v[0], p[9])"
    assert p.doprint(-2 * y * sp.sign(x)) == "gagen_coulomb(-2*v[1], v[0], p[9])"
    p.smooth_sign_width = None
    # a sum's terms in SymPy's canonical order, negative ones subtracted, as a balanced tree
    terms = sp.Add(*[(-1) ** k * s for k, s in enumerate(V + Q[:1])])
    expected = _balanced_sum([(a.could_extract_minus_sign(), p.doprint(-a if
                              a.could_extract_minus_sign() else a)) for a in terms.args])
    assert p.doprint(terms) == expected
    assert p.doprint(terms).count("(") == 2  # 7 terms: ((a + b) + (c + d)) + ((e + f) + g)


def test_unusual_nodes_go_to_sympys_printer():
    p = printer()
    x, y = V[0], V[1]
    for e in (sp.sqrt(x), x**5, x ** sp.Rational(1, 3), sp.pi / 2, sp.pi * x, sp.tanh(x) * y,
              sp.Function("f")(x) + y, sp.Abs(x) - y, 1 / sp.sqrt(x + y)):
        assert p.doprint(e) == p.sympy_doprint(e), e
    assert p.doprint(sp.pi / 2) == "M_PI_2"
    assert "pow(v[0], 5)" in p.doprint(y + x**5)


def test_fast_printer_reads_and_trig():
    p = printer()
    e = sp.sin(Q[0]) * V[0] + sp.cos(Q[2]) ** 2 - sp.sign(V[1] + sp.sin(V[2]))
    assert p.reads(e) == {"sn0", "cs2", "q[0]", "q[2]", "v[0]", "v[1]", "v[2]"}
    assert p.trig_used([e, sp.cos(Q[1])]) == [0, 1, 2]
