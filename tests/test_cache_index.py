"""The cache's index separates every load option: one URDF loaded with and without a
floating base, with and without the derivative module, strict or not, into one cache gets
its own module for each (the right nq and nv, the derivative module of the same option),
in one process and in fresh ones, where the index finds each without SymPy; an inertia
accepted with a warning is still refused under strict=True."""

from __future__ import annotations

import json
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

import gagen

# Two joints; l2's moments break the triangle inequality a little (the Allegro hand's tips):
# a warning without strict, refused with it
URDF = """<?xml version="1.0"?>
<robot name="index_probe">
  <link name="base"><inertial><mass value="1.0"/>
    <inertia ixx="0.01" iyy="0.02" izz="0.02" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <link name="l1"><inertial><mass value="0.5"/><origin xyz="0 0 0.1"/>
    <inertia ixx="0.004" iyy="0.004" izz="0.001" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <link name="l2"><inertial><mass value="0.2"/><origin xyz="0.05 0 0"/>
    <inertia ixx="2.30e-4" iyy="3.49e-4" izz="7.27e-4" ixy="0" ixz="0" iyz="0"/></inertial>
  </link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/>
    <origin xyz="0 0 0.1"/><axis xyz="0 1 0"/>
    <limit lower="-2" upper="2" effort="5" velocity="5"/></joint>
  <joint name="j2" type="prismatic"><parent link="l1"/><child link="l2"/>
    <origin xyz="0 0 0.2"/><axis xyz="1 0 0"/>
    <limit lower="-0.1" upper="0.1" effort="5" velocity="1"/></joint>
</robot>
"""
HERE = Path(__file__).resolve().parent
SIZES = {False: (2, 2), True: (9, 8)}  # floating_base -> (nq, nv)
OPTIONS = [(False, False), (True, False), (False, True), (True, True)]  # (floating, derivatives)

# a fresh process: the module found for one option, and whether that took SymPy
LOAD_IN_A_FRESH_PROCESS = """
import json, sys
from test_cache_index import facts, load
floating, derivatives = json.loads(sys.argv[3])
dyn = load(sys.argv[1], sys.argv[2], floating, derivatives)
found = "sympy" not in sys.modules
print(json.dumps({"found without sympy": found, **facts(dyn)}))
"""
STRICT_IN_A_FRESH_PROCESS = """
import sys, gagen
for floating in (True, False):
    try:
        gagen.load(sys.argv[1], cache_dir=sys.argv[2], strict=True, floating_base=floating)
        print("loaded")
    except gagen.ModelError as exc:
        print("refused:", exc)
"""


def values(dyn) -> dict:
    """M and d qdd/d q at one state: they tell the fixed and the floating model apart."""
    q = dyn.neutral()
    q[-2:] = [0.4, 0.05]
    v = np.linspace(-1.0, 1.0, dyn.nv)
    return {"M": dyn.mass_matrix(q).tolist(),
            "dqdd_dq": dyn.forward_dynamics_derivatives(q, v, np.ones(dyn.nv))[0].tolist()}


def facts(dyn) -> dict:
    """The sizes and modules of a compiled dynamics object (its derivative module as
    loaded, then as a derivative call finds it) and its values."""
    up_front = dyn.derivative_module
    found = values(dyn)
    return {"nq": dyn.nq, "nv": dyn.nv, "module": dyn.module.__name__,
            "derivatives up front": None if up_front is None else up_front.__name__,
            "derivatives": dyn.derivative_module.__name__, **found}


def load(path, cache, floating: bool, derivatives: bool = False, **options):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", gagen.InertiaWarning)
        if options.get("backend") == "lambdify":
            return gagen.load(path, floating_base=floating, **options)
        return gagen.load(path, cache_dir=cache, floating_base=floating,
                          derivatives=derivatives, **options)


def check(got: dict, floating: bool, derivatives: bool) -> None:
    nq, nv = SIZES[floating]
    assert (got["nq"], got["nv"]) == (nq, nv), (floating, derivatives)
    assert got["derivatives"] == got["module"] + "_derivatives"
    assert (got["derivatives up front"] is not None) == derivatives
    assert np.shape(got["M"]) == np.shape(got["dqdd_dq"]) == (nv, nv)


@pytest.fixture(scope="module")
def probe(tmp_path_factory):
    """The URDF and the cache it is loaded into."""
    folder = tmp_path_factory.mktemp("index")
    path = folder / "probe.urdf"
    path.write_text(URDF)
    return path, folder / "cache"


def load_every_option(path, cache) -> dict:
    """Fixed, floating, then both again with the derivatives up front (each checked); and
    strict refused for both: (floating, derivatives) -> facts."""
    found = {}
    for floating, derivatives in OPTIONS:
        found[floating, derivatives] = facts(load(path, cache, floating, derivatives))
        check(found[floating, derivatives], floating, derivatives)
    for floating in (False, True):
        with pytest.raises(gagen.ModelError, match="strict=True"):
            load(path, cache, floating, True, strict=True)
    return found


@pytest.fixture(scope="module")
def loaded(probe):
    return load_every_option(*probe)


def test_one_process_gets_a_module_per_option(loaded):
    names = {option: (got["module"], got["derivatives"]) for option, got in loaded.items()}
    # the derivative module is the main module's own, whichever load built it
    assert names[False, False] == names[False, True]
    assert names[True, False] == names[True, True]
    assert len({*names[False, False], *names[True, False]}) == 4
    # the same joints: the floating base's M has the fixed base's as its joints' block
    fixed, floating = (np.array(loaded[f, True]["M"]) for f in (False, True))
    np.testing.assert_allclose(floating[6:, 6:], fixed, rtol=1e-12, atol=1e-15)


def test_fresh_processes_find_each_option_in_the_index(probe, loaded):
    path, cache = probe
    for floating, derivatives in reversed(OPTIONS):
        proc = subprocess.run([sys.executable, "-c", LOAD_IN_A_FRESH_PROCESS, str(path),
                               str(cache), json.dumps([floating, derivatives])], cwd=HERE,
                              capture_output=True, text=True, timeout=600, check=False)
        assert proc.returncode == 0, proc.stderr
        got = json.loads(proc.stdout.splitlines()[-1])
        assert got.pop("found without sympy"), (floating, derivatives)
        check(got, floating, derivatives)
        assert got == loaded[floating, derivatives]  # the very module, the same numbers
    proc = subprocess.run([sys.executable, "-c", STRICT_IN_A_FRESH_PROCESS, str(path),
                           str(cache)], capture_output=True, text=True, timeout=600, check=False)
    lines = proc.stdout.splitlines()
    assert len(lines) == 2 and all(line.startswith("refused:") and "strict=True" in line
                                   for line in lines), proc
