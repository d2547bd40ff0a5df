"""Hostile text in a description is data, never code (issue 11, classes 1, 2 and 4).

Every text field of a model file and of a URDF is filled with injection payloads: Python
that would run if it ended a docstring or a comment of generated Python, C that
would compile if it ended a comment, paths that would escape the output folder, names that
would shadow gagen's own symbols, files and headers. Each test asserts that nothing ran, that
no payload reached the generated sources, and that the numbers equal those of the same robot
with plain names, on both backends.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np
import pytest

import gagen
from gagen.app.cli import main as cli_main
from gagen.codegen.render import c_identifier
from gagen.model.modelfile import load_model_file
from gagen.model.urdf import parse_urdf_text

MARKER = "PWNED_BY_PAYLOAD"


def payloads(sentinel: Path) -> list[str]:
    """Texts that would run, compile or escape if pasted into generated sources or paths."""
    touch = f"__import__('pathlib').Path({str(sentinel)!r}).touch()"
    return [
        f'x"""\n{touch}  # {MARKER}\n"""',                    # ends the module docstring
        f"x\r{touch}  # {MARKER}",                              # a bare CR ends a # comment
        f"x\n{touch}  # {MARKER}",
        f"x */ int {MARKER} = 1; /* ",                          # ends a C comment
        f"x\u2028{touch} # {MARKER}",                           # Unicode line separator
        f"x'); {touch}; ('{MARKER}",                            # ends a string literal
        f'x"; {touch}; "{MARKER}',
        f"../../../tmp/{MARKER}",                               # a path
        f"/tmp/{MARKER}",
        f"{{{{ {MARKER} }}}} {{% if 1 %}}{MARKER}{{% endif %}}",  # Jinja syntax
        f"\\ \\\\ \\n {MARKER} \\x00",
    ]


# ------------------------------------------------------------------------- model files


def arm_document(names: dict) -> dict:
    """A three-body arm (revolute, prismatic, fixed) whose every name comes from `names`."""
    p = names["params"]
    return {
        "name": names["model"],
        "description": names["description"],
        "gravity": [0, 0, f"-{p[0]}"],
        "parameters": {p[0]: 9.81, p[1]: 0.7, p[2]: 2.5, p[3]: 0.04},
        "bodies": [
            {"name": names["bodies"][0], "parent": "world",
             "joint": {"name": names["joints"][0], "type": "revolute", "axis": [0, 1, 1]},
             "mass": p[2], "com": [0, 0, f"-{p[1]}/2"],
             "inertia": [p[3], p[3], 0.01, 0, 0, 0]},
            {"name": names["bodies"][1], "parent": names["bodies"][0],
             "joint": {"name": names["joints"][1], "type": "prismatic",
                       "origin": {"xyz": [0, 0, f"-{p[1]}"], "rpy": [0.1, 0.2, 0.3]},
                       "axis": [1, 0, 0]},
             "mass": 1.5, "com": [0.1, 0, 0], "inertia": [0.02, 0.03, 0.04, 0, 0, 0]},
            {"name": names["bodies"][2], "parent": names["bodies"][1],
             "joint": {"name": names["joints"][2], "type": "fixed",
                       "origin": {"xyz": [0.2, 0, 0]}},
             "mass": 0.5, "inertia": [0.001, 0.001, 0.001, 0, 0, 0]},
        ],
    }


PLAIN = {"model": "arm", "description": "plain", "params": ["g", "L", "m", "I"],
         "bodies": ["b1", "b2", "b3"], "joints": ["j1", "j2", "j3"]}


def hostile_names(texts: list[str]) -> dict:
    """Every field a different payload (names must stay unique within their kind)."""
    pick = iter(texts * 3)
    return {"model": next(pick), "description": next(pick),
            "params": [f"{next(pick)}#{k}" for k in range(4)],
            "bodies": [f"{next(pick)}#b{k}" for k in range(3)],
            "joints": [f"{next(pick)}#j{k}" for k in range(3)]}


def write_model(folder: Path, names: dict, stem: str) -> Path:
    path = folder / f"{stem}.json"
    path.write_text(json.dumps(arm_document(names)))
    return path


