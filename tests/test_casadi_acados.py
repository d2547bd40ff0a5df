"""The exported CasADi library inside acados (issue 28): acados' integrators and an optimal
control problem on `python -m gagen export casadi`'s library, in a fresh process that never
imports gagen (docs/acados_reach.py), against gagen's own calls and IPOPT.

acados is not on PyPI under its own name: CI installs the build that the package
`comma-deps-acados` ships (its libraries, headers, template renderer and `acados_template`)
with `pip install --no-deps --target DIR` and names DIR in GAGEN_ACADOS (.ci/run). Without
it these tests skip, saying so."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ca = pytest.importorskip("casadi", reason="gagen.casadi needs casadi (pip install gagen[casadi])")

import gagen
import gagen.casadi as gc

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / "docs" / "acados_reach.py"
H = 0.01  # the integrators' step


def acados_root() -> Path:
    """The folder holding acados' Python package (`acados/`), from GAGEN_ACADOS."""
    folder = os.environ.get("GAGEN_ACADOS")
    if not folder or not (Path(folder) / "acados" / "install" / "lib").is_dir():
        pytest.skip("acados is not installed: GAGEN_ACADOS names a folder with "
                    "comma-deps-acados installed (pip install --no-deps --target DIR "
                    "comma-deps-acados; .ci/run does)")
    return Path(folder) / "acados"


def run_script(acados: Path, library: Path, prefix: str, problem: dict, folder: Path) -> dict:
    """docs/acados_reach.py in a fresh process, as a user runs it: acados' and the exported
    library's folders on LD_LIBRARY_PATH, gagen nowhere on the path."""
    (folder / "problem.json").write_text(json.dumps(problem))
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "LD_LIBRARY_PATH")}
    env.update(ACADOS_SOURCE_DIR=str(acados / "install"),
               ACADOS_PYTHON_INTERFACE_PATH=str(acados / "acados_template"),
               LD_LIBRARY_PATH=f"{acados / 'install' / 'lib'}:{library.parent}",
               PYTHONPATH=str(acados))
    run = subprocess.run([sys.executable, str(SCRIPT), str(library), prefix, "--json",
                          str(folder / "problem.json")], capture_output=True, text=True,
                         env=env, cwd=folder, timeout=600, check=False)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    return json.loads(run.stdout.strip().splitlines()[-1])


def rate(dyn, x, u):
    n = dyn.nv
    return np.concatenate([x[n:], dyn.forward_dynamics(x[:n], x[n:], u)])


def rate_jacobian(dyn, x, u) -> np.ndarray:
    """d(qd, qdd)/d(x, u) from gagen's forward_dynamics_derivatives."""
    n = dyn.nv
    dq, dqd, minv = dyn.forward_dynamics_derivatives(x[:n], x[n:], u)
    top = np.hstack([np.zeros((n, n)), np.eye(n), np.zeros((n, n))])
    return np.vstack([top, np.hstack([dq, dqd, minv])])


def rk4_with_sensitivities(dyn, x, u, h):
    """One RK4 step and its exact Jacobian by (x, u), by the chain rule through the stages
    (an independent assembly of what acados' ERK computes)."""
    n2 = len(x)
    seed = np.hstack([np.eye(n2), np.zeros((n2, len(u)))])
    du = np.hstack([np.zeros((len(u), n2)), np.eye(len(u))])
    stages, tangents = [], []
    for c, base in ((0.0, None), (0.5, 0), (0.5, 1), (1.0, 2)):
        xs = x if base is None else x + c * h * stages[base]
        dxs = seed if base is None else seed + c * h * tangents[base]
        stages.append(rate(dyn, xs, u))
        tangents.append(rate_jacobian(dyn, xs, u) @ np.vstack([dxs, du]))
    weights = (1.0, 2.0, 2.0, 1.0)
    x1 = x + h / 6 * sum(w * k for w, k in zip(weights, stages))
    S = seed + h / 6 * sum(w * t for w, t in zip(weights, tangents))
    return x1, S


