"""The benchmark report: report.md (machine, method, one table per section) and PNG plots.

`write_report(results, out)` takes the dict that `gagen.bench.run` also saves as
results.json; any section may be missing (not run) or hold an "error" instead of rows.
"""

from __future__ import annotations

import math
from pathlib import Path

from .simulation import format_time
from .simulation import markdown_table as simulation_table

PLOTS = {"percall": "percall.png", "batched": "batched.png", "simulation": "simulation.png",
         "scaling": "scaling.png"}


def _num(value, digits: int = 3) -> str:
    """A number with `digits` significant digits, thousands separated; '—' for none/NaN."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "—"
    if value == 0:
        return "0"
    decimals = max(0, digits - 1 - math.floor(math.log10(abs(value))))
    return f"{value:,.{decimals}f}"


def _ratio(value) -> str:
    return _num(value, 3)


def _duration(seconds: float) -> str:
    minutes, sec = divmod(seconds, 60.0)
    return f"{int(minutes)} min {sec:.0f} s" if minutes >= 1 else f"{sec:.1f} s"


# ------------------------------------------------------------------------------ markdown


def machine_table(m: dict) -> str:
    cores = f"{m.get('cores')} logical cores"
    if m.get("usable_cores") and m.get("usable_cores") != m.get("cores"):
        cores += f", {m['usable_cores']} usable"
    rows = [
        ("CPU", f"{m.get('cpu')} ({cores})"),
        ("system", f"{m.get('system')} {m.get('machine')}"),
        ("Python", m.get("python")),
        ("NumPy / SciPy / SymPy", f"{m.get('numpy')} / {m.get('scipy')} / {m.get('sympy')}"),
        ("Cython", m.get("cython")),
        ("C compiler", m.get("compiler")),
        ("gagen", m.get("gagen")),
        ("Pinocchio / PyDy", (f"{m.get('pinocchio') or 'not installed'} / "
                             f"{m.get('pydy') or 'not installed'}")),
        ("MuJoCo / Dask distributed", (f"{m.get('mujoco') or 'not installed'} / "
                                       f"{m.get('dask') or 'not installed'}")),
        ("date", m.get("date")),
    ]
    lines = ["| machine | |", "|---|---|"]
    lines += [f"| {key} | {value} |" for key, value in rows]
    return "\n".join(lines)


def percall_table(rows: list[dict], baseline: str = "gagen compiled") -> str:
    lines = [(f"| quantity | implementation | call | median µs | IQR µs (q1–q3) "
             f"| ratio to {baseline} |"), "|---|---|---|--:|--:|--:|"]
    for r in rows:
        lines.append(f"| {r['quantity']} | {r['implementation']} | `{r['call']}` "
                     f"| {_num(r['median_us'])} | {_num(r['iqr_us'], 2)} ({_num(r['q1_us'])}–"
                     f"{_num(r['q3_us'])}) | {_ratio(r['ratio'])} |")
    return "\n".join(lines)


def batched_table(rows: list[dict]) -> str:
    backends = list(dict.fromkeys(r["backend"] for r in rows))
    base = backends[0]
    head = "| N | " + " | ".join(f"{b} ns/state (IQR)" for b in backends)
    head += "".join(f" | {b} / {base}" for b in backends[1:]) + " |"
    lines = [head, "|--:|" + "--:|" * (2 * len(backends) - 1)]
    for count in dict.fromkeys(r["N"] for r in rows):
        cells = {r["backend"]: r for r in rows if r["N"] == count}
        line = f"| {count:,} | " + " | ".join(
            f"{_num(cells[b]['ns_per_state'])} ({_num(cells[b]['iqr_ns_per_state'], 2)})"
            if b in cells else "—" for b in backends)
        line += "".join(f" | {_ratio(cells[b]['ratio']) if b in cells else '—'}"
                        for b in backends[1:])
        lines.append(line + " |")
    return "\n".join(lines)


def derivatives_table(rows: list[dict]) -> str:
    lines = [("| model | quantity | implementation | call | median µs | IQR µs (q1–q3) "
             "| ratio to gagen compiled |"),
             "|---|---|---|---|--:|--:|--:|"]
    for r in rows:
        lines.append(f"| {r.get('model', '')} | {r['quantity']} | {r['implementation']} "
                     f"| `{r['call']}` | {_num(r['median_us'])} | {_num(r['iqr_us'], 2)} "
                     f"({_num(r['q1_us'])}–{_num(r['q3_us'])}) | {_ratio(r['ratio'])} |")
    return "\n".join(lines)


def scaling_table(rows: list[dict]) -> str:
    from .scaling import markdown_table

    return markdown_table(rows)


def identification_table(rows: list[dict]) -> str:
    lines = ["| task | implementation | call | median s | q1–q3 s | ratio to gagen |",
             "|---|---|---|--:|--:|--:|"]
    for r in rows:
        lines.append(f"| {r['task']} | {r['implementation']} | `{r['call']}` "
                     f"| {_num(r['median_s'])} | {_num(r['q1_s'])}–{_num(r['q3_s'])} "
                     f"| {_ratio(r['ratio'])} |")
    return "\n".join(lines)


HOW = """\
How: every section times its candidates in one process, interleaved: each repeat times
every candidate once (a `timeit` loop of about {target} per sample, divided by the loop
size), the starting candidate rotating from one repeat to the next, so a slow phase of
the machine hits all candidates alike. Shown: the median sample, the spread as the
interquartile range (IQR, q3 − q1, with q1–q3), and the ratio of a median to the
baseline's median (> 1: slower than the baseline). Results are checked to agree before
anything is timed. Per-call times are from Python, including argument checks and the
allocation of the result. A machine's speed can drift by tens of percent between runs
(frequency scaling, neighbours on a shared host): compare ratios rather than absolute
times across runs; results.json holds every sample."""


def _jax_table(rows: list[dict]) -> str:
    from .jaxbench import markdown_table

    return markdown_table(rows)


def throughput_table(rows: list[dict]) -> str:
    from .throughput import markdown_table

    return markdown_table(rows)


def _section(results: dict, key: str, title: str, intro: str, table, out: Path | None,
             images: dict) -> list[str]:
    section = results.get(key)
    if section is None:
        return []
    lines = [f"## {title}", ""]
    if intro:
        lines += [intro, ""]
    if section.get("error"):
        lines += [f"**Failed:** `{section['error']}`", ""]
        return lines
    rows = section.get("rows") or []
    if not rows:
        lines += ["(nothing measured)", ""]
        return lines
    lines += [table(rows), ""]
    if key in images:
        lines += [f"![{title}]({images[key]})", ""]
    if section.get("elapsed_s") is not None:
        lines += [f"_Section time: {_duration(section['elapsed_s'])}{_load(section)}._", ""]
    return lines


def _load(section: dict) -> str:
    """'; the load average ... at its start and ... at its end', where it was recorded."""
    load = section.get("load")
    if not load or len(load) != 2 or not all(isinstance(x, (int, float)) for x in load):
        return ""
    return (f"; the machine's 1-minute load average {float(load[0]):.1f} at its start and "
            f"{float(load[1]):.1f} at its end")


def markdown(results: dict, images: dict | None = None) -> str:
    images = images or {}
    settings = results.get("settings", {})
    mode = settings.get("mode", "default")
    command = settings.get("command", "python -m gagen bench")
    lines = ["# gagen benchmarks", ""]
    total = results.get("elapsed_s")
    lines += [f"`{command}` ({mode} mode)"
              + (f", {_duration(total)} in all." if total is not None else "."), ""]
    lines += [machine_table(results.get("machine", {})), ""]
    target = settings.get("target_s", 0.05)
    lines += [HOW.format(target=f"{target * 1e3:g} ms"), ""]

    build = results.get("rrr_build")
    rrr_note = ""
    if build:
        stages = ", ".join(f"{k} {v:.2f} s" for k, v in build.get("stages", {}).items())
        state = "reused from the cache" if build.get("cached") else f"built cold ({stages})"
        rrr_note = (f" The compiled rrr module was {state}; "
                    f"{build.get('ops_after_cse', 0):,} operations after CSE.")
    pc = results.get("percall", {})
    lines += _section(
        results, "percall", "Per call on rrr (the paper's robot, 3 joints)",
        f"One fixed state, {pc.get('repeats', '?')} interleaved repeats.{rrr_note} PyDy's rhs "
        "returns (qd, qdd) from the Kane equations of the same robot; the naive SymPy "
        "row lambdifies M and F with every intermediate substituted and no CSE, then "
        "calls numpy.linalg.solve. Pinocchio's crba fills only the upper triangle.",
        percall_table, None, images)
    bt = results.get("batched", {})
    lines += _section(
        results, "batched", "Batched forward dynamics on rrr",
        f"`dyn.forward_dynamics(q, qd, tau)` on (N, 3) arrays: time per call over N, "
        f"{bt.get('repeats', '?')} interleaved repeats; the ratio is per N.",
        batched_table, None, images)
    sm = results.get("simulation", {})
    lines += _section(
        results, "simulation", "The paper's 5-s simulation",
        "rrr from rest at q = 0 under `paper_controller()`, rtol = 1e-6, atol = 1e-8, 501 "
        f"output samples; one complete `gagen.simulate(...)` call each, "
        f"{sm.get('repeats', '?')} interleaved repeats.",
        simulation_table, None, images)
    tp = results.get("throughput", {})
    dev = tp.get("mujoco_max_dev_rad")
    lines += _section(
        results, "throughput", "Throughput: many simulations at once",
        f"`gagen.simulate_batch` on 1 and {tp.get('threads', '?')} threads, a Python loop "
        "over `gagen.simulate`, MuJoCo's `rollout` (same URDF, RK4, h = 1 ms, no contacts, "
        "PD as position actuators, gravcomp) and a Dask LocalCluster of 2 worker processes. "
        "paper: rrr's 5-s run (dopri5, 501 samples, m3 drawn per run); panda: 1 s of PD "
        "with gravity compensation, rk4, the state at every step. One call runs all N; "
        f"{tp.get('repeats', '?')} interleaved repeats; states/s counts the samples."
        + (f" MuJoCo's trajectory differs from gagen's by at most {dev:.1e} rad."
           if dev is not None else "")
        + "".join(f" Dask overhead per chunk: {r['overhead_per_chunk_s'] * 1e3:.1f} ms."
                  for r in tp.get("rows", []) if "overhead_per_chunk_s" in r),
        throughput_table, None, images)
    dv = results.get("derivatives", {})
    lines += _section(
        results, "derivatives",
        "The derivatives per call (rrr, the Panda; ANYmal C and Talos reduced floating)",
        "`dyn.forward_dynamics_derivatives`, `inverse_dynamics_derivatives` and "
        "`coriolis_matrix` from the compiled derivative module against Pinocchio's "
        "`computeABADerivatives`, `computeRNEADerivatives` and `computeCoriolisMatrix` (the "
        "robots: Pinocchio's own URDF parse, on its FreeFlyer for ANYmal and Talos), and "
        "against central differences of gagen's compiled forward dynamics (6n states in "
        f"one stacked call; fixed bases only); {dv.get('repeats', '?')} interleaved "
        "repeats, ratios to gagen compiled per model and quantity (> 1: slower than "
        "gagen).", derivatives_table, None, images)
    if dv.get("casadi"):
        from .casadi_c import FLAGS
        from .derivatives import casadi_table

        lines += [("In C, on a floating base: gagen's derivative module against the C that "
                   "CasADi generates for the Jacobian of adam's `aba` (by q, v and the "
                   f"joint torques; compiled with `{' '.join(FLAGS)}`), both in one "
                   "harness over the same 100 random states, round by round (medians of "
                   "21 rounds, µs per evaluation):"), "", casadi_table(dv["casadi"]), ""]
    if dv.get("builds"):
        from .derivatives import build_table

        lines += [("Each model's main module and then its derivative module, built cold in "
                  "fresh processes (the derivative module derives the equations again, then "
                  "their derivatives):"), "", build_table(dv["builds"]), ""]
    pa = results.get("panda", {})
    lines += _section(
        results, "panda", "Per call on the Panda (9 coordinates: 7 arm joints and 2 fingers, from its URDF)",
        f"gagen compiled against Pinocchio's own URDF parse, {pa.get('repeats', '?')} "
        "interleaved repeats; ratios to gagen compiled.", percall_table, None, images)
    fl = results.get("floating", {})
    lines += _section(
        results, "floating", "Floating bases per call: ANYmal C and Talos",
        "Pinocchio's FreeFlyer on its own URDF parse (`aba`, `rnea`, `crba`, "
        "`computeFrameJacobian` of a foot, LOCAL_WORLD_ALIGNED) and MuJoCo's `mj_forward` on "
        "the same URDF with a floating joint and no contacts (kinematics, M, bias forces and "
        f"qacc in one call), {fl.get('repeats', '?')} interleaved repeats; ratios to gagen.",
        percall_table, None, images)
    cg = results.get("centroidal", {})
    lines += _section(
        results, "centroidal", "Centroidal dynamics per call: ANYmal C",
        "The centre of mass, A_g (at the centre of mass, world axes, linear first), its bias "
        "d/dt A_g qd and d/dt A_g against Pinocchio's `computeCentroidalMap`, `ccrba`, "
        "`dccrba` (A_g and d/dt A_g), `computeCentroidalMapTimeVariation` and `centerOfMass` "
        f"on its own URDF parse (FreeFlyer), {cg.get('repeats', '?')} interleaved repeats; "
        "ratios to gagen.", percall_table, None, images)
    rg = results.get("regressor", {})
    lines += _section(
        results, "regressor", "The regressor and identification on the Panda",
        f"`dyn.regressor(q, qd, qdd)` (9 x 117: 10 columns per body and damping, friction "
        f"and armature per joint) against Pinocchio's computeJointTorqueRegressor (9 x 90), "
        f"checked equal on the body columns, {rg.get('repeats', '?')} interleaved repeats.",
        percall_table, None, images)
    if rg.get("identify"):
        lines += [("Identification from noisy torques along an exciting trajectory: "
                  "`gagen.identify` (base regressor, normal equations, standard "
                  "deviations; the base grouping computed once and cached on the dynamics, "
                  "timed on its own), "
                  "against Pinocchio's regressor in a Python loop over the samples and "
                  "`numpy.linalg.lstsq` (minimum-norm, no base parameters), "
                  f"{rg.get('identify_repeats', '?')} interleaved repeats."), "",
                  identification_table(rg["identify"]), ""]
    ts = results.get("taskspace", {})
    lines += _section(
        results, "taskspace", "Task space per call: the Panda's tool and an ANYmal C foot",
        "`dyn.frame_bias_acceleration` (J̇ q̇, classical, LOCAL_WORLD_ALIGNED), "
        "`frame_jacobian_time_variation` (J̇) and `operational_space_inertia` (Λ: the "
        "tool's 6 rows, the foot's 3) against Pinocchio on its own URDF parse, as a user "
        "calls it from Python: `forwardKinematics(q, v, 0)` + "
        "`getFrameClassicalAcceleration`, `computeJointJacobiansTimeVariation` + "
        "`getFrameJacobianTimeVariation`, `computeMinverse` + `computeFrameJacobian` + "
        f"NumPy; {ts.get('repeats', '?')} interleaved repeats, ratios to gagen "
        "(> 1: slower than gagen).", percall_table, None, images)
    cs = results.get("constraints", {})
    lines += _section(
        results, "constraints", "Constrained dynamics per call: ANYmal C on four feet",
        "`dyn.constrained_forward_dynamics(q, qd, tau)`, `dyn.impulse_dynamics(q, qd)` and "
        "`dyn.constrained_forward_dynamics_derivatives(q, qd, tau)` (against "
        "`constraintDynamics` + `computeConstraintDynamicsDerivatives`) "
        "with the four feet as 3-D point contacts (LOCAL_WORLD_ALIGNED) against Pinocchio's "
        "`constraintDynamics` and `impulseDynamics` on its own URDF parse (FreeFlyer; "
        "`RigidConstraintModel` CONTACT_3D per foot, `initConstraintDynamics` once, "
        "`ProximalSettings(1e-12, mu=0, 1)`: the exact KKT solution), checked equal first; "
        f"{cs.get('repeats', '?')} interleaved repeats, ratios to gagen (> 1: slower than "
        "gagen).", percall_table, None, images)
    lines += _casadi_lines(results, images)
    sc = results.get("scaling", {})
    lines += _section(
        results, "scaling", "Scaling: build and call time against the robot's size",
        "Cold builds, each in a fresh process and cache folder: derive, generate and "
        "compile (the C compiler, as many at once as there are cores) as "
        "`gagen.building.build` reports them, the build's wall time and the peak memory of "
        "its process tree. Then, per model, gagen's forward dynamics, inverse dynamics and "
        "mass matrix per call from Python against Pinocchio's `aba`, `rnea` and `crba` "
        f"(Pinocchio's own URDF parse; {sc.get('repeats', '?')} interleaved repeats), and "
        "per state in gagen's batched loop (1000 stacked states) against Pinocchio's "
        "algorithms in a C++ loop compiled with -O3 -march=native, where available, "
        "timed twice: each result left in Pinocchio's `data` for the next call to "
        "overwrite, and every state's result stored (M in full) in a fresh array of the "
        "batch, the output gagen's batched call returns. The batched loop and the C++ "
        "loop alternate, round after round (medians of 9 rounds, the C++ side's median "
        "of 3 passes in each), so both meet the machine in the same states. "
        "(×): Pinocchio's time as a multiple of gagen's (> 1: gagen is faster).",
        scaling_table, None, images)
    jx = results.get("jax", {})
    lines += _section(
        results, "jax", "gagen inside JAX: batched forward dynamics and its Jacobian",
        f"{jx.get('states', '?')} states inside `jax.jit(jax.vmap(...))` (float64): "
        "gagen's FFI functions (`gagen.jax.functions(dyn)`: one call of the compiled C loop "
        "per batch), the printed JAX functions (`target=\"jax\"`), adam's JAX backend and "
        "MuJoCo MJX (contacts and constraints off), against gagen's stacked call from "
        "NumPy; the Jacobian is jax.jacfwd by (q, q̇, τ), the stacked call's "
        "`dyn.forward_dynamics_derivatives`. Every result checked first; "
        f"{jx.get('repeats', '?')} interleaved repeats.", _jax_table, None, images)
    if jx.get("compile"):
        from .jaxbench import compile_table

        lines += [("JIT compile times of the vmapped functions (this process, wall and "
                   "CPU), after printing the model's programs as JAX (once per model, kept "
                   "in the cache):"), "", compile_table(jx["compile"]), ""]
    notes = results.get("notes") or []
    if notes:
        lines += ["## Notes", ""] + [f"- {n}" for n in notes] + [""]
    return "\n".join(lines).rstrip() + "\n"


def _casadi_lines(results: dict, images: dict) -> list[str]:
    from .casadi import evaluation_table, solve_table

    cs = results.get("casadi", {})
    if not cs:
        return []
    lines = _section(
        results, "casadi", "gagen inside CasADi against adam",
        "Forward dynamics and its Jacobian by (q, qd, tau) per evaluation inside CasADi, "
        f"over {cs.get('states', '?')} states in one `Function.map` call (time / states), "
        f"{cs.get('repeats', '?')} interleaved repeats: gagen's `gagen.casadi.functions` "
        "(an external of gagen's library; its Jacobian the library's analytic `jac_` as "
        "CasADi calls it, and `jacobian()` of an MX and of an SX expression calling the "
        "function: SX differentiates the call once per output), adam's CasADi expression "
        "graph in CasADi's virtual machine (SX), and generated by CasADi and compiled with "
        "-O3 (C). The Panda "
        "with its fingers fixed (adam fails on prismatic joints) and no joint damping or "
        "friction (adam has none): adam's mass matrix and bias force at the base fixed, the "
        "joint block solved; ANYmal C: adam's `aba`. Ratios to gagen (> 1: slower).",
        evaluation_table, None, images)
    if cs.get("solve"):
        differences = ", ".join(f"{k} {v:.1e}" for k, v in
                                cs.get("optimum_difference", {}).items())
        lines += [("The Panda's minimum-effort swing of docs/casadi.md (direct multiple "
                   "shooting, 40 RK4 intervals over 1 s, casadi.Opti and IPOPT to tol 1e-10) "
                   "on each forward dynamics; IPOPT's exact Hessian (gagen: central "
                   "differences of its analytic Jacobian) and its limited-memory one. The "
                   f"optima differ by at most {differences} (joint angles and torques)."),
                  "", solve_table(cs["solve"]), ""]
    return lines


# --------------------------------------------------------------------------------- plots


def _figure(figsize: tuple[float, float]):
    """A Figure with its own Agg canvas: no global backend, no pyplot, nothing left open."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize)
    FigureCanvasAgg(fig)
    return fig


