"""Tests of the standalone C99 integrators in templates/integrator.c (and gagen_ode.h).

The C file is compiled with gcc together with a small C file of test right-hand sides
into a shared library, which is driven through ctypes. (The model-specialised
second-order integrators of gagen_second_order.h are tested through the compiled models,
in test_simulation_c.py.)
gagen_dopri5 is a transcription of scipy's RK45, so besides the values, the step
sequence itself (nfev, accepted and rejected steps) must be identical to scipy's.
"""

from __future__ import annotations

import ctypes
import math
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

GCC = shutil.which("gcc")
pytestmark = pytest.mark.skipif(
    GCC is None, reason="gcc not found on PATH: cannot compile integrator.c"
)

TEMPLATES = Path(__file__).resolve().parents[1] / "src" / "gagen" / "codegen" / "templates" / "c"
INTEGRATOR_C = TEMPLATES / "integrator.c"
CFLAGS = ["-O2", "-std=c99", "-Wall", "-Wextra", "-Werror", "-fPIC"]

GAGEN_ERR_STEP_TOO_SMALL = -101
GAGEN_ERR_MAX_STEPS = -102
GAGEN_ERR_BAD_ARG = -103

TEST_MODELS_C = r"""
#include <math.h>
#include <stddef.h>
#include "integrator.h"

size_t test_sizeof_stats(void);
int osc_rhs(void *ctx, double t, const double *y, double *dydt);
int vdp_rhs(void *ctx, double t, const double *y, double *dydt);
int kepler_rhs(void *ctx, double t, const double *y, double *dydt);
int forced_rhs(void *ctx, double t, const double *y, double *dydt);
int blowup_rhs(void *ctx, double t, const double *y, double *dydt);
int failing_rhs(void *ctx, double t, const double *y, double *dydt);

size_t test_sizeof_stats(void) { return sizeof(gagen_ode_stats); }

/* damped oscillator, p = [omega, zeta] */
int osc_rhs(void *ctx, double t, const double *y, double *dydt)
{
    const double *p = (const double *)ctx;
    (void)t;
    dydt[0] = y[1];
    dydt[1] = -2.0 * p[1] * p[0] * y[1] - p[0] * p[0] * y[0];
    return 0;
}

/* Van der Pol, p = [mu] */
int vdp_rhs(void *ctx, double t, const double *y, double *dydt)
{
    const double *p = (const double *)ctx;
    (void)t;
    dydt[0] = y[1];
    dydt[1] = p[0] * (1.0 - y[0] * y[0]) * y[1] - y[0];
    return 0;
}

/* planar Kepler problem, mu = 1 */
int kepler_rhs(void *ctx, double t, const double *y, double *dydt)
{
    double r2 = y[0] * y[0] + y[1] * y[1];
    double r3 = r2 * sqrt(r2);
    (void)ctx;
    (void)t;
    dydt[0] = y[2];
    dydt[1] = y[3];
    dydt[2] = -y[0] / r3;
    dydt[3] = -y[1] / r3;
    return 0;
}

/* time-dependent: checks the stage times */
int forced_rhs(void *ctx, double t, const double *y, double *dydt)
{
    (void)ctx;
    dydt[0] = -y[0] + sin(3.0 * t);
    return 0;
}

/* y' = y^2 blows up at t = 1/y0 */
int blowup_rhs(void *ctx, double t, const double *y, double *dydt)
{
    (void)ctx;
    (void)t;
    dydt[0] = y[0] * y[0];
    return 0;
}

typedef struct { long calls; long fail_at; int code; } fail_ctx;

int failing_rhs(void *ctx, double t, const double *y, double *dydt)
{
    fail_ctx *c = (fail_ctx *)ctx;
    (void)t;
    if (++c->calls >= c->fail_at) return c->code;
    dydt[0] = -y[0];
    return 0;
}
"""

