"""The time of the Jacobian of gagen's CasADi functions with the parameters as an input
(the `_p` functions' `jac_`, all of p's columns), one state, from Python: medians of many
calls of `f.jacobian()` at a random state and the model's defaults.

    python benchmarks/casadi_p_jacobian.py [--urdf tests/data/urdf/anymal_c.urdf]
        [--floating] [--repeats 200] [NAME ...]

To compare two versions of gagen, run it with each one's `src` on PYTHONPATH in turn
(several rounds, the same machine).
"""

from __future__ import annotations

import argparse
import statistics
import time
import warnings

import numpy as np

DEFAULT = ["forward_dynamics", "inverse_dynamics", "gravity", "mass_matrix", "coriolis_matrix",
           "frame_jacobian", "center_of_mass", "centroidal_map", "delassus"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", default=DEFAULT)
    parser.add_argument("--urdf", default="tests/data/urdf/anymal_c.urdf")
    parser.add_argument("--floating", action="store_true", default=None)
    parser.add_argument("--repeats", type=int, default=200)
    args = parser.parse_args()
    import casadi as ca

    import gagen
    import gagen.casadi as gc

    floating = args.floating if args.floating is not None else "anymal" in args.urdf
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", gagen.InertiaWarning)
        dyn = gagen.load(args.urdf, floating_base=floating, derivatives=True)
    fns = gc.functions(dyn, parameters=True)
    rng = np.random.default_rng(0)
    q = dyn.integrate(dyn.neutral(), rng.uniform(-1, 1, dyn.nv))
    qd, u = rng.uniform(-1, 1, (2, dyn.nv))
    values = {"q": q, "qd": qd, "tau": u, "qdd": u, "frame": len(dyn.frames) - 1,
              "p": dyn.parameter_vector()}
    print(f"{dyn.info.name}: nv = {dyn.nv}, {len(values['p'])} parameters")
    for name in args.names:
        f = fns[name]
        jac = f.jacobian()
        inputs = [ca.DM(np.asarray(values[f.name_in(i)], float)) for i in range(f.n_in())]
        inputs += [ca.DM.zeros(f.sparsity_out(i)) for i in range(f.n_out())]
        jac.call(inputs)
        times = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            jac.call(inputs)
            times.append(time.perf_counter() - t0)
        print(f"{name:20s} {statistics.median(times) * 1e6:10.1f} us", flush=True)


if __name__ == "__main__":
    main()
