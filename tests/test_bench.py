"""The benchmark suite: the interleaved runner, the report writer, and `bench --smoke`."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import pytest

import gagen
from gagen.app.cli import main
from gagen.bench import timing
from gagen.bench.common import cpu_model, find_urdf_dir, machine_info
from gagen.bench.report import markdown, write_report
from gagen.bench.scaling import scaling_models
from gagen.bench.timing import Candidate, interleaved, loop_size, order, quartiles


class FakeClock:
    """A clock that only moves when a candidate says how long its call took."""

    def __init__(self):
        self.now = 0.0

    def __call__(self) -> float:
        return self.now

    def spend(self, durations):
        it = iter(durations)

        def call():
            self.now += next(it)

        return call


# ---------------------------------------------------------------------------------- timing


def test_round_robin_rotates_the_starting_candidate():
    assert order(3, 4) == [[0, 1, 2], [1, 2, 0], [2, 0, 1], [0, 1, 2]]
    log = []
    cands = [Candidate(name, log.append, (name,)) for name in "abc"]
    interleaved(cands, repeats=3, numbers=[1, 1, 1])
    assert "".join(log) == "abc" + "bca" + "cab"


def test_loop_size_applies_to_every_call_of_a_sample():
    log = []
    cands = [Candidate("a", log.append, ("a",)), Candidate("b", log.append, ("b",))]
    results = interleaved(cands, repeats=2, numbers=[2, 3])
    assert "".join(log) == "aabbb" + "bbbaa"
    assert [r.number for r in results] == [2, 3]
    assert [len(r.samples) for r in results] == [2, 2]


def test_median_iqr_and_ratio_on_a_fake_clock():
    clock = FakeClock()
    a = Candidate("a", clock.spend([1.0, 5.0, 3.0, 2.0, 4.0]))
    b = Candidate("b", clock.spend([6.0] * 5))
    ta, tb = interleaved([a, b], repeats=5, numbers=[1, 1], clock=clock, baseline="a")
    assert ta.samples == [1.0, 5.0, 3.0, 2.0, 4.0]
    assert (ta.q1, ta.median, ta.q3, ta.iqr, ta.min) == (2.0, 3.0, 4.0, 2.0, 1.0)
    assert tb.median == 6.0 and tb.iqr == 0.0
    assert ta.ratio == 1.0 and tb.ratio == 2.0 and tb.baseline == "a"
    row = tb.as_dict()
    assert row["median_s"] == 6.0 and row["repeats"] == 5 and row["ratio"] == 2.0


def test_a_sample_is_the_loop_time_over_the_loop_size():
    clock = FakeClock()
    (t,) = interleaved([Candidate("a", clock.spend([1.0, 3.0, 2.0, 2.0]))], repeats=2,
                       numbers=[2], clock=clock)
    assert t.samples == [2.0, 2.0]


def test_ratios_per_group():
    clock = FakeClock()
    cands = [Candidate("x1", clock.spend([1.0] * 3), group="x"),
             Candidate("x2", clock.spend([3.0] * 3), group="x"),
             Candidate("y1", clock.spend([2.0] * 3), group="y"),
             Candidate("y2", clock.spend([1.0] * 3), group="y"),
             Candidate("z", clock.spend([1.0] * 3), group="z")]
    res = interleaved(cands, repeats=3, numbers=[1] * 5, clock=clock,
                      baseline={"x": "x1", "y": "y1"})
    assert [r.ratio for r in res] == [1.0, 3.0, 1.0, 0.5, None]
    with pytest.raises(KeyError):
        timing.apply_baseline(res, "nobody")


def test_quartiles_match_linear_interpolation():
    values = [0.3, 0.1, 0.7, 0.2, 0.9, 0.4]
    expected = np.percentile(values, [25, 50, 75])
    np.testing.assert_allclose(quartiles(values), expected)
    assert quartiles([2.5]) == (2.5, 2.5, 2.5)
    with pytest.raises(ValueError):
        quartiles([])


def test_loop_is_sized_to_the_target():
    clock = FakeClock()
    timer = Candidate("a", clock.spend([1e-4] * 10_000)).timer(clock)
    assert loop_size(timer, target=0.02) == 200


def test_a_slow_first_call_does_not_size_the_loop():
    clock = FakeClock()
    timer = Candidate("a", clock.spend([0.5] + [1e-4] * 10_000)).timer(clock)
    assert loop_size(timer, target=0.02) == 200


def test_warmup_calls_are_timed_apart_from_the_samples():
    clock = FakeClock()
    log = []

    def call(name, durations):
        spend = clock.spend(durations)
        return lambda: (log.append(name), spend())

    a = Candidate("a", call("a", [9.0, 1.0, 1.0, 8.0, 3.0, 3.0]))
    b = Candidate("b", call("b", [7.0, 2.0, 6.0, 2.0]))
    ta, tb = interleaved([a, b], repeats=2, numbers=[2, 1], clock=clock, warmup=True)
    assert "".join(log) == "aaabb" + "bbaaa"
    assert ta.first == [9.0, 8.0] and ta.samples == [1.0, 3.0]
    assert tb.first == [7.0, 6.0] and tb.samples == [2.0, 2.0]
    assert ta.as_dict()["first_median_s"] == 8.5
    (tc,) = interleaved([Candidate("c", clock.spend([1.0] * 2))], repeats=2, numbers=[1],
                        clock=clock)
    assert tc.first == [] and "first_median_s" not in tc.as_dict()


def test_candidate_names_must_be_unique():
    with pytest.raises(ValueError):
        interleaved([Candidate("a", len, ("x",)), Candidate("a", len, ("y",))], numbers=[1, 1])


def test_real_calls_are_timed():
    (t,) = interleaved([Candidate("sum", sum, ([1.0, 2.0],))], repeats=3, target=1e-3)
    assert len(t.samples) == 3 and t.number >= 1 and 0 < t.median < 1e-3


# ---------------------------------------------------------------------------------- report


def synthetic_results() -> dict:
    machine = machine_info()
    machine["cpu"] = "Test CPU 9000"
    percall = [{"quantity": q, "implementation": impl, "call": "f(x)", "median_us": m,
                "q1_us": 0.9 * m, "q3_us": 1.1 * m, "iqr_us": 0.2 * m, "ratio": r,
                "baseline": "gagen compiled", "number": 1000, "repeats": 5}
               for q, impl, m, r in [("forward dynamics", "gagen compiled", 0.2, 1.0),
                                     ("forward dynamics", "Pinocchio", 1.5, 7.5),
                                     ("mass matrix", "gagen compiled", 0.3, 1.0)]]
    batched = [{"backend": b, "N": n, "call": "fd", "median_s": n * k * 1e-9,
                "q1_s": 0.0, "q3_s": 0.0, "ns_per_state": k, "iqr_ns_per_state": 1.0,
                "ratio": k / 60.0, "baseline": "compiled", "number": 10, "repeats": 5}
               for n in (1, 10) for b, k in (("compiled", 60.0), ("lambdify", 6000.0))]
    simulation = [{"case": c, "label": label, "backend": "x", "method": m, "median_s": s,
                   "q1_s": 0.9 * s, "q3_s": 1.1 * s, "min_s": s, "repeats": 3, "calls": 1,
                   "steps": 301, "nfev": 1820, "final_q_deg": [-60.0, -60.0, -30.0],
                   "max_dev_rad": 1e-15, "speedup": 0.15 / s}
                  for c, label, m, s in [("a", "scipy RK45, lambdify backend", "RK45", 0.15),
                                         ("c", "compiled dopri5", "dopri5", 3e-4)]]
    scaling = [{"model": name, "dof": n, "derive_s": 0.1 * n, "generate_s": 0.1 * n,
                "compile_s": 5.0, "build_s": 5.5, "peak_mb": 300.0, "ops_before_cse": 100 * n,
                "ops_after_cse": 80 * n, "load_s": 0.01, "cached": False,
                "fd_us": 0.1 * n, "id_us": 0.05 * n, "M_us": 0.08 * n,
                "pin_fd_us": 0.5 * n, "pin_id_us": 0.2 * n, "pin_M_us": 0.2 * n,
                "fd_state_us": 0.09 * n, "id_state_us": 0.04 * n, "M_state_us": 0.07 * n,
                "cpp_fd_us": float("nan"), "cpp_id_us": float("nan"), "cpp_M_us": float("nan")}
               for name, n in (("chain:2", 2), ("chain:4", 4), ("ur5", 6))]
    return {"machine": machine,
            "settings": {"mode": "default", "command": "python -m gagen bench",
                         "target_s": 0.02},
            "elapsed_s": 83.0,
            "notes": ["PyDy is not installed: its row is skipped."],
            "percall": {"rows": percall, "repeats": 5},
            "batched": {"rows": batched, "repeats": 5},
            "simulation": {"rows": simulation, "repeats": 3},
            "scaling": {"rows": scaling, "repeats": 5},
            "panda": {"error": "RuntimeError: no panda"}}


def test_report_has_the_tables_the_machine_and_the_plots(tmp_path):
    path = write_report(synthetic_results(), tmp_path)
    text = path.read_text()
    assert "| CPU | Test CPU 9000" in text
    for header in (("| quantity | implementation | call | median µs | IQR µs (q1–q3) "
                   "| ratio to gagen compiled |"),
                   ("| N | compiled ns/state (IQR) | lambdify ns/state (IQR) "
                   "| lambdify / compiled |"),
                   "| case | method | median | spread (quartiles) |",
                   ("| model | dof | derive s | generate s | compile s | build s | peak MB "
                   "| FD µs (Pinocchio ×) |")):
        assert header in text, header
    assert "| chain:4 | 4 | 0.40 | 0.40 | 5.00 | 5.5 | 300 | 0.40 (5.0×) |" in text
    assert "| forward dynamics | Pinocchio | `f(x)` | 1.50 |" in text
    assert "| 10 | 60.0 (1.0) | 6,000 (1.0) | 100 |" in text
    assert "**Failed:** `RuntimeError: no panda`" in text
    assert "- PyDy is not installed" in text
    assert "1 min 23 s" in text
    for png in ("percall.png", "batched.png", "simulation.png", "scaling.png"):
        assert (tmp_path / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert f"]({png})" in text


def test_report_leaves_out_sections_that_did_not_run():
    results = synthetic_results()
    for key in ("batched", "simulation", "scaling", "panda"):
        del results[key]
    text = markdown(results)
    assert "Per call on rrr" in text and "Scaling" not in text and "Batched" not in text


def test_machine_info_names_cpu_and_versions():
    info = machine_info()
    assert info["cpu"] == cpu_model() and info["cpu"]
    assert info["cores"] >= 1
    for key in ("python", "numpy", "sympy", "cython", "compiler", "gagen", "date"):
        assert info[key], key


# ------------------------------------------------------------------------- URDFs and CLI


def test_urdf_dir_is_found_or_skipped_with_a_note(tmp_path):
    assert find_urdf_dir(tmp_path) is None
    (tmp_path / "ur5_robot.urdf").write_text("<robot/>")
    assert find_urdf_dir(tmp_path) == tmp_path
    models, notes = scaling_models(full=False, urdf_dir=tmp_path)
    assert models == ["chain:2", "chain:4", "chain:6", str(tmp_path / "ur5_robot.urdf")]
    assert notes == []
    models, notes = scaling_models(full=True, urdf_dir=tmp_path)
    assert models[:8] == [f"chain:{n}" for n in (5, 10, 15, 20, 24, 30, 40, 50)]
    assert len(notes) == 5 and "panda.urdf" in notes[0] and "tiago.urdf" in notes[-1]
    models, notes = scaling_models(full=False, urdf_dir=tmp_path / "nowhere")
    assert models == ["chain:2", "chain:4", "chain:6"] and "ur5_robot.urdf" in notes[0]


def test_a_section_gives_the_load_average_at_its_start_and_end():
    results = synthetic_results()
    results["percall"].update(elapsed_s=12.0, load=[0.5, 1.75])
    results["batched"].update(elapsed_s=3.0, load=["=cmd()", 1.0])  # not numbers: left out
    results["simulation"].update(elapsed_s=4.0)  # none recorded (a platform without one)
    text = markdown(results)
    assert ("_Section time: 12.0 s; the machine's 1-minute load average 0.5 at its start and "
            "1.8 at its end._") in text
    assert "_Section time: 3.0 s._" in text and "_Section time: 4.0 s._" in text
    assert "=cmd()" not in text


@pytest.mark.slow
def test_bench_smoke_run_writes_the_report(tmp_path, cache_dir, capsys):
    out = tmp_path / "bench"
    assert main(["bench", "--out", str(out), "--smoke", "--cache-dir", str(cache_dir)]) == 0
    progress = capsys.readouterr().out
    for section in ("per call", "batched", "simulation", "throughput", "scaling", "derivatives",
                    "report"):
        assert f"] {section}:" in progress, section
    text = (out / "report.md").read_text()
    assert f"| CPU | {cpu_model()}" in text
    assert "(smoke mode)" in text and "| chain:2 | 2 |" in text
    for header in ("## Per call on rrr", "## Batched forward dynamics",
                   "## The paper's 5-s simulation", "## Scaling"):
        assert header in text
    results = json.loads((out / "results.json").read_text(),
                         parse_constant=lambda c: pytest.fail(f"{c} in results.json"))
    rows = results["percall"]["rows"]
    impls = {r["implementation"] for r in rows}
    assert {"gagen compiled", "gagen lambdify", "SymPy lambdify (naive)"} <= impls
    assert all(math.isfinite(r["median_us"]) and r["median_us"] > 0 for r in rows)
    assert {r["N"] for r in results["batched"]["rows"]} == {1, 10, 100}
    assert [r["case"] for r in results["simulation"]["rows"]] == ["a", "b", "c", "d"]
    tp = results["throughput"]["rows"]
    assert [r["candidate"] for r in tp][0::2] == ["gagen, 1 thread",
                                                  "Python loop over gagen.simulate"]
    assert all(r["sims_per_s"] > 0 and r["runs"] == 8 for r in tp)
    assert "## Throughput: many simulations at once" in text
    assert [r["model"] for r in results["scaling"]["rows"]] == ["chain:2"]
    dv = results["derivatives"]
    assert {(r["quantity"], r["implementation"]) for r in dv["rows"]} >= {
        ("forward dynamics derivatives", "gagen compiled"),
        ("forward dynamics derivatives", "gagen central differences"),
        ("inverse dynamics derivatives", "gagen compiled"), ("Coriolis matrix", "gagen compiled")}
    assert [(r["model"], r["module"]) for r in dv["builds"]] == [("rrr", "main"),
                                                                ("rrr", "derivatives")]
    assert "## The derivatives per call" in text
    for png in ("percall.png", "batched.png", "simulation.png", "scaling.png"):
        assert (out / png).exists()
    if hasattr(os, "getloadavg"):
        for key in ("percall", "batched", "simulation", "throughput", "scaling", "derivatives"):
            start, end = results[key]["load"]
            assert 0 <= start < 1000 and 0 <= end < 1000, key
        assert "1-minute load average" in text


def test_scaling_table_shows_both_cpp_peers():
    """The batched columns give the C++ loop's ratio leaving its results and storing them."""
    from gagen.bench.scaling import markdown_table

    row = dict(synthetic_results()["scaling"]["rows"][2])
    row.update({"M_state_us": 2.0, "cpp_M_us": 1.8, "cpp_stored_M_us": 4.0})
    table = markdown_table([row])
    assert "C++ storing ×" in table.splitlines()[0]
    assert table.splitlines()[2].endswith("| 2.00 (0.9×, 2.0×) |")