# numpy twins of the C right-hand sides, for scipy
PY_RHS = {
    "osc": lambda p: lambda t, y: np.array([y[1], -2.0 * p[1] * p[0] * y[1] - p[0] * p[0] * y[0]]),
    "vdp": lambda p: lambda t, y: np.array([y[1], p[0] * (1.0 - y[0] * y[0]) * y[1] - y[0]]),
    "kepler": lambda p: _kepler_py,
    "forced": lambda p: lambda t, y: np.array([-y[0] + math.sin(3.0 * t)]),
    "blowup": lambda p: lambda t, y: y * y,
}


def _kepler_py(t, y):
    r2 = y[0] * y[0] + y[1] * y[1]
    r3 = r2 * math.sqrt(r2)
    return np.array([y[2], y[3], -y[0] / r3, -y[1] / r3])


c_double_p = ctypes.POINTER(ctypes.c_double)


class Stats(ctypes.Structure):
    _fields_ = [
        ("nfev", ctypes.c_long),
        ("nsteps", ctypes.c_long),
        ("naccepted", ctypes.c_long),
        ("nrejected", ctypes.c_long),
        ("status", ctypes.c_int),
    ]


class FailCtx(ctypes.Structure):
    _fields_ = [("calls", ctypes.c_long), ("fail_at", ctypes.c_long), ("code", ctypes.c_int)]


def _dp(a: np.ndarray):
    return a.ctypes.data_as(c_double_p)


@pytest.fixture(scope="module")
def lib(tmp_path_factory):
    d = tmp_path_factory.mktemp("integrator_c")
    models = d / "test_models.c"
    models.write_text(TEST_MODELS_C)
    so = d / "libgagen_integrator_test.so"
    cmd = [GCC, *CFLAGS, "-shared", f"-I{TEMPLATES}", str(INTEGRATOR_C), str(models)]
    cmd += ["-o", str(so), "-lm"]
    res = subprocess.run(cmd, check=False, capture_output=True, text=True)
    assert res.returncode == 0, f"compilation failed:\n{' '.join(cmd)}\n{res.stderr}"
    L = ctypes.CDLL(str(so))
    L.gagen_dopri5.restype = ctypes.c_int
    L.gagen_dopri5.argtypes = [
        ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int, ctypes.c_double, ctypes.c_double,
        c_double_p, ctypes.c_double, c_double_p, ctypes.c_double, ctypes.c_double,
        ctypes.c_long, c_double_p, ctypes.c_int, c_double_p, c_double_p, ctypes.POINTER(Stats),
    ]  # fmt: skip
    L.gagen_rk4.restype = ctypes.c_int
    L.gagen_rk4.argtypes = [
        ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int, ctypes.c_double, ctypes.c_double,
        c_double_p, ctypes.c_double, c_double_p, ctypes.c_int, c_double_p, c_double_p,
        ctypes.POINTER(Stats),
    ]  # fmt: skip
    for name in ("gagen_dopri5_work_size", "gagen_rk4_work_size"):
        getattr(L, name).restype = ctypes.c_long
        getattr(L, name).argtypes = [ctypes.c_int]
    L.test_sizeof_stats.restype = ctypes.c_size_t
    return L


def fptr(lib, name: str) -> int:
    return ctypes.cast(getattr(lib, name), ctypes.c_void_p).value


def run_dopri5(lib, rhs, ctx, y0, t0, t1, t_eval, rtol=1e-6, atol=1e-9, first_step=0.0,
               max_step=0.0, max_steps=0, work_pad=0):  # fmt: skip
    y0 = np.ascontiguousarray(y0, dtype=float)
    n = y0.size
    atol_a = np.ascontiguousarray(np.broadcast_to(np.asarray(atol, dtype=float), (n,)))
    t_eval = np.ascontiguousarray(t_eval, dtype=float)
    out = np.full((t_eval.size, n), 12345.0)
    work = np.full(lib.gagen_dopri5_work_size(n) + work_pad, np.nan)
    st = Stats()
    f = fptr(lib, rhs) if isinstance(rhs, str) else rhs
    rc = lib.gagen_dopri5(
        f, ctx, n, t0, t1, _dp(y0), rtol, _dp(atol_a), first_step, max_step, max_steps,
        _dp(t_eval), t_eval.size, _dp(out), _dp(work), ctypes.byref(st),
    )  # fmt: skip
    assert st.status == rc
    return rc, out, st


