"""An arm's reach in acados, on the library that `python -m gagen export casadi` writes
(docs/casadi.md, "acados"). This script never imports gagen: acados' generated solver
calls the exported C functions and their Jacobians like any CasADi-generated code.

    python -m gagen export casadi rrr --out casadi_rrr
    export ACADOS_SOURCE_DIR=/path/to/acados          # its lib/, include/, bin/t_renderer
    export LD_LIBRARY_PATH=$ACADOS_SOURCE_DIR/lib:$PWD/casadi_rrr
    python docs/acados_reach.py casadi_rrr/librrr_casadi.so rrr_casadi

It builds, in a scratch folder, on x = (q, qd), u = tau and xdot = (qd, forward_dynamics(q,
qd, tau)) (the exported function through `casadi.external`, in MX):
- acados' integrators, one step of explicit RK4 (ERK) and of implicit Gauss-Legendre (IRK),
  with their forward sensitivities;
- an optimal control problem (`reach`): from rest at `start`, reach `goal` at rest in
  `duration` seconds, least squares on (q - goal, qd, tau) per interval and on the end
  state, one RK4 step per interval, SQP with the Gauss-Newton Hessian (first derivatives
  only: gagen's Jacobians through acados' variational equations).
`--json FILE` (tests/test_casadi_acados.py) reads the states, the problem and the weights
from FILE and prints the results as JSON.
"""

from __future__ import annotations

import argparse
import ctypes
import json
import sys
import tempfile
import time
from pathlib import Path

import casadi as ca
import numpy as np


def dynamics_model(fd, n: int, name: str):
    """The acados model x = (q, qd), u = tau on the external forward dynamics `fd`, in its
    explicit (ERK) and implicit (IRK) forms."""
    from acados_template import AcadosModel

    x, u, xdot = ca.MX.sym("x", 2 * n), ca.MX.sym("u", n), ca.MX.sym("xdot", 2 * n)
    rate = ca.vertcat(x[n:], fd(x[:n], x[n:], u))
    model = AcadosModel()
    model.name, model.x, model.u, model.xdot = name, x, u, xdot
    model.f_expl_expr, model.f_impl_expr = rate, xdot - rate
    return model


def integrate(fd, n: int, folder: Path, integrator: str, h: float, x0, u0) -> dict:
    """One step of acados' integrator from (x0, u0): x1 and its sensitivities."""
    from acados_template import AcadosSim, AcadosSimSolver

    sim = AcadosSim()
    sim.model = dynamics_model(fd, n, f"gagen_{integrator.lower()}")
    options = sim.solver_options
    options.T, options.integrator_type, options.num_steps = h, integrator, 1
    options.num_stages = 4 if integrator == "ERK" else 2
    options.sens_forw = True
    if integrator == "IRK":  # Newton's method on the stages, to convergence
        options.newton_iter, options.newton_tol = 20, 1e-14
    sim.code_export_directory = str(folder / f"sim_{integrator.lower()}")
    solver = AcadosSimSolver(sim, json_file=str(folder / f"sim_{integrator.lower()}.json"),
                             verbose=False)
    solver.set("x", np.asarray(x0, float))
    solver.set("u", np.asarray(u0, float))
    status = solver.solve()
    return {"status": int(status), "x": solver.get("x").tolist(),
            "Sx": solver.get("Sx").tolist(), "Su": solver.get("Su").tolist(),
            "code": sim.code_export_directory}


