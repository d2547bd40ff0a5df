"""The derivative module's two forms (gagen.symbolic.derivatives.derivative_form): unrolled
(the analytical algorithm's program printed whole) or loop (the tree's geometry generated,
short C loops over the tree). The measurements behind the rule DERIVATIVE_LOOP_FROM.

For each model: the main module and both forms of the derivative module built cold, each in
a fresh process and a fresh cache folder (wall time); then per call from Python, in one
interleaved run, the forward-dynamics derivatives, the inverse-dynamics derivatives and the
Coriolis matrix of both forms (medians), and unrolled / loop (above 1: the loop form is
faster).

    python benchmarks/derivative_form.py
    python benchmarks/derivative_form.py --models tests/data/urdf/panda.urdf \\
        tests/data/urdf/anymal_c.urdf@floating
"""

from __future__ import annotations

import argparse
import tempfile
import warnings
from pathlib import Path

import numpy as np

import gagen
from gagen.bench.coldbuild import measured_build
from gagen.bench.timing import Candidate, interleaved
from gagen.building.builder import load_derivative_module
from gagen.codegen.config import CodegenConfig
from gagen.model.resolve import resolve_model

REPO = Path(__file__).resolve().parents[1]
URDF = REPO / "tests" / "data" / "urdf"
DEFAULT_MODELS = ["chain:4", "chain:8", str(URDF / "ur5_robot.urdf"), str(URDF / "panda.urdf"),
                  "chain:16", f"{URDF / 'anymal_c.urdf'}@floating",
                  f"{URDF / 'talos_reduced.urdf'}@floating", "chain:50",
                  f"{URDF / 'tiago.urdf'}@floating", f"{URDF / 'talos_full_v2.urdf'}@floating"]
FORMS = ("unrolled", "loop")
QUANTITIES = ("FD derivatives", "ID derivatives", "Coriolis")


def measure(spec: str, folder: Path, repeats: int, target: float) -> dict:
    name, _, flag = spec.partition("@")
    floating = flag == "floating"
    builds = {"main": measured_build(name, folder / "main", floating_base=floating)}
    for form in FORMS:
        builds[form] = measured_build(name, folder / form, derivatives=True,
                                      floating_base=floating, derivative_form=form)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", gagen.InertiaWarning)
        model = resolve_model(name, floating_base=floating)
    dyns = {}
    for form in FORMS:
        dyn = gagen.load(model, cache_dir=folder / "main")
        dyn.bind_derivatives(load_derivative_module(
            model, cache_dir=folder / form, config=CodegenConfig(derivative_form=form)))
        dyns[form] = dyn
    rng = np.random.default_rng(0)
    q = dyns["loop"].neutral()
    joints = [k for k, c in enumerate(dyns["loop"].configuration)
              if c in dyns["loop"].coordinates]
    q[joints] = rng.uniform(-0.5, 0.5, len(joints))
    qd, qdd = rng.normal(size=(2, model.dof))
    tau = dyns["loop"].inverse_dynamics(q, qd, qdd)
    for a, b in zip(dyns["unrolled"].forward_dynamics_derivatives(q, qd, tau),
                    dyns["loop"].forward_dynamics_derivatives(q, qd, tau)):
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-9 * max(1.0, np.abs(a).max()))
    cands = []
    for form, dyn in dyns.items():
        cands += [Candidate(f"FD derivatives {form}", dyn.forward_dynamics_derivatives,
                            (q, qd, tau), group="FD derivatives"),
                  Candidate(f"ID derivatives {form}", dyn.inverse_dynamics_derivatives,
                            (q, qd, qdd), group="ID derivatives"),
                  Candidate(f"Coriolis {form}", dyn.coriolis_matrix, (q, qd),
                            group="Coriolis")]
    times = {t.name: t.median * 1e6 for t in interleaved(cands, repeats, target)}
    label = Path(name).stem + (" (floating)" if floating else "") if name.endswith(".urdf") \
        else name
    return {"model": label, "dof": model.dof, "builds": {k: v["wall_s"] for k, v in builds.items()},
            "times": times}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="+", default=DEFAULT_MODELS,
                        help="built-in names or URDF paths; PATH@floating on a floating base")
    parser.add_argument("--repeats", type=int, default=21)
    parser.add_argument("--target", type=float, default=0.02)
    args = parser.parse_args(argv)
    print("| model | dof | cold build s: main, unrolled, loop | per call us, unrolled / loop "
          "(ratio): FD derivatives | ID derivatives | Coriolis |")
    print("|---|--:|---|---|---|---|")
    with tempfile.TemporaryDirectory(prefix="gagen-form-") as tmp:
        for k, spec in enumerate(args.models):
            r = measure(spec, Path(tmp) / f"m{k}", args.repeats, args.target)
            b, t = r["builds"], r["times"]
            cells = [f"{t[f'{q} unrolled']:.2f} / {t[f'{q} loop']:.2f} "
                     f"({t[f'{q} unrolled'] / t[f'{q} loop']:.2f})" for q in QUANTITIES]
            print(f"| {r['model']} | {r['dof']} | {b['main']:.1f}, {b['unrolled']:.1f}, "
                  f"{b['loop']:.1f} | {' | '.join(cells)} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