def run_rk4(lib, rhs, ctx, y0, t0, t1, h, t_eval):
    y0 = np.ascontiguousarray(y0, dtype=float)
    n = y0.size
    t_eval = np.ascontiguousarray(t_eval, dtype=float)
    out = np.full((t_eval.size, n), 12345.0)
    work = np.full(lib.gagen_rk4_work_size(n), np.nan)
    st = Stats()
    rc = lib.gagen_rk4(fptr(lib, rhs), ctx, n, t0, t1, _dp(y0), h, _dp(t_eval), t_eval.size,
                       _dp(out), _dp(work), ctypes.byref(st))  # fmt: skip
    assert st.status == rc
    return rc, out, st


def scipy_rk45(fun, y0, t0, t1, t_eval, rtol, atol, first_step=None, max_step=np.inf):
    """scipy reference: values at t_eval, step end points, nfev, accepted, rejected."""
    kw = {"method": "RK45", "rtol": rtol, "atol": atol, "max_step": max_step}
    if first_step is not None:
        kw["first_step"] = first_step
    with_eval = solve_ivp(fun, (t0, t1), y0, t_eval=t_eval, **kw)
    steps = solve_ivp(fun, (t0, t1), y0, **kw)
    assert with_eval.nfev == steps.nfev
    naccepted = steps.t.size - 1
    # RK45 evaluates f six times per attempt, plus f(t0) and one probe in select_initial_step.
    setup = 1 if first_step is not None else 2
    assert (steps.nfev - setup) % 6 == 0
    nrejected = (steps.nfev - setup) // 6 - naccepted
    return with_eval, steps, naccepted, nrejected


# name, C rhs, ctx params, y0, (t0, t1), rtol, atol
PROBLEMS = [
    ("osc", [2.0, 0.1], [1.0, 0.0], (0.0, 10.0), 1e-6, 1e-9),
    ("osc_loose", [2.0, 0.1], [1.0, 0.0], (0.0, 10.0), 1e-3, 1e-6),
    ("vdp", [5.0], [2.0, 0.0], (0.0, 30.0), 1e-6, [1e-8, 1e-7]),
    ("vdp_loose", [5.0], [2.0, 0.0], (0.0, 30.0), 1e-3, 1e-6),
    ("kepler", [], [0.5, 0.0, 0.0, math.sqrt(3.0)], (0.0, 20.0), 1e-9, 1e-12),
    ("forced", [], [0.3], (0.5, 7.0), 1e-8, 1e-10),
]


def _problem_fun(name):
    base = name.split("_")[0]
    return base, f"{base}_rhs"


