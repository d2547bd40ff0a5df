"""The derivative module's two forms (gagen.symbolic.derivatives.derivative_form): unrolled
(the analytical algorithm's program printed whole) or loop (the tree's geometry generated,
short C loops over the tree). The measurements behind the rule DERIVATIVE_LOOP_FROM.

For each model: the main module and both forms of the derivative module built cold, each in
a fresh process and a fresh cache folder (wall time); then both forms' C, compiled with
gagen's flags into one program, timed per call round by round, alternating (the best of
200 rounds of 200 calls: on a busy shared machine the least disturbed round): the
forward-dynamics derivatives, the inverse-dynamics derivatives and the Coriolis matrix, and
unrolled / loop (above 1: the loop form is faster). Both forms' results agree to 1e-9
first.

    python benchmarks/derivative_form.py
    python benchmarks/derivative_form.py --models tests/data/urdf/panda.urdf \\
        tests/data/urdf/anymal_c.urdf@floating
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import tempfile
import warnings
from pathlib import Path

import gagen
from gagen.bench.coldbuild import measured_build
from gagen.building.builder import generate_sources
from gagen.building.cache import compile_flags
from gagen.codegen.config import CodegenConfig
from gagen.model.resolve import resolve_model

REPO = Path(__file__).resolve().parents[1]
URDF = REPO / "tests" / "data" / "urdf"
DEFAULT_MODELS = ["chain:4", str(URDF / "ur5_robot.urdf"), "chain:8", str(URDF / "panda.urdf"),
                  "chain:12", "chain:16", "chain:50",
                  f"{URDF / 'double_pendulum.urdf'}@floating",
                  f"{URDF / 'panda.urdf'}@floating", f"{URDF / 'anymal_c.urdf'}@floating",
                  f"{URDF / 'talos_reduced.urdf'}@floating", f"{URDF / 'tiago.urdf'}@floating",
                  f"{URDF / 'talos_full_v2.urdf'}@floating"]
FORMS = ("unrolled", "loop")
API = ("forward_dynamics_derivatives", "inverse_dynamics_derivatives", "coriolis_matrix",
       "linearize")
HARNESS = r"""
#define _POSIX_C_SOURCE 199309L
#include <math.h>
#include <stdio.h>
#include <time.h>
int unrolled_fd(const double*, const double*, const double*, const double*, double*, double*,
                double*);
int loop_fd(const double*, const double*, const double*, const double*, double*, double*,
            double*);
