"""Hypothesis-driven fuzz of the compiled wrapper: any input gives a result or a clean error."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

import gagen
from gagen.runtime.dynamics import SingularMassMatrixError

ALLOWED = (ValueError, TypeError, SingularMassMatrixError, KeyError)


@pytest.fixture(scope="module")
def dyn(cache_dir):
    return gagen.load("rrr", cache_dir=cache_dir)


dtypes = st.sampled_from([np.float64, np.float32, np.int64, np.int8, np.uint16, np.bool_,
                          np.complex128, np.object_, np.str_])
shapes = st.one_of(st.just((3,)), hnp.array_shapes(min_dims=0, max_dims=3, max_side=5))
values = st.floats(allow_nan=True, allow_infinity=True, width=64)


@st.composite
def arrays(draw):
    dtype = draw(dtypes)
    shape = draw(shapes)
    if dtype in (np.object_, np.str_):
        return np.full(shape, "x", dtype=dtype)
    if np.issubdtype(dtype, np.floating):
        elements = st.floats(allow_nan=True, allow_infinity=True, width=32
                             if dtype == np.float32 else 64)
    elif dtype == np.complex128:
        elements = st.complex_numbers(allow_nan=True, allow_infinity=True)
    elif dtype == np.bool_:
        elements = st.booleans()
    else:
        info = np.iinfo(dtype)
        elements = st.integers(int(info.min), int(info.max))
    arr = draw(hnp.arrays(dtype, shape, elements=elements))
    if draw(st.booleans()) and arr.ndim >= 1 and arr.shape[-1] > 1:
        arr = arr[..., ::2]  # non-contiguous view
    return arr


inputs = st.one_of(arrays(), st.lists(values, max_size=5), st.none(), st.text(max_size=3),
                   st.floats())


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(inputs, inputs, inputs)
def test_wrapper_survives_anything(dyn, a, b, c):
    for call in (lambda: dyn.forward_dynamics(a, b, c), lambda: dyn.inverse_dynamics(a, b, c),
                 lambda: dyn.forcing(a, b, c), lambda: dyn.mass_matrix(a),
                 lambda: dyn.energy(a, b)):
        try:
            out = call()
        except ALLOWED:
            continue
        assert out is not None


@settings(max_examples=200, deadline=None)
@given(hnp.arrays(np.float64, (3,), elements=st.floats(-1e300, 1e300)),
       hnp.arrays(np.float64, (3,), elements=st.floats(-1e300, 1e300)))
def test_huge_values_give_numbers_or_a_clean_error(dyn, q, qd):
    try:
        qdd = dyn.forward_dynamics(q, qd, np.zeros(3))
    except SingularMassMatrixError:
        return
    assert qdd.shape == (3,)


@pytest.fixture(scope="module")
def lam():
    return gagen.load("rrr", backend="lambdify")


@settings(max_examples=100, deadline=None)
@given(st.one_of(st.none(), st.dictionaries(st.sampled_from(["g", "m1", "L2", "nope"]),
                                            st.floats(allow_nan=True)),
                 hnp.arrays(np.float64, st.integers(0, 20),
                            elements=st.one_of(st.floats(-1e3, 1e3),
                                               st.sampled_from([np.nan, np.inf, -np.inf])))))
def test_parameter_argument_fuzz(dyn, lam, p):
    """Exactly one outcome per input: the right numbers, or the documented error."""
    q = np.array([0.3, -0.2, 0.5])
    values = list(p.values()) if isinstance(p, dict) else p
    wrong_size = isinstance(p, np.ndarray) and p.shape != (len(dyn.parameters),)
    if isinstance(p, dict) and "nope" in p:
        expected = KeyError
    elif wrong_size or (p is not None and not np.all(np.isfinite(values))):
        expected = ValueError
    else:
        expected = None
    if expected is not None:
        with pytest.raises(expected):
            dyn.mass_matrix(q, p)
        return
    M = dyn.mass_matrix(q, p)
    np.testing.assert_allclose(M, lam.mass_matrix(q, p), rtol=1e-11,
                               atol=1e-11 * max(1.0, np.abs(M).max()))
    if p is None or (isinstance(p, dict) and not p):
        np.testing.assert_array_equal(M, dyn.mass_matrix(q))
