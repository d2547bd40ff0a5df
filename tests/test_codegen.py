"""Generated C: golden files, reproducibility, standalone use, identifiers, the build cache."""

from __future__ import annotations

import hashlib
import os
import re
import shutil
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from conftest import REPO

import gagen
from gagen.building.builder import build, generate_sources, module_name_for, source_key
from gagen.codegen.render import COPIED_FILES, MODEL_C_FILES, MODULE_FILE, generate
from gagen.model.modelfile import parse_model_text
from gagen.sim.controllers import paper_controller
from gagen.sim.simulate import simulate

GOLDEN = REPO / "generated" / "rrr"
UPDATE = ("python -m gagen build rrr --out generated/rrr   (or GAGEN_UPDATE_GOLDEN=1 pytest "
          "tests/test_codegen.py)")
GENERATOR_CHANGED = ("the generator changed (its code or templates under symbolic/ and "
                     "codegen/, or the model rrr, or gagen's version): its key is {new}, the "
                     "golden files in generated/rrr were written with {old}, and its C for "
                     "'rrr' differs from them{files}. If that change is intended, update the "
                     "golden files with:  " + UPDATE)
EDITED = ("generated/rrr/{name} differs from what the generator writes under the same key "
          "({new}): the golden file was edited by hand, or generation is not reproducible; "
          "restore it with:  " + UPDATE)
KEY_LINE = re.compile(r'"KEY", "([0-9a-f]{64})"')
needs_gcc = pytest.mark.skipif(shutil.which("gcc") is None, reason="gcc is not installed")


def rrr_code():
    model = gagen.resolve_model("rrr")
    key = source_key(model)
    return generate(gagen.derive(model), module_name_for(model, key), key)


def golden_mismatch(files: dict[str, str], folder=GOLDEN) -> str | None:
    """Why the generated files differ from the golden ones in `folder` (None if they do
    not): the generator's key changed (its module.c carries the key, which hashes the
    generator's code and templates), or a golden file differs under the same key."""
    committed = {p.name for p in folder.iterdir() if p.suffix in (".c", ".h", ".pyx")
                 and not (p.suffix == ".c" and p.name.startswith("gagen_"))}
    differing = sorted(name for name in set(files) | committed
                       if name not in files or name not in committed
                       or (folder / name).read_text() != files[name])
    if not differing:
        return None
    new = KEY_LINE.search(files[MODULE_FILE]).group(1)
    old = KEY_LINE.search((folder / MODULE_FILE).read_text()) \
        if MODULE_FILE in committed else None
    if old is None or old.group(1) != new:
        others = [name for name in differing if name != MODULE_FILE]
        listed = f" ({', '.join(others)} besides module.c's key)" if others else \
            " (only in module.c's key)"
        return GENERATOR_CHANGED.format(new=new[:12], old=old.group(1)[:12] if old else
                                        "no key", files=listed)
    return EDITED.format(name=", ".join(differing), new=new[:12])


def test_generated_rrr_matches_golden_files():
    code = rrr_code()
    if os.environ.get("GAGEN_UPDATE_GOLDEN"):
        for old in GOLDEN.glob("gagen_*.pyx"):  # the Cython wrapper of older gagens
            old.unlink()
        GOLDEN.mkdir(parents=True, exist_ok=True)
        for name, text in code.files.items():
            (GOLDEN / name).write_text(text)
    mismatch = golden_mismatch(code.files)
    assert mismatch is None, mismatch


def test_the_golden_test_says_what_changed(tmp_path, monkeypatch):
    """A new generator (another key in module.c) is named as such, with the files whose C
    changed; a golden file edited under the same key is named as edited."""
    from gagen.building import builder

    code = rrr_code()
    golden = tmp_path / "golden"
    golden.mkdir()
    for name, text in code.files.items():
        (golden / name).write_text(text)
    assert golden_mismatch(code.files, golden) is None
    monkeypatch.setattr(builder, "generator_digest", lambda: "a changed generator")
    changed = rrr_code()
    message = golden_mismatch(changed.files, golden)
    assert message.startswith("the generator changed") and "update the golden" in message
    assert "edited" not in message and "(only in module.c's key)" in message
    assert KEY_LINE.search(changed.files[MODULE_FILE]).group(1)[:12] in message
    (golden / "rhs.c").write_text(code.files["rhs.c"] + "/* by hand */\n")
    message = golden_mismatch(code.files, golden)
    assert message.startswith("generated/rrr/rhs.c differs") and "edited by hand" in message
    assert "(rhs.c besides module.c's key)" in golden_mismatch(changed.files, golden)


