"""Simulations end, and say why (issue 11, classes 5 to 7): Ctrl-C stops the compiled
integrators, a default step budget stops a stiff system, impossible step counts and
non-finite tolerances are refused up front, and NaN gets its own message."""

from __future__ import annotations

import time

import numpy as np
import pytest
from interrupting import seconds_to_stop

import gagen
from gagen import NonFiniteStateError, SingularMassMatrixError
from gagen.sim.simulate import DEFAULT_MAX_STEPS

STIFF = gagen.PD(kp=1e10, kd=1.0)


@pytest.fixture(scope="module")
def dyn():
    return gagen.load("rrr")


@pytest.mark.parametrize("run", [
    "method='dopri5', controller=gagen.PD(kp=1e10, kd=1.0), max_steps=2**60",
    "method='rk4', h=1e-9, max_steps=2**60",
])
def test_ctrl_c_stops_a_compiled_integration_within_a_second(cache_dir, run):
    assert seconds_to_stop(f"gagen.simulate(dyn, (0, 1e6), [0.1, 0.2, 0.3], {run})") < 5.0


def test_a_stiff_system_stops_at_the_default_step_budget(dyn):
    with pytest.raises(RuntimeError, match="step budget") as info:
        gagen.simulate(dyn, (0, 100), [0.1, 0.2, 0.3], method="dopri5", controller=STIFF)
    assert f"{DEFAULT_MAX_STEPS:,}" in str(info.value)
    with pytest.raises(RuntimeError, match="step budget"):
        gagen.simulate(dyn, (0, 100), [0.1, 0.2, 0.3], method="dopri5", controller=STIFF,
                       max_steps=1000)


def test_a_budget_can_be_raised_and_is_checked(dyn):
    result = gagen.simulate(dyn, (0, 1), [0.1, 0.2, 0.3], method="rk4", h=1e-6,
                            max_steps=2_000_000, t_eval=[0, 1])
    assert result.stats["steps"] == 1_000_000
    for bad in (0, -5, 2.5, "many", True):
        with pytest.raises(ValueError, match="max_steps"):
            gagen.simulate(dyn, (0, 1), [0, 0, 0], method="dopri5", max_steps=bad)


def test_rk4_refuses_step_counts_past_the_budget_at_once(dyn):
    start = time.perf_counter()
    with pytest.raises(ValueError, match="1e\\+12 steps"):
        gagen.simulate(dyn, (0, 1), [0, 0, 0], method="rk4", h=1e-12)
    assert time.perf_counter() - start < 0.5


@pytest.mark.parametrize("method", ["RK45", "dopri5"])
@pytest.mark.parametrize("option", [{"rtol": np.inf}, {"rtol": np.nan}, {"atol": np.inf},
                                    {"atol": np.nan}, {"atol": [1e-8] * 5 + [np.inf]},
                                    {"atol": -1.0}, {"rtol": 0.0}])
def test_non_finite_tolerances_are_refused(dyn, method, option):
    with pytest.raises(ValueError, match="rtol|atol"):
        gagen.simulate(dyn, (0, 1), [0.1, 0, 0], method=method, **option)


@pytest.mark.parametrize("backend", ["compiled", "lambdify"])
def test_nan_in_the_state_is_named_not_called_singular(backend):
    dyn = gagen.load("rrr", backend=backend)
    with pytest.raises(NonFiniteStateError, match="NaN or inf"):
        dyn.forward_dynamics([0.1, np.nan, 0.3], [0, 0, 0], [0, 0, 0])
    with pytest.raises(NonFiniteStateError):
        dyn.forward_dynamics([[0.1, 0.2, 0.3], [0.1, 0.2, np.inf]], np.zeros((2, 3)),
                             np.zeros((2, 3)))
    # a true singular M is still a SingularMassMatrixError, not a NaN complaint
    with pytest.raises(SingularMassMatrixError) as info:
        massless = {name: 0.0 for name in dyn.parameters if name[0] in "mI"}
        dyn.forward_dynamics([0.1, 0.2, 0.3], [0, 0, 0], [0, 0, 0], p=massless)
    assert not isinstance(info.value, NonFiniteStateError)


def test_a_controller_returning_nan_is_named(dyn):
    with pytest.raises(NonFiniteStateError, match="controller nan_torques"):
        def nan_torques(t, q, qd):
            return np.full(3, np.nan)
        gagen.simulate(dyn, (0, 1), [0.1, 0, 0], controller=nan_torques)


def test_a_diverging_compiled_simulation_says_nan_not_singular(dyn):
    with pytest.raises(NonFiniteStateError, match="NaN or inf"):
        gagen.simulate(dyn, (0, 10), [0.1, 0, 0], method="rk4", h=1e-2,
                       controller=gagen.PD(kp=1e300, kd=1e300))


@pytest.mark.parametrize("method", ["RK45", "Radau", "dopri5", "rk4"])
def test_a_zero_length_span_returns_the_initial_state(dyn, method):
    result = gagen.simulate(dyn, (0.5, 0.5), [0.1, 0.2, 0.3], method=method)
    assert result.q.shape[1] == 3 and len(result.t) == len(result.q) >= 1
    np.testing.assert_array_equal(result.q, np.tile([0.1, 0.2, 0.3], (len(result.t), 1)))
    assert (result.t == 0.5).all()