def states(n: int, count: int = 4, seed: int = 11):
    rng = np.random.default_rng(seed)
    return [rng.uniform(-1.5, 1.5, size=(3, n)) for _ in range(count)]


def assert_same_dynamics(ours, plain, renamed: dict[str, str]) -> None:
    """Same numbers everywhere; a parameter override by the hostile name reaches the same slot."""
    n = plain.n
    for q, qd, tau in states(n):
        np.testing.assert_allclose(ours.mass_matrix(q), plain.mass_matrix(q), rtol=1e-12)
        np.testing.assert_allclose(ours.forward_dynamics(q, qd, tau),
                                   plain.forward_dynamics(q, qd, tau), rtol=1e-11)
        np.testing.assert_allclose(ours.inverse_dynamics(q, qd, tau),
                                   plain.inverse_dynamics(q, qd, tau), rtol=1e-11, atol=1e-12)
        np.testing.assert_allclose(ours.energy(q, qd), plain.energy(q, qd), rtol=1e-12)
        override = {hostile: 1.25 * plain.parameters[name] for name, hostile in renamed.items()}
        back = {name: 1.25 * plain.parameters[name] for name in renamed}
        np.testing.assert_allclose(ours.forward_dynamics(q, qd, tau, p=override),
                                   plain.forward_dynamics(q, qd, tau, p=back), rtol=1e-11)


def generated_text(dyn) -> str:
    folder = Path(dyn.module.__file__).parent
    return "\n".join(p.read_text(errors="replace") for p in sorted(folder.iterdir())
                     if p.suffix in (".c", ".h", ".pyx", ".py", ".json") and p.is_file())


def assert_names_only_as_identifiers(dyn, names: list[str]) -> None:
    """The payloads reach the generated sources only as c_identifier(name): every token
    around the marker is one of those identifiers, and no payload's own text is there."""
    text = generated_text(dyn)
    allowed = {c_identifier(n) for n in names}
    allowed |= {a.upper() for a in allowed}
    tokens = set(re.findall(rf"[A-Za-z0-9_]*{MARKER}[A-Za-z0-9_]*", text))
    stray = {t for t in tokens if not any(a in t for a in allowed)}
    assert not stray, stray
    for name in names:
        if MARKER in name:
            assert name not in text


@pytest.fixture(scope="module")
def hostile_model_file(tmp_path_factory):
    folder = tmp_path_factory.mktemp("hostile")
    sentinel = folder / "ran"
    names = hostile_names(payloads(sentinel))
    return folder, sentinel, names, write_model(folder, names, "hostile")


@pytest.mark.parametrize("backend", ["lambdify", "compiled"])
def test_model_file_payloads_run_nothing_and_compute_the_plain_numbers(
        hostile_model_file, cache_dir, backend):
    folder, sentinel, names, path = hostile_model_file
    options = {"cache_dir": cache_dir, "verbose": False} if backend == "compiled" else {}
    ours = gagen.load(path, backend=backend, **options)
    plain = gagen.load(write_model(folder, PLAIN, "plain"), backend=backend, **options)
    assert ours.coordinates == names["joints"][:2]
    assert list(ours.parameters) == names["params"]
    assert_same_dynamics(ours, plain, dict(zip(PLAIN["params"], names["params"])))
    assert not sentinel.exists()
    if backend == "compiled":
        assert_names_only_as_identifiers(ours, [v for vs in names.values()
                                                for v in ([vs] if isinstance(vs, str) else vs)])


def test_cached_hostile_module_imports_cleanly_in_a_fresh_process(hostile_model_file, cache_dir):
    """The first finding ran its payload at every load, also from the cache."""
    folder, sentinel, _, path = hostile_model_file
    gagen.load(path, cache_dir=cache_dir, verbose=False)
    script = ("import sys, gagen, numpy as np; d = gagen.load(sys.argv[1], cache_dir=sys.argv[2],"
              " verbose=False); print(d.forward_dynamics(np.zeros(2), np.zeros(2), np.ones(2)))")
    subprocess.run([sys.executable, "-c", script, str(path), str(cache_dir)], check=True,
                   capture_output=True, cwd=folder)
    assert not sentinel.exists()


# ------------------------------------------------------------------------------- URDF


