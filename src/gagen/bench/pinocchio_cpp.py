"""Pinocchio in C++, the peer of gagen's batched C loop: `aba`, `rnea` and `crba` over
stacked states with no Python in between, so a per-state time of gagen's batched kernels
meets Pinocchio's own per-call cost, not Pinocchio plus its Python binding.

The harness is compiled against the headers of the installed `pin` wheel (its cmeel
prefix, with Eigen from `cmeel-eigen`: `pip install gagen[bench]`), header-only, with
`-O3 -DNDEBUG -march=native` (Pinocchio at its best on this CPU; gagen's kernels get FMA
through their per-CPU clones). Models reach it as Pinocchio's own binary serialisation
(`Model.saveToBinary`), so the C++ side needs no URDF parser. Anything missing gives None
and a note: the section then compares with Pinocchio from Python only.
"""

from __future__ import annotations

import json
import shutil
import subprocess
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
#include <vector>

// usage: harness MODEL.bin STATES REPEATS -> {"aba": us, "rnea": us, "crba": us} (medians)
int main(int argc, char **argv) {
  if (argc < 4) return 2;
  pinocchio::Model model;
  model.loadFromBinary(argv[1]);
  pinocchio::Data data(model);
  const int n = std::atoi(argv[2]), repeats = std::atoi(argv[3]);
  std::srand(1);
  std::vector<Eigen::VectorXd> q(n), v(n), t(n);
  for (int i = 0; i < n; ++i) {
    q[i] = 0.8 * Eigen::VectorXd::Random(model.nq);
    v[i] = Eigen::VectorXd::Random(model.nv);
    t[i] = Eigen::VectorXd::Random(model.nv);
  }
  std::vector<double> s[3];
  double sink = 0.0;
  for (int r = 0; r < repeats; ++r) {
    auto t0 = std::chrono::steady_clock::now();
    for (int i = 0; i < n; ++i) sink += pinocchio::aba(model, data, q[i], v[i], t[i])[0];
    auto t1 = std::chrono::steady_clock::now();
    for (int i = 0; i < n; ++i) sink += pinocchio::rnea(model, data, q[i], v[i], t[i])[0];
    auto t2 = std::chrono::steady_clock::now();
    for (int i = 0; i < n; ++i) sink += pinocchio::crba(model, data, q[i])(0, 0);
    auto t3 = std::chrono::steady_clock::now();
    s[0].push_back(std::chrono::duration<double>(t1 - t0).count() / n);
    s[1].push_back(std::chrono::duration<double>(t2 - t1).count() / n);
    s[2].push_back(std::chrono::duration<double>(t3 - t2).count() / n);
  }
  for (auto &x : s) std::sort(x.begin(), x.end());
  std::printf("{\"aba\": %.6f, \"rnea\": %.6f, \"crba\": %.6f, \"sink\": %g}\n",
              s[0][repeats / 2] * 1e6, s[1][repeats / 2] * 1e6, s[2][repeats / 2] * 1e6, sink);
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
    """Compile the harness into `folder`; (its path, "") or (None, why not)."""
    prefix = cmeel_prefix()
    if prefix is None:
        return None, "Pinocchio's C++ headers were not found (pip install pin)"
    if not (prefix / "include" / "eigen3" / "Eigen").is_dir():
        return None, "Eigen's headers were not found (pip install cmeel-eigen)"
    compiler = shutil.which("g++") or shutil.which("c++") or shutil.which("clang++")
    if compiler is None:
        return None, "no C++ compiler"
    folder.mkdir(parents=True, exist_ok=True)
    source, binary = folder / "pinocchio_harness.cpp", folder / "pinocchio_harness"
    source.write_text(HARNESS)
    lib = prefix / "lib"
    command = [compiler, "-O3", "-DNDEBUG", "-march=native", "-std=c++17", *DEFINES,
               f"-I{prefix / 'include'}", f"-I{prefix / 'include' / 'eigen3'}", str(source),
               "-o", str(binary), f"-L{lib}", "-lboost_serialization", f"-Wl,-rpath,{lib}"]
    result = subprocess.run(command, capture_output=True, text=True, check=False)
    if result.returncode != 0:
        return None, "the C++ harness did not compile: " + result.stderr.strip()[-300:]
    return binary, ""


def cpp_times(binary: Path, pinocchio_model, folder: Path, states: int = 1000,
              repeats: int = 11) -> dict[str, float]:
    """Median µs per call of aba, rnea and crba over `states` stacked random states."""
    path = folder / "model.bin"
    pinocchio_model.saveToBinary(str(path))
    result = subprocess.run([str(binary), str(path), str(states), str(repeats)],
                            capture_output=True, text=True, check=True)
    times = json.loads(result.stdout)
    return {key: times[key] for key in ("aba", "rnea", "crba")}
