"""The inline sin/cos of src/gagen/codegen/templates/c/gagen_math.h: accuracy, special cases, consistency.

A small C driver that includes the header is compiled with gcc into a shared library and
called through ctypes on numpy arrays.  Reference values come from mpmath (120 bits).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import math
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

mpmath = pytest.importorskip("mpmath")

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")

TEMPLATES = Path(__file__).resolve().parents[1] / "src" / "gagen" / "codegen" / "templates" / "c"
CFLAGS = ["-std=c99", "-pedantic", "-Wall", "-Wextra", "-Werror", "-O2"]
CUTOFF = 2.0**20  # GAGEN_TRIG_MAX: inline below, libm from there on
MAX_ULP = 1.0

DRIVER = r"""
#include <math.h>
#include "gagen_math.h"

void drv_sincos(const double *x, double *s, double *c, long n);
void drv_sin(const double *x, double *out, long n);
void drv_cos(const double *x, double *out, long n);
void drv_sin_cos_same_x(const double *x, double *s, double *c, long n);
void drv_sincos2(const double *x, double *s, double *c, long n);

void drv_sincos(const double *x, double *s, double *c, long n)
{
    long i;
    for (i = 0; i < n; i++) gagen_sincos(x[i], &s[i], &c[i]);
}

void drv_sin(const double *x, double *out, long n)
{
    long i;
    for (i = 0; i < n; i++) out[i] = gagen_sin(x[i]);
}

void drv_cos(const double *x, double *out, long n)
{
    long i;
    for (i = 0; i < n; i++) out[i] = gagen_cos(x[i]);
}

/* two arguments at a time (x[i], x[i + 1]), as generated kernels call it */
void drv_sincos2(const double *x, double *s, double *c, long n)
{
    long i;
    for (i = 0; i + 1 < n; i += 2) gagen_sincos2(x[i], x[i + 1], &s[i], &c[i], &s[i + 1], &c[i + 1]);
    if (i < n) gagen_sincos(x[i], &s[i], &c[i]);
}

