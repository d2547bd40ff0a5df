"""The runtime never imports SymPy (issue 12): `import gagen`, a cached `gagen.load` of the
paper's robot and of a URDF, every `dyn` method and `simulate` with gagen's controllers,
each checked in a fresh process, where `sys.modules` tells the truth."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

URDF = Path(__file__).parent / "data" / "urdf" / "ur5_robot.urdf"

SCRIPT = textwrap.dedent("""
    import json, sys
    import numpy as np
    import gagen
    imported = {"after import gagen": "sympy" in sys.modules}
    dyn = gagen.load(sys.argv[1], cache_dir=sys.argv[2], verbose=False)
    n = dyn.n
    q, qd, tau = np.full(n, 0.1), np.full(n, -0.2), np.full(n, 0.3)
    values = {
        "M": dyn.mass_matrix(q).tolist(),
        "qdd": dyn.forward_dynamics(q, qd, tau).tolist(),
        "tau": dyn.inverse_dynamics(q, qd, tau).tolist(),
        "F": dyn.forcing(q, qd, tau).tolist(),
        "g": dyn.gravity(q).tolist(),
        "E": list(dyn.energy(q, qd)),
        "stacked": dyn.forward_dynamics(np.tile(q, (4, 1)), qd, tau, p=dyn.parameters).tolist(),
        "names": [dyn.coordinates, list(dyn.parameters), repr(dyn)],
    }
    imported["after the dyn methods"] = "sympy" in sys.modules
    for controller, method in ((gagen.PD(kp=50.0, kd=5.0), "dopri5"),
                               (gagen.PD(kp=50.0, kd=5.0, gravity_compensation=True), "RK45"),
                               (None, "rk4")):
        result = gagen.simulate(dyn, (0, 0.05), q, controller=controller, method=method)
        values["sim " + method] = result.q[-1].tolist()
    imported["after simulate"] = "sympy" in sys.modules
    print(json.dumps({"imported": imported, "values": values}))
""")


def run(model, cache) -> dict:
    proc = subprocess.run([sys.executable, "-c", SCRIPT, str(model), str(cache)],
                          capture_output=True, text=True, timeout=900, check=False)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.splitlines()[-1])


@pytest.mark.parametrize("model", ["rrr", URDF], ids=["rrr", "ur5 urdf"])
def test_a_cached_load_and_its_use_never_import_sympy(tmp_path, model):
    first = run(model, tmp_path)  # reads the model (SymPy), builds or finds the module
    assert first["imported"]["after import gagen"] is False
    second = run(model, tmp_path)
    assert second["imported"] == {"after import gagen": False, "after the dyn methods": False,
                                  "after simulate": False}
    assert second["values"] == first["values"]  # the same module, the same numbers


def test_an_edited_model_file_is_not_served_from_the_index(tmp_path, cache_dir):
    """The index is keyed by the file's bytes: an edit is a new model, never the old one."""
    import gagen

    text = URDF.read_text()
    path = tmp_path / "arm.urdf"
    path.write_text(text)
    before = gagen.load(path, cache_dir=cache_dir, verbose=False)
    path.write_text(text.replace('<mass value="3.7"/>', '<mass value="4.7"/>', 1))
    after = gagen.load(path, cache_dir=cache_dir, verbose=False)
    assert '<mass value="3.7"/>' in text
    assert before.parameters != after.parameters
