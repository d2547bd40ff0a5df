"""gagen inside JAX (gagen.jax): batched forward dynamics and its Jacobian for 4,096 states,
inside jax.jit(jax.vmap(...)), and the compile times of the printed functions.

Per model (the Panda; the Panda's arm alone, its fingers fixed; ANYmal C on a floating
base), every candidate checked against gagen's stacked call before anything is timed,
all of them timed interleaved in one run (medians; the JAX calls wait for their results;
each sample follows one untimed call of its candidate, reported as its first call; MJX in a
run of its own after the others):

  forward dynamics   gagen's stacked call dyn.forward_dynamics(Q, QD, T) (NumPy; the
                     baseline), gagen.jax.functions(dyn)["forward_dynamics"] (the FFI:
                     one call of the same C loop per batch), the printed JAX functions
                     (target="jax"), adam's JAX backend (its M and bias force solved for
                     the fixed-base Panda, its aba for ANYmal), MuJoCo MJX's forward with
                     contacts and constraints off
  FD Jacobian        ∂q̈/∂(q, q̇, τ): dyn.forward_dynamics_derivatives (the baseline), and
                     jax.jacfwd of each JAX function above

adam fails on prismatic joints (the Panda's fingers): it runs on the arm alone, where
gagen runs too. adam's forward dynamics runs on the 4,096 states; its Jacobian (minutes
per 4,096 states on ANYmal C) and MJX (seconds) on fewer (MJX on 256, the Jacobians on 32),
and every row's ratio is per state. The printed functions' compile times (jit of the vmapped function, with
and without jacfwd) are measured in this process, after the printing (once per model,
kept in the cache), which is reported apart.
"""

from __future__ import annotations

import re
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from .common import PANDA, find_urdf_dir, optional
from .timing import Candidate, interleaved

ANYMAL = "anymal_c.urdf"
STATES = 4096
FFI_GOAL = 1.5  # the FFI's time at most this times the stacked C call's
ADAM_GOAL = 20.0  # gagen's throughput at least this times adam's
COMPILE_GOAL = 60.0  # seconds: the printed Panda derivatives' JIT
# MJX on the CPU is slow (tens of ms per state here): it runs on fewer states
MJX_STATES = 256
MJX_JACOBIAN_STATES = 32
# adam on the CPU: its forward dynamics on the 4,096 states as gagen (about 0.03 s on the
# Panda arm, 0.08 s on ANYmal C per call); its Jacobian on fewer (minutes per 4,096 states
# on ANYmal C), compared per state
ADAM_STATES = STATES
ADAM_JACOBIAN_STATES = 32
STACKED = "gagen stacked (NumPy)"
FFI = "gagen FFI"
PRINTED = "gagen printed JAX"
ADAM = "adam (JAX)"
MJX = "MuJoCo MJX"


def panda_arm_urdf(urdf: Path, folder: Path) -> Path:
    """The Panda with its finger joints fixed (adam refuses prismatic joints)."""
    root = ET.parse(urdf).getroot()
    for joint in root.iter("joint"):
        if joint.get("type") == "prismatic":
            joint.set("type", "fixed")
            for tag in ("limit", "dynamics", "mimic"):
                for element in joint.findall(tag):
                    joint.remove(element)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "panda_arm.urdf"
    path.write_text(ET.tostring(root, encoding="unicode"))
    return path


def _states(dyn, rng, count: int):
    """Random states; a floating base gets no generalised force (adam's aba and MJX's
    actuators take the joints' torques only)."""
    v = rng.normal(size=(count, dyn.nv)) * 0.5
    q = dyn.integrate(np.broadcast_to(dyn.neutral(), (count, dyn.nq)), v)
    tau = rng.normal(size=(count, dyn.nv)) * 5.0
    if dyn.nq > dyn.nv:
        tau[:, :6] = 0.0
    return q, rng.normal(size=(count, dyn.nv)), tau


def _blocking(fn):
    import jax

    def call(*args):
        return jax.block_until_ready(fn(*args))

    return call


def _check(what: str, got, want, rtol: float = 1e-8) -> None:
    got, want = np.asarray(got), np.asarray(want)
    scale = max(1.0, float(np.max(np.abs(want))))
    err = float(np.max(np.abs(got - want)))
    if not err <= rtol * scale:
        raise AssertionError(f"{what}: off by {err:.3g} (scale {scale:.3g})")


