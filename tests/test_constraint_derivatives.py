"""The derivatives of the constrained forward dynamics (issue 26, item 4).

References: Pinocchio 4.1's computeConstraintDynamicsDerivatives (after constraintDynamics,
ProximalSettings with mu = 0) to 1e-9 relative on ANYmal C (every subset of its feet as
3-D contacts, both references, 6-D feet, 3-D and 6-D loops in both references, Baumgarte's
kd) and on random branched floating trees (both backends); central differences of
constrained_forward_dynamics along dyn.integrate for what Pinocchio does not have (any
subset of axes, a damped solve) and for the planar four-bar's loop (both backends).
"""

from __future__ import annotations

import ctypes
import itertools
import shutil
import subprocess
import warnings
from pathlib import Path

import numpy as np
import pytest
from test_constraints import (
    ANYMAL_CONSTRAINTS,
    RTOL,
    URDF,
    PinConstraints,
    close,
    closed_fourbar,
    conditioned_state,
    fourbar,
    load_tree,
    mask,
    rows_of,
    standing,
)
from test_floating import random_state

import gagen
from gagen.model.numeric import numeric_model
from gagen.reference.pinocchio import pinocchio_model

needs_cc = pytest.mark.skipif(shutil.which("cc") is None and shutil.which("gcc") is None,
                              reason="no C compiler (cc or gcc)")
NAMES = ("dqdd_dq", "dqdd_dqd", "dqdd_dtau", "dforces_dq", "dforces_dqd", "dforces_dtau")


def pinocchio_derivatives(ref: PinConstraints, names, q, v, tau, kd=0.0):
    """Pinocchio's six derivatives in gagen's coordinates (λ's rows: the named ones)."""
    pin, twin = ref.pin, ref.twin
    models, datas = ref._models(names, 0.0, kd)
    settings = pin.ProximalSettings(1e-14, 0.0, 1)
    pin.constraintDynamics(ref.model, ref.data, twin.q(q), twin.v(v), twin.v(tau), models,
                           datas, settings)
    pin.computeConstraintDynamicsDerivatives(ref.model, ref.data, models, datas, settings)
    d, vi = ref.data, twin.v_index
    return (d.ddq_dq[np.ix_(vi, vi)], d.ddq_dv[np.ix_(vi, vi)], d.ddq_dtau[np.ix_(vi, vi)],
            d.dlambda_dq[:, vi], d.dlambda_dv[:, vi], d.dlambda_dtau[:, vi])


def check_against_pinocchio(dyn, ref, names, q, v, tau, kd=0.0, rtol=RTOL):
    ours = dyn.constrained_forward_dynamics_derivatives(q, v, tau, mask(dyn, *names),
                                                        baumgarte=(0.0, kd))
    theirs = pinocchio_derivatives(ref, names, q, v, tau, kd)
    rows = rows_of(dyn, names)
    inactive = np.setdiff1d(np.arange(dyn.info.constraint_rows), rows)
    for name, x, y in zip(NAMES, ours, theirs):
        if name.startswith("dforces"):
            assert np.all(x[inactive] == 0.0), f"{name}: the inactive rows are zero"
            x = x[rows]
        close(x, y, f"{name} of {dyn.info.name} {', '.join(names)} (kd {kd})", rtol)


def central_differences(dyn, q, v, tau, on, h=1e-6, **options):
    """The six derivatives by central differences of constrained_forward_dynamics, q moved
    along dyn.integrate (the tangent space)."""
    def f(q, v, tau):
        qdd, forces = dyn.constrained_forward_dynamics(q, v, tau, on, **options)
        return np.concatenate([qdd, forces])
    nv = dyn.nv
    cols = {"q": [], "v": [], "tau": []}
    for k in range(nv):
        e = np.zeros(nv)
        e[k] = h
        cols["q"].append((f(dyn.integrate(q, e), v, tau) - f(dyn.integrate(q, -e), v, tau))
                         / (2 * h))
        cols["v"].append((f(q, v + e, tau) - f(q, v - e, tau)) / (2 * h))
        cols["tau"].append((f(q, v, tau + e) - f(q, v, tau - e)) / (2 * h))
    D = {key: np.stack(c, axis=-1) for key, c in cols.items()}
    return tuple(D[key][:nv] for key in ("q", "v", "tau")) + \
        tuple(D[key][nv:] for key in ("q", "v", "tau"))


