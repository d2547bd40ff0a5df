"""CasADi's generated C of adam's articulated-body algorithm, differentiated: the peer of
gagen's forward-dynamics derivatives in C, for floating-base robots.

adam (`pip install adam-robotics`) writes Featherstone's ABA in CasADi's symbolic SX;
CasADi differentiates it (`casadi.jacobian`) and generates C, which is compiled with
`-O3 -march=native` (CasADi at its best on this CPU). Its compile takes minutes for a
quadruped, so the object is kept in a folder under a hash of the generated source and of
the command (`harness_folder`) and reused by later runs. gagen's side is the derivative
module's C (as `gagen.load` builds it, with gagen's flags). Both go into one C harness that
times them over the same random states, round by round, alternating (medians).

The state: q = (x, y, z, qx, qy, qz, qw, joints), v = (the base's linear and angular
velocity in its own axes: adam's BODY_FIXED representation, Pinocchio's and gagen's
FreeFlyer), tau (the joints'). CasADi's function returns the (6+n) x (7+n + 6+n + n)
Jacobian of the accelerations by (q, v, tau); gagen's `forward_dynamics_derivatives` its
three (6+n) x (6+n) blocks: d/dq along the velocity directions, d/dv, and d/dtau (the
base's wrench too). Before anything is timed, adam's accelerations are checked against
gagen's forward dynamics, and the Jacobian's columns by v and by the joint torques against
gagen's (the joints' damping, which gagen's dynamics have and adam's do not, taken out).
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import os
import shutil
import subprocess
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

from .casadi import COMPILE_LIMIT, _compile
from .common import optional

FLAGS = ("-O3", "-march=native")
HARNESS = r"""
#define _POSIX_C_SOURCE 199309L
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include "%(ident)s_derivatives.h"
#include "%(casadi)s.h"

/* usage: harness STATES ROUNDS -> {"gagen": us, "casadi": us} (medians per evaluation) */
static double now(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return t.tv_sec + 1e-9 * t.tv_nsec;
}

