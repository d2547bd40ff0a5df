"""Every public robot loads and matches: a sweep of example-robot-data's URDFs (fixed and
floating base) against Pinocchio's own parse, and of dm-control's MJCF suite against
MuJoCo, written as a Markdown table.

    python benchmarks/public_robots.py --out public-robots.md [--only NAME ...]
        [--urdf-dir DIR] [--mjcf-dir DIR] [--states 3] [--timeout 1800]

For each description: does the peer load it, does gagen (`gagen.load(..., backend=
"lambdify")`; a refusal is listed with its message), do the coordinates come in the peer's
order, and the largest relative differences (over max(|peer|, 1)) at random states:

- URDF, against `pinocchio.buildModelFromUrdf` (with `JointModelFreeFlyer()` for the
  floating base), each tool in its own order with no permutation: M (crba), FD (aba),
  ID (rnea), every common frame's placement and LOCAL_WORLD_ALIGNED Jacobian
  (`gagen.reference.pinocchio.compare_with_urdf_parse`);
- MJCF, against MuJoCo: M (mj_fullM), the bias forces (qfrc_bias), every body frame
  (xmat, xpos) and its Jacobian (mj_jacBody), in gagen's coordinates
  (`gagen.reference.mujoco`).

Each case runs in a child process (a derivation of a 100-joint robot takes minutes and
memory), one at a time. example-robot-data comes with `pip install example-robot-data`;
dm-control's suite is in the `dm_control` package (`suite/*.xml`).
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np


def cases(urdf_dir: Path | None, mjcf_dir: Path | None, only: list[str]) -> list[dict]:
    out = []
    if urdf_dir is not None:
        for path in sorted(urdf_dir.rglob("*.urdf")):
            for floating in (False, True):
                out.append({"kind": "urdf", "path": str(path), "floating": floating,
                            "name": str(path.relative_to(urdf_dir))})
    if mjcf_dir is not None:
        for path in sorted(mjcf_dir.glob("*.xml")):
            out.append({"kind": "mjcf", "path": str(path), "floating": None,
                        "name": f"dm_control/suite/{path.name}"})
    if only:
        out = [c for c in out if any(word in c["name"] for word in only)]
    return out


# --- one case, in a child process ------------------------------------------------------------

def run_case(case: dict, states: int) -> dict:
    warnings.simplefilter("ignore")
    result = {"peer": "", "gagen": "", "order": "", "errors": {}, "nq": None, "nv": None,
              "note": "", "warnings": 0}
    try:
        result.update(_urdf_case(case, states) if case["kind"] == "urdf"
                      else _mjcf_case(case, states))
    except Exception as exc:  # noqa: BLE001 (whatever fails is a row of the table)
        result["note"] = f"{type(exc).__name__}: {exc}"
    return result


def _gagen_model(path: str, floating) -> tuple[object | None, str, int]:
    """(the Model or None, its message if refused, the number of warnings)."""
    from gagen.errors import ModelError
    from gagen.model.resolve import resolve_model

    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        try:
            model = resolve_model(path, floating_base=bool(floating))
        except ModelError as exc:
            return None, str(exc), len(record)
    return model, "", len(record)


def _urdf_case(case: dict, states: int) -> dict:
    import pinocchio as pin

    import gagen
    from gagen.reference.pinocchio import compare_with_urdf_parse, urdf_joint_names

    out: dict = {}
    try:
        pm = pin.buildModelFromUrdf(case["path"], pin.JointModelFreeFlyer()) \
            if case["floating"] else pin.buildModelFromUrdf(case["path"])
        out["peer"] = f"loads (nv {pm.nv})"
    except (ValueError, RuntimeError) as exc:
        pm, out["peer"] = None, f"refuses: {str(exc).splitlines()[0][:120]}"
    model, message, count = _gagen_model(case["path"], case["floating"])
    out["warnings"] = count
    if model is None:
        out["gagen"], out["note"] = "refuses", message
        return out
    out["gagen"], out["nq"], out["nv"] = "loads", model.nq, model.nv
    if pm is None:
        return out
    out["order"] = "same" if urdf_joint_names(model) == list(pm.names)[1:] else "DIFFERENT"
    dyn = gagen.load(model, backend="lambdify")
    out["errors"] = compare_with_urdf_parse(dyn, pm, np.random.default_rng(0), states)
    return out


def _mjcf_case(case: dict, states: int) -> dict:
    import mujoco

    import gagen
    from gagen.reference.mujoco import MujocoState, body_names, random_configuration

    out: dict = {}
    try:
        mj = mujoco.MjModel.from_xml_path(case["path"])
        out["peer"] = f"loads (nv {mj.nv})"
    except (ValueError, RuntimeError) as exc:
        mj, out["peer"] = None, f"refuses: {str(exc).splitlines()[0][:120]}"
    model, message, count = _gagen_model(case["path"], None)
    out["warnings"] = count
    if model is None:
        out["gagen"], out["note"] = "refuses", message
        return out
    out["gagen"], out["nq"], out["nv"] = "loads", model.nq, model.nv
    if mj is None:
        return out
    names = [mujoco.mj_id2name(mj, mujoco.mjtObj.mjOBJ_JOINT, j) or f"joint{j}"
             for j in range(mj.njnt)]
    joints = [b.joint.name for b in model.moving_bodies]
    out["order"] = "same" if joints == names else "DIFFERENT"
    dyn = gagen.load(model, backend="lambdify")
    rng = np.random.default_rng(0)
    rigid = {k: 0.0 for k in dyn.parameters if k.startswith(("damping_", "friction_"))}
    errors = dict.fromkeys(("M", "bias", "placement", "jacobian"), 0.0)
    for _ in range(states):
        q, qd = random_configuration(mj, rng), rng.uniform(-1, 1, mj.nv)
        ref = MujocoState(mj, q, qd)
        errors["M"] = max(errors["M"], _relative(dyn.mass_matrix(q), ref.mass_matrix()))
        errors["bias"] = max(errors["bias"], _relative(
            dyn.inverse_dynamics(q, qd, np.zeros(mj.nv), p=rigid), ref.bias()))
        for body, name in enumerate(body_names(mj), start=1):
            R, p = dyn.frame_placement(q, name)
            R_ref, p_ref = ref.body_placement(body)
            errors["placement"] = max(errors["placement"], _relative(
                np.hstack([R, p[:, None]]), np.hstack([R_ref, p_ref[:, None]])))
            errors["jacobian"] = max(errors["jacobian"], _relative(
                dyn.frame_jacobian(q, name), ref.body_jacobian(body)))
    out["errors"] = errors
    return out


def _relative(actual, expected) -> float:
    expected = np.asarray(expected, dtype=float)
    scale = max(float(np.abs(expected).max()), 1.0)
    return float(np.abs(np.asarray(actual, dtype=float) - expected).max()) / scale


# --- the sweep -------------------------------------------------------------------------------

def run_in_child(case: dict, states: int, timeout: float) -> dict:
    try:
        done = subprocess.run([sys.executable, __file__, "--case", json.dumps(case),
                               "--states", str(states)], check=False, capture_output=True,
                              text=True, timeout=timeout)
        lines = done.stdout.strip().splitlines()
        result = json.loads(lines[-1]) if done.returncode == 0 and lines else {
            "gagen": "crashed", "note": (done.stderr.strip().splitlines() or ["?"])[-1]}
    except subprocess.TimeoutExpired:
        result = {"gagen": "timeout", "note": f"more than {timeout:.0f} s"}
    return result


def table(rows: list[tuple[dict, dict]]) -> str:
    head = ("| description | base | peer | gagen | nq/nv | order | M | FD or bias | ID | "
            "frames | Jacobians | note |")
    lines = [head, "|" + "---|" * 12]
    for case, r in rows:
        e = r.get("errors") or {}
        base = {None: "", False: "fixed", True: "floating"}[case["floating"]]
        cells = [case["name"], base, r.get("peer", "").replace(case["path"], case["name"]),
                 r.get("gagen", ""),
                 f"{r['nq']}/{r['nv']}" if r.get("nq") is not None else "",
                 r.get("order", ""), _e(e.get("M")), _e(e.get("FD", e.get("bias"))),
                 _e(e.get("ID")), _e(e.get("placement")), _e(e.get("jacobian")),
                 (r.get("note") or "").replace(case["path"], case["name"]).replace("|", "/")
                 [:300]
                 + (f" ({r['warnings']} warnings)" if r.get("warnings") else "")]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _e(value) -> str:
    if value is None:
        return ""
    return "M singular" if math.isnan(value) else f"{value:.1e}"  # NaN: no FD (compare)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--urdf-dir", type=Path, default=None,
                        help="example-robot-data's robots/ folder (default: the installed "
                             "package's)")
    parser.add_argument("--mjcf-dir", type=Path, default=None,
                        help="dm_control's suite/ folder (default: the installed package's)")
    parser.add_argument("--only", nargs="*", default=[], help="cases whose name has a word")
    parser.add_argument("--states", type=int, default=3)
    parser.add_argument("--timeout", type=float, default=1800.0)
    parser.add_argument("--out", type=Path, default=None, help="the Markdown table")
    parser.add_argument("--case", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.case:
        print(json.dumps(run_case(json.loads(args.case), args.states)))
        return 0
    urdf_dir = args.urdf_dir or _installed("example_robot_data", "robots")
    mjcf_dir = args.mjcf_dir or _installed("dm_control", "suite")
    rows = []
    for case in cases(urdf_dir, mjcf_dir, args.only):
        result = run_in_child(case, args.states, args.timeout)
        rows.append((case, result))
        print(table([(case, result)]).splitlines()[-1], flush=True)
    text = table(rows)
    if args.out:
        args.out.write_text(text)
    return 0


def _installed(package: str, folder: str) -> Path | None:
    """A data folder of an installed package: example-robot-data's robots (under cmeel's
    prefix in site-packages), dm_control's suite."""
    import importlib.util

    if package == "example_robot_data":
        for root in map(Path, sys.path):
            candidate = root / "cmeel.prefix" / "share" / "example-robot-data" / folder
            if candidate.is_dir():
                return candidate
        return None
    spec = importlib.util.find_spec(package)
    if spec is None or not spec.submodule_search_locations:
        return None
    candidate = Path(next(iter(spec.submodule_search_locations))) / folder
    return candidate if candidate.is_dir() else None


if __name__ == "__main__":
    sys.exit(main())