def urdf_text(robot: str, links: list[str], joints: list[str]) -> str:
    """A base, two moving links (revolute, prismatic mimicking nothing) and a fixed tool."""
    a = [quoteattr(x) for x in links]
    j = [quoteattr(x) for x in joints]
    inertial = ('<inertial><origin xyz="0.01 0.02 -0.1" rpy="0.1 0 0"/><mass value="{m}"/>'
                '<inertia ixx="0.02" ixy="0.001" ixz="0" iyy="0.03" iyz="0" izz="0.015"/>'
                '</inertial>')
    return f"""<?xml version="1.0"?>
<robot name={quoteattr(robot)}>
  <link name={a[0]}/>
  <link name={a[1]}>{inertial.format(m=2.0)}</link>
  <link name={a[2]}>{inertial.format(m=1.0)}</link>
  <link name={a[3]}>{inertial.format(m=0.3)}</link>
  <joint name={j[0]} type="revolute"><parent link={a[0]}/><child link={a[1]}/>
    <axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="10" velocity="1"/></joint>
  <joint name={j[1]} type="prismatic"><parent link={a[1]}/><child link={a[2]}/>
    <origin xyz="0 0 -0.3" rpy="0 0.2 0"/><axis xyz="1 0 0"/>
    <mimic joint={j[0]} multiplier="1"/></joint>
  <joint name={j[2]} type="fixed"><parent link={a[2]}/><child link={a[3]}/>
    <origin xyz="0.1 0 0"/></joint>
</robot>
"""


@pytest.mark.parametrize("backend", ["lambdify", "compiled"])
def test_urdf_payloads_run_nothing_and_compute_the_plain_numbers(tmp_path, cache_dir, backend):
    sentinel = tmp_path / "ran"
    texts = payloads(sentinel)
    links = [f"{texts[k % len(texts)]}#l{k}" for k in range(4)]
    joints = [f"{texts[(k + 4) % len(texts)]}#j{k}" for k in range(3)]
    hostile = parse_urdf_text(urdf_text(texts[0], links, joints), "hostile.urdf")
    plain = parse_urdf_text(urdf_text("plain", ["l0", "l1", "l2", "l3"], ["j0", "j1", "j2"]),
                            "plain.urdf")
    options = {"cache_dir": cache_dir, "verbose": False} if backend == "compiled" else {}
    ours = gagen.load(hostile, backend=backend, **options)
    reference = gagen.load(plain, backend=backend, **options)
    assert ours.coordinates == joints[:2]
    assert_same_dynamics(ours, reference, {"m_l1": f"m_{links[1]}", "cx_l2": f"cx_{links[2]}"})
    assert not sentinel.exists()
    if backend == "compiled":
        params = [f"{kind}_{link}" for link in links for kind in ("m", "cx", "Ixx")]
        assert_names_only_as_identifiers(ours, [texts[0], *links, *joints, *params])


# ----------------------------------------------------------------- names gagen uses itself


INTERNAL_LOOKALIKES = {
    # the derivation's intermediates (_g), CSE temporaries (_x), hoisted terms (_h), and
    # the names of the C locals, arrays and the lambdify arguments
    "joints": ["_g0", "_g1", "_h0"],
    "params": ["sin", "cos", "_x0", "t0"],
    "bodies": ["a0", "q", "p"],
}


def test_names_like_gagens_own_symbols_give_the_plain_numbers(tmp_path, cache_dir):
    """Joints called `_g0`/`_g1` gave silently wrong accelerations (lambdify) and a cyclic-
    definition error (compiled); `_h0` broke the C build; parameters `sin`, `cos` broke
    lambdify. The symbols of each kind live in separate namespaces now."""
    names = dict(PLAIN, model="lookalike", **INTERNAL_LOOKALIKES)
    path = write_model(tmp_path, names, "lookalike")
    plain_path = write_model(tmp_path, PLAIN, "plain")
    renamed = dict(zip(PLAIN["params"], names["params"]))
    for backend in ("lambdify", "compiled"):
        options = {"cache_dir": cache_dir, "verbose": False} if backend == "compiled" else {}
        assert_same_dynamics(gagen.load(path, backend=backend, **options),
                             gagen.load(plain_path, backend=backend, **options), renamed)


