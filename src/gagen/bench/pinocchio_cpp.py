"""Pinocchio in C++, the peer of gagen's batched C loop: `aba`, `rnea` and `crba` over
stacked states with no Python in between, so a per-state time of gagen's batched kernels
meets Pinocchio's own per-call cost, not Pinocchio plus its Python binding. Each is timed
twice: leaving each result in Pinocchio's `data`, where the next call overwrites it, and
storing every state's result (M in full) in a fresh array of the batch, the output that
gagen's batched call returns; for the mass matrix of a big robot that output is most of
the memory traffic (chain:50: 20 MB per 1000 states).

The harness is compiled against the headers of the installed `pin` wheel (its cmeel
prefix, with Eigen from `cmeel-eigen`: `pip install gagen[bench]`), header-only, with
`-O3 -DNDEBUG -march=native` (Pinocchio at its best on this CPU; gagen's kernels get FMA
through their per-CPU clones). Models reach it as Pinocchio's own binary serialisation
(`Model.saveToBinary`), so the C++ side needs no URDF parser. Anything missing gives None
and a note: the section then compares with Pinocchio from Python only.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

HARNESS = r"""
#include <pinocchio/multibody.hpp>
#include <pinocchio/serialization.hpp>
#include <pinocchio/algorithm/aba.hpp>
#include <pinocchio/algorithm/rnea.hpp>
#include <pinocchio/algorithm/crba.hpp>
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <memory>
#include <vector>

// usage: harness MODEL.bin STATES REPEATS -> {"aba": us, ..., "crba_stored": us} (medians)
// "aba", "rnea", "crba": each call's result left in `data` and overwritten by the next;
// "..._stored": every state's result written to a fresh array of the batch (allocated
// per batch, uninitialised, freed after it, M in full), as gagen's batched call returns it
int main(int argc, char **argv) {
  if (argc < 4) return 2;
  pinocchio::Model model;
  model.loadFromBinary(argv[1]);
  pinocchio::Data data(model);
  const int n = std::atoi(argv[2]), repeats = std::atoi(argv[3]);
  const long nv = model.nv;
  std::srand(1);
  std::vector<Eigen::VectorXd> q(n), v(n), t(n);
  for (int i = 0; i < n; ++i) {
    q[i] = 0.8 * Eigen::VectorXd::Random(model.nq);
    v[i] = Eigen::VectorXd::Random(model.nv);
    t[i] = Eigen::VectorXd::Random(model.nv);
  }
  std::vector<double> s[6];
  double sink = 0.0;
  using clock = std::chrono::steady_clock;
  auto per_state = [n](clock::time_point a, clock::time_point b) {
    return std::chrono::duration<double>(b - a).count() / n;
  };
  // every state's result, `size` doubles, into a fresh array of the batch
  auto stored = [&](long size, auto write) {
    std::unique_ptr<double[]> out(new double[n * size]);
    for (int i = 0; i < n; ++i) write(i, out.get() + i * size);
    sink += out[n * size - 1];
  };
  for (int r = 0; r < repeats; ++r) {
    auto t0 = clock::now();
    for (int i = 0; i < n; ++i) sink += pinocchio::aba(model, data, q[i], v[i], t[i])[0];
    auto t1 = clock::now();
    for (int i = 0; i < n; ++i) sink += pinocchio::rnea(model, data, q[i], v[i], t[i])[0];
    auto t2 = clock::now();
    for (int i = 0; i < n; ++i) sink += pinocchio::crba(model, data, q[i])(0, 0);
    auto t3 = clock::now();
    stored(nv, [&](int i, double *o) {
      Eigen::Map<Eigen::VectorXd>(o, nv) = pinocchio::aba(model, data, q[i], v[i], t[i]);
    });
    auto t4 = clock::now();
    stored(nv, [&](int i, double *o) {
      Eigen::Map<Eigen::VectorXd>(o, nv) = pinocchio::rnea(model, data, q[i], v[i], t[i]);
    });
    auto t5 = clock::now();
    stored(nv * nv, [&](int i, double *o) {
      pinocchio::crba(model, data, q[i]);
      Eigen::Map<Eigen::MatrixXd>(o, nv, nv) = data.M.selfadjointView<Eigen::Upper>();
    });
    auto t6 = clock::now();
    s[0].push_back(per_state(t0, t1));
    s[1].push_back(per_state(t1, t2));
    s[2].push_back(per_state(t2, t3));
    s[3].push_back(per_state(t3, t4));
    s[4].push_back(per_state(t4, t5));
    s[5].push_back(per_state(t5, t6));
  }
  for (auto &x : s) std::sort(x.begin(), x.end());
  const char *names[6] = {"aba", "rnea", "crba", "aba_stored", "rnea_stored", "crba_stored"};
  std::printf("{");
  for (int k = 0; k < 6; ++k) std::printf("\"%s\": %.6f, ", names[k], s[k][repeats / 2] * 1e6);
  std::printf("\"sink\": %g}\n", sink);
  return 0;
}
"""
# Pinocchio's CMake config gives its users these definitions (its joint variant has more
# alternatives than Boost.MPL's default limits)
DEFINES = ("-DBOOST_MPL_LIMIT_LIST_SIZE=30", "-DBOOST_MPL_LIMIT_VECTOR_SIZE=30",
           "-DBOOST_MPL_CFG_NO_PREPROCESSED_HEADERS", "-DBOOST_FUSION_INVOKE_MAX_ARITY=12")


def cmeel_prefix() -> Path | None:
    """The prefix of the `pin` wheel's C++ files (headers, libraries), if it has one."""
    try:
        import pinocchio
    except ImportError:
        return None
    for parent in Path(pinocchio.__file__).resolve().parents:
        candidate = parent / "cmeel.prefix"
        if (candidate / "include" / "pinocchio").is_dir():
            return candidate
    return None