/* both on the same argument, as generated kernels call them */
void drv_sin_cos_same_x(const double *x, double *s, double *c, long n)
{
    long i;
    for (i = 0; i < n; i++) {
        double xi = x[i];
        double si = gagen_sin(xi);
        double ci = gagen_cos(xi);
        s[i] = si;
        c[i] = ci;
    }
}
"""


def _compile(tmp_path, name: str, extra: tuple[str, ...] = ()) -> ctypes.CDLL:
    src = tmp_path / f"{name}.c"
    src.write_text(DRIVER)
    obj, lib = tmp_path / f"{name}.o", tmp_path / f"{name}.so"
    # Compile and link separately: linked with -ffast-math, the library would carry
    # crtfastmath.o, which turns on flush-to-zero for the whole test process when loaded.
    for cmd in (["gcc", *CFLAGS, *extra, "-fPIC", "-c", f"-I{TEMPLATES}", str(src), "-o", str(obj)],
                ["gcc", "-shared", str(obj), "-o", str(lib), "-lm"]):
        proc = subprocess.run(cmd, check=False, capture_output=True, text=True)
        assert proc.returncode == 0, f"{' '.join(cmd)}\n{proc.stderr}"
    return ctypes.CDLL(str(lib))


class Trig:
    """numpy-array front end of one compiled driver."""

    def __init__(self, lib: ctypes.CDLL):
        self.lib = lib

    @staticmethod
    def _ptr(a: np.ndarray):
        return a.ctypes.data_as(ctypes.POINTER(ctypes.c_double))

    def _call(self, fn: str, x, nout: int) -> tuple[np.ndarray, ...]:
        x = np.ascontiguousarray(x, dtype=np.float64)
        outs = [np.empty_like(x) for _ in range(nout)]
        getattr(self.lib, fn)(self._ptr(x), *map(self._ptr, outs), ctypes.c_long(x.size))
        return tuple(outs)

    def sincos(self, x):
        return self._call("drv_sincos", x, 2)

    def sin(self, x):
        return self._call("drv_sin", x, 1)[0]

    def cos(self, x):
        return self._call("drv_cos", x, 1)[0]

    def sin_cos_same_x(self, x):
        return self._call("drv_sin_cos_same_x", x, 2)

    def sincos2(self, x):
        return self._call("drv_sincos2", x, 2)


@pytest.fixture(scope="module")
def build_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("fast_trig")


@pytest.fixture(scope="module")
def trig(build_dir) -> Trig:
    return Trig(_compile(build_dir, "drv"))


@pytest.fixture(scope="module")
def libm():
    lib = ctypes.CDLL(ctypes.util.find_library("m") or "libm.so.6")
    for name in ("sin", "cos"):
        getattr(lib, name).restype = ctypes.c_double
        getattr(lib, name).argtypes = [ctypes.c_double]
    return lib


# ---------------------------------------------------------------- test points


def near_multiples_of_pi_2(kmax: int) -> np.ndarray:
    """The doubles nearest k*pi/2 (k = 1..kmax) and their neighbours, both signs."""
    with mpmath.workprec(200):
        half_pi = mpmath.pi / 2
        x = np.array([float(k * half_pi) for k in range(1, kmax + 1)])
    x = np.concatenate([x, np.nextafter(x, np.inf), np.nextafter(x, -np.inf)])
    return np.concatenate([x, -x])


def hardest_reductions(emin: int = -1, emax: int = 19) -> np.ndarray:
    """Doubles closest (relative) to a multiple of pi/2 in each binade [2^e, 2^(e+1)).

    x = m * 2^(e-52) ~ k*pi/2 means m/k ~ beta = (pi/2) * 2^(52-e): m/k is taken from the last
    continued-fraction convergents of beta with m < 2^53, scaled into [2^52, 2^53).  These need
    the second and third rounds of the reduction (cancellation down to 2^-72 relative).
    """
    out = []
    with mpmath.workprec(300):
        for e in range(emin, emax + 1):
            frac = (mpmath.pi / 2) * mpmath.mpf(2) ** (52 - e)
            p0, p1, q0, q1 = 1, int(mpmath.floor(frac)), 0, 1
            frac -= mpmath.floor(frac)
            numerators = [p1]
            while True:
                frac = 1 / frac
                a = int(mpmath.floor(frac))
                frac -= a
                p0, p1, q0, q1 = p1, a * p1 + p0, q1, a * q1 + q0
                if p1 >= 2**53:
                    break
                numerators.append(p1)
            for p in numerators[-4:]:
                j = -(-(2**52) // p)
                out += [math.ldexp(m, e - 52) for m in (j * p, (j + 1) * p) if m < 2**53]
    x = np.array(out)
    return np.concatenate([x, -x])


TINY = np.array([5e-324, 1e-310, 2.2250738585072014e-308, 1e-300, 1e-200, 1e-100, 1e-20,
                 1e-10, 2.0**-27, 2.0**-26, 1e-8, 1e-5, 1e-3])
NEAR_CUTOFF = np.array([np.nextafter(CUTOFF, 0), CUTOFF, np.nextafter(CUTOFF, np.inf),
                        CUTOFF - 1.0, CUTOFF + 1.0, 1047000.5, 1049000.25, 1647099.3])


def accuracy_points() -> np.ndarray:
    rng = np.random.default_rng(20240611)
    parts = [
        rng.uniform(-10.0, 10.0, 2000),
        rng.uniform(-CUTOFF, CUTOFF, 300),
        np.exp(rng.uniform(math.log(1e-6), math.log(CUTOFF), 300)) * rng.choice([-1, 1], 300),
        near_multiples_of_pi_2(1000),
        hardest_reductions(),
        TINY, -TINY,
        NEAR_CUTOFF, -NEAR_CUTOFF,
        np.array([math.pi / 4, -math.pi / 4, np.nextafter(math.pi / 4, 1), 0.78, 0.8, 2.356]),
    ]
    return np.concatenate(parts)


def ulp_errors(x: np.ndarray, got: np.ndarray, func) -> np.ndarray:
    """|got - f(x)| in units in the last place of the exact f(x) (subnormal-aware)."""
    err = np.empty(x.size)
    with mpmath.workprec(120):
        for i, (xi, gi) in enumerate(zip(x.tolist(), got.tolist())):
            exact = func(mpmath.mpf(xi))
            _, e = mpmath.frexp(exact)  # |exact| in [2^(e-1), 2^e)
            ulp = mpmath.ldexp(1, max(e, -1021) - 53)
            err[i] = float(abs(mpmath.mpf(gi) - exact) / ulp)
    return err


def ulp_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Number of doubles between a and b (finite values)."""
    def ordered(v):
        i = v.view(np.int64)
        return np.where(i < 0, np.int64(-(2**63)) - i, i)

    return np.abs(ordered(a) - ordered(b))