def reach(fd, n: int, library: Path, folder: Path, start, goal, duration: float,
          intervals: int, weights: dict) -> dict:
    """The reach as an acados OCP (module docstring); the solver links `library`."""
    from acados_template import AcadosOcp, AcadosOcpSolver

    ocp = AcadosOcp()
    ocp.model = dynamics_model(fd, n, "gagen_reach")
    ocp.dims.N = intervals
    target = np.concatenate([goal, np.zeros(n)])
    # acados' linear least squares: stage k costs h/2 |(x, u) - (target, 0)|^2_W (acados
    # scales a stage's weight by its interval's length), the end 1/2 |x - target|^2_We
    ocp.cost.cost_type, ocp.cost.cost_type_e = "LINEAR_LS", "LINEAR_LS"
    ocp.cost.Vx = np.vstack([np.eye(2 * n), np.zeros((n, 2 * n))])
    ocp.cost.Vu = np.vstack([np.zeros((2 * n, n)), np.eye(n)])
    ocp.cost.W = np.diag(stage_weights(weights, n))
    ocp.cost.yref = np.concatenate([target, np.zeros(n)])
    ocp.cost.Vx_e, ocp.cost.yref_e = np.eye(2 * n), target
    ocp.cost.W_e = np.diag(np.repeat([weights["end_q"], weights["end_qd"]], n))
    at_rest = np.concatenate([start, np.zeros(n)])
    ocp.constraints.x0 = at_rest
    options = ocp.solver_options
    options.tf = duration
    options.integrator_type, options.sim_method_num_stages = "ERK", 4
    options.sim_method_num_steps = 1
    # Gauss-Newton SQP: first derivatives only, gagen's Jacobians through acados' VDE
    options.nlp_solver_type, options.hessian_approx = "SQP", "GAUSS_NEWTON"
    options.qp_solver = "PARTIAL_CONDENSING_HPIPM"
    options.nlp_solver_max_iter = 200
    options.tol = 1e-10
    options.print_level = 0
    # acados' generated solver links the exported library (found on LD_LIBRARY_PATH)
    options.model_external_shared_lib_dir = str(library.parent)
    options.model_external_shared_lib_name = library.stem.removeprefix("lib")
    ocp.code_export_directory = str(folder / "ocp")
    solver = AcadosOcpSolver(ocp, json_file=str(folder / "ocp.json"), verbose=False)
    for k in range(intervals + 1):
        solver.set(k, "x", at_rest)
    began = time.perf_counter()
    status = solver.solve()
    seconds = time.perf_counter() - began
    return {"status": int(status),
            "iterations": int(np.ravel(solver.get_stats("sqp_iter"))[0]),
            "seconds": seconds,
            "tau": [solver.get(k, "u").tolist() for k in range(intervals)],
            "x": [solver.get(k, "x").tolist() for k in range(intervals + 1)],
            "cost": float(solver.get_cost())}


def stage_weights(weights: dict, n: int) -> np.ndarray:
    """The diagonal of a stage's weight on (q - goal, qd, tau)."""
    return np.repeat([weights["q"], weights["qd"], weights["tau"]], n)


def load_library(library: Path) -> None:
    """acados' integrator library (AcadosSimSolver) does not link model libraries: load
    the exported library first, its symbols global, for it to resolve them."""
    ctypes.CDLL(str(library.resolve()), mode=ctypes.RTLD_GLOBAL)


def default_problem(n: int) -> dict:
    """The states and the problem of a plain run: a reach of 1 rad per joint in 1 s."""
    return {"x0": [0.3] * (2 * n), "u0": [0.1] * n, "h": 0.01, "start": [0.0] * n,
            "goal": [1.0] * n, "duration": 1.0, "intervals": 20,
            "weights": {"q": 100.0, "qd": 1.0, "tau": 1e-3, "end_q": 1e4, "end_qd": 1e3}}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("library", type=Path, help="the exported lib<prefix>.so")
    parser.add_argument("prefix", help="the functions' prefix, e.g. rrr_casadi")
    parser.add_argument("--json", type=Path, help="states and problem (the test's)")
    args = parser.parse_args(argv)
    fd = ca.external(f"{args.prefix}_forward_dynamics", str(args.library.resolve()),
                     {"jacobian_options": {"enable_fd": True, "fd_method": "central"}})
    n = fd.size1_in(0)
    problem = json.loads(args.json.read_text()) if args.json else default_problem(n)
    load_library(args.library)
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(scratch)
        out = {name: integrate(fd, n, folder, name, problem["h"], problem["x0"],
                               problem["u0"]) for name in ("ERK", "IRK")}
        out["calls"] = {name: sorted(_called_functions(Path(out[name].pop("code")),
                                                       args.prefix))
                        for name in ("ERK", "IRK")}
        out["reach"] = reach(fd, n, args.library.resolve(), folder,
                             np.asarray(problem["start"], float),
                             np.asarray(problem["goal"], float), problem["duration"],
                             problem["intervals"], problem["weights"])
    assert not any(m == "gagen" or m.startswith("gagen.") for m in sys.modules)
    if args.json:
        print(json.dumps(out))
    else:
        r = out["reach"]
        print(f"acados SQP: status {r['status']}, {r['iterations']} iterations, "
              f"{r['seconds'] * 1e3:.1f} ms; first torques {np.round(r['tau'][0], 4)}")
    return 0


def _called_functions(code: Path, prefix: str) -> set[str]:
    """The exported functions that acados' generated C calls (with or without jac_)."""
    import re

    names: set[str] = set()
    for source in code.rglob("*.c"):
        names |= set(re.findall(rf"\b(?:jac_)?{re.escape(prefix)}_[a-z_]+?(?=\()",
                                source.read_text()))
    return {n for n in names if not n.endswith(("_checkout", "_release", "_incref",
                                                "_decref", "_work", "_n_in", "_n_out"))}


if __name__ == "__main__":
    sys.exit(main())