def test_coordinates_rates_and_parameters_never_collide(tmp_path):
    """A parameter called like a coordinate's rate, acceleration or torque is its own symbol."""
    names = dict(PLAIN, joints=["q1", "q2", "q3"], params=["g", "q1_d", "tau_q2", "q2_dd"])
    dyn = gagen.load(write_model(tmp_path, names, "shadows"), backend="lambdify")
    plain = gagen.load(write_model(tmp_path, PLAIN, "plain"), backend="lambdify")
    assert_same_dynamics(dyn, plain, dict(zip(PLAIN["params"], names["params"])))


RESERVED_MODEL_NAMES = ["integrator", "gagen_so", "math", "stdio", "features", "mass_matrix",
                        "GAGEN", "int", "3arm", ""]


@pytest.mark.parametrize("name", RESERVED_MODEL_NAMES)
def test_model_names_never_take_gagens_identifiers(name):
    ident = c_identifier(name)
    assert ident.isidentifier() and ident.isascii()
    assert not ident.lower().startswith("gagen")
    assert ident.lower() not in {"integrator", "mass_matrix", "int", "gagen_math", "gagen_ode"}


@pytest.mark.parametrize("name", ["math", *(pytest.param(name, marks=pytest.mark.slow)
                                           for name in ("integrator", "gagen_so", "features"))])
def test_models_named_like_gagens_files_or_system_headers_build(tmp_path, cache_dir, name):
    """`integrator` and `gagen_so` collided with gagen's own header and symbols; `math` and
    `features` would shadow system headers if the build folder were on the include path."""
    doc = arm_document(dict(PLAIN, model=name))
    path = tmp_path / "arm.json"
    path.write_text(json.dumps(doc))
    compiled = gagen.load(path, cache_dir=cache_dir, verbose=False)
    reference = gagen.load(path, backend="lambdify")
    assert_same_dynamics(compiled, reference, {})


# ------------------------------------------------------------------------- output paths


@pytest.mark.parametrize("evil", ["../../escaped", *(pytest.param(evil, marks=pytest.mark.slow)
                                   for evil in ("/tmp/absolute-escape", "..", "a/../../b"))])
def test_model_names_never_choose_the_output_folder(tmp_path, cache_dir, monkeypatch, evil):
    """`simulate` and `inverse` without --out write into ./out/<identifier>, whatever the name."""
    work = tmp_path / "work" / "deep"
    work.mkdir(parents=True)
    monkeypatch.chdir(work)
    path = tmp_path / "arm.json"
    path.write_text(json.dumps(arm_document(dict(PLAIN, model=evil))))
    before = set(_all_files(tmp_path))
    assert cli_main(["inverse", str(path), "--points", "5", "--cache-dir", str(cache_dir)]) == 0
    written = set(_all_files(tmp_path)) - before
    assert written, "inverse wrote nothing"
    out = work / "out"
    assert all(out in f.parents for f in written), written
    assert not Path("/tmp/absolute-escape").exists()


def _all_files(root: Path) -> list[Path]:
    return [Path(d) / f for d, _, files in os.walk(root) for f in files]


def test_out_naming_an_existing_file_is_a_one_line_error(tmp_path, cache_dir, capsys):
    target = tmp_path / "taken"
    target.write_text("keep me")
    code = cli_main(["inverse", "rrr", "--points", "5", "--out", str(target),
                     "--cache-dir", str(cache_dir)])
    err = capsys.readouterr().err  # (a first build of rrr also reports its progress there)
    errors = [line for line in err.splitlines() if line.startswith("gagen: error:")]
    assert code == 1 and len(errors) == 1 and "taken" in errors[0] and "not a folder" in errors[0]
    assert "Traceback" not in err
    assert target.read_text() == "keep me"


def test_model_file_names_are_checked_identifiers_in_the_loaded_model(hostile_model_file):
    """The Model keeps the user's names as they are (they are data); only generated code
    and paths get identifiers."""
    _, _, names, path = hostile_model_file
    model = load_model_file(path)
    assert model.name == names["model"]
    assert [b.name for b in model.bodies][:2] == names["bodies"][:2]