def _fd_jacobian(fd):
    """jacfwd of fd(q, qd, tau) by all three, as one (nv, nq + 2 nv) matrix."""
    import jax
    import jax.numpy as jnp

    def jacobian(q, qd, tau):
        parts = jax.jacfwd(fd, argnums=(0, 1, 2))(q, qd, tau)
        return jnp.concatenate(parts, axis=-1)

    return jacobian


def _stacked_jacobian(dyn):
    def jacobian(Q, QD, T):
        dq, dqd, dtau = dyn.forward_dynamics_derivatives(Q, QD, T)
        return dq, dqd, dtau

    return jacobian


def gagen_candidates(label, dyn, Q, QD, T, printed: bool, compile_rows: list, progress,
                     cache_dir=None):
    """The stacked call, the FFI and (optionally) the printed functions of one model, each
    checked; appends each JAX function's compile times to compile_rows."""
    import jax.numpy as jnp

    import gagen.jax as gj

    want = dyn.forward_dynamics(Q, QD, T)
    dq, dqd, dtau = dyn.forward_dynamics_derivatives(Q[:4], QD[:4], T[:4])
    jq, jqd, jtau = (jnp.asarray(x) for x in (Q, QD, T))
    cands = [
        _c(label, "forward dynamics", STACKED, "dyn.forward_dynamics(Q, QD, T)",
           dyn.forward_dynamics, (Q, QD, T)),
        _c(label, "FD Jacobian", STACKED, "dyn.forward_dynamics_derivatives(Q, QD, T)",
           _stacked_jacobian(dyn), (Q, QD, T)),
    ]
    targets = [(FFI, "ffi")] + ([(PRINTED, "jax")] if printed else [])
    for name, target in targets:
        row = {"model": label, "implementation": name}
        if target == "jax":
            from gagen.jax.printed import printed_module

            start = time.perf_counter()
            printed_module(dyn, "dynamics", cache_dir)
            printed_module(dyn, "derivatives", cache_dir)
            row["print_s"] = time.perf_counter() - start
        start = time.perf_counter()
        fd = gj.functions(dyn, target=target, cache_dir=cache_dir)["forward_dynamics"]
        row["functions_s"] = time.perf_counter() - start
        batched = _compiled(row, "forward dynamics", fd, (jq, jqd, jtau), progress, label)
        jac = _compiled(row, "FD Jacobian", _fd_jacobian(fd), (jq, jqd, jtau), progress,
                        label)
        compile_rows.append(row)
        _check(f"{label}: {name} forward dynamics", batched(jq, jqd, jtau), want)
        got = np.asarray(jac(jq, jqd, jtau))[:4]
        if dyn.nq == dyn.nv:  # d/dq by q's entries: the kernels' d/dv on a fixed base
            _check(f"{label}: {name} FD Jacobian", got,
                   np.concatenate([dq, dqd, dtau], axis=-1))
        else:
            _check(f"{label}: {name} FD Jacobian (q̇, τ)", got[..., dyn.nq:],
                   np.concatenate([dqd, dtau], axis=-1))
        call = f"jax.jit(jax.vmap(gagen.jax.functions(dyn{_target(target)})"
        cands += [
            _c(label, "forward dynamics", name, call + '["forward_dynamics"]))',
               _blocking(batched), (jq, jqd, jtau)),
            _c(label, "FD Jacobian", name, call.replace("jax.vmap(", "jax.vmap(jax.jacfwd(")
               + '["forward_dynamics"], argnums=(0, 1, 2))))', _blocking(jac),
               (jq, jqd, jtau)),
        ]
    return cands


def _compiled(row: dict, what: str, fn, args, progress, label):
    """jax.jit(jax.vmap(fn)) compiled for `args`; its trace and compile times (wall, CPU)
    into `row`."""
    import jax

    wall, cpu = time.perf_counter(), time.process_time()
    lowered = jax.jit(jax.vmap(fn)).lower(*args)
    row[f"{what} trace_s"] = time.perf_counter() - wall
    executable = lowered.compile()
    row[f"{what} total_s"] = time.perf_counter() - wall
    row[f"{what} cpu_s"] = time.process_time() - cpu
    progress(f"{label}: {row['implementation']} {what} compiled in "
             f"{row[f'{what} total_s']:.1f} s ({row[f'{what} cpu_s']:.1f} s CPU)")
    return executable


def _target(target: str) -> str:
    return "" if target == "ffi" else f', target="{target}"'