void unrolled_id(const double*, const double*, const double*, const double*, double*, double*);
void loop_id(const double*, const double*, const double*, const double*, double*, double*);
void unrolled_c(const double*, const double*, const double*, double*);
void loop_c(const double*, const double*, const double*, double*);
static double now(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return t.tv_sec + 1e-9 * t.tv_nsec;
}
#define N %(n)d
static double q[%(nq)d], qd[N], x[N], p[%(np)d] = {%(p)s}, A[3][N * N], B[3][N * N];
static double diff(int m)
{
    double worst = 0.0, scale = 1.0;
    int k, j;
    for (j = 0; j < m; ++j)
        for (k = 0; k < N * N; ++k) {
            if (fabs(A[j][k]) > scale) scale = fabs(A[j][k]);
            if (fabs(A[j][k] - B[j][k]) > worst) worst = fabs(A[j][k] - B[j][k]);
        }
    return worst / scale;
}
int main(void)
{
    double best[6] = {1e9, 1e9, 1e9, 1e9, 1e9, 1e9}, t0, t, sink = 0.0, worst = 0.0;
    int k, r, round;
    for (k = 0; k < %(nq)d; ++k) q[k] = 0.1 * k - 0.4;
    %(quaternion)s
    for (k = 0; k < N; ++k) { qd[k] = 0.2 - 0.03 * k; x[k] = 0.1 * k; }
    unrolled_fd(q, qd, x, p, A[0], A[1], A[2]); loop_fd(q, qd, x, p, B[0], B[1], B[2]);
    if (diff(3) > worst) worst = diff(3);
    unrolled_id(q, qd, x, p, A[0], A[1]); loop_id(q, qd, x, p, B[0], B[1]);
    if (diff(2) > worst) worst = diff(2);
    unrolled_c(q, qd, p, A[0]); loop_c(q, qd, p, B[0]);
    if (diff(1) > worst) worst = diff(1);
#define TIME(slot, call) t0 = now(); for (r = 0; r < 200; ++r) { call; sink += A[0][r %% (N * N)]; } \
    t = (now() - t0) / 200; if (t < best[slot]) best[slot] = t
    for (round = 0; round < 200; ++round) {
        TIME(0, unrolled_fd(q, qd, x, p, A[0], A[1], A[2]));
        TIME(1, loop_fd(q, qd, x, p, A[0], A[1], A[2]));
        TIME(2, unrolled_id(q, qd, x, p, A[0], A[1]));
        TIME(3, loop_id(q, qd, x, p, A[0], A[1]));
        TIME(4, unrolled_c(q, qd, p, A[0]));
        TIME(5, loop_c(q, qd, p, A[0]));
    }
    printf("{\"fd\": [%%g, %%g], \"id\": [%%g, %%g], \"c\": [%%g, %%g], \"diff\": %%g, \"sink\": %%g}\n",
           best[0] * 1e6, best[1] * 1e6, best[2] * 1e6, best[3] * 1e6, best[4] * 1e6,
           best[5] * 1e6, worst, sink);
    return 0;
}
"""


def c_times(model, folder: Path) -> dict:
    """Both forms' C per call (µs, the best round) and their largest relative difference."""
    cc = shutil.which("cc") or "gcc"
    objects = []
    for form in FORMS:
        src = folder / form
        generate_sources(model, src, derivatives=True,
                         config=CodegenConfig(derivative_form=form))
        ident = next(src.glob("*_derivatives.h")).name[: -len("_derivatives.h")]
        short = {"forward_dynamics_derivatives": "fd", "inverse_dynamics_derivatives": "id",
                 "coriolis_matrix": "c", "linearize": "lin"}
        renames = [f"-D{ident}_{name}={form}_{short[name]}" for name in API]
        renames += [f"-D{ident}_d_{stage}={form}_d_{stage}" for stage in
                    ("fixed", "acceleration", "mass_forcing", "geometry", "joints", "solve")]
        for c_file in sorted(src.glob("*.c")):
            if c_file.name == "derivatives_module.c":
                continue
            target = folder / f"{form}-{c_file.stem}.o"
            subprocess.run([cc, "-fwrapv", *compile_flags(), *renames, "-c", str(c_file),
                            "-o", str(target)], check=True, capture_output=True)
            objects.append(str(target))
    quaternion = "q[3] = 0.1; q[4] = -0.3; q[5] = 0.2; q[6] = 0.9;" if model.floating else ""
    from gagen.manifest import ModelInfo

    info = ModelInfo.from_model(model)
    p = ", ".join(repr(float(v)) for v in dict(info.parameters).values()) or "0.0"
    (folder / "harness.c").write_text(HARNESS % {
        "n": model.dof, "nq": model.nq, "np": max(1, len(info.parameters)), "p": p,
        "quaternion": quaternion})
    binary = folder / "harness"
    subprocess.run([cc, "-O2", str(folder / "harness.c"), *objects, "-o", str(binary), "-lm"],
                   check=True, capture_output=True)
    out = json.loads(subprocess.run([str(binary)], capture_output=True, text=True,
                                    check=True).stdout)
    if out["diff"] > 1e-9:
        raise RuntimeError(f"the two forms disagree by {out['diff']:.2g}")
    return out


def measure(spec: str, folder: Path) -> dict:
    name, _, flag = spec.partition("@")
    floating = flag == "floating"
    builds = {"main": measured_build(name, folder / "main", floating_base=floating)}
    for form in FORMS:
        builds[form] = measured_build(name, folder / form, derivatives=True,
                                      floating_base=floating, derivative_form=form)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", gagen.InertiaWarning)
        model = resolve_model(name, floating_base=floating)
    times = c_times(model, folder / "c")
    label = (Path(name).stem + (" (floating)" if floating else "")
             if name.endswith(".urdf") else name)
    return {"model": label, "dof": model.dof,
            "builds": {k: v["wall_s"] for k, v in builds.items()}, "times": times}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="+", default=DEFAULT_MODELS,
                        help="built-in names or URDF paths; PATH@floating on a floating base")
    args = parser.parse_args(argv)
    print("| model | dof | cold build s: main, unrolled, loop | per call µs in C, unrolled / "
          "loop (ratio): FD derivatives | ID derivatives | Coriolis |")
    print("|---|--:|---|---|---|---|")
    with tempfile.TemporaryDirectory(prefix="gagen-form-") as tmp:
        for k, spec in enumerate(args.models):
            folder = Path(tmp) / f"m{k}"
            (folder / "c").mkdir(parents=True)
            r = measure(spec, folder)
            b, t = r["builds"], r["times"]
            cells = [f"{t[q][0]:.2f} / {t[q][1]:.2f} ({t[q][0] / t[q][1]:.2f})"
                     for q in ("fd", "id", "c")]
            print(f"| {r['model']} | {r['dof']} | {b['main']:.1f}, {b['unrolled']:.1f}, "
                  f"{b['loop']:.1f} | {' | '.join(cells)} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
