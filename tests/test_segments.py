"""Big kernels split into segment functions (codegen/segments.py): the workspace protocol,
the statement order, and compiled modules whose kernels are split into many segments over
many files, against the same model unsplit and against the lambdify backend."""

from __future__ import annotations

import numpy as np
import pytest

from gagen.building.builder import build, import_extension
from gagen.codegen.config import CodegenConfig
from gagen.codegen.segments import Statement, schedule_late, split
from gagen.model.resolve import resolve_model
from gagen.runtime.compiled import CompiledDynamics
from gagen.runtime.lambdify import LambdifyDynamics
from gagen.symbolic.derivation import derive_equations


def _chain_program(length: int, fan: int = 3) -> list[Statement]:
    """t0 = q[0]; t_k reads a few earlier values, some far back (long live ranges)."""
    rng = np.random.default_rng(length)
    out = [Statement("t0", "q[0]", frozenset({"q[0]"}))]
    for k in range(1, length):
        reads = {f"t{int(j)}" for j in rng.integers(0, k, size=fan)} | {f"t{k - 1}"}
        out.append(Statement(f"t{k}", " + ".join(sorted(reads)), frozenset(reads)))
    return out


def _run(segments) -> dict[str, object]:
    """Execute segments symbolically: each local holds the name of the value it computes,
    w slots hold whatever was last stored; check every read sees the right value."""
    w: dict[str, str] = {}
    results = {}
    for segment in segments:
        env = {}
        for local, source in segment.imports:
            env[local] = w[source] if source.startswith("w[") else source
        for local, text in segment.locals:
            for r in text.split(" + "):
                if r.startswith("t"):
                    assert env.get(r) == r, f"{segment.name} reads {r} as {env.get(r)}"
            env[local] = local
        for slot, local in segment.exports:
            w[slot] = env[local]
        for target, text in segment.outputs:
            assert env.get(text) == text, f"output {target} reads {text} as {env.get(text)}"
            results[target] = env[text]
    return results