def _c(label, quantity, implementation, call, fn, args) -> Candidate:
    group = f"{label}: {quantity}"
    return Candidate(f"{group} / {implementation}", fn, tuple(args), group=group,
                     info={"model": label, "quantity": quantity,
                           "implementation": implementation, "call": call,
                           "states": int(args[0].shape[0])})


def adam_candidates(label, dyn, urdf: Path, Q, QD, T, notes: list) -> list[Candidate]:
    """adam's JAX backend on the same states (its dynamics without the URDF's joint damping
    and friction, which gagen's include: checked against gagen with them set to 0)."""
    adam = optional("adam.jax")
    if adam is None:
        notes.append("adam-robotics is not installed: its JAX backend is not timed.")
        return []
    import jax
    import jax.numpy as jnp
    from adam.jax import KinDynComputations

    g = dyn.parameters.get("g", 9.81)
    joints = [j.name for j in dyn.info.joints if j.type != "floating"]
    floating = dyn.nq > dyn.nv
    kd = KinDynComputations(urdf.read_text(), joints, root_link=None,
                            gravity=jnp.array([0.0, 0.0, -g, 0.0, 0.0, 0.0]))
    factory = getattr(kd.rbdalgos.math, "factory", None)
    if getattr(factory, "_device", None) is not None:
        # adam 0.5 passes the reference array's device to jnp.asarray, which this JAX
        # refuses for traced values (under jit, vmap and jacfwd alike): without it, the
        # arrays stay where JAX puts them (the one CPU device)
        factory._device = None
        notes.append(f"{label}: adam's array factory had a device set, which this JAX "
                     "refuses for traced values under jit/vmap/jacfwd; the bench clears "
                     "it (no other change to adam).")
    if floating:
        from adam.core.constants import Representations

        kd.set_frame_velocity_representation(Representations.BODY_FIXED_REPRESENTATION)

        def fd(q, qd, tau):
            H = _homogeneous(q[:7])
            out = kd.aba(H, q[7:], qd[:6], qd[6:], tau[6:])
            return out

        call = "KinDynComputations.aba(H, s, base velocity, s_dot, tau), body-fixed"
    else:
        def fd(q, qd, tau):
            H = jnp.eye(4, dtype=q.dtype)
            zero = jnp.zeros(6, q.dtype)
            M = kd.mass_matrix(H, q)[6:, 6:]
            h = kd.bias_force(H, q, zero, qd)[6:]
            return jnp.linalg.solve(M, tau - h)

        call = "solve(M[6:, 6:], tau - bias_force[6:]) of KinDynComputations, fixed base"
    no_terms = {k: 0.0 for k in dyn.parameters if k.startswith(("damping_", "friction_"))}
    want = dyn.forward_dynamics(Q[:8], QD[:8], T[:8], p=no_terms)
    jq, jqd, jtau = (jnp.asarray(x) for x in (Q, QD, T))
    mapped = "vmap"
    try:
        batched = jax.jit(jax.vmap(fd))
        got = batched(jq[:8], jqd[:8], jtau[:8])
    except Exception as exc:  # noqa: BLE001 - adam's own limits: mapped instead
        notes.append(f"{label}: adam fails under jax.vmap ({type(exc).__name__}); it is "
                     "mapped with jax.lax.map instead.")
        mapped = "lax.map"
        batched = jax.jit(lambda a, b, c: jax.lax.map(lambda x: fd(*x), (a, b, c)))
        got = batched(jq[:8], jqd[:8], jtau[:8])
    try:
        _check(f"{label}: adam's forward dynamics", got, want, 1e-7)
    except AssertionError as exc:
        notes.append(f"{label}: adam's result differs from gagen's ({exc}); timed anyway.")
    jac = jax.jit(jax.vmap(_fd_jacobian(fd))) if mapped == "vmap" else jax.jit(
        lambda a, b, c: jax.lax.map(lambda x: _fd_jacobian(fd)(*x), (a, b, c)))
    notes.append(f"{label}: adam runs on the CPU at {ADAM_STATES:,} states (forward) and "
                 f"{ADAM_JACOBIAN_STATES} (its Jacobian: minutes per 4,096 states on ANYmal "
                 "C): its rows compare per state.")
    few = tuple(x[:ADAM_JACOBIAN_STATES] for x in (jq, jqd, jtau))
    jac(*few)
    return [
        _c(label, "forward dynamics", ADAM, f"jax.jit(jax.{mapped}({call}))",
           _blocking(batched), tuple(x[:ADAM_STATES] for x in (jq, jqd, jtau))),
        _c(label, "FD Jacobian", ADAM, f"jax.jit(jax.{mapped}(jax.jacfwd(...)))",
           _blocking(jac), few),
    ]