def assert_step(step: dict, x1, S, nv: int) -> None:
    """acados' step (its status, x and sensitivities Sx, Su) against the reference: values
    to 1e-12, sensitivities to 1e-10 of their scale."""
    assert step["status"] == 0
    np.testing.assert_allclose(step["x"], x1, rtol=1e-12, atol=1e-12)
    scale = np.abs(S).max()
    np.testing.assert_allclose(step["Sx"], S[:, :2 * nv], rtol=0, atol=1e-10 * scale)
    np.testing.assert_allclose(step["Su"], S[:, 2 * nv:], rtol=0, atol=1e-10 * scale)


def ipopt_reach(dyn, problem: dict) -> dict:
    """The reach of docs/acados_reach.py transcribed for casadi.Opti and IPOPT on gagen's
    CasADi forward dynamics: the reference optimum."""
    n, N, T = dyn.nv, problem["intervals"], problem["duration"]
    h = T / N
    fd = gc.functions(dyn, ["forward_dynamics"])["forward_dynamics"]
    x, u = ca.MX.sym("x", 2 * n), ca.MX.sym("u", n)

    def f(xs):
        return ca.vertcat(xs[n:], fd(xs[:n], xs[n:], u))

    k1 = f(x)
    k2 = f(x + h / 2 * k1)
    k3 = f(x + h / 2 * k2)
    k4 = f(x + h * k3)
    step = ca.Function("rk4", [x, u], [x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)])
    w = problem["weights"]
    W = np.repeat([w["q"], w["qd"], w["tau"]], n)
    We = np.repeat([w["end_q"], w["end_qd"]], n)
    target = np.concatenate([problem["goal"], np.zeros(n)])
    opti = ca.Opti()
    X, U = opti.variable(2 * n, N + 1), opti.variable(n, N)
    cost = 0
    for k in range(N):
        y = ca.vertcat(X[:, k] - target, U[:, k])
        cost += h / 2 * ca.sumsqr(np.sqrt(W) * y)
    cost += 0.5 * ca.sumsqr(np.sqrt(We) * (X[:, N] - target))
    opti.minimize(cost)
    opti.subject_to(step.map(N)(X[:, :-1], U) == X[:, 1:])
    opti.subject_to(X[:, 0] == np.concatenate([problem["start"], np.zeros(n)]))
    opti.set_initial(X, np.tile(np.concatenate([problem["start"], np.zeros(n)])[:, None],
                                (1, N + 1)))
    opti.solver("ipopt", {"print_time": False}, {"print_level": 0, "tol": 1e-12, "sb": "yes"})
    solution = opti.solve()
    return {"x": np.array(solution.value(X)).T, "tau": np.array(solution.value(U)).reshape(n, N).T,
            "cost": float(solution.value(cost))}


@pytest.fixture(scope="module")
def acados_run(tmp_path_factory):
    """The paper's robot exported, and the script's results on it."""
    acados = acados_root()
    from gagen.app.cli import main

    folder = tmp_path_factory.mktemp("acados")
    assert main(["-q", "export", "casadi", "rrr", "--out", str(folder / "export")]) == 0
    dyn = gagen.load("rrr", derivatives=True)
    prefix = gc.build.prefix_of(gc.build.model_ident(dyn))
    library = folder / "export" / gc.build.library_name(dyn)
    rng = np.random.default_rng(28)
    problem = {"x0": rng.uniform(-1, 1, 2 * dyn.nv).tolist(),
               "u0": rng.uniform(-5, 5, dyn.nv).tolist(), "h": H,
               "start": [0.0] * dyn.nv, "goal": [1.0, -0.5, 0.8], "duration": 1.0,
               "intervals": 20,
               "weights": {"q": 100.0, "qd": 1.0, "tau": 1e-3, "end_q": 1e4, "end_qd": 1e3}}
    return dyn, prefix, problem, run_script(acados, library, prefix, problem, folder)