@pytest.mark.parametrize(
    ("name", "p", "y0", "span", "rtol", "atol"), PROBLEMS, ids=[p[0] for p in PROBLEMS]
)
def test_dopri5_matches_scipy_rk45(lib, name, p, y0, span, rtol, atol):
    base, crhs = _problem_fun(name)
    pa = np.array(p + [0.0])
    t0, t1 = span
    t_eval = np.concatenate([[t0], np.sort(np.random.default_rng(0).uniform(t0, t1, 200)), [t1]])
    ref, steps, nacc, nrej = scipy_rk45(PY_RHS[base](pa), y0, t0, t1, t_eval, rtol, atol)
    assert ref.status == 0

    rc, out, st = run_dopri5(lib, crhs, pa.ctypes.data, y0, t0, t1, t_eval, rtol=rtol, atol=atol)
    assert rc == 0
    # Same algorithm, same step sequence: the counts are identical, not just close.
    assert (st.nfev, st.naccepted, st.nrejected) == (ref.nfev, nacc, nrej)
    assert st.nsteps == st.naccepted + st.nrejected
    if "vdp" in name:
        assert st.nrejected > 5  # the case is meant to exercise the rejection path

    # Bit-identical results are not possible: numpy's dot goes through OpenBLAS, whose
    # summation order and FMA use depend on the CPU kernel. Those last-bit differences are
    # amplified by the dynamics; with loose tolerances on Van der Pol's fast transitions the
    # amplification reaches ~1e-8, exactly as much as scipy differs from ITSELF when y0 is
    # moved by one ulp. So compare to 1e-10 relative, widened only to that measured
    # round-off sensitivity of the reference.
    y0_ulp = np.nextafter(np.asarray(y0, dtype=float), np.inf)
    nudged = solve_ivp(
        PY_RHS[base](pa), (t0, t1), y0_ulp, method="RK45", rtol=rtol, atol=atol, t_eval=t_eval
    )
    sensitivity = np.max(np.abs(nudged.y - ref.y))
    scale = np.max(np.abs(ref.y))
    tol = max(1e-10 * scale, 10 * sensitivity)
    if name != "vdp_loose":
        assert tol == 1e-10 * scale  # the plain 1e-10 criterion holds everywhere else
    np.testing.assert_allclose(out, ref.y.T, rtol=1e-10, atol=tol)
    assert np.array_equal(out[0], np.asarray(y0, dtype=float))  # t_eval == t0 is y0 exactly

    # At scipy's own step ends our output is the step value itself: compare the step states.
    rc, at_steps, _ = run_dopri5(
        lib, crhs, pa.ctypes.data, y0, t0, t1, steps.t, rtol=rtol, atol=atol
    )
    assert rc == 0
    np.testing.assert_allclose(at_steps, steps.y.T, rtol=1e-10, atol=tol)
    assert np.array_equal(at_steps[-1], out[-1])  # t1: final state, not an interpolant


@pytest.mark.parametrize(
    ("first_step", "max_step"), [(1e-3, np.inf), (0.0, 0.05), (0.2, 0.3), (0.0, 0.0)]
)
def test_dopri5_first_step_and_max_step_match_scipy(lib, first_step, max_step):
    pa = np.array([5.0])
    y0, t0, t1 = [2.0, 0.0], 0.0, 12.0
    t_eval = np.linspace(t0, t1, 97)
    ref, _, nacc, nrej = scipy_rk45(
        PY_RHS["vdp"](pa), y0, t0, t1, t_eval, 1e-6, 1e-8,
        first_step=first_step if first_step > 0 else None,
        max_step=max_step if max_step > 0 else np.inf,
    )  # fmt: skip
    rc, out, st = run_dopri5(lib, "vdp_rhs", pa.ctypes.data, y0, t0, t1, t_eval, rtol=1e-6,
                             atol=1e-8, first_step=first_step, max_step=max_step)  # fmt: skip
    assert rc == 0
    assert (st.nfev, st.naccepted, st.nrejected) == (ref.nfev, nacc, nrej)
    np.testing.assert_allclose(out, ref.y.T, rtol=1e-10, atol=1e-10)
    max_step = math.inf if max_step <= 0 else max_step
    assert st.naccepted >= (t1 - t0) / max_step


def test_dopri5_backward_matches_scipy(lib):
    pa = np.array([2.0, 0.1])
    t0, t1 = 5.0, -3.0
    t_eval = np.linspace(t0, t1, 41)
    ref, _, nacc, nrej = scipy_rk45(PY_RHS["osc"](pa), [0.3, -1.0], t0, t1, t_eval, 1e-7, 1e-9)
    rc, out, st = run_dopri5(lib, "osc_rhs", pa.ctypes.data, [0.3, -1.0], t0, t1, t_eval,
                             rtol=1e-7, atol=1e-9)  # fmt: skip
    assert rc == 0
    assert (st.nfev, st.naccepted, st.nrejected) == (ref.nfev, nacc, nrej)
    np.testing.assert_allclose(out, ref.y.T, rtol=1e-10, atol=1e-10)