def check_against_differences(dyn, q, v, tau, on, rtol=1e-6, **options):
    ours = dyn.constrained_forward_dynamics_derivatives(q, v, tau, on, **options)
    for name, x, y in zip(NAMES, ours, central_differences(dyn, q, v, tau, on, **options)):
        close(x, y, f"{name} of {dyn.info.name} {on} {options} (central differences)", rtol)


# ------------------------------------------------------------------------------- ANYmal C

@pytest.fixture(scope="module")
def anymal(cache_dir):
    """test_constraints's build of ANYmal C (the same constraints: one cached build)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", gagen.InertiaWarning)
        return gagen.load(URDF / "anymal_c.urdf", floating_base=True, cache_dir=cache_dir,
                          constraints=ANYMAL_CONSTRAINTS)


@pytest.fixture(scope="module")
def anymal_pin(anymal):
    pytest.importorskip("pinocchio")
    from test_taskspace import urdf_twin

    return PinConstraints(anymal, urdf_twin(anymal, "anymal_c.urdf", True))


def test_anymal_every_subset_of_feet_matches_pinocchio(anymal, anymal_pin):
    """3-D point contacts in LOCAL_WORLD_ALIGNED and LOCAL, every non-empty subset of feet."""
    rng = np.random.default_rng(20)
    q, v, tau = standing(anymal, rng)
    for count in range(1, 5):
        for feet in itertools.combinations(("LF", "RF", "LH", "RH"), count):
            check_against_pinocchio(anymal, anymal_pin, feet, q, v, tau)
            check_against_pinocchio(anymal, anymal_pin, [f"{f}_local" for f in feet], q, v,
                                    tau)


def test_anymal_6d_contacts_and_loops_match_pinocchio(anymal, anymal_pin):
    rng = np.random.default_rng(21)
    for names in (("LF6",), ("RH6",), ("LF6", "RH6"), ("RH6", "LF_local", "RF"),
                  ("loop3",), ("loop3_local", "LH"), ("loop6",), ("loop6_local",)):
        q, v, tau = conditioned_state(anymal, names, rng)
        check_against_pinocchio(anymal, anymal_pin, names, q, v, tau)
    q, v, tau = standing(anymal, rng)
    check_against_pinocchio(anymal, anymal_pin, ("LF", "RF", "LH", "RH"), q, v, tau, kd=7.0)
    check_against_pinocchio(anymal, anymal_pin, ("LF6", "RH_local"), q, v, tau, kd=3.0)


def test_anymal_any_axes_and_damping_match_central_differences(anymal):
    """A foot held on five axes, a loop on two (no Pinocchio counterpart), a damped solve
    of redundant rows."""
    rng = np.random.default_rng(22)
    q, v, tau = standing(anymal, rng)
    check_against_differences(anymal, q, v, tau, mask(anymal, "RF5", "loop2", "LH"))
    check_against_differences(anymal, q, v, tau, mask(anymal, "LF", "LF_local", "RH"),
                              damping=0.1)
    check_against_differences(anymal, q, v, tau, mask(anymal, "LF6", "RH"),
                              baumgarte=(0.0, 4.0))


# --------------------------------------------------------------- random trees, the loop

# the default run's tree is test_constraints's compiled one; the lambdify backend derives
# its inverse dynamics derivatives in SymPy first (10-20 s a tree), with the slow tests (the
# four-bar's test runs that backend by default)
@pytest.mark.parametrize("seed, backend", [
    (2, "compiled"), pytest.param(1, "compiled", marks=pytest.mark.slow),
    pytest.param(1, "lambdify", marks=pytest.mark.slow),
    pytest.param(2, "lambdify", marks=pytest.mark.slow)])
def test_random_floating_trees_match_pinocchio(seed, backend, cache_dir):
    pytest.importorskip("pinocchio")
    from test_taskspace import Twin

    dyn = load_tree(seed, backend, cache_dir)
    ref = PinConstraints(dyn, Twin(dyn, pinocchio_model(numeric_model(dyn.model))))
    rng = np.random.default_rng(seed + 20)
    for names in (("leaf_a", "leaf_b"), ("loop",), ("loop_local",), ("base",),
                  ("base", "loop")):
        q, v, tau = random_state(dyn, rng)
        check_against_pinocchio(dyn, ref, names, q, v, tau)


@pytest.mark.parametrize("backend", ["lambdify", "compiled"])
def test_fourbar_loop_matches_central_differences(backend, cache_dir):
    dyn = fourbar(backend, cache_dir)
    rng = np.random.default_rng(23)
    for crank in (0.4, 2.2):
        q, v, tau = closed_fourbar(crank), rng.normal(size=3), rng.normal(size=3)
        check_against_differences(dyn, q, v, tau, None)
        # the loop's own check: the constrained accelerations' derivatives keep J q̈ + J̇ q̇
        # = 0 to first order in q̇ (∂/∂q̇ of the rows' acceleration is zero)
        dqdd_dqd = dyn.constrained_forward_dynamics_derivatives(q, v, tau)[1]
        J = dyn.constraint_jacobian(q)
        h = 1e-6
        ddrift = np.stack([(dyn.constraint_drift(q, v + h * e) - dyn.constraint_drift(
            q, v - h * e)) / (2 * h) for e in np.eye(3)], axis=-1)
        close(J @ dqdd_dqd + ddrift, np.zeros((2, 3)), "∂(J q̈ + J̇ q̇)/∂q̇ = 0",
              rtol=1e-7, scale=float(np.abs(ddrift).max()))


# ----------------------------------------------------------------- the API's contract

# the lambdify tree derives its inverse dynamics derivatives in SymPy first (14 s): slow
@pytest.mark.parametrize("backend", [pytest.param("lambdify", marks=pytest.mark.slow),
                                     "compiled"])
def test_stacked_inputs_give_stacked_fresh_outputs(backend, cache_dir):
    dyn = load_tree(2, backend, cache_dir)
    rng = np.random.default_rng(24)
    states = [random_state(dyn, rng) for _ in range(3)]
    Q, V, T = (np.stack([s[k] for s in states]) for k in range(3))
    on = mask(dyn, "leaf_a", "loop_local")
    stacked = dyn.constrained_forward_dynamics_derivatives(Q, V, T, on, (0.0, 1.5))
    nv, rows = dyn.nv, dyn.info.constraint_rows
    assert [x.shape for x in stacked] == [(3, nv, nv)] * 3 + [(3, rows, nv)] * 3
    for k in range(3):
        one = dyn.constrained_forward_dynamics_derivatives(Q[k], V[k], T[k], on, (0.0, 1.5))
        for name, s, o in zip(NAMES, stacked, one):
            close(s[k], o, f"stacked {name}", rtol=1e-13)
    again = dyn.constrained_forward_dynamics_derivatives(Q[0], V[0], T[0], on, (0.0, 1.5))
    assert all(not np.shares_memory(a, b) for a in again for b in one)
    assert all(not np.shares_memory(a, b) for a, b in itertools.combinations(again, 2))


@pytest.mark.parametrize("backend", ["lambdify", "compiled"])
def test_bad_arguments_are_refused_with_one_line(backend, cache_dir):
    dyn = fourbar(backend, cache_dir)
    q, v = closed_fourbar(0.5), np.zeros(3)
    call = dyn.constrained_forward_dynamics_derivatives
    with pytest.raises(ValueError, match="active must have 1 booleans"):
        call(q, v, v, [True, False])
    with pytest.raises(ValueError, match="kp must be 0"):
        call(q, v, v, baumgarte=(1.0, 0.0))
    with pytest.raises(ValueError, match="baumgarte gains must be finite and >= 0"):
        call(q, v, v, baumgarte=(0.0, -1.0))
    with pytest.raises(ValueError, match="damping must be finite and >= 0"):
        call(q, v, v, damping=-1.0)
    with pytest.raises(ValueError, match="qd must have shape"):
        call(q, np.zeros(2), v)
    out = call(q, v, v, [False])  # nothing held: the unconstrained derivatives
    free = dyn.forward_dynamics_derivatives(q, v, v)
    for x, y in zip(out, free):
        close(x, y, "no active constraint", rtol=1e-12)
    assert all(not x.any() for x in out[3:])


def test_the_c_of_one_state_matches_the_numpy_path(anymal, monkeypatch):
    """A compiled model's call goes through runtime/_constraint_terms.pyx, a build without
    it (and the lambdify backend) through NumPy: the two agree on random sets of every kind
    of constraint, with kd and damping."""
    from gagen.runtime import constraint_derivatives

    assert constraint_derivatives._terms is not None, "the runtime's C was not built"
    rng = np.random.default_rng(25)
    names = [c.name for c in anymal.constraints]
    checked = 0
    while checked < 12:
        chosen = tuple(n for n in names if rng.random() < 0.25)
        if not chosen:
            continue
        try:
            q, v, tau = conditioned_state(anymal, chosen, rng, limit=1e4)
        except AssertionError:  # dependent rows at every state tried
            continue
        options = {"baumgarte": (0.0, float(rng.choice([0.0, 3.0]))),
                   "damping": float(rng.choice([0.0, 0.1]))}
        on = mask(anymal, *chosen)
        ours = anymal.constrained_forward_dynamics_derivatives(q, v, tau, on, **options)
        with monkeypatch.context() as patch:
            patch.setattr(constraint_derivatives, "_terms", None)
            numpy = anymal.constrained_forward_dynamics_derivatives(q, v, tau, on, **options)
        for name, x, y in zip(NAMES, ours, numpy):
            close(x, y, f"{name} of {chosen} {options}: C against NumPy")
        checked += 1


class _Counting:
    """_constraint_terms with its derivatives() calls counted (its other names as they are)."""

    def __init__(self, module):
        self.module, self.calls = module, []

    def __getattr__(self, name):
        return getattr(self.module, name)

    def derivatives(self, plan, q, *args):
        self.calls.append(np.shape(q))
        return self.module.derivatives(plan, q, *args)


def test_stacked_states_go_through_the_c_and_equal_single_ones(anymal, monkeypatch):
    """Stacked states are one call into the C (a loop over the states there): each state's
    result is the single call's, bit for bit, and the NumPy reference's."""
    from gagen.runtime import constraint_derivatives

    rng = np.random.default_rng(27)
    chosen = ("LF6", "RH_local", "loop3")
    on = mask(anymal, *chosen)
    states = [conditioned_state(anymal, chosen, rng, limit=1e4) for _ in range(4)]
    Q, V, T = (np.stack([s[k] for s in states]) for k in range(3))
    options = {"baumgarte": (0.0, 2.0), "damping": 0.05}
    counting = _Counting(constraint_derivatives._terms)
    with monkeypatch.context() as patch:
        patch.setattr(constraint_derivatives, "_terms", counting)
        stacked = anymal.constrained_forward_dynamics_derivatives(Q, V, T, on, **options)
        assert counting.calls == [Q.shape], "stacked states did not take one call into C"
        singles = [anymal.constrained_forward_dynamics_derivatives(Q[k], V[k], T[k], on,
                                                                   **options)
                   for k in range(len(Q))]
    with monkeypatch.context() as patch:
        patch.setattr(constraint_derivatives, "_terms", None)
        numpy = anymal.constrained_forward_dynamics_derivatives(Q, V, T, on, **options)
    for i, name in enumerate(NAMES):
        assert stacked[i].shape == (len(Q),) + singles[0][i].shape
        for k in range(len(Q)):
            np.testing.assert_array_equal(stacked[i][k], singles[k][i], f"{name} state {k}")
        close(stacked[i], numpy[i], f"stacked {name}: C against NumPy", rtol=1e-11)


def test_the_direct_call_equals_the_checked_one(cache_dir, monkeypatch):
    """Options that need no conversion (None or bools for active, a tuple of numbers for
    baumgarte): the call goes straight into the C; its results are those of the checked
    path (a mask array), for arrays and lists alike, in fresh arrays; a bad state still
    gets the checked path's one-line error."""
    from gagen.runtime import constraint_derivatives

    dyn = fourbar("compiled", cache_dir)
    rng = np.random.default_rng(28)
    q, v, tau = closed_fourbar(0.7), rng.normal(size=3), rng.normal(size=3)
    counting = _Counting(constraint_derivatives._terms)
    with monkeypatch.context() as patch:
        patch.setattr(constraint_derivatives, "_terms", counting)
        fast = dyn.constrained_forward_dynamics_derivatives(q, v, tau)
        assert counting.calls == [q.shape]
    checked = dyn.constrained_forward_dynamics_derivatives(q, v, tau, np.array([True]),
                                                           (0.0, 0.0), 0.0)
    with monkeypatch.context() as patch:
        patch.setattr(constraint_derivatives, "_terms", counting)
        direct = dyn.constrained_forward_dynamics_derivatives(q, v, tau, [True], (0, 1.5), 0.1)
        assert counting.calls == [q.shape] * 2
    kept = dyn.constrained_forward_dynamics_derivatives(q, v, tau, np.array([True]), (0, 1.5),
                                                        0.1)
    for name, x, y in zip(NAMES, direct, kept):
        np.testing.assert_array_equal(x, y, name)
    lists = dyn.constrained_forward_dynamics_derivatives(q.tolist(), list(v), list(tau))
    again = dyn.constrained_forward_dynamics_derivatives(q, v, tau)
    for name, x, y, z, w in zip(NAMES, fast, checked, lists, again):
        np.testing.assert_array_equal(x, y, name)
        np.testing.assert_array_equal(x, z, name)
        assert not np.shares_memory(x, w)
    with pytest.raises(ValueError, match="tau must have shape"):
        dyn.constrained_forward_dynamics_derivatives(q, v, tau[:-1])
    tree = load_tree(2, "compiled", cache_dir)
    q, v, tau = random_state(tree, rng)
    (iq, _), = tree.info.floating_joints()
    q[iq + 3: iq + 7] = 0.0
    with pytest.raises(ValueError, match="cannot be normalised in double precision"):
        tree.constrained_forward_dynamics_derivatives(q, v, tau)