def test_every_template_is_in_the_generator_key(tmp_path, monkeypatch):
    """Editing any file under codegen/templates (.h, .c, .j2; a file of any other kind
    there would fail this test until the key covers it) changes the generator's digest and
    with it the key of every build and of the index: the build key (source_key) and the
    input key (input_key). Checked on a copy of the stages the keys read."""
    from types import SimpleNamespace

    from gagen.building import cache
    from gagen.building.builder import source_key

    source = REPO / "src" / "gagen"
    copy = tmp_path / "gagen"
    for package in cache.PIPELINE_PACKAGES:
        shutil.copytree(source / package, copy / package,
                        ignore=shutil.ignore_patterns("__pycache__"))
    model = gagen.resolve_model("rrr")

    def keys() -> tuple[str, str]:
        cache._packages_digest.cache_clear()
        return source_key(model), cache.input_key("rrr", ["-O3"])

    templates = sorted(p for p in (copy / "codegen" / "templates").rglob("*") if p.is_file())
    assert len(templates) >= 20 and {p.suffix for p in templates} == {".h", ".c", ".j2"}
    try:
        real = keys()
        monkeypatch.setattr(cache, "resources", SimpleNamespace(
            files=lambda name: copy / name.split(".")[-1]))
        assert keys() == real  # the copy is hashed as the package is
        for template in templates:
            text = template.read_bytes()
            template.write_bytes(text + b"\n")
            edited = keys()
            template.write_bytes(text)
            assert edited[0] != real[0] and edited[1] != real[1], template.name
    finally:
        monkeypatch.undo()
        cache._packages_digest.cache_clear()
    assert keys() == real


def test_generation_is_byte_identical_across_processes(tmp_path):
    # also with the kernels split into segment functions (workspace slots, imports, exports)
    script = textwrap.dedent("""
        import sys
        from pathlib import Path
        import gagen
        from gagen.building.builder import generate_sources
        from gagen.codegen.config import CodegenConfig
        model = gagen.resolve_model(sys.argv[1])
        generate_sources(model, Path(sys.argv[2]) / "whole")
        generate_sources(model, Path(sys.argv[2]) / "split",
                         config=CodegenConfig(split_chars=1_000, segment_chars=300))
    """)
    digests = []
    for seed in ("1", "2"):
        out = tmp_path / seed
        env = dict(os.environ, PYTHONHASHSEED=seed)
        subprocess.run([sys.executable, "-c", script, "chain:4", str(out)], check=True, env=env)
        digests.append({str(p.relative_to(out)): hashlib.sha256(p.read_bytes()).hexdigest()
                        for p in sorted(out.rglob("*")) if p.is_file()})
    assert any(name.startswith("split/kernels_") for name in digests[0])
    assert digests[0] == digests[1]


def test_every_file_has_the_generated_header():
    code = rrr_code()
    for name, text in code.files.items():
        first = text.splitlines()[0]
        assert "generated by gagen" in first and "do not edit" in first, name
        assert "'rrr'" in first and gagen.__version__ in first, name


def test_generated_c_is_standalone_and_has_no_globals():
    code = rrr_code()
    for name in (*MODEL_C_FILES, "rrr.h", *COPIED_FILES):
        assert "Python.h" not in code.files[name], name
    for name in ("mass_matrix.c", "rhs.c", "inverse_dynamics.c", "rrr.h"):
        assert "static" not in code.files[name], name
    # simulation.c's own functions are static; its only data are gagen_ode.h's constant
    # tableaus (test_compiled_objects_define_no_global_data checks the object file)
    assert re.search(r"static\s+(?!int|void|inline|const double gagen_dp_)", code.files[
        "simulation.c"] + code.files["gagen_second_order.h"]) is None