def test_dopri5_tiny_rtol_is_raised_like_scipy(lib):
    pa = np.array([2.0, 0.1])
    t_eval = np.array([0.0, 1.0, 2.0])
    with pytest.warns(UserWarning, match="rtol"):
        ref, _, nacc, nrej = scipy_rk45(
            PY_RHS["osc"](pa), [1.0, 0.0], 0.0, 2.0, t_eval, 1e-16, 1e-14
        )
    rc, out, st = run_dopri5(lib, "osc_rhs", pa.ctypes.data, [1.0, 0.0], 0.0, 2.0, t_eval,
                             rtol=1e-16, atol=1e-14)  # fmt: skip
    assert rc == 0
    assert (st.nfev, st.naccepted, st.nrejected) == (ref.nfev, nacc, nrej)
    np.testing.assert_allclose(out, ref.y.T, rtol=1e-12, atol=1e-13)


def test_dopri5_degenerate_interval_and_empty_t_eval(lib):
    pa = np.array([2.0, 0.1])
    rc, out, st = run_dopri5(lib, "osc_rhs", pa.ctypes.data, [1.0, 2.0], 3.0, 3.0, [3.0, 3.0])
    assert rc == 0
    assert np.array_equal(out, [[1.0, 2.0], [1.0, 2.0]])
    assert (st.nfev, st.naccepted) == (1, 0)  # scipy also evaluates f(t0) once

    rc, out, st = run_dopri5(lib, "osc_rhs", pa.ctypes.data, [1.0, 2.0], 0.0, 1.0, [])
    assert rc == 0 and st.naccepted > 0


def test_dopri5_uses_only_declared_work(lib):
    # NaN-filled work beyond the declared size must never be read or written.
    pa = np.array([2.0, 0.1])
    n = 2
    size = lib.gagen_dopri5_work_size(n)
    y0 = np.array([1.0, 0.0])
    atol = np.full(n, 1e-9)
    t_eval = np.linspace(0, 3, 7)
    out = np.empty((7, n))
    work = np.full(size + 16, -7.0)
    st = Stats()
    rc = lib.gagen_dopri5(
        fptr(lib, "osc_rhs"), pa.ctypes.data, n, 0.0, 3.0, _dp(y0), 1e-6, _dp(atol), 0.0, 0.0, 0,
        _dp(t_eval), 7, _dp(out), _dp(work), ctypes.byref(st),
    )  # fmt: skip
    assert rc == 0
    assert np.all(work[size:] == -7.0)


def test_rhs_error_code_aborts(lib):
    fc = FailCtx(calls=0, fail_at=40, code=7)
    t_eval = np.linspace(0.0, 10.0, 11)
    rc, out, st = run_dopri5(lib, "failing_rhs", ctypes.addressof(fc), [1.0], 0.0, 10.0, t_eval)
    assert rc == 7 and st.status == 7
    assert st.nfev == 40 == fc.calls  # stops at the failing call, no further evaluations
    assert np.array_equal(out[0], [1.0])
    assert np.isnan(out[-1]).all()  # points not reached are NaN
    reached = ~np.isnan(out[:, 0])
    np.testing.assert_allclose(out[reached, 0], np.exp(-t_eval[reached]), rtol=1e-4)

    # failure in the very first evaluation, and in select_initial_step's probe
    for fail_at in (1, 2):
        fc = FailCtx(calls=0, fail_at=fail_at, code=9)
        fail_ptr = ctypes.addressof(fc)
        rc, out, st = run_dopri5(lib, "failing_rhs", fail_ptr, [1.0], 0.0, 1.0, [0.0, 1.0])
        assert (rc, st.nfev) == (9, fail_at)
        assert np.isnan(out).all()

    fc = FailCtx(calls=0, fail_at=10, code=5)
    fail_ptr = ctypes.addressof(fc)
    rc, out, st = run_rk4(lib, "failing_rhs", fail_ptr, [1.0], 0.0, 1.0, 0.1, [0.5, 1.0])
    assert (rc, st.nfev, fc.calls) == (5, 10, 10)
    assert np.isnan(out).all()