def test_parameters_reach_the_c(cache_dir, monkeypatch):
    """Parameters other than the defaults (the four-bar's link lengths, which move its loop's
    frames, and a mass) give the C the NumPy reference's numbers, not the defaults'."""
    from gagen.runtime import constraint_derivatives

    dyn = fourbar("compiled", cache_dir)
    rng = np.random.default_rng(30)
    q, v, tau = closed_fourbar(0.4), rng.normal(size=3), rng.normal(size=3)
    p = {"b": 1.05, "c": 0.85, "m2": 2.5}
    ours = dyn.constrained_forward_dynamics_derivatives(q, v, tau, p=p)
    with monkeypatch.context() as patch:
        patch.setattr(constraint_derivatives, "_terms", None)
        numpy = dyn.constrained_forward_dynamics_derivatives(q, v, tau, p=p)
    default = dyn.constrained_forward_dynamics_derivatives(q, v, tau)
    for name, x, y in zip(NAMES, ours, numpy):
        close(x, y, f"{name} with parameters: C against NumPy", rtol=1e-11)
    assert any(np.abs(x - z).max() > 1e-6 * np.abs(z).max() for x, z in zip(ours, default))


def test_dependent_rows_are_refused_as_the_dynamics_refuse_them(anymal):
    """The C's Delassus factor tests its pivots as the model's constrained dynamics do: a
    foot held twice is the same one-line error, and with damping a damped answer."""
    q, v, tau = standing(anymal, np.random.default_rng(29))
    twice = mask(anymal, "LF", "LF_local", "RH")
    with pytest.raises(gagen.SingularConstraintError, match="linearly dependent"):
        anymal.constrained_forward_dynamics(q, v, tau, twice)
    with pytest.raises(gagen.SingularConstraintError, match="linearly dependent"):
        anymal.constrained_forward_dynamics_derivatives(q, v, tau, twice)
    damped = anymal.constrained_forward_dynamics_derivatives(q, v, tau, twice, damping=0.1)
    assert all(np.isfinite(x).all() for x in damped)