STANDALONE_MAIN = r"""
#include <stdio.h>
#include "rrr.h"
int main(void) {
    const double p[RRR_NP] = {%(params)s};
    const double q[3] = {0.3, -0.7, 1.1}, qd[3] = {0.5, -1.5, 2.0}, tau[3] = {1.0, 20.0, -5.0};
    double M[9], F[3], qdd[3], back[3], TV[2], G[3], u[3], gqdd[3];
    rrr_mass_matrix(q, p, M);
    rrr_forcing(q, qd, tau, p, F);
    if (rrr_forward_dynamics(q, qd, tau, p, qdd) != 0) return 3;
    rrr_inverse_dynamics(q, qd, qdd, p, back);
    rrr_energy(q, qd, p, TV);
    for (int i = 0; i < 9; ++i) printf("%%.17g\n", M[i]);
    for (int i = 0; i < 3; ++i) printf("%%.17g\n", qdd[i]);
    for (int i = 0; i < 3; ++i) printf("%%.17g\n", back[i]);
    printf("%%.17g\n%%.17g\n", TV[0], TV[1]);
    /* forward dynamics with gravity compensation: qdd under tau + gravity(q) */
    rrr_gravity(q, p, G);
    for (int i = 0; i < 3; ++i) u[i] = tau[i] - G[i];
    if (rrr_forward_dynamics_gc(q, qd, u, p, gqdd) != 0) return 4;
    for (int i = 0; i < 3; ++i) printf("%%.17g\n", gqdd[i]);
    /* the paper's direct dynamics, 1 s under its PD law with gravity compensation */
    const double kp[3] = {500, 300, 200}, kd[3] = {300, 150, 100};
    const double target[3] = {-1.0471975511965976, -1.0471975511965976, -0.5235987755982988};
    const gagen_control law = {GAGEN_CTRL_PD, kp, kd, target, 1, NULL, NULL, 0.0,
                                NULL, NULL, NULL, 0, NULL, NULL};
    const double y0[6] = {0}, atol[6] = {1e-8, 1e-8, 1e-8, 1e-8, 1e-8, 1e-8}, t_end = 1.0;
    double y[6];
    gagen_ode_stats stats;
    if (rrr_simulate(GAGEN_METHOD_DOPRI5, &law, p, 0.0, 1.0, y0, 1e-6, atol, 0.0, 0.0, 0, 0.0,
                     &t_end, 1, y, &stats) != 0) return 5;
    for (int i = 0; i < 6; ++i) printf("%%.17g\n", y[i]);
    printf("%%ld\n", stats.nfev);
    return 0;
}
"""


@needs_gcc
def test_standalone_c_program_computes_the_same_numbers(tmp_path):
    code = rrr_code()
    for name, text in code.files.items():
        (tmp_path / name).write_text(text)
    dyn = gagen.load("rrr", backend="lambdify")
    params = ", ".join(repr(v) for v in dyn.parameters.values())
    (tmp_path / "main.c").write_text(STANDALONE_MAIN % {"params": params})
    exe = tmp_path / "rrr_demo"
    kernels = [f for f in MODEL_C_FILES if f != "integrator.c"]
    subprocess.run(["gcc", "-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-pedantic",
                    "-o", str(exe), "main.c", *kernels, "-lm"], cwd=tmp_path, check=True)
    values = np.array(subprocess.run([str(exe)], capture_output=True, text=True,
                                     check=True).stdout.split(), dtype=float)
    q, qd, tau = np.array([0.3, -0.7, 1.1]), np.array([0.5, -1.5, 2.0]), np.array([1.0, 20, -5])
    qdd = dyn.forward_dynamics(q, qd, tau)
    np.testing.assert_allclose(values[:9], dyn.mass_matrix(q).ravel(), rtol=1e-13)
    np.testing.assert_allclose(values[9:12], qdd, rtol=1e-12)
    np.testing.assert_allclose(values[12:15], tau, rtol=1e-11, atol=1e-11)
    np.testing.assert_allclose(values[15:17], dyn.energy(q, qd), rtol=1e-13)
    # forward_dynamics_gc(u = tau - g) is forward_dynamics(tau)
    np.testing.assert_allclose(values[17:20], qdd, rtol=1e-12)
    # rrr_simulate is gagen.simulate's compiled dopri5
    compiled = gagen.load("rrr")
    res = simulate(compiled, (0.0, 1.0), np.zeros(3), None, paper_controller(),
                   method="dopri5", t_eval=[1.0])
    np.testing.assert_allclose(values[20:26], np.hstack([res.q[0], res.qd[0]]), rtol=1e-10)
    assert values[26] == res.stats["nfev"]


@needs_gcc
def test_compiled_objects_define_no_global_data(tmp_path):
    code = rrr_code()
    for name, text in code.files.items():
        (tmp_path / name).write_text(text)
    for src in MODEL_C_FILES:
        obj = tmp_path / (src + ".o")
        subprocess.run(["gcc", "-std=c99", "-O2", "-c", src, "-o", str(obj)], cwd=tmp_path,
                       check=True)
        symbols = subprocess.run(["nm", str(obj)], capture_output=True, text=True,
                                 check=True).stdout.split("\n")
        data = [s for s in symbols if len(s.split()) == 3 and s.split()[1] in "BDdbCG"]
        assert data == [], f"{src} defines global or static data: {data}"