def test_step_size_too_small_like_scipy(lib):
    # y' = y^2, y(0) = 1 blows up at t = 1: the step size collapses before t = 2.
    t_eval = np.array([0.0, 0.5, 0.9, 1.5, 2.0])
    ref = solve_ivp(PY_RHS["blowup"](None), (0.0, 2.0), [1.0], method="RK45", rtol=1e-6, atol=1e-9)
    assert ref.status == -1 and "step size" in ref.message
    rc, out, st = run_dopri5(lib, "blowup_rhs", None, [1.0], 0.0, 2.0, t_eval, rtol=1e-6, atol=1e-9)
    assert rc == GAGEN_ERR_STEP_TOO_SMALL
    assert st.nfev == ref.nfev and st.naccepted == ref.t.size - 1
    np.testing.assert_allclose(out[:3, 0], 1.0 / (1.0 - t_eval[:3]), rtol=1e-5)
    assert np.isnan(out[3:]).all()


def test_max_steps_and_bad_arguments(lib):
    pa = np.array([5.0])
    rc, out, st = run_dopri5(
        lib, "vdp_rhs", pa.ctypes.data, [2.0, 0.0], 0.0, 30.0, [30.0], max_steps=25
    )
    assert rc == GAGEN_ERR_MAX_STEPS and st.nsteps == 25
    assert np.isnan(out).all()

    bad_t_eval = [[1.0, 0.5], [-0.1], [30.5], [np.nan]]
    for te in bad_t_eval:
        rc, _, st = run_dopri5(lib, "vdp_rhs", pa.ctypes.data, [2.0, 0.0], 0.0, 30.0, te)
        assert rc == GAGEN_ERR_BAD_ARG and st.nfev == 0
        rc, _, st = run_rk4(lib, "vdp_rhs", pa.ctypes.data, [2.0, 0.0], 0.0, 30.0, 0.1, te)
        assert rc == GAGEN_ERR_BAD_ARG and st.nfev == 0
    rc, _, _ = run_dopri5(lib, "vdp_rhs", pa.ctypes.data, [2.0, 0.0], 0.0, 1.0, [1.0], atol=-1.0)
    assert rc == GAGEN_ERR_BAD_ARG
    rc, _, _ = run_rk4(lib, "vdp_rhs", pa.ctypes.data, [2.0, 0.0], 0.0, 1.0, 0.0, [1.0])
    assert rc == GAGEN_ERR_BAD_ARG


def _osc_exact(t, omega=2.0, zeta=0.1):
    wd = omega * math.sqrt(1 - zeta**2)
    a = zeta * omega
    x = np.exp(-a * t) * (np.cos(wd * t) + a / wd * np.sin(wd * t))
    v = -np.exp(-a * t) * (omega**2 / wd) * np.sin(wd * t)
    return np.stack([x, v], axis=-1)


def test_rk4_fourth_order_convergence(lib):
    pa = np.array([2.0, 0.1])
    t0, t1 = 0.0, 5.0
    t_eval = np.array([0.0, 0.37, 1.234, 2.5, 3.9999, 5.0])  # mostly between grid points
    exact = _osc_exact(t_eval)
    errs = []
    for h in (0.1, 0.05, 0.025, 0.0125):
        rc, out, st = run_rk4(lib, "osc_rhs", pa.ctypes.data, [1.0, 0.0], t0, t1, h, t_eval)
        assert rc == 0
        nsteps = round((t1 - t0) / h)
        assert (st.naccepted, st.nsteps, st.nrejected) == (nsteps, nsteps, 0)
        # f(t0), 3 new stages per step, f at each interior grid point (the next step's k1);
        # f(t1) is skipped because no t_eval point lies inside the last step
        assert st.nfev == 1 + 3 * nsteps + (nsteps - 1)
        errs.append(np.max(np.abs(out - exact)))
        assert np.array_equal(out[0], [1.0, 0.0])
    ratios = np.array(errs[:-1]) / np.array(errs[1:])
    assert np.all((ratios > 13.0) & (ratios < 19.0)), ratios
    assert errs[-1] < 1e-7