@pytest.mark.parametrize("backend", ["lambdify", "compiled"])
def test_a_bad_floating_state_is_refused_with_one_line(backend, cache_dir):
    dyn = load_tree(2, backend, cache_dir)
    q, v, tau = random_state(dyn, np.random.default_rng(26))
    (iq, _), = dyn.info.floating_joints()
    zero = q.copy()
    zero[iq + 3: iq + 7] = 0.0
    on = ["leaf_a"]
    with pytest.raises(ValueError, match="cannot be normalised in double precision"):
        dyn.constrained_forward_dynamics_derivatives(zero, v, tau, on)
    nan = v.copy()
    nan[0] = np.nan  # as forward_dynamics: a NaN velocity gives NaN, never a crash
    assert np.isnan(dyn.constrained_forward_dynamics_derivatives(q, nan, tau, on)[1]).any()
    with pytest.raises(ValueError, match="q must have shape"):
        dyn.constrained_forward_dynamics_derivatives(q[:-1], v, tau, on)


# ------------------------------------------------- the model's own C, without Python

def standalone_library(dyn, folder: Path) -> ctypes.CDLL:
    """The model's C files and its derivative module's (not their Python entry points,
    module.c and derivatives_module.c) compiled by the system's C compiler into a shared
    library with no Python include path, as a C user embeds them; loaded by ctypes."""
    dyn.load_derivatives()
    folder.mkdir(exist_ok=True)
    for module in (dyn.module, dyn.derivative_module):
        for path in sorted(Path(module.__file__).parent.iterdir()):
            if path.suffix in (".c", ".h") and path.name not in ("module.c",
                                                                  "derivatives_module.c"):
                shutil.copy(path, folder / path.name)
    assert (folder / "constrained_derivatives.c").is_file()
    cc = shutil.which("cc") or shutil.which("gcc")
    # the new file on its own, as strictly as the other generated C is checked
    subprocess.run([cc, "-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-pedantic", "-c",
                    "constrained_derivatives.c", "-o", "cd.o"], cwd=folder, check=True)
    library = folder / "libmodel.so"
    sources = sorted(p.name for p in folder.glob("*.c"))
    # -O0: ANYmal's kernels compile in seconds (-O2: tens of seconds)
    subprocess.run([cc, "-std=c99", "-O0", "-fPIC", "-shared", "-o", str(library), *sources,
                    "-lm"], cwd=folder, check=True)
    return ctypes.CDLL(str(library))