UNUSUAL = """
name: "my robot-1.v2"
parameters: {"m.1": 2.0, "I_{xx}": 0.3, "int": 0.5, "g": 9.81}
bodies:
  - name: "arm link"
    joint: {name: "joint 1", type: revolute, axis: [0, 1, 1]}
    mass: m.1
    com: [int, 0, 0]
    inertia: ["I_{xx}", 0.2, 0.25, 0, 0, 0]
  - name: second
    parent: "arm link"
    joint: {name: "2nd", type: prismatic, origin: {xyz: [int, 0, 0], rpy: [0.1, 0.2, 0.3]}}
    mass: 1.5
    inertia: [0.1, 0.1, 0.1, 0, 0, 0]
"""


def test_unusual_names_give_valid_c(cache_dir):
    model = parse_model_text(UNUSUAL, "unusual.yaml")
    compiled = gagen.load(model, cache_dir=cache_dir)
    reference = gagen.load(model, backend="lambdify")
    assert compiled.coordinates == ["joint 1", "2nd"]
    rng = np.random.default_rng(5)
    for _ in range(5):
        q, qd, tau = rng.normal(size=(3, 2))
        np.testing.assert_allclose(compiled.forward_dynamics(q, qd, tau),
                                   reference.forward_dynamics(q, qd, tau), rtol=1e-12)
        p = {"m.1": 3.0, "I_{xx}": 0.35}
        np.testing.assert_allclose(compiled.mass_matrix(q, p), reference.mass_matrix(q, p),
                                   rtol=1e-12)


def test_fast_math_is_opt_in_and_cached_separately(tmp_path):
    model = gagen.resolve_model("chain:2")
    plain, _ = build(model, cache_dir=tmp_path)
    fast, _ = build(model, cache_dir=tmp_path, fast_math=True)
    assert plain != fast and plain.exists() and fast.exists()
    again, report = build(model, cache_dir=tmp_path)
    assert again == plain and report.cached


def test_changed_model_never_loads_stale_module(tmp_path):
    text = (REPO / "src" / "gagen" / "model" / "rrr.yaml").read_text()
    path = tmp_path / "arm.yaml"
    path.write_text(text)
    first = gagen.load(path, cache_dir=tmp_path / "cache")
    q = np.array([0.1, 0.5, -0.3])
    path.write_text(text.replace("L2: 0.4", "L2: 0.9"))
    second = gagen.load(path, cache_dir=tmp_path / "cache")
    assert first.module.KEY != second.module.KEY
    assert not np.allclose(first.mass_matrix(q), second.mass_matrix(q))
    reference = gagen.load(path, backend="lambdify")
    np.testing.assert_allclose(second.mass_matrix(q), reference.mass_matrix(q), rtol=1e-12)


