"""The compiled backend: agreement with lambdify, the wrapper's input checks, the cache."""

from __future__ import annotations

import numpy as np
import pytest
from random_trees import random_model

import gagen
from gagen.errors import NonFiniteStateError
from gagen.runtime.dynamics import SingularMassMatrixError

METHODS = ("mass_matrix", "forcing", "forward_dynamics", "inverse_dynamics", "energy")


@pytest.fixture(scope="module")
def rrr(cache_dir):
    return gagen.load("rrr", cache_dir=cache_dir), gagen.load("rrr", backend="lambdify")


def _call(dyn, method, q, qd, x, p=None):
    if method == "mass_matrix":
        return dyn.mass_matrix(q, p)
    if method == "energy":
        return np.array(dyn.energy(q, qd, p))
    return getattr(dyn, method)(q, qd, x, p)


def assert_backends_agree(compiled, reference, rng, states=10, rtol=1e-12, p=None):
    n = compiled.n
    for _ in range(states):
        q, qd, x = rng.uniform(-2, 2, size=(3, n))
        for method in METHODS:
            got = _call(compiled, method, q, qd, x, p)
            want = _call(reference, method, q, qd, x, p)
            scale = max(1.0, np.abs(want).max())
            np.testing.assert_allclose(got, want, rtol=0, atol=rtol * scale, err_msg=method)


def test_rrr_backends_agree(rrr):
    assert_backends_agree(*rrr, np.random.default_rng(0))


def test_rrr_backends_agree_with_parameter_overrides(rrr):
    compiled, reference = rrr
    rng = np.random.default_rng(1)
    assert_backends_agree(compiled, reference, rng, p={"m3": 5.0, "L2": 0.7})
    full = compiled.parameter_vector({"g": 3.7})
    assert_backends_agree(compiled, reference, rng, p=full)


@pytest.mark.parametrize("seed", [3, pytest.param(11, marks=pytest.mark.slow),
                                  pytest.param(17, marks=pytest.mark.slow)])
def test_random_trees_backends_agree(seed, cache_dir):
    rng = np.random.default_rng(seed)
    model = random_model(rng, 5, symbolic=seed % 2 == 1)
    compiled = gagen.load(model, cache_dir=cache_dir)
    reference = gagen.load(model, backend="lambdify")
    assert_backends_agree(compiled, reference, rng, states=5)


@pytest.mark.slow
def test_chain7_backends_agree(cache_dir):
    compiled = gagen.load("chain:7", cache_dir=cache_dir)
    reference = gagen.load("chain:7", backend="lambdify")
    assert_backends_agree(compiled, reference, np.random.default_rng(7), states=5)


def test_gravity_is_inverse_dynamics_at_rest(rrr):
    rng = np.random.default_rng(9)
    zero = np.zeros(3)
    for dyn in rrr:
        for _ in range(5):
            q = rng.uniform(-3, 3, 3)
            np.testing.assert_allclose(dyn.gravity(q), dyn.inverse_dynamics(q, zero, zero),
                                       rtol=1e-13, atol=1e-12)
    Q = rng.normal(size=(4, 3))
    np.testing.assert_allclose(rrr[0].gravity(Q, {"g": 1.62}), rrr[1].gravity(Q, {"g": 1.62}),
                               rtol=1e-12)


def test_stacked_inputs_match_single_calls(rrr):
    dyn, _ = rrr
    rng = np.random.default_rng(4)
    Q, QD, X = rng.normal(size=(3, 6, 3))
    for method in METHODS:
        stacked = _call(dyn, method, Q, QD, X)
        if method == "energy":
            stacked = np.stack(stacked, axis=-1)
        for k in range(6):
            np.testing.assert_array_equal(stacked[k], _call(dyn, method, Q[k], QD[k], X[k]))
    # a single state broadcasts against stacked ones
    np.testing.assert_array_equal(dyn.forward_dynamics(Q[0], QD, X)[2],
                                  dyn.forward_dynamics(Q[0], QD[2], X[2]))


def test_every_call_returns_fresh_memory(rrr):
    dyn, _ = rrr
    q = np.array([0.1, 0.2, 0.3])
    a = dyn.forward_dynamics(q, q, q)
    b = dyn.forward_dynamics(q, q, q)
    assert not np.shares_memory(a, b)
    a[:] = 123.0
    np.testing.assert_array_equal(b, dyn.forward_dynamics(q, q, q))
    M1, M2 = dyn.mass_matrix(q), dyn.mass_matrix(q)
    assert not np.shares_memory(M1, M2)