def same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    return np.array_equal(a.view(np.uint64), b.view(np.uint64))


# ---------------------------------------------------------------- tests


def test_max_ulp_error_against_mpmath(trig):
    x = accuracy_points()
    s, c = trig.sincos(x)
    es = ulp_errors(x, s, mpmath.sin)
    ec = ulp_errors(x, c, mpmath.cos)
    worst_s, worst_c = int(np.argmax(es)), int(np.argmax(ec))
    assert es[worst_s] <= MAX_ULP, f"sin({x[worst_s]!r}) off by {es[worst_s]:.3f} ulp"
    assert ec[worst_c] <= MAX_ULP, f"cos({x[worst_c]!r}) off by {ec[worst_c]:.3f} ulp"
    # 0.66 ulp here (0.80 on 300k random points): more would be a regression in the kernels
    assert max(es.max(), ec.max()) < 0.85


def test_hardest_reductions_are_exercised():
    x = hardest_reductions()
    with mpmath.workprec(300):
        rel = [abs(mpmath.mpf(v) - mpmath.nint(mpmath.mpf(v) / (mpmath.pi / 2)) * mpmath.pi / 2)
               / abs(v) for v in x.tolist()]
    assert min(rel) < mpmath.mpf(2) ** -70  # needs the third round of the reduction


def test_tiny_arguments_are_exact(trig):
    x = np.concatenate([TINY[TINY < 2.0**-27], -TINY[TINY < 2.0**-27]])
    s, c = trig.sincos(x)
    assert same_bits(s, x)
    assert np.all(c == 1.0)


def test_signed_zero(trig):
    s, c = trig.sincos(np.array([0.0, -0.0]))
    assert s[0] == 0.0 and not np.signbit(s[0])
    assert s[1] == 0.0 and np.signbit(s[1])
    assert np.all(c == 1.0) and not np.any(np.signbit(c))


def test_inf_and_nan_give_nan(trig):
    s, c = trig.sincos(np.array([np.inf, -np.inf, np.nan, -np.nan]))
    assert np.all(np.isnan(s)) and np.all(np.isnan(c))


def test_beyond_cutoff_equals_libm(trig, libm):
    x = np.array([CUTOFF, -CUTOFF, np.nextafter(CUTOFF, np.inf), 1647099.3, 2.0**30 + 0.5,
                  1e22, 6381956970095103.0 * 2.0**797, 1e300, -1e300, np.finfo(float).max])
    s, c = trig.sincos(x)
    ref_s = np.array([libm.sin(v) for v in x.tolist()])
    ref_c = np.array([libm.cos(v) for v in x.tolist()])
    assert same_bits(s, ref_s)
    assert same_bits(c, ref_c)


def test_agrees_with_numpy(trig):
    x = np.random.default_rng(7).uniform(-50.0, 50.0, 100_000)
    s, c = trig.sincos(x)
    assert ulp_distance(s, np.sin(x)).max() <= 1
    assert ulp_distance(c, np.cos(x)).max() <= 1