def test_centroidal_goal_is_judged_on_ccrba_and_dccrba():
    from gagen.bench.centroidal import goal_notes

    robot = "anymal (floating, nv = 18)"
    rows = [{"quantity": f"{robot}: A_g", "implementation": "Pinocchio", "ratio": 1.1},
            {"quantity": f"{robot}: A_g", "implementation": "Pinocchio ccrba (A_g and h_g)",
             "ratio": 2.1},
            {"quantity": f"{robot}: A_g and its bias d/dt A_g qd",
             "implementation": "Pinocchio", "ratio": 1.2}]
    first, second = goal_notes(rows)
    assert "ccrba" in first and first.endswith("met (2.10x).") and "NOT" not in first
    assert "dccrba" in second and second.endswith("NOT met (1.20x).")


# --------------------------------------------------- the derivatives' floating-base peers

def test_derivative_goal_and_build_notes_and_the_casadi_table():
    from gagen.bench.derivatives import build_notes, casadi_table, goal_note

    rows = [{"model": "ANYmal C", "quantity": "inverse dynamics derivatives",
             "implementation": implementation, "median_us": us}
            for implementation, us in (("gagen compiled", 2.0), ("Pinocchio", 5.0))]
    note = goal_note(rows, "ANYmal C", "inverse dynamics derivatives", 2.0)
    assert note.startswith("Goal: ANYmal C's inverse dynamics derivatives") and "met (2.50x" in note
    assert "NOT met" in goal_note(rows, "ANYmal C", "inverse dynamics derivatives", 3.0)
    assert goal_note(rows, "ANYmal C") is None  # no forward-dynamics rows
    builds = [{"model": "anymal (floating)", "module": "main", "wall_s": 12.0},
              {"model": "anymal (floating)", "module": "derivatives", "wall_s": 9.0}]
    assert build_notes(builds, ["anymal (floating)"]) == [
        ("Goal: anymal (floating)'s derivative module built cold no slower than its main "
         "module: met (9.0 s against 12.0 s).")]
    table = casadi_table([{"model": "ANYmal C", "nv": 18, "gagen_us": 4.0, "casadi_us": 60.0,
                           "ratio": 15.0}])
    assert table.splitlines()[2] == "| ANYmal C | 18 | 4.00 | 60.00 | 15.00 |"