def test_large_stacked_outputs_are_streamed_and_exact(cache_dir):
    """A stacked call whose output is large (gagen.runtime._native.STREAM_STATE doubles per
    state, STREAM_BYTES in all) goes through a per-state buffer and streaming stores: the
    same numbers as one call per state, in fresh memory, the first and last rows included."""
    from gagen.runtime import _native

    dyn = gagen.load("chain:5", cache_dir=cache_dir)
    per_state = dyn.n * len(dyn.regressor_parameters())
    assert per_state >= _native.STREAM_STATE
    rows = _native.STREAM_BYTES // (8 * per_state) + 3  # an odd count: unaligned rows too
    rng = np.random.default_rng(8)
    Q, QD, QDD = rng.normal(size=(3, rows, dyn.n))
    Y = dyn.regressor(Q, QD, QDD)
    assert Y.nbytes >= _native.STREAM_BYTES
    for k in (0, 1, rows // 2, rows - 1):
        np.testing.assert_array_equal(Y[k], dyn.regressor(Q[k], QD[k], QDD[k]))
    again = dyn.regressor(Q, QD, QDD)
    assert not np.shares_memory(Y, again)
    np.testing.assert_array_equal(Y, again)


def test_lists_ints_and_non_contiguous_inputs(rrr):
    dyn, _ = rrr
    q = np.array([0.1, -0.4, 0.9])
    want = dyn.forward_dynamics(q, 2 * q, 3 * q)
    np.testing.assert_array_equal(dyn.forward_dynamics(list(q), tuple(2 * q), 3 * q), want)
    wide = np.zeros((3, 6))
    wide[:, ::2] = [q, 2 * q, 3 * q]
    np.testing.assert_array_equal(dyn.forward_dynamics(wide[0, ::2], wide[1, ::2], wide[2, ::2]),
                                  want)
    np.testing.assert_array_equal(dyn.mass_matrix(np.array([0, 1, 2])),
                                  dyn.mass_matrix(np.array([0.0, 1.0, 2.0])))
    np.testing.assert_array_equal(dyn.forward_dynamics(q.astype(np.float32), 2 * q, 3 * q),
                                  dyn.forward_dynamics(q.astype(np.float32).astype(float),
                                                       2 * q, 3 * q))


@pytest.mark.parametrize("bad, error", [
    (np.zeros(2), ValueError),
    (np.zeros(4), ValueError),
    (np.zeros((2, 2)), ValueError),
    (np.zeros((2, 3, 3)), ValueError),
    (np.zeros(()), ValueError),
    ("abc", TypeError),
    (None, TypeError),
    (np.array(["a", "b", "c"]), TypeError),
    (np.zeros(3, dtype=complex), TypeError),
    ([1, "x", 3], TypeError),
])
def test_bad_inputs_raise(rrr, bad, error):
    dyn, _ = rrr
    ok = np.zeros(3)
    with pytest.raises(error):
        dyn.forward_dynamics(bad, ok, ok)
    with pytest.raises(error):
        dyn.inverse_dynamics(ok, ok, bad)
    with pytest.raises(error):
        dyn.mass_matrix(bad)


def test_mismatched_stacks_and_bad_parameters_raise(rrr):
    dyn, _ = rrr
    with pytest.raises(ValueError, match="rows"):
        dyn.forward_dynamics(np.zeros((4, 3)), np.zeros((5, 3)), np.zeros(3))
    with pytest.raises(ValueError):
        dyn.mass_matrix(np.zeros(3), p=np.ones(3))
    with pytest.raises(KeyError, match="unknown parameter"):
        dyn.mass_matrix(np.zeros(3), p={"mass_of_the_moon": 1.0})


def test_singular_mass_matrix_raises(rrr):
    dyn, lam = rrr
    # massless, inertia-free arm: M = 0
    zero = {k: 0.0 for k in dyn.parameters if k[0] in "mI"}
    for backend in (dyn, lam):
        with pytest.raises(SingularMassMatrixError, match="not positive definite"):
            backend.forward_dynamics(np.zeros(3), np.zeros(3), np.zeros(3), p=zero)
    with pytest.raises(NonFiniteStateError, match="row 1"):
        dyn.forward_dynamics(np.array([[0.0, 0, 0], [0, np.nan, 0]]), np.zeros(3), np.zeros(3))


def test_missing_compiler_names_lambdify(monkeypatch, tmp_path):
    from gagen.building import builder as build

    monkeypatch.setenv("CC", "no-such-compiler-gagen")
    with pytest.raises(build.CompilerNotFoundError, match="lambdify"):
        gagen.load("chain:2", cache_dir=tmp_path)
    assert not any(tmp_path.iterdir()), "a failed build must leave nothing behind"