def test_concurrent_builds_of_one_model_both_succeed(tmp_path):
    script = ("import sys, gagen, numpy as np; d = gagen.load('chain:3', cache_dir=sys.argv[1]);"
              "print(d.forward_dynamics(np.zeros(3), np.zeros(3), np.ones(3))[0])")
    procs = [subprocess.Popen([sys.executable, "-c", script, str(tmp_path)],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for _ in range(2)]
    outputs = [p.communicate(timeout=600) for p in procs]
    assert [p.returncode for p in procs] == [0, 0], outputs
    assert outputs[0][0] == outputs[1][0]
    entries = [p for p in tmp_path.iterdir() if not p.name.startswith(".") and p.name != "index"]
    assert len(entries) == 1
    leftovers = [p for p in tmp_path.iterdir() if p.name.startswith(".")]
    assert leftovers == []


def test_interrupted_build_leaves_nothing_loadable(tmp_path, monkeypatch):
    from gagen.building import builder as build_module

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(build_module, "compile_sources", interrupted)
    with pytest.raises(KeyboardInterrupt):
        gagen.load("chain:2", cache_dir=tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_compiler_errors_are_shown(tmp_path, monkeypatch):
    from gagen.building import builder as build_module

    real = build_module.generate_sources

    def broken(model, folder, *args, **kwargs):
        report = real(model, folder, *args, **kwargs)
        (folder / "rhs.c").write_text("this is not C;\n")
        return report

    monkeypatch.setattr(build_module, "generate_sources", broken)
    with pytest.raises(build_module.BuildError, match="rhs.c") as info:
        gagen.load("chain:2", cache_dir=tmp_path)
    message = str(info.value)
    assert "error" in message and "this is not C" in message  # the compiler's own words
    assert "Traceback" not in message and "distutils" not in message


def test_sources_only_generation_writes_every_file(tmp_path):
    report = generate_sources(gagen.resolve_model("rrr"), tmp_path)
    names = {p.name for p in tmp_path.iterdir()}
    assert {*MODEL_C_FILES, *COPIED_FILES, "rrr.h", MODULE_FILE} == names
    assert report.ops_after_cse < report.ops_before_cse


def test_small_models_inline_their_stages_and_large_ones_call_them():
    """simulation.c puts the position and velocity stages inline into the integrators only
    when they are small (INLINE_STAGE_OPS): a dozen copies of a large one compile slowly."""
    from gagen.codegen.render import INLINE_STAGE_OPS
    from gagen.symbolic.gibbs_appell import derive

    for name, inline in (("rrr", True), ("chain:4", False)):
        text = generate(derive(gagen.resolve_model(name)), "m", "k").files["simulation.c"]
        ops = int(re.search(r"The two stages have (\d+) operations", text).group(1))
        assert (ops <= INLINE_STAGE_OPS) == inline, (name, ops)
        assert ("always_inline" in text) == inline, name


def test_the_codegen_config_chooses_libm_trig_and_inlining():
    from gagen.codegen.config import CodegenConfig
    from gagen.codegen.render import generate

    eqs = gagen.derive(gagen.resolve_model("rrr"))
    fast = generate(eqs, "gagen_rrr_x", "k").files
    plain = generate(eqs, "gagen_rrr_x", "k", CodegenConfig(fast_trig=False,
                                                            inline_stage_ops=0)).files
    assert "gagen_sincos" in fast["rhs.c"] and "gagen_sincos" not in plain["rhs.c"]
    assert " = sin(q[" in plain["rhs.c"]
    assert "always_inline" in fast["simulation.c"]
    assert "always_inline" not in plain["simulation.c"]


def test_a_mostly_zero_mass_matrix_is_cleared_at_once_and_still_exact(tmp_path):
    """A branching tree's M is mostly structural zeros: mass_matrix() clears M with one
    memset and writes the other entries (both triangles); a chain's M has no zeros and is
    written entry by entry. Either way M is exactly symmetric, with its zeros exact, and
    equals the lambdify backend's."""
    from gagen.codegen.render import zero_fills_mass_matrix

    assert zero_fills_mass_matrix(4, 3) and not zero_fills_mass_matrix(4, 2)
    generate_sources(gagen.resolve_model("chain:3"), tmp_path / "chain")
    assert "memset" not in (tmp_path / "chain" / "mass_matrix.c").read_text()
    text = textwrap.dedent("""
        name: fork
        gravity: [0, 0, -g]
        parameters: {g: 9.81}
        bodies:
          - {name: base, parent: world, mass: 2.0, com: [0.1, 0, 0],
             inertia: [0.1, 0.1, 0.1, 0, 0, 0],
             joint: {name: j0, type: revolute, axis: [0, 0, 1]}}
          - {name: left, parent: base, mass: 1.0, com: [0, 0.2, 0],
             inertia: [0.02, 0.03, 0.04, 0, 0, 0],
             joint: {name: j1, type: revolute, axis: [1, 0, 0], origin: {xyz: [0.3, 0.2, 0]}}}
          - {name: right, parent: base, mass: 1.5, com: [0.2, 0, 0.1],
             inertia: [0.05, 0.02, 0.03, 0, 0, 0],
             joint: {name: j2, type: revolute, axis: [0, 1, 0], origin: {xyz: [0.3, -0.2, 0]}}}
          - {name: left2, parent: left, mass: 0.5, com: [0, 0.1, 0],
             inertia: [0.01, 0.01, 0.01, 0, 0, 0],
             joint: {name: j3, type: prismatic, axis: [0, 1, 0], origin: {xyz: [0, 0.4, 0]}}}
          - {name: right2, parent: right, mass: 0.7, com: [0.1, 0, 0],
             inertia: [0.01, 0.02, 0.01, 0, 0, 0],
             joint: {name: j4, type: revolute, axis: [0, 0, 1], origin: {xyz: [0.4, 0, 0]}}}
    """)
    path = tmp_path / "fork.yaml"
    path.write_text(text)
    generate_sources(gagen.resolve_model(str(path)), tmp_path / "fork")
    assert "memset(M, 0" in (tmp_path / "fork" / "mass_matrix.c").read_text()
    compiled = gagen.load(str(path), cache_dir=tmp_path / "cache")
    reference = gagen.load(str(path), backend="lambdify")
    Q = np.random.default_rng(3).normal(size=(5, 5))
    M = compiled.mass_matrix(Q)
    np.testing.assert_allclose(M, reference.mass_matrix(Q), rtol=1e-12, atol=1e-14)
    assert np.array_equal(M, np.transpose(M, (0, 2, 1)))
    zero = np.abs(reference.mass_matrix(Q[0])) == 0
    assert zero.sum() >= 8 and np.all(M[:, zero] == 0)