class ModelC:
    """<model>_constrained_forward_dynamics_derivatives of a standalone library."""

    def __init__(self, dyn, lib: ctypes.CDLL):
        ident = dyn.module.__name__.split(".")[-1].split("_")[1:-1]
        self.f = getattr(lib, f"{'_'.join(ident)}_constrained_forward_dynamics_derivatives")
        self.f.restype = ctypes.c_int
        self.nv, self.rows, self.p = dyn.nv, dyn.info.constraint_rows, dyn.parameter_vector()

    def __call__(self, q, qd, tau, active=None, kd=0.0, damping=0.0, p=None):
        def ptr(x):
            return x.ctypes.data_as(ctypes.POINTER(ctypes.c_double))
        nv, rows = self.nv, self.rows
        outs = [np.full((nv, nv), np.nan) for _ in range(3)] + [
            np.full((rows, nv), np.nan) for _ in range(3)]
        inputs = [np.ascontiguousarray(x, dtype=float) for x in
                  (q, qd, tau, self.p if p is None else p)]
        flags = None if active is None else (ctypes.c_ubyte * len(active))(*active)
        rc = self.f(*map(ptr, inputs), flags, ctypes.c_double(kd), ctypes.c_double(damping),
                    *map(ptr, outs))
        return rc, outs