def test_sin_and_cos_equal_sincos_bit_for_bit(trig):
    rng = np.random.default_rng(3)
    x = np.concatenate([accuracy_points(), rng.uniform(-50.0, 50.0, 20_000),
                        np.array([0.0, -0.0, np.inf, -np.inf, np.nan, 1e300])])
    s, c = trig.sincos(x)
    assert same_bits(trig.sin(x), s)
    assert same_bits(trig.cos(x), c)
    s2, c2 = trig.sin_cos_same_x(x)
    assert same_bits(s2, s) and same_bits(c2, c)


def _cpu_has_fma() -> bool:
    try:
        return " fma " in Path("/proc/cpuinfo").read_text().replace("\n", " ")
    except OSError:
        return False


@pytest.mark.parametrize("flags", [(), ("-std=gnu99", "-O3"), ("-std=gnu99", "-O3", "-mfma")])
def test_two_at_a_time_equals_one_at_a_time_bit_for_bit(build_dir, trig, flags):
    """gagen_sincos2 (one SSE2 vector) gives gagen_sincos's bits on both lanes, also where
    one lane takes the slow path (huge, inf, nan, close to a multiple of pi/2), and also
    with contraction into FMA (GNU C, -mfma: the kernels' FMA clones)."""
    if "-mfma" in flags and not _cpu_has_fma():
        pytest.skip("this CPU has no FMA")
    lib = trig if not flags else Trig(_compile(build_dir, "drv2" + "".join(flags), flags))
    rng = np.random.default_rng(13)
    special = np.array([0.0, -0.0, np.inf, -np.inf, np.nan, 1e300, -3e7, 2.0**20, 5e-324])
    x = np.concatenate([accuracy_points(), rng.uniform(-50.0, 50.0, 20_000), special,
                        rng.permutation(np.concatenate([special, rng.uniform(-4, 4, 9)]))])
    s, c = lib.sincos(x)
    for shifted in (x, np.roll(x, 1)):  # every value in both lanes
        s2, c2 = lib.sincos2(shifted)
        s1, c1 = lib.sincos(shifted)
        assert same_bits(s2, s1) and same_bits(c2, c1)
    if not flags:
        s2, c2 = lib.sincos2(x)
        assert same_bits(s2, s) and same_bits(c2, c)


def test_same_results_at_other_optimisation_levels(build_dir, trig):
    x = np.concatenate([accuracy_points(), np.random.default_rng(5).uniform(-50, 50, 20_000)])
    s, c = trig.sincos(x)
    for flag in ("-O0", "-O3"):
        other = Trig(_compile(build_dir, f"drv{flag}", (flag,)))
        s2, c2 = other.sincos(x)
        assert same_bits(s2, s) and same_bits(c2, c), flag


def test_fast_math_falls_back_to_libm(build_dir, libm):
    fast = Trig(_compile(build_dir, "drv_fast_math", ("-ffast-math",)))
    x = np.random.default_rng(11).uniform(-10, 10, 200)
    s, c = fast.sincos(x)
    assert same_bits(s, np.array([libm.sin(v) for v in x.tolist()]))
    assert same_bits(c, np.array([libm.cos(v) for v in x.tolist()]))


@pytest.mark.skipif(shutil.which("nm") is None, reason="needs nm")
def test_object_has_no_mutable_data(build_dir):
    src = build_dir / "nm_probe.c"
    src.write_text(DRIVER)
    for flag in ("-O0", "-O2"):
        obj = build_dir / f"nm_probe{flag}.o"
        subprocess.run(["gcc", *CFLAGS, flag, "-c", f"-I{TEMPLATES}", str(src), "-o", str(obj)],
                       check=True)
        syms = subprocess.run(["nm", str(obj)], capture_output=True, text=True, check=True).stdout
        kinds = {line.split()[-2] for line in syms.splitlines() if len(line.split()) >= 2}
        assert not kinds & set("BbDdCGgSs"), syms