def plot_percall(rows: list[dict], path: Path) -> None:
    labels = [f"{r['quantity']}: {r['implementation']}" for r in rows]
    medians = [r["median_us"] for r in rows]
    errors = [[r["median_us"] - r["q1_us"] for r in rows],
              [r["q3_us"] - r["median_us"] for r in rows]]
    colours = {"mass matrix": "tab:blue", "forward dynamics": "tab:orange",
               "inverse dynamics": "tab:green"}
    fig = _figure((8, 0.35 * len(rows) + 1.4))
    ax = fig.subplots()
    y = list(range(len(rows)))[::-1]
    ax.barh(y, medians, xerr=errors, color=[colours.get(r["quantity"], "grey") for r in rows],
            capsize=2)
    ax.set_yticks(y, labels, fontsize=8)
    ax.set_xscale("log")
    ax.set_xlabel("µs per call (median, bars: q1–q3)")
    ax.set_title("Per call on rrr, from Python")
    for yi, m in zip(y, medians):
        ax.text(m * 1.15, yi, _num(m), va="center", fontsize=7)
    ax.set_xlim(min(medians) / 2, max(r["q3_us"] for r in rows) * 3)
    ax.grid(axis="x", which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def plot_batched(rows: list[dict], path: Path) -> None:
    fig = _figure((6, 4))
    ax = fig.subplots()
    for backend in dict.fromkeys(r["backend"] for r in rows):
        mine = [r for r in rows if r["backend"] == backend]
        ax.errorbar([r["N"] for r in mine], [r["ns_per_state"] for r in mine],
                    yerr=[r["iqr_ns_per_state"] / 2 for r in mine], marker="o",
                    label=backend, capsize=2)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("N (states per call)")
    ax.set_ylabel("ns per state (median)")
    ax.set_title("Batched forward dynamics on rrr")
    ax.grid(which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def plot_simulation(rows: list[dict], path: Path) -> None:
    fig = _figure((7, 2.8))
    ax = fig.subplots()
    y = list(range(len(rows)))[::-1]
    medians = [r["median_s"] for r in rows]
    errors = [[r["median_s"] - r["q1_s"] for r in rows], [r["q3_s"] - r["median_s"] for r in rows]]
    ax.barh(y, medians, xerr=errors, color="tab:purple", capsize=2)
    ax.set_yticks(y, [f"({r['case']}) {r['label']}" for r in rows], fontsize=8)
    ax.set_xscale("log")
    ax.set_xlabel("seconds per 5-s simulation (median)")
    for yi, r in zip(y, rows):
        ax.text(r["median_s"] * 1.15, yi, f"{format_time(r['median_s'])}, "
                f"{r['speedup']:,.0f}x", va="center", fontsize=7)
    ax.set_xlim(min(medians) / 2, max(r["q3_s"] for r in rows) * 6)
    ax.grid(axis="x", which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def plot_scaling(rows: list[dict], path: Path) -> None:
    """Left: the cold build's stages against the degrees of freedom; right: per-call
    times of gagen and Pinocchio (solid: chains, markers: the URDF robots)."""
    from matplotlib.ticker import MaxNLocator

    fig = _figure((11, 4.2))
    left, right = fig.subplots(1, 2)
    chains = [r for r in rows if r["model"].startswith("chain:")]
    others = [r for r in rows if not r["model"].startswith("chain:")]
    markers = "sD^v<>p*"
    stages = (("derive_s", "derive", "tab:blue"), ("generate_s", "generate", "tab:orange"),
              ("compile_s", "compile", "tab:green"), ("build_s", "whole build (wall)",
                                                      "black"))
    for key, label, colour in stages:
        left.plot([r["dof"] for r in chains], [r[key] for r in chains], "o-", color=colour,
                  label=label, markersize=4)
        for k, r in enumerate(others):
            left.plot([r["dof"]], [r[key]], markers[k % len(markers)], color=colour,
                      markersize=7, markerfacecolor="none")
    for k, r in enumerate(others):
        left.plot([], [], markers[k % len(markers)], color="grey", markerfacecolor="none",
                  label=r["model"])
    kernels = (("fd", "FD", "tab:red"), ("id", "ID", "tab:purple"), ("M", "M", "tab:cyan"))
    for key, label, colour in kernels:
        right.plot([r["dof"] for r in chains], [r[f"{key}_us"] for r in chains], "o-",
                   color=colour, markersize=4, label=f"gagen {label}")
        right.plot([r["dof"] for r in chains], [r[f"pin_{key}_us"] for r in chains], "o--",
                   color=colour, markersize=4, markerfacecolor="none",
                   label=f"Pinocchio {label}")
        for k, r in enumerate(others):
            right.plot([r["dof"]], [r[f"{key}_us"]], markers[k % len(markers)], color=colour,
                       markersize=7)
            right.plot([r["dof"]], [r[f"pin_{key}_us"]], markers[k % len(markers)],
                       color=colour, markersize=7, markerfacecolor="none")
    left.set_title("Cold build (chains: lines; robots: markers)")
    left.set_ylabel("seconds")
    right.set_title("Per call from Python (filled: gagen, open/dashed: Pinocchio)")
    right.set_ylabel("µs per call (median)")
    for ax in (left, right):
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.set_yscale("log")
        ax.set_xlabel("degrees of freedom")
        ax.grid(which="both", alpha=0.3)
        ax.legend(fontsize=6, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


PLOTTERS = {"percall": plot_percall, "batched": plot_batched, "simulation": plot_simulation,
            "scaling": plot_scaling}


def write_plots(results: dict, out: Path) -> dict[str, str]:
    """One PNG per section that has rows; returns {section: file name}."""
    written = {}
    for key, plot in PLOTTERS.items():
        rows = (results.get(key) or {}).get("rows")
        if rows:
            plot(rows, out / PLOTS[key])
            written[key] = PLOTS[key]
    return written


def write_report(results: dict, out) -> Path:
    """Write report.md and the PNGs into `out`; return the report's path."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    images = write_plots(results, out)
    path = out / "report.md"
    path.write_text(markdown(results, images))
    return path
