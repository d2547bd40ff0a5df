"""Forward-mode differentiation through the named intermediates (symbolic/differentiate.py)
against central finite differences of the lambdify backend, and its program's shape."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

from gagen.model.resolve import resolve_model
from gagen.runtime.lambdify import LambdifyDynamics
from gagen.symbolic.derivation import derive_equations
from gagen.symbolic.differentiate import differentiate, needed_definitions, recorder_after


def _jacobian_function(eqs, rec, jacobian):
    c = eqs.coords
    flat = [*c.q, *c.qd, *c.qdd, *eqs.parameters]
    outs = [e for row in jacobian for e in row]
    rename = {s: sp.Symbol(f"a{k}") for k, s in enumerate(flat)}
    defs = needed_definitions(rec.definitions, outs)
    rename.update({s: sp.Symbol(f"t{k}") for k, (s, _) in enumerate(defs)})
    renamed = [(rename[s], e.xreplace(rename)) for s, e in defs]
    return sp.lambdify([rename[s] for s in flat], [sp.sympify(e).xreplace(rename) for e in outs],
                       cse=lambda ex: (renamed, ex))


@pytest.mark.parametrize("name, derivation", [("rrr", "gibbs-appell"), ("chain:5", "recursive")])
def test_inverse_dynamics_jacobian_matches_central_differences(name, derivation):
    model = resolve_model(name)
    eqs = derive_equations(model, derivation)
    rec = recorder_after(eqs.intermediates)
    c = eqs.coords
    jac = differentiate(eqs.intermediates, list(eqs.inverse_dynamics), c.q + c.qd, rec)
    f = _jacobian_function(eqs, rec, jac)
    dyn = LambdifyDynamics(eqs)
    n = eqs.n
    rng = np.random.default_rng(3)
    for _ in range(3):
        q, qd, qdd = rng.normal(size=(3, n))
        J = np.array(f(*q, *qd, *qdd, *model.parameter_vector()), float).reshape(n, 2 * n)
        h = 1e-6
        Jf = np.empty((n, 2 * n))
        for j in range(n):
            e = np.zeros(n)
            e[j] = h
            Jf[:, j] = (dyn.inverse_dynamics(q + e, qd, qdd)
                        - dyn.inverse_dynamics(q - e, qd, qdd)) / (2 * h)
            Jf[:, n + j] = (dyn.inverse_dynamics(q, qd + e, qdd)
                            - dyn.inverse_dynamics(q, qd - e, qdd)) / (2 * h)
        np.testing.assert_allclose(J, Jf, rtol=1e-6, atol=1e-7 * np.abs(Jf).max())


def test_structural_zeros_are_exact_and_definitions_continue_the_program():
    eqs = derive_equations(resolve_model("chain:4"), "recursive")
    given = len(eqs.intermediates)
    rec = recorder_after(eqs.intermediates)
    c = eqs.coords
    # the velocity terms of a chain's last joint do not depend on... nothing is free: but
    # the gravity torques do not depend on the rates at all
    jac = differentiate(eqs.intermediates, list(eqs.gravity_forces), c.qd, rec)
    assert all(e == 0 for row in jac for e in row)
    jac = differentiate(eqs.intermediates, list(eqs.gravity_forces), c.q, rec)
    # joint 1 (about the vertical axis) never changes the potential energy
    assert all(row[0] == 0 for row in jac)
    assert rec.definitions[:given] == eqs.intermediates
    names = [s for s, _ in rec.definitions]
    assert len(names) == len(set(names))


def test_differentiation_is_deterministic_across_hash_seeds(tmp_path):
    import subprocess
    import sys

    code = ("from gagen.model.resolve import resolve_model\n"
            "from gagen.symbolic.derivation import derive_equations\n"
            "from gagen.symbolic.differentiate import differentiate, recorder_after\n"
            "eqs = derive_equations(resolve_model('chain:3'), 'recursive')\n"
            "rec = recorder_after(eqs.intermediates)\n"
            "J = differentiate(eqs.intermediates, list(eqs.inverse_dynamics), eqs.coords.q, rec)\n"
            "print([(str(s), str(e)) for s, e in rec.definitions], J)\n")
    outs = {subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                           env={"PYTHONHASHSEED": seed, "PATH": ""}).stdout for seed in ("1", "2")}
    assert len(outs) == 1