def _homogeneous(pose):
    """The 4x4 transform of (x, y, z, qx, qy, qz, qw) (gagen's floating configuration)."""
    import jax.numpy as jnp

    x, y, z, w = pose[3], pose[4], pose[5], pose[6]
    s = 1.0 / (x * x + y * y + z * z + w * w)
    R = jnp.array([[1 - 2 * s * (y * y + z * z), 2 * s * (x * y - z * w), 2 * s * (x * z + y * w)],
                   [2 * s * (x * y + z * w), 1 - 2 * s * (x * x + z * z), 2 * s * (y * z - x * w)],
                   [2 * s * (x * z - y * w), 2 * s * (y * z + x * w), 1 - 2 * s * (x * x + y * y)]])
    top = jnp.concatenate([R, pose[:3, None]], axis=1)
    return jnp.concatenate([top, jnp.array([[0.0, 0.0, 0.0, 1.0]], dtype=pose.dtype)], axis=0)


def mjx_candidates(label, dyn, urdf: Path, Q, QD, T, notes: list) -> list[Candidate]:
    """MJX's forward on MuJoCo's import of the URDF (geometry, contacts and constraints
    off), the same states; checked against gagen on a fixed base (MuJoCo's free joint
    differs in its velocity's frame: timed only)."""
    mujoco = optional("mujoco")
    mjx = optional("mujoco.mjx")
    if mujoco is None or mjx is None:
        notes.append("MuJoCo MJX is not installed (pip install mujoco-mjx): not timed.")
        return []
    import jax
    import jax.numpy as jnp

    mjx = mujoco.mjx
    text = re.sub(r"<(visual|collision)\b.*?</\1>", "", urdf.read_text(), flags=re.DOTALL)
    floating = dyn.nq > dyn.nv
    if floating:
        start = text.index("<link")
        root = dyn.model.bodies[0].name
        text = (text[:start] + f'<link name="world"/><joint name="floating_base" '
                f'type="floating"><parent link="world"/><child link="{root}"/></joint>'
                + text[start:])
    spec = mujoco.MjSpec.from_string(text)
    spec.option.disableflags |= (mujoco.mjtDisableBit.mjDSBL_CONSTRAINT
                                 | mujoco.mjtDisableBit.mjDSBL_CONTACT)
    # MuJoCo reads the URDF's damping and friction (gagen's joint terms, set to 0 below
    # for the check); ANYmal's camera links break the triangle inequality, which MuJoCo
    # refuses unless told to balance them (gagen accepts them welded to the base)
    spec.compiler.balanceinertia = True
    for joint in spec.joints:
        for name in ("damping", "frictionloss", "armature"):
            value = getattr(joint, name)  # a number, or an array in newer MuJoCo
            setattr(joint, name, np.zeros_like(value) if np.ndim(value) else 0.0)
    spec.option.gravity = [0.0, 0.0, -dyn.parameters.get("g", 9.81)]
    try:
        model = spec.compile()
        mx = mjx.put_model(model)
    except Exception as exc:  # noqa: BLE001 - MuJoCo's own checks
        notes.append(f"{label}: MuJoCo MJX refuses the model ({type(exc).__name__}: {exc}).")
        return []
    if model.nv != dyn.nv:
        notes.append(f"{label}: MuJoCo's model has {model.nv} velocities, gagen's {dyn.nv}: "
                     "MJX not timed.")
        return []
    if floating:  # MuJoCo's free joint: quaternion w first
        qpos = np.concatenate([Q[:, :3], Q[:, 6:7], Q[:, 3:6], Q[:, 7:]], axis=1)
    else:
        qpos = Q
    data = mjx.make_data(mx)

    def forward(qp, qv, tau):
        d = data.replace(qpos=qp, qvel=qv, qfrc_applied=tau)
        return mjx.forward(mx, d).qacc

    batched = jax.jit(jax.vmap(forward))
    jp, jv, jt = (jnp.asarray(x) for x in (qpos, QD, T))
    got = batched(jp[:8], jv[:8], jt[:8])
    notes.append(f"{label}: MJX runs on the CPU at {MJX_STATES} states (forward) and "
                 f"{MJX_JACOBIAN_STATES} (its Jacobian): its rows compare per state.")
    if not floating:
        terms = {k: 0.0 for k in dyn.parameters if k.startswith(("damping_", "friction_"))}
        try:
            _check(f"{label}: MJX's forward", got, dyn.forward_dynamics(Q[:8], QD[:8], T[:8],
                                                                        p=terms), 1e-6)
        except AssertionError as exc:
            notes.append(f"{label}: MJX's qacc differs from gagen's ({exc}); timed anyway.")
    jac = jax.jit(jax.vmap(_fd_jacobian(forward)))
    few = tuple(x[:MJX_JACOBIAN_STATES] for x in (jp, jv, jt))
    jac(*few)
    return [
        _c(label, "forward dynamics", MJX, "jax.jit(jax.vmap(mjx.forward)) (qacc)",
           _blocking(batched), tuple(x[:MJX_STATES] for x in (jp, jv, jt))),
        _c(label, "FD Jacobian", MJX, "jax.jit(jax.vmap(jax.jacfwd(mjx.forward)))",
           _blocking(jac), few),
    ]