static int by_value(const void *a, const void *b)
{
    const double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

int main(int argc, char **argv)
{
    static const double p[%(np)d] = {%(p)s};
    const int states = argc > 1 ? atoi(argv[1]) : 100, rounds = argc > 2 ? atoi(argv[2]) : 21;
    const int nq = %(nq)d, nv = %(nv)d, nj = %(nj)d;
    double *q = malloc(sizeof(double) * nq * states), *v = malloc(sizeof(double) * nv * states);
    double *tau = malloc(sizeof(double) * nv * states), *out = malloc(sizeof(double) * 3 * nv * nv);
    double *jac = malloc(sizeof(double) * nv * (nq + nv + nj));
    double *g_t = malloc(sizeof(double) * rounds), *c_t = malloc(sizeof(double) * rounds);
    casadi_int sz_arg, sz_res, sz_iw, sz_w;
    const casadi_real **arg;
    casadi_real **res, *w;
    casadi_int *iw;
    double sink = 0.0, t0;
    int i, k, r;
    %(casadi)s_work(&sz_arg, &sz_res, &sz_iw, &sz_w);
    arg = malloc(sizeof(*arg) * (sz_arg > 3 ? sz_arg : 3));
    res = malloc(sizeof(*res) * (sz_res > 1 ? sz_res : 1));
    iw = malloc(sizeof(*iw) * (sz_iw > 0 ? sz_iw : 1));
    w = malloc(sizeof(*w) * (sz_w > 0 ? sz_w : 1));
    srand(1);
    for (i = 0; i < states; ++i) {
        double *qi = q + i * nq, norm = 0.0;
        for (k = 0; k < nq; ++k)
            qi[k] = 2.0 * rand() / RAND_MAX - 1.0;
        for (k = 3; k < 7; ++k)
            norm += qi[k] * qi[k];
        for (k = 3; k < 7; ++k)
            qi[k] /= sqrt(norm);
        for (k = 7; k < nq; ++k)
            qi[k] *= 0.5;
        for (k = 0; k < nv; ++k) {
            v[i * nv + k] = 2.0 * rand() / RAND_MAX - 1.0;
            tau[i * nv + k] = k < 6 ? 0.0 : 2.0 * rand() / RAND_MAX - 1.0;
        }
    }
    for (r = 0; r < rounds; ++r) {
        t0 = now();
        for (i = 0; i < states; ++i) {
            %(ident)s_forward_dynamics_derivatives(q + i * nq, v + i * nv, tau + i * nv, p, out,
                                                   out + nv * nv, out + 2 * nv * nv);
            sink += out[i %% (nv * nv)];
        }
        g_t[r] = (now() - t0) / states;
        t0 = now();
        for (i = 0; i < states; ++i) {
            arg[0] = q + i * nq;
            arg[1] = v + i * nv;
            arg[2] = tau + i * nv + 6;
            res[0] = jac;
            %(casadi)s(arg, res, iw, w, 0);
            sink += jac[i %% (nv * nv)];
        }
        c_t[r] = (now() - t0) / states;
    }
    qsort(g_t, rounds, sizeof(double), by_value);
    qsort(c_t, rounds, sizeof(double), by_value);
    printf("{\"gagen\": %%.6f, \"casadi\": %%.6f, \"sink\": %%g}\n", g_t[rounds / 2] * 1e6,
           c_t[rounds / 2] * 1e6, sink);
    return 0;
}
"""


def harness_folder() -> Path:
    """Where the compiled CasADi objects are kept between runs: gagen's cache folder."""
    from ..building.cache import default_cache_dir, usable_cache_dir

    return usable_cache_dir(default_cache_dir()) / "bench-casadi-c"


def available() -> str | None:
    """None if adam, CasADi and a C compiler are there; else why not."""
    if optional("casadi") is None or optional("adam") is None:
        return "adam and CasADi are not installed (pip install gagen[bench])"
    if _compiler() is None:
        return "no C compiler"
    return None


def _compiler() -> str | None:
    return shutil.which(os.environ.get("CC", "") or "cc") or shutil.which("gcc")


class CasadiPeer:
    """adam's ABA of a URDF on a floating base as CasADi functions: `aba(q, v, tau_joints)`
    and its Jacobian `jacobian(q, v, tau_joints)` by (q, v, tau_joints)."""

    NAME = "gagen_casadi_aba_jacobian"

    def __init__(self, urdf: Path, joints: list[str], gravity: float):
        import casadi as cs
        from adam import Representations
        from adam.casadi import KinDynComputations

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # adam on the root link it picks itself
            kd = KinDynComputations(_for_adam(Path(urdf).read_text()), list(joints),
                                    gravity=np.array([0.0, 0.0, -gravity, 0.0, 0.0, 0.0]))
        kd.set_frame_velocity_representation(Representations.BODY_FIXED_REPRESENTATION)
        n = len(joints)
        q, v, tau = cs.SX.sym("q", 7 + n), cs.SX.sym("v", 6 + n), cs.SX.sym("tau", n)
        x, y, z, qx, qy, qz, qw = (q[k] for k in range(7))
        R = cs.vertcat(
            cs.horzcat(1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)),
            cs.horzcat(2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)),
            cs.horzcat(2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)))
        H = cs.vertcat(cs.horzcat(R, cs.vertcat(x, y, z)), cs.horzcat(0, 0, 0, 1))
        acc = kd.aba(H, q[7:], v[:6], v[6:], tau)
        self.n = n
        self.aba = cs.Function("aba", [q, v, tau], [acc])
        self.jacobian = cs.Function(self.NAME, [q, v, tau],
                                    [cs.densify(cs.jacobian(acc, cs.vertcat(q, v, tau)))])

    def source(self, folder: Path) -> Path:
        """The Jacobian's generated C (and header) in `folder`."""
        import casadi as cs

        gen = cs.CodeGenerator(f"{self.NAME}.c", {"with_header": True})
        gen.add(self.jacobian)
        gen.generate(str(folder) + os.sep)
        return folder / f"{self.NAME}.c"


def _for_adam(text: str) -> str:
    """The URDF with an explicit origin in every <inertial> (URDF's default, the identity,
    which adam's parser does not supply: Talos leaves some out)."""
    import xml.etree.ElementTree as ET

    robot = ET.fromstring(text)
    for inertial in robot.iter("inertial"):
        if inertial.find("origin") is None:
            ET.SubElement(inertial, "origin", {"xyz": "0 0 0", "rpy": "0 0 0"})
    return ET.tostring(robot, encoding="unicode")


def compiled_object(source: Path, folder: Path, limit: float = COMPILE_LIMIT
                    ) -> tuple[Path | None, str]:
    """CasADi's generated C compiled once (-O3 -march=native) and kept in `folder` under the
    hash of the source and the command; (its path, "") or (None, why not). One process
    compiles a source at a time (a lock file next to the object; another run of the same
    source waits for it); waiting and compiling together stop after `limit` seconds."""
    compiler = _compiler()
    version = subprocess.run([compiler, "--version"], capture_output=True, text=True,
                             check=False).stdout
    key = hashlib.sha256("\0".join([source.read_text(), compiler, version, *FLAGS])
                         .encode()).hexdigest()[:20]
    obj = folder / f"{source.stem}-{key}.o"
    if obj.is_file():
        return obj, ""
    folder.mkdir(parents=True, exist_ok=True)
    deadline = time.monotonic() + limit
    late = f"CasADi's C did not compile within {limit / 60:.0f} min on this machine"
    with open(folder / f"{obj.stem}.lock", "w") as lock:
        while True:  # another run compiling the same source: wait for its object
            try:
                fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() > deadline:
                    return None, late
                time.sleep(5.0)
        if obj.is_file():
            return obj, ""
        with tempfile.TemporaryDirectory(dir=folder) as tmp:
            built = Path(tmp) / "casadi.o"
            try:
                _compile([compiler, *FLAGS, "-c", str(source), "-o", str(built)],
                         max(deadline - time.monotonic(), 1.0))
            except subprocess.TimeoutExpired:
                return None, late
            except subprocess.CalledProcessError as error:
                return None, "CasADi's C did not compile: " + error.output.decode(
                    errors="replace").strip()[-300:]
            os.replace(built, obj)
    return obj, ""