def build_harness(folder: Path) -> tuple[Path | None, str]:
    """The compiled harness, (its path, "") or (None, why not). Pinocchio's headers take
    minutes to compile, so the binary is kept in `folder` under a hash of what it is built
    from (the source, the command, Pinocchio's headers' place and version, the compiler's
    version) and reused by later runs."""
    prefix = cmeel_prefix()
    if prefix is None:
        return None, "Pinocchio's C++ headers were not found (pip install pin)"
    if not (prefix / "include" / "eigen3" / "Eigen").is_dir():
        return None, "Eigen's headers were not found (pip install cmeel-eigen)"
    compiler = shutil.which("g++") or shutil.which("c++") or shutil.which("clang++")
    if compiler is None:
        return None, "no C++ compiler"
    lib = prefix / "lib"
    flags = ["-O3", "-DNDEBUG", "-march=native", "-std=c++17", *DEFINES,
             f"-I{prefix / 'include'}", f"-I{prefix / 'include' / 'eigen3'}"]
    links = [f"-L{lib}", "-lboost_serialization", f"-Wl,-rpath,{lib}"]
    binary = folder / f"pinocchio_harness-{_harness_key(compiler, flags + links)[:16]}"
    if binary.is_file() and os.access(binary, os.X_OK):
        return binary, ""
    folder.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=folder) as tmp:
        source, built = Path(tmp) / "pinocchio_harness.cpp", Path(tmp) / "harness"
        source.write_text(HARNESS)
        result = subprocess.run([compiler, *flags, str(source), "-o", str(built), *links],
                                capture_output=True, text=True, check=False)
        if result.returncode != 0:
            return None, "the C++ harness did not compile: " + result.stderr.strip()[-300:]
        os.replace(built, binary)  # whole or not at all, for the next run to find
    return binary, ""


def harness_folder() -> Path:
    """Where compiled harnesses are kept between runs: gagen's cache folder."""
    from ..building.cache import default_cache_dir, usable_cache_dir

    return usable_cache_dir(default_cache_dir()) / "bench-pinocchio-cpp"


def _harness_key(compiler: str, arguments: list[str]) -> str:
    """A hash of what the harness binary depends on."""
    import pinocchio

    version = subprocess.run([compiler, "--version"], capture_output=True, text=True,
                             check=False).stdout
    parts = [HARNESS, compiler, version, pinocchio.__version__, *arguments]
    return hashlib.sha256("\0".join(parts).encode()).hexdigest()


def cpp_times(binary: Path, pinocchio_model, folder: Path, states: int = 1000,
              repeats: int = 11) -> dict[str, float]:
    """Median µs per state of aba, rnea and crba over `states` stacked random states: each
    result left in Pinocchio's `data` (keys "aba", "rnea", "crba") or written, M in full,
    to a fresh array of the batch as gagen's batched call returns them ("..._stored")."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "model.bin"
    pinocchio_model.saveToBinary(str(path))
    result = subprocess.run([str(binary), str(path), str(states), str(repeats)],
                            capture_output=True, text=True, check=True)
    times = json.loads(result.stdout)
    return {key: value for key, value in times.items() if key != "sink"}