@pytest.mark.parametrize("length, budget", [(40, 30), (300, 100), (300, 2000)])
def test_workspace_slots_are_never_overwritten_before_their_last_read(length, budget):
    statements = _chain_program(length)
    outputs = [(f"out[{k}]", f"t{j}", frozenset({f"t{j}"}))
               for k, j in enumerate((0, length // 2, length - 1))]
    segments, workspace = split("f", ([], []), statements, outputs, segment_chars=budget)
    assert _run(segments) == {f"out[{k}]": f"t{j}" for k, j in
                              enumerate((0, length // 2, length - 1))}
    exported = {local for s in segments for _, local in s.exports}
    assert workspace <= len(exported)
    if len(segments) > 2:
        assert workspace < len(exported), "slots are reused once their value is dead"


def test_late_schedule_respects_dependencies_and_keeps_every_statement():
    statements = _chain_program(200)
    order = schedule_late(statements, [frozenset({"t199"}), frozenset({"t5"})])
    assert sorted(s.name for s in order) == sorted(s.name for s in statements)
    seen = set()
    for s in order:
        assert all(r in seen for r in s.reads if r.startswith("t")), s.name
        seen.add(s.name)


def _compiled(model, folder, config):
    path, report = build(model, out=folder, config=config)
    return CompiledDynamics(import_extension(path, report.module_name), model)


@pytest.fixture(scope="module")
def split_and_whole(tmp_path_factory):
    """chain:9 (recursive, articulated-body forward dynamics) built twice: every kernel as
    one function, and every kernel in segments of a few statements over many files."""
    model = resolve_model("chain:9")
    whole = _compiled(model, tmp_path_factory.mktemp("whole"),
                      CodegenConfig(split_chars=10**9))
    tiny = CodegenConfig(split_chars=200, segment_chars=400, file_chars=3000)
    folder = tmp_path_factory.mktemp("split")
    pieces = _compiled(model, folder, tiny)
    return model, whole, pieces, folder


def test_split_build_has_many_segments_and_files(split_and_whole):
    *_, folder = split_and_whole
    files = sorted(p.name for p in folder.glob("kernels_*.c"))
    assert len(files) >= 4
    text = "".join((folder / f).read_text() for f in files)
    assert text.count("_part") >= 40
    assert "double w[" in (folder / "inverse_dynamics.c").read_text()


def test_split_kernels_compute_what_whole_kernels_compute(split_and_whole):
    model, whole, pieces, _ = split_and_whole
    reference = LambdifyDynamics(derive_equations(model, "recursive"))
    rng = np.random.default_rng(7)
    q, qd, tau = rng.normal(size=(3, 20, model.dof))
    p = model.parameter_vector() * rng.uniform(0.8, 1.2, size=len(model.parameters))
    for name, args in (("mass_matrix", (q,)), ("forcing", (q, qd, tau)),
                       ("forward_dynamics", (q, qd, tau)), ("inverse_dynamics", (q, qd, tau)),
                       ("gravity", (q,)), ("energy", (q, qd)),
                       # straight-line code that reads the placements (centroidal.c)
                       ("center_of_mass", (q,)), ("centroidal_map", (q,)),
                       ("com_jacobian", (q,))):
        a = np.asarray(getattr(pieces, name)(*args, p=p))
        b = np.asarray(getattr(whole, name)(*args, p=p))
        c = np.asarray(getattr(reference, name)(*args, p=p))
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12 * np.abs(b).max(), err_msg=name)
        np.testing.assert_allclose(a, c, rtol=1e-10, atol=1e-10 * np.abs(c).max(), err_msg=name)


def test_split_simulation_takes_the_same_steps(split_and_whole):
    import gagen

    model, whole, pieces, _ = split_and_whole
    controller = gagen.PD(kp=50.0, kd=5.0, target=np.full(model.dof, 0.3),
                          gravity_compensation=True)
    runs = [gagen.simulate(d, (0.0, 0.5), np.zeros(model.dof), np.zeros(model.dof),
                           controller=controller, method="dopri5") for d in (whole, pieces)]
    assert runs[0].stats["nfev"] == runs[1].stats["nfev"]
    np.testing.assert_allclose(runs[0].q, runs[1].q, rtol=1e-11, atol=1e-12)


def test_articulated_body_pivots_report_singular_and_nonfinite_states(split_and_whole):
    import gagen

    model, whole, pieces, _ = split_and_whole
    n = model.dof
    zero_last = {name: 0.0 for name in (f"m{n}", f"I{n}x", f"I{n}y", f"I{n}z")}
    assert set(zero_last) <= set(model.parameters)
    for dyn in (whole, pieces):
        with pytest.raises(gagen.SingularMassMatrixError):
            dyn.forward_dynamics(np.zeros(n), np.zeros(n), np.zeros(n), p=zero_last)
        with pytest.raises(gagen.NonFiniteStateError):
            dyn.forward_dynamics(np.full(n, np.nan), np.zeros(n), np.zeros(n))


def test_split_derivative_module_computes_what_lambdify_computes(tmp_path):
    """The derivative module's kernels in segments of a few statements (its own threshold,
    `derivative_split_chars`), against the lambdify backend's derivatives."""
    model = resolve_model("chain:5")
    tiny = CodegenConfig(derivative_split_chars=200, segment_chars=400, file_chars=3000)
    main = _compiled(model, tmp_path / "main", tiny)
    path, report = build(model, out=tmp_path / "derivatives", config=tiny, derivatives=True)
    assert len(list((tmp_path / "derivatives").glob("derivative_kernels_*.c"))) >= 4
    main.bind_derivatives(import_extension(path, report.module_name))
    reference = LambdifyDynamics(derive_equations(model))
    rng = np.random.default_rng(3)
    q, qd, qdd = rng.normal(size=(3, 10, model.dof))
    for name, args in (("inverse_dynamics_derivatives", (q, qd, qdd)),
                       ("forward_dynamics_derivatives", (q, qd, qdd)),
                       ("coriolis_matrix", (q, qd))):
        for a, c in zip(_as_tuple(getattr(main, name)(*args)),
                        _as_tuple(getattr(reference, name)(*args))):
            np.testing.assert_allclose(a, c, rtol=1e-10, atol=1e-10 * np.abs(c).max(),
                                       err_msg=name)


def _as_tuple(x):
    return x if isinstance(x, tuple) else (x,)