def check(dyn, peer: CasadiPeer, rng) -> None:
    """Raise unless adam's accelerations and its Jacobian's columns by v and by the joint
    torques agree with gagen's at a random state (gagen's joint damping taken out)."""
    n = peer.n
    q = dyn.neutral()
    quaternion = rng.normal(size=4)
    q[:3], q[3:7] = rng.normal(size=3), quaternion / np.linalg.norm(quaternion)
    q[7:] = rng.uniform(-0.5, 0.5, n)
    v, tau = rng.normal(size=6 + n), np.concatenate([np.zeros(6), rng.normal(size=n)])
    damping, friction, _ = dyn.joint_terms()
    forces = damping * v + friction * np.sign(v)
    ours = dyn.forward_dynamics(q, v, tau + forces)
    theirs = np.array(peer.aba(q, v, tau[6:])).ravel()
    _close("adam's forward dynamics and gagen's", theirs, ours)
    _, dv, minv = dyn.forward_dynamics_derivatives(q, v, tau + forces)
    J = np.array(peer.jacobian(q, v, tau[6:]))
    _close("adam's d qdd/d v and gagen's", J[:, 7 + n: 13 + 2 * n], dv + minv * damping)
    _close("adam's d qdd/d tau and gagen's", J[:, 13 + 2 * n:], minv[:, 6:])


def _close(what: str, theirs, ours, rtol: float = 1e-8) -> None:
    scale = max(float(np.abs(ours).max()), 1.0)
    if not np.allclose(theirs, ours, rtol=rtol, atol=rtol * scale):
        raise RuntimeError(f"{what} disagree (largest difference "
                           f"{np.abs(np.asarray(theirs) - ours).max():.3g})")


def c_times(dyn, urdf: Path, folder: Path, states: int = 100, rounds: int = 21,
            progress=None) -> tuple[dict | None, str]:
    """Median µs per evaluation of gagen's forward-dynamics derivatives and of CasADi's
    Jacobian of adam's ABA, in one C harness, interleaved; (times, "") or (None, why not).
    `dyn` is the robot on a floating base with its derivative module."""
    from ..building.builder import generate_sources
    from ..building.cache import compile_flags

    why = available()
    if why:
        return None, why
    dyn.load_derivatives()
    g = dict(zip(dyn.parameters, dyn.parameter_vector())).get("g", 9.81)
    peer = CasadiPeer(urdf, dyn.coordinates[6:], g)
    check(dyn, peer, np.random.default_rng(0))
    compiler = _compiler()
    with tempfile.TemporaryDirectory(prefix="gagen-casadi-") as tmp:
        tmp = Path(tmp)
        source = peer.source(tmp)
        if progress:
            progress("compiling CasADi's C (once; kept for later runs)")
        obj, why = compiled_object(source, folder)
        if obj is None:
            return None, why
        gagen_dir = tmp / "gagen"
        generate_sources(dyn.model, gagen_dir, derivatives=True)
        ident = dyn.info.name
        sources = [p for p in sorted(gagen_dir.glob("*.c")) if p.name != "derivatives_module.c"]
        flags = ["-fwrapv", *compile_flags()]
        objects = []
        for c_file in sources:
            target = c_file.with_suffix(".o")
            subprocess.run([compiler, *flags, "-c", str(c_file), "-o", str(target)],
                           check=True, capture_output=True)
            objects.append(target)
        p = ", ".join(repr(float(x)) for x in dyn.parameter_vector())
        (tmp / "harness.c").write_text(HARNESS % {
            "ident": ident, "casadi": peer.NAME, "np": len(dyn.parameters) or 1,
            "p": p or "0.0", "nq": dyn.nq, "nv": dyn.nv, "nj": peer.n})
        binary = tmp / "harness"
        subprocess.run([compiler, "-O2", f"-I{gagen_dir}", f"-I{tmp}", str(tmp / "harness.c"),
                        *map(str, objects), str(obj), "-o", str(binary), "-lm"],
                       check=True, capture_output=True)
        result = subprocess.run([str(binary), str(states), str(rounds)], capture_output=True,
                                text=True, check=True)
    times = json.loads(result.stdout)
    return {key: value for key, value in times.items() if key != "sink"}, ""