def test_acados_erk_step_and_sensitivities_are_gagen_s(acados_run):
    """acados' explicit RK4 step on the exported forward dynamics equals RK4 on gagen's own
    call, and its forward sensitivities equal the chain rule through gagen's analytic
    derivatives (1e-12 and 1e-10: acados uses the library's Jacobian, no differences)."""
    dyn, _, problem, out = acados_run
    x0, u0 = np.array(problem["x0"]), np.array(problem["u0"])
    x1, S = rk4_with_sensitivities(dyn, x0, u0, H)
    assert_step(out["ERK"], x1, S, dyn.nv)


def gauss_legendre_with_sensitivities(dyn, x, u, h):
    """One step of the two-stage Gauss-Legendre method (acados' IRK default) on gagen's
    dynamics, its stages solved by Newton's method in NumPy, and the step's Jacobian by
    (x, u) by differentiating the stage equations K = f(x + h A K, u)."""
    r = np.sqrt(3.0) / 6.0
    A, b = np.array([[0.25, 0.25 - r], [0.25 + r, 0.25]]), np.array([0.5, 0.5])
    nx, nu = len(x), len(u)
    K = np.tile(rate(dyn, x, u), (2, 1))
    for _ in range(50):
        points = [x + h * (A[i] @ K) for i in range(2)]
        residual = np.concatenate([K[i] - rate(dyn, points[i], u) for i in range(2)])
        jac = [rate_jacobian(dyn, points[i], u) for i in range(2)]
        newton = np.eye(2 * nx) - np.block([[h * A[i, j] * jac[i][:, :nx] for j in range(2)]
                                            for i in range(2)])
        K = K - np.linalg.solve(newton, residual).reshape(2, nx)
        if np.abs(residual).max() < 1e-15:
            break
    points = [x + h * (A[i] @ K) for i in range(2)]
    jac = [rate_jacobian(dyn, points[i], u) for i in range(2)]
    newton = np.eye(2 * nx) - np.block([[h * A[i, j] * jac[i][:, :nx] for j in range(2)]
                                        for i in range(2)])
    right = np.vstack([np.hstack([jac[i][:, :nx], jac[i][:, nx:]]) for i in range(2)])
    dK = np.linalg.solve(newton, right).reshape(2, nx, nx + nu)
    seed = np.hstack([np.eye(nx), np.zeros((nx, nu))])
    return x + h * (b @ K), seed + h * np.tensordot(b, dK, axes=1)


def test_acados_irk_step_and_sensitivities_are_gagen_s(acados_run):
    """acados' implicit Gauss-Legendre step (its Newton iterations on gagen's Jacobian)
    equals the same method on gagen's own calls in NumPy, values (1e-12) and
    sensitivities (1e-10)."""
    dyn, _, problem, out = acados_run
    x1, S = gauss_legendre_with_sensitivities(dyn, np.array(problem["x0"]),
                                              np.array(problem["u0"]), H)
    assert_step(out["IRK"], x1, S, dyn.nv)


def test_acados_code_calls_the_library_s_function_and_jacobian(acados_run):
    """acados' generated C calls the exported function and its Jacobian jac_F (gagen's
    derivative kernels), for both integrators: CasADi did not differentiate the robot."""
    _, prefix, _, out = acados_run
    for integrator in ("ERK", "IRK"):
        called = set(out["calls"][integrator])
        assert f"jac_{prefix}_forward_dynamics" in called, (integrator, called)
    assert f"{prefix}_forward_dynamics" in set(out["calls"]["ERK"])


def test_acados_reach_reaches_ipopt_s_optimum(acados_run):
    """acados' Gauss-Newton SQP on the exported library converges to the optimum IPOPT
    finds on gagen.casadi's functions for the same transcription (1e-6)."""
    dyn, _, problem, out = acados_run
    ours = out["reach"]
    assert ours["status"] == 0, ours["status"]
    reference = ipopt_reach(dyn, problem)
    tau, x = np.array(ours["tau"]), np.array(ours["x"])
    np.testing.assert_allclose(tau, reference["tau"], rtol=0,
                               atol=1e-6 * np.abs(reference["tau"]).max())
    np.testing.assert_allclose(x, reference["x"], rtol=0, atol=1e-6)
    assert abs(ours["cost"] - reference["cost"]) <= 1e-8 * reference["cost"]
