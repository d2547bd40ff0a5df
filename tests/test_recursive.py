"""derive_recursive (RNEA + CRBA) against the Gibbs-Appell derivation, and its structure."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp
from conftest import SHARED_URDF
from random_trees import random_model

from gagen.building import builder
from gagen.building.cache import import_extension
from gagen.model.resolve import resolve_model
from gagen.runtime.compiled import CompiledDynamics
from gagen.runtime.lambdify import LambdifyDynamics
from gagen.symbolic.gibbs_appell import derive
from gagen.symbolic.recursive import derive_recursive

RTOL = 1e-12


def _outputs(dyn, q, qd, x, p) -> dict[str, np.ndarray]:
    return {
        "mass_matrix": dyn.mass_matrix(q, p),
        "forcing": dyn.forcing(q, qd, x, p),
        "forward_dynamics": dyn.forward_dynamics(q, qd, x, p),
        "inverse_dynamics": dyn.inverse_dynamics(q, qd, x, p),
        "gravity": dyn.gravity(q, p),
        "energy": np.array(dyn.energy(q, qd, p)),
    }


def assert_agree(got, want, rng, states=5):
    """The two backends agree at random states and random parameter values."""
    n = want.n
    defaults = want.parameter_vector()
    for _ in range(states):
        q, qd, x = rng.uniform(-2, 2, size=(3, n))
        p = defaults * rng.uniform(0.5, 1.5, size=defaults.shape)
        a, b = _outputs(got, q, qd, x, p), _outputs(want, q, qd, x, p)
        for name, expected in b.items():
            scale = max(1.0, np.abs(expected).max())
            np.testing.assert_allclose(a[name], expected, rtol=0, atol=RTOL * scale, err_msg=name)


def _model(name: str):
    if name == "random":
        return random_model(np.random.default_rng(3), 5, symbolic=True)
    if name == "ur5":
        return resolve_model(SHARED_URDF / "ur5_robot.urdf")
    return resolve_model(name)


@pytest.mark.parametrize("name", ["rrr", "chain:5", "random", "ur5"])
def test_recursive_equals_gibbs_appell(name):
    model = _model(name)
    assert_agree(LambdifyDynamics(derive_recursive(model)), LambdifyDynamics(derive(model)),
                 np.random.default_rng(5))


@pytest.mark.parametrize("seed", [11, 17, 23])
def test_recursive_equals_gibbs_appell_on_random_trees(seed):
    """Trees mixing prismatic, revolute, continuous and fixed joints with odd axes."""
    model = random_model(np.random.default_rng(seed), 4, symbolic=seed % 2 == 1)
    assert_agree(LambdifyDynamics(derive_recursive(model)), LambdifyDynamics(derive(model)),
                 np.random.default_rng(seed), states=3)


def test_same_symbols_and_fields():
    model = resolve_model("rrr")
    new, old = derive_recursive(model), derive(model)
    assert new.coords == old.coords and new.parameters == old.parameters
    assert new.mass_matrix.shape == old.mass_matrix.shape == (3, 3)
    assert new.mass_matrix == new.mass_matrix.T
    allowed = set(old.coords.q) | set(old.coords.qd) | set(old.coords.qdd) | set(old.coords.tau)
    allowed |= set(old.parameters) | {s for s, _ in new.intermediates}
    for exprs in new.outputs().values():
        for e in exprs:
            assert sp.sympify(e).free_symbols <= allowed


def test_every_intermediate_is_small_and_defined_before_use():
    """O(1) per definition, whatever the depth: the chain:16's largest matches chain:4's."""
    sizes = {}
    for n in (4, 16):
        eqs = derive_recursive(resolve_model(f"chain:{n}"))
        defined: set[sp.Symbol] = set()
        names = {s for s, _ in eqs.intermediates}
        for symbol, expr in eqs.intermediates:
            assert expr.free_symbols & names <= defined, symbol
            defined.add(symbol)
        sizes[n] = max(sp.count_ops(e) for _, e in eqs.intermediates)
        assert sizes[n] <= 30
    assert sizes[16] <= sizes[4]


def test_inverse_dynamics_consistent_with_mass_matrix_and_bias():
    """tau = M qdd + b - Qg, the identity the outputs must share (recursive alone)."""
    dyn = LambdifyDynamics(derive_recursive(_model("random")))
    rng = np.random.default_rng(8)
    q, qd, qdd = rng.uniform(-2, 2, size=(3, dyn.n))
    tau = dyn.inverse_dynamics(q, qd, qdd)
    zero = np.zeros(dyn.n)
    expected = dyn.mass_matrix(q) @ qdd - dyn.forcing(q, qd, zero)
    np.testing.assert_allclose(tau, expected, rtol=0, atol=1e-11 * np.abs(tau).max())
    np.testing.assert_allclose(dyn.forward_dynamics(q, qd, tau), qdd, rtol=1e-9, atol=1e-9)


@pytest.mark.slow
def test_compiled_chain5_from_recursive_equations(tmp_path):
    model = resolve_model("chain:5")
    path, report = builder.build(model, out=tmp_path / "recursive", derivation="recursive")
    compiled = CompiledDynamics(import_extension(path, report.module_name), model)
    assert_agree(compiled, LambdifyDynamics(derive(model)), np.random.default_rng(2))


def test_auto_takes_the_recursive_form_from_six_coordinates():
    from gagen.symbolic.derivation import RECURSIVE_FROM_DOF, derivation_for

    assert derivation_for(resolve_model("rrr")) == "gibbs-appell"
    assert derivation_for(resolve_model(f"chain:{RECURSIVE_FROM_DOF - 1}")) == "gibbs-appell"
    assert derivation_for(resolve_model(f"chain:{RECURSIVE_FROM_DOF}")) == "recursive"
    assert RECURSIVE_FROM_DOF == 6  # benchmarks/derivation_rule.py
    assert derivation_for(resolve_model("rrr"), "recursive") == "recursive"
    with pytest.raises(ValueError, match="unknown derivation"):
        derivation_for(resolve_model("rrr"), "kane")


def test_the_derivation_is_part_of_the_source_key():
    model = resolve_model("chain:3")
    keys = {builder.source_key(model, d) for d in ("gibbs-appell", "recursive")}
    assert len(keys) == 2 and builder.source_key(model) == builder.source_key(model, "gibbs-appell")