def test_adam_and_casadi_agree_with_gagen_on_a_floating_base():
    """The CasADi peer's conventions (BODY_FIXED velocities, q's layout, the Jacobian's
    columns) checked against gagen's forward dynamics and its derivatives."""
    pytest.importorskip("casadi")
    pytest.importorskip("adam")
    from gagen.bench.casadi_c import CasadiPeer, check

    path = Path(__file__).resolve().parent / "data" / "urdf" / "double_pendulum.urdf"
    dyn = gagen.load(path, floating_base=True, backend="lambdify")
    g = dict(zip(dyn.parameters, dyn.parameter_vector()))["g"]
    peer = CasadiPeer(path, dyn.coordinates[6:], g)
    check(dyn, peer, np.random.default_rng(1))
    wrong = CasadiPeer(path, dyn.coordinates[6:], g + 1.0)
    with pytest.raises(RuntimeError, match="disagree"):
        check(dyn, wrong, np.random.default_rng(1))


def test_casadi_objects_are_compiled_once_and_a_held_lock_is_waited_for_within_the_limit(
        tmp_path):
    """bench/casadi_c.compiled_object: the object is kept under its source's hash and reused;
    while another run holds the source's lock, a second waits, and gives up with a note
    once the limit has passed instead of compiling the same C again."""
    import fcntl

    from gagen.bench.casadi_c import _compiler, compiled_object

    if _compiler() is None:
        pytest.skip("no C compiler")
    source = tmp_path / "peer.c"
    source.write_text("double peer(double x) { return 2.0 * x; }\n")
    folder = tmp_path / "objects"
    obj, why = compiled_object(source, folder)
    assert why == "" and obj.is_file() and obj.parent == folder
    built = obj.stat().st_mtime_ns
    assert compiled_object(source, folder) == (obj, "") and obj.stat().st_mtime_ns == built
    source.write_text("double peer(double x) { return 3.0 * x; }\n")
    probe, _ = compiled_object(source, tmp_path / "probe")  # the new source's object name
    with open(folder / f"{probe.stem}.lock", "w") as lock:  # held as a compiling run holds it
        fcntl.flock(lock, fcntl.LOCK_EX)
        late, why = compiled_object(source, folder, limit=0.5)
    assert late is None and "did not compile within" in why
    assert not (folder / probe.name).exists()
    assert compiled_object(source, folder) == (folder / probe.name, "")