def check_model_c(dyn, c: ModelC, q, v, tau, on, kd=0.0, damping=0.0):
    rc, ours = c(q, v, tau, on, kd, damping)
    assert rc == 0, f"{on}: the C returned {rc}"
    theirs = dyn.constrained_forward_dynamics_derivatives(q, v, tau, on, baumgarte=(0.0, kd),
                                                          damping=damping)
    for name, x, y in zip(NAMES, ours, theirs):
        close(x, y, f"{name} of {dyn.info.name} {on}: the model's C", rtol=1e-12)


@needs_cc
def test_the_models_own_c_equals_the_runtime_on_anymal(anymal, tmp_path):
    """ANYmal C's constrained_derivatives.c, compiled without Python with the model's and
    its derivative module's C, gives the runtime's six derivatives on its feet (all four
    3-D, a subset, both references), 6-D and 5-D feet, 6-D, 3-D and 2-D loops in both
    references, with kd and damping; and its errors: non-finite inputs, dependent rows, a
    bad argument."""
    c = ModelC(anymal, standalone_library(anymal, tmp_path))
    rng = np.random.default_rng(31)
    sets = [("LF", "RF", "LH", "RH"), ("LF", "RH"), ("RF_local", "LH_local", "RH"),
            ("LF6", "RF"), ("RH6",), ("RF5", "LH"), ("loop6_local", "RF"), ("loop6", "LH_local"),
            ("loop3_local", "loop2"), ("loop3", "LF6")]
    for k, chosen in enumerate(sets):
        q, v, tau = standing(anymal, rng)
        on = mask(anymal, *chosen)
        check_model_c(anymal, c, q, v, tau, on, kd=[0.0, 2.5][k % 2],
                      damping=[0.0, 1e-3][k // 4 % 2])
    q, v, tau = standing(anymal, rng)
    feet = mask(anymal, "LF", "RF", "LH", "RH")
    # every constraint (NULL): feet held twice, dependent rows, which damping solves
    assert c(q, v, tau, None)[0] == 4
    check_model_c(anymal, c, q, v, tau, None, damping=0.1)
    bad = v.copy()
    bad[3] = np.nan
    assert c(q, bad, tau, feet)[0] == 2  # <MODEL>_ERR_NONFINITE
    assert c(q, v, tau, mask(anymal, "LF", "LF_local"))[0] == 4  # _ERR_SINGULAR_CONSTRAINTS
    assert c(q, v, tau, feet, kd=-1.0)[0] == -103  # GAGEN_ERR_BAD_ARG
    zero = q.copy()
    zero[3:7] = 0.0
    assert c(zero, v, tau, feet)[0] == -103


@needs_cc
def test_the_models_own_c_equals_the_runtime_on_a_loop(cache_dir, tmp_path):
    """The four-bar's loop, and a random floating tree's 6-D base contact, 3-D leaves and
    loops (both references), through their models' own C."""
    bar = fourbar("compiled", cache_dir)
    c = ModelC(bar, standalone_library(bar, tmp_path / "bar"))
    rng = np.random.default_rng(32)
    for crank in (0.4, 2.2):
        check_model_c(bar, c, closed_fourbar(crank), rng.normal(size=3), rng.normal(size=3),
                      None, kd=1.5)
    tree = load_tree(2, "compiled", cache_dir)
    c = ModelC(tree, standalone_library(tree, tmp_path / "tree"))
    for names in (("base",), ("leaf_a", "leaf_b"), ("loop",), ("loop_local",),
                  ("base", "loop")):
        q, v, tau = random_state(tree, rng)
        check_model_c(tree, c, q, v, tau, mask(tree, *names))