def test_rk4_last_step_lands_on_t1_and_hermite_is_consistent(lib):
    pa = np.array([2.0, 0.1])
    h = 0.3  # 1.0 / 0.3 is not an integer: the 4th step is shortened to 0.1
    grid = [0.0, 0.3, 0.6, 0.9]
    rc, at_grid, st = run_rk4(lib, "osc_rhs", pa.ctypes.data, [1.0, 0.0], 0.0, 1.0, h, grid + [1.0])
    assert rc == 0 and st.naccepted == 4
    np.testing.assert_allclose(at_grid, _osc_exact(np.array(grid + [1.0])), atol=1e-2)  # coarse h
    # final state equals a run that ends exactly there; interpolation is continuous at grid points
    eps = 1e-9
    probes = [0.3 - eps, 0.3 + eps, 1.0 - eps]
    rc, near, st = run_rk4(lib, "osc_rhs", pa.ctypes.data, [1.0, 0.0], 0.0, 1.0, h, probes)
    assert st.nfev == 1 + 3 * 4 + 3 + 1  # f(t1) is evaluated only because 1 - eps needs it
    np.testing.assert_allclose(near[0], at_grid[1], atol=1e-8)
    np.testing.assert_allclose(near[1], at_grid[1], atol=1e-8)
    np.testing.assert_allclose(near[2], at_grid[4], atol=1e-8)

    # an exact multiple of h must not produce an extra sliver step
    rc, _, st = run_rk4(lib, "osc_rhs", pa.ctypes.data, [1.0, 0.0], 0.0, 0.7, 0.1, [0.7])
    assert rc == 0 and st.naccepted == 7

    # backward integration
    back = [0.0, -0.5, -1.0]
    rc, out, _ = run_rk4(lib, "osc_rhs", pa.ctypes.data, [1.0, 0.0], 0.0, -1.0, 0.01, back)
    assert rc == 0
    np.testing.assert_allclose(out, _osc_exact(np.array([0.0, -0.5, -1.0])), rtol=1e-8, atol=1e-9)


def test_ctypes_struct_layouts_match_c(lib):
    assert lib.test_sizeof_stats() == ctypes.sizeof(Stats)


def test_integrator_is_strict_c99_without_mutable_globals(tmp_path):
    obj = tmp_path / "integrator.o"
    cmd = [GCC, *CFLAGS, "-pedantic", "-Wshadow", "-Wstrict-prototypes", "-Wmissing-prototypes",
           "-Wcast-qual", "-c", str(INTEGRATOR_C), "-o", str(obj)]  # fmt: skip
    res = subprocess.run(cmd, check=False, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    text = INTEGRATOR_C.read_text() + (TEMPLATES / "integrator.h").read_text()
    assert "#include <Python.h>" not in text and "#include <stdlib.h>" not in text
    assert re.search(r"\b(malloc|calloc|realloc|free)\s*\(", text) is None
    nm = shutil.which("nm")
    if nm is None:
        pytest.skip("nm not available to inspect symbols")
    syms = subprocess.run([nm, str(obj)], capture_output=True, text=True, check=True).stdout
    # nm lines are "[value] type name"; B/D/C/G/S are bss, data, common, small data
    types = [ln.split()[-2] for ln in syms.splitlines() if len(ln.split()) >= 2]
    writable = [t for t in types if t in "BbDdCGgSs"]
    assert not writable, f"writable data (not reentrant): {writable}"