def jax_rows(urdf_dir, scratch: Path, repeats: int, target: float, progress,
             states: int = STATES, printed: bool = True, cache_dir: Path | None = None) -> dict:
    """The section: timing rows, compile rows and notes; the models are built into
    `cache_dir` (default: a fresh folder under `scratch`)."""
    jax = optional("jax")
    if jax is None:
        note = "JAX is not installed (pip install gagen[jax]): the section is skipped."
        return {"rows": [], "compile": [], "notes": [note]}
    jax.config.update("jax_enable_x64", True)
    import gagen

    notes: list[str] = []
    folder = find_urdf_dir(urdf_dir, needed=PANDA)
    if folder is None:
        note = f"{PANDA} not found (--urdf-dir): the jax section is skipped."
        return {"rows": [], "compile": [], "notes": [note]}
    rng = np.random.default_rng(29)
    models = [("Panda", folder / PANDA, False, False),
              ("Panda arm", panda_arm_urdf(folder / PANDA, scratch / "panda-arm"), False,
               True),
              ("ANYmal C", folder / ANYMAL, True, True)]
    notes.append("adam fails on prismatic joints (the Panda's fingers): adam and MJX run on "
                 "the Panda arm (fingers fixed), where gagen runs as well.")
    cache_dir = cache_dir or scratch / "cache"
    cands: list[Candidate] = []
    slow: list[Candidate] = []
    shown: list[str] = []  # the table's order: per model, MJX after adam
    compile_rows: list[dict] = []
    for label, urdf, floating, peers in models:
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            dyn = gagen.load(urdf, floating_base=floating, cache_dir=cache_dir)
        dyn.load_derivatives()
        Q, QD, T = _states(dyn, rng, states)
        progress(f"{label}: checking gagen's stacked call, FFI and printed functions")
        cands += gagen_candidates(label, dyn, Q, QD, T, printed, compile_rows, progress,
                                  cache_dir)
        if peers:
            progress(f"{label}: checking adam and MJX")
            cands += adam_candidates(label, dyn, urdf, Q, QD, T, notes)
            slow += mjx_candidates(label, dyn, urdf, Q, QD, T, notes)
        shown += [c.name for c in cands + slow if c.name not in shown]
    progress(f"{len(cands)} candidates; timing {repeats} interleaved repeats")
    timings = interleaved(cands, repeats, target, warmup=True)
    if slow:
        # MJX apart: on the CPU its calls take seconds over arrays of hundreds of MB, and
        # the call after one ran tens of times slower than the same call after gagen's or
        # adam's, for several calls (gagen's FFI 22 against 1.5 ms, its steady calls 1.05
        # against 0.68 ms on the Panda arm): interleaved with them it measured its own wake
        notes.append("MuJoCo MJX is timed in an interleaved run of its own, after the others "
                     "(its calls take seconds here and leave the caches cold for the next).")
        progress(f"{len(slow)} MJX candidates; timing {repeats} interleaved repeats")
        timings += interleaved(slow, repeats, target, warmup=True)
        timings.sort(key=lambda t: shown.index(t.name))
    rows = [{"model": t.info["model"], "quantity": t.info["quantity"],
             "implementation": t.info["implementation"], "call": t.info["call"],
             "states": t.info["states"], "median_ms": t.median * 1e3, "q1_ms": t.q1 * 1e3,
             "q3_ms": t.q3 * 1e3, "per_state_us": t.median / t.info["states"] * 1e6,
             "first_ms": t.first_median * 1e3, "number": t.number,
             "repeats": len(t.samples)} for t in timings]
    base = {(r["model"], r["quantity"]): r["per_state_us"] for r in rows
            if r["implementation"] == STACKED}
    for r in rows:  # per state: adam and MJX run on fewer states than the others
        r["ratio"] = r["per_state_us"] / base[(r["model"], r["quantity"])]
    notes += goal_notes(rows, compile_rows)
    return {"rows": rows, "compile": compile_rows, "notes": notes, "states": states}


def goal_notes(rows: list[dict], compile_rows: list[dict]) -> list[str]:
    """The issue's goals, met or not, from the measured rows."""
    out = []
    by = {(r["model"], r["quantity"], r["implementation"]): r["per_state_us"] for r in rows}
    first = {(r["model"], r["quantity"], r["implementation"]): r["first_ms"] / r["states"]
             for r in rows if "first_ms" in r}
    for (model, quantity, impl), ms in sorted(by.items()):
        if impl == FFI:
            base = by[(model, quantity, STACKED)]
            ratio = ms / base
            out.append(f"Goal: {model} {quantity}, FFI at most {FFI_GOAL}x the stacked C "
                       f"call: {'met' if ratio <= FFI_GOAL else 'NOT met'} ({ratio:.2f}x).")
        if impl == ADAM:
            for ours in (FFI, PRINTED):
                if (model, quantity, ours) in by:
                    speedup = ms / by[(model, quantity, ours)]
                    out.append(f"Goal: {model} {quantity}, {ours} at least {ADAM_GOAL:g}x "
                               f"adam's throughput: {'met' if speedup >= ADAM_GOAL else 'NOT met'}"
                               f" ({speedup:.1f}x{_first_calls(first, model, quantity, ours)}).")
    for row in compile_rows:
        if row["model"] == "Panda" and row["implementation"] == PRINTED:
            total = row["FD Jacobian total_s"]
            out.append(f"Goal: the printed Panda derivatives JIT in under {COMPILE_GOAL:g} s: "
                       f"{'met' if total < COMPILE_GOAL else 'NOT met'} ({total:.1f} s wall, "
                       f"{row['FD Jacobian cpu_s']:.1f} s CPU).")
    return out


def _first_calls(first: dict, model: str, quantity: str, ours: str) -> str:
    """The same ratio for the calls that follow another candidate's (the warm-up calls)."""
    theirs, mine = first.get((model, quantity, ADAM)), first.get((model, quantity, ours))
    if theirs is None or mine is None:
        return ""
    return f"; first calls after another candidate: {theirs / mine:.1f}x"


def markdown_table(rows: list[dict]) -> str:
    """The timing rows: per model and quantity, each implementation's time per batch (in a
    run of calls, and its first call after the other candidates), states per second and its
    time over the stacked call's."""
    header = ("| model | quantity | implementation | states | ms per batch | first call, ms | "
              "states/s | × stacked (per state) |")
    lines = [header, "|---|---|---|--:|--:|--:|--:|--:|"]
    for r in rows:
        rate = r["states"] / (r["median_ms"] * 1e-3)
        first = f"{r['first_ms']:.3g}" if "first_ms" in r else ""
        lines.append(f"| {r['model']} | {r['quantity']} | {r['implementation']} | "
                     f"{r['states']:,} | {r['median_ms']:.3g} | {first} | {rate:,.0f} | "
                     f"{r['ratio']:.2f} |")
    return "\n".join(lines)


def compile_table(rows: list[dict]) -> str:
    """Seconds to print (printed target, once per model) and to JIT each function."""
    header = ("| model | implementation | print | FD: trace + compile (CPU) | "
              "FD Jacobian: trace + compile (CPU) |")
    lines = [header, "|---|---|--:|--:|--:|"]
    for r in rows:
        printing = f"{r['print_s']:.1f} s" if "print_s" in r else ""
        lines.append(
            f"| {r['model']} | {r['implementation']} | {printing} | "
            f"{r['forward dynamics total_s']:.1f} s ({r['forward dynamics cpu_s']:.1f} s) | "
            f"{r['FD Jacobian total_s']:.1f} s ({r['FD Jacobian cpu_s']:.1f} s) |")
    return "\n".join(lines)
