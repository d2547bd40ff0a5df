"""Hostile and careless input, round 3 (issue 23): each class of the review's findings, with
payloads of our own. Every refusal is one line and takes under 2 s; the asset bombs are
refused before MuJoCo decodes anything (peak memory measured in a subprocess).

1. MJCF amplification: images bounded by the pixels their own headers declare, <replicate>
   by the elements it generates, every MuJoCo error a ModelError naming the file.
2. Quaternions whose squared norm overflows or underflows, refused in every method.
3. Shapes: integrate and difference check q against nq and velocities against nv.
4. CSV: what identify reads (duplicated columns, no rows, undecodable bytes) and what gagen
   writes (text cells a spreadsheet would run as formulas).
5. The CLI: no traceback (MemoryError, a missing extra, overflowing ranges), and a sweep
   that cannot fit is refused before anything is built.
6. The cache: a module that fails to import, or is another module, is rebuilt.
7. Messages: a NaN traced to the initial state; simulate_batch with wrenches; warnings at
   the user's line.
"""

from __future__ import annotations

import json
import shutil
import struct
import subprocess
import sys
import textwrap
import time
import warnings
import zlib
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import gagen
from gagen.app import cli, sweep
from gagen.app.cli import main as cli_main
from gagen.errors import ModelError, NonFiniteStateError
from gagen.ident.data import read_measurements
from gagen.model import mjcf_files
from gagen.model.resolve import resolve_model

REFUSAL_SECONDS = 2.0


def refused(call, error=Exception, match=None):
    """The exception `call()` raises (of type `error`, matching `match`), checked to be one
    line and raised within REFUSAL_SECONDS."""
    start = time.perf_counter()
    with pytest.raises(error, match=match) as info:
        call()
    seconds = time.perf_counter() - start
    assert seconds < REFUSAL_SECONDS, f"refused after {seconds:.2f} s"
    assert "\n" not in str(info.value)
    return info.value


# ============================================================ 1. MJCF amplification

mujoco = pytest.importorskip("mujoco")

BODY = '<body name="b"><joint name="j" axis="0 1 0"/><geom size="0.1" mass="1"/></body>'


def mjcf(asset: str = "", world: str = "") -> str:
    return (f"<mujoco><asset>{asset}</asset><worldbody>{BODY}{world}</worldbody></mujoco>")


def write(folder: Path, name: str, data) -> Path:
    path = folder / name
    path.parent.mkdir(parents=True, exist_ok=True)
    if isinstance(data, str):
        path.write_text(data)
    else:
        path.write_bytes(data)
    return path


def png(width: int, height: int, rows: int | None = None, color: int = 2) -> bytes:
    """A PNG whose header declares width x height (RGB unless `color`), with `rows` rows of
    zeros compressed (all of them: a real image; fewer: a header with a tiny body)."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return (struct.pack(">I", len(data)) + kind + data
                + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF))

    channels = {0: 1, 2: 3, 6: 4}[color]
    row = b"\0" * (1 + width * channels)
    packer = zlib.compressobj(9)
    body = b"".join(packer.compress(row) for _ in range(height if rows is None else rows))
    header = struct.pack(">IIBBBBB", width, height, 8, color, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header)
            + chunk(b"IDAT", body + packer.flush()) + chunk(b"IEND", b""))


def custom_hfield(rows: int, cols: int, body: int = 64) -> bytes:
    """MuJoCo's custom height field: rows and columns (int32), then float32 data."""
    return struct.pack("<ii", rows, cols) + bytes(body)


FACES = ("fileright", "fileleft", "fileup", "filedown", "filefront", "fileback")


def image_bombs(folder: Path) -> dict[str, tuple[str, str]]:
    """One payload per asset kind: (the MJCF text, what the refusal says)."""
    write(folder, "huge.png", png(100_000, 100_000, rows=1))
    write(folder, "5k.png", png(5000, 5000, rows=1))
    write(folder, "face.png", png(2048, 2048, rows=1))
    write(folder, "4k.png", png(4096, 4096, rows=1))
    write(folder, "gray.png", png(20_000, 20_000, rows=1, color=0))
    write(folder, "terrain.bin", custom_hfield(60_000, 60_000))
    write(folder, "noheader.png", b"\x89PNG\r\n\x1a\n" + bytes(40))
    faces = " ".join(f'{face}="face.png"' for face in FACES)
    return {
        "texture PNG": ('<texture name="t" type="2d" file="huge.png"/>', "pixels"),
        "texture PNG past 4096 x 4096": ('<texture name="t" type="2d" file="5k.png"/>',
                                         "25,000,000 pixels"),
        "texture PNG under another extension": (
            '<texture name="t" type="2d" file="5k.dat" content_type="image/png"/>', "pixels"),
        "texture cube of six files": (f'<texture name="t" type="cube" {faces}/>', "pixels"),
        "builtin cube: six faces of width x width": (
            '<texture name="t" type="cube" builtin="checker" width="4096" height="1"/>',
            "pixels"),
        "builtin skybox, height left out": (
            '<texture name="t" type="skybox" builtin="gradient" width="5000"/>', "pixels"),
        "builtin texture without a type (MuJoCo's default: cube)": (
            '<texture name="t" builtin="flat" width="2000" height="2000"/>', "pixels"),
        "height field PNG": ('<hfield name="h" file="gray.png" size="1 1 1 1"/>', "pixels"),
        "height field, custom binary header": (
            '<hfield name="h" file="terrain.bin" size="1 1 1 1"/>', "pixels"),
        "images that together decode to too much": (
            "".join(f'<texture name="t{k}" type="2d" file="4k.png"/>' for k in range(3)),
            "together"),
        "PNG without its header chunk": ('<texture name="t" type="2d" file="noheader.png"/>',
                                         "IHDR"),
    }


def replicate_bombs() -> dict[str, str]:
    """<replicate> and plain element counts past MAX_ELEMENTS (none past MAX_REPLICATE)."""
    sites = "<site/>" * 5
    return {
        "5000 copies of 5 sites": f'<replicate count="5000" offset="0 0 1">{sites}</replicate>',
        "nested 100 x 60 copies of 4 geoms": (
            '<replicate count="100" offset="1 0 0"><replicate count="60" offset="0 1 0">'
            + '<geom size="0.1" contype="0" conaffinity="0"/>' * 4 + "</replicate></replicate>"),
        "20,001 plain sites": "<body>" + "<site/>" * 20_001 + "</body>",
    }


@pytest.fixture
def no_mujoco(monkeypatch):
    """MuJoCo's compiler must not be reached."""
    monkeypatch.setattr(mujoco.MjModel, "from_xml_path",
                        lambda *a, **k: pytest.fail("MuJoCo was called"))


@pytest.mark.parametrize("case", list(image_bombs(Path("/nonexistent")).keys()))
def test_images_are_bounded_by_their_decoded_size(tmp_path, no_mujoco, case):
    text, reason = image_bombs(tmp_path)[case]
    if "5k.dat" in text:
        shutil.copyfile(tmp_path / "5k.png", tmp_path / "5k.dat")
    path = write(tmp_path, "m.xml", mjcf(asset=text))
    error = refused(lambda: resolve_model(path), ModelError, reason)
    assert str(path) in str(error) and ("<texture>" in str(error) or "<hfield>" in str(error))


def test_images_within_the_bounds_load(tmp_path):
    """A real 4096 x 4096 texture, a KTX texture (kept as bytes), a small height field."""
    write(tmp_path, "4k.png", png(4096, 4096))
    write(tmp_path, "t.ktx", b"\xabKTX 20\xbb\r\n\x1a\n" + bytes(64))
    write(tmp_path, "h.png", png(64, 64, color=0))
    write(tmp_path, "h.bin", custom_hfield(8, 8, 8 * 8 * 4))
    text = mjcf(asset='<texture name="a" type="2d" file="4k.png"/><texture name="k" '
                'type="2d" file="t.ktx"/><hfield name="h" file="h.png" size="1 1 1 1"/>'
                '<hfield name="c" file="h.bin" size="1 1 1 1"/><texture name="s" '
                'type="skybox" builtin="gradient" width="800" height="800"/>')
    files = mjcf_files.scan_mjcf(write(tmp_path, "m.xml", text))
    assert files.pixels == 4096 * 4096 + 64 * 64 + 8 * 8 + 6 * 800 * 800
    assert resolve_model(tmp_path / "m.xml").dof == 1


@pytest.mark.parametrize("case", list(replicate_bombs()))
def test_replicate_is_bounded_by_the_elements_it_generates(tmp_path, no_mujoco, case):
    path = write(tmp_path, "m.xml", mjcf(world=replicate_bombs()[case]))
    refused(lambda: resolve_model(path), ModelError,
            f"more than {mjcf_files.MAX_ELEMENTS:,} elements")


def test_replicated_elements_within_the_bound_load(tmp_path):
    path = write(tmp_path, "m.xml", mjcf(world='<replicate count="40" offset="0 0 1">'
                                                '<site/><site/></replicate>'))
    assert mjcf_files.scan_mjcf(path).element_count < 100
    assert resolve_model(path).dof == 1


BOMB_RSS = textwrap.dedent("""
    import json, resource, sys, time
    import gagen, mujoco
    from gagen.errors import ModelError
    from gagen.model.resolve import resolve_model

    def peak():
        # VmHWM: this process image's peak (ru_maxrss would carry over the forking
        # parent's peak across exec, e.g. a long test session's)
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    before, out = peak(), []
    for path in sys.argv[1:]:
        start = time.perf_counter()
        try:
            resolve_model(path)
            message = None
        except ModelError as exc:
            message = str(exc)
        out.append([path, message, time.perf_counter() - start])
    print(json.dumps({"before": before, "after": peak(), "runs": out}))
""")


def test_asset_bombs_are_refused_before_they_cost_memory(tmp_path):
    """Real bombs (each makes MuJoCo allocate 0.6-1.2 GB when let through): a PNG of
    190 kB that decodes to 8000 x 8000, a builtin cube texture of six 8000 x 8000 faces
    declared with height 1, replicated sites; the process's peak memory stays where the
    imports left it."""
    write(tmp_path, "bomb.png", png(8000, 8000))
    assert (tmp_path / "bomb.png").stat().st_size < 300_000
    files = [
        write(tmp_path, "png.xml", mjcf(asset='<texture name="t" type="2d" file="bomb.png"/>')),
        write(tmp_path, "hfield.xml", mjcf(asset='<hfield name="h" file="bomb.png" '
                                                 'size="1 1 1 1"/>')),
        write(tmp_path, "cube.xml", mjcf(asset='<texture name="t" type="cube" '
                                               'builtin="checker" width="8000" height="1"/>')),
        write(tmp_path, "replicate.xml", mjcf(world='<replicate count="9000" offset="0 0 1">'
                                                    '<site/><site/><site/></replicate>')),
    ]
    result = subprocess.run([sys.executable, "-c", BOMB_RSS, *map(str, files)],
                            capture_output=True, text=True, timeout=300, check=True)
    report = json.loads(result.stdout)
    for path, message, seconds in report["runs"]:
        assert message is not None and path in message, (path, message)
        assert seconds < REFUSAL_SECONDS, (path, seconds)
    grown = report["after"] - report["before"]
    assert grown < 50 * 2**20, f"the refusals grew the process by {grown / 2**20:.0f} MB"
    assert report["after"] < 400 * 2**20


@pytest.mark.parametrize("raised, says", [
    (MemoryError(), "ran out of memory"),
    (RuntimeError("Caught an unknown exception!"), "failed without saying why"),
    (SystemError("error return without exception set"), "error return"),
    (ValueError("Error: something\nElement name 'x', line 3"), "something"),
])
def test_every_mujoco_error_is_a_model_error_naming_the_file(tmp_path, monkeypatch, raised,
                                                            says):
    def compile_fails(path):
        raise raised

    monkeypatch.setattr(mujoco.MjModel, "from_xml_path", compile_fails)
    path = write(tmp_path, "m.xml", mjcf())
    error = refused(lambda: resolve_model(path), ModelError, says)
    assert str(error).startswith(f"{path}: MuJoCo's compiler:")


OUT_OF_MEMORY = textwrap.dedent("""
    import resource, sys
    from gagen.model import mjcf_files
    from gagen.model.mjcf import compile_mjcf
    from gagen.errors import ModelError
    mjcf_files.MAX_IMAGE_PIXELS = mjcf_files.MAX_TOTAL_PIXELS = 2**40  # the bound taken away
    resource.setrlimit(resource.RLIMIT_AS, (1536 * 2**20, 1536 * 2**20))
    try:
        compile_mjcf(sys.argv[1])
    except ModelError as exc:
        print(exc)
""")


def test_mujoco_running_out_of_memory_is_a_model_error(tmp_path):
    """With the bound lifted and an address-space limit, MuJoCo's own allocation fails:
    a ModelError naming the file, not a crash or a bare MemoryError."""
    path = write(tmp_path, "m.xml", mjcf(asset='<texture name="t" type="cube" '
                                               'builtin="checker" width="12000" height="1"/>'))
    result = subprocess.run([sys.executable, "-c", OUT_OF_MEMORY, str(path)],
                            capture_output=True, text=True, timeout=300, check=False)
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.startswith(f"{path}: MuJoCo's compiler:"), result.stdout
    assert result.stdout.count("\n") == 1


def test_the_bounds_are_in_one_table():
    assert mjcf_files.BOUNDS["elements"] == mjcf_files.MAX_ELEMENTS
    assert mjcf_files.BOUNDS["pixels per image"] == mjcf_files.MAX_IMAGE_PIXELS == 4096 ** 2
    assert mjcf_files.BOUNDS["pixels of all images"] == mjcf_files.MAX_TOTAL_PIXELS


# ========================================================= 2. quaternions that overflow

TUMBLER = """
name: tumbler
gravity: [0, 0, -g]
parameters: {g: 9.81, m: 2.0}
bodies:
  - name: box
    joint: {name: base, type: floating}
    mass: m
    com: [0.1, 0, 0]
    inertia: [0.1, 0.2, 0.3, 0.01, 0, 0]
  - name: arm
    parent: box
    joint: {name: hinge, type: revolute, axis: [0, 1, 0], origin: {xyz: [0.2, 0, 0]}}
    mass: 1.0
    com: [0, 0, -0.2]
    inertia: [0.02, 0.02, 0.001, 0, 0, 0]
"""


@pytest.fixture(scope="module")
def tumblers(tmp_path_factory):
    """The floating tumbler of test_floating.py, compiled and through lambdify."""
    path = tmp_path_factory.mktemp("model") / "tumbler.yaml"
    path.write_text(TUMBLER)
    return {"compiled": gagen.load(path), "lambdify": gagen.load(path, backend="lambdify")}


# (x, y, z, w) whose squared norm is inf, zero or subnormal although every entry is finite
BAD_QUATERNIONS = {
    "overflows": ([1e200, 0.0, 0.0, 1e200], "overflows"),
    "one entry overflows": ([0.0, 1e160, 0.0, 0.0], "overflows"),
    "two entries just past": ([1e154, 1e154, 0.0, 0.0], "overflows"),
    "underflows": ([1e-170, 0.0, 0.0, 1e-170], "underflows"),
    "subnormal": ([1e-160, 1e-160, 1e-160, 1e-160], "underflows"),
    "zero": ([0.0, 0.0, 0.0, 0.0], "is zero"),
}


def every_method(dyn, q):
    """Each method taking q, called at q (the derivative ones too)."""
    v = np.zeros(dyn.nv)
    fext = {"arm": [0.0, 0.0, 1.0, 0.0, 0.0, 0.0]}
    return {
        "mass_matrix": lambda: dyn.mass_matrix(q),
        "forcing": lambda: dyn.forcing(q, v, v),
        "forward_dynamics": lambda: dyn.forward_dynamics(q, v, v),
        "forward_dynamics fext": lambda: dyn.forward_dynamics(q, v, v, fext=fext),
        "inverse_dynamics": lambda: dyn.inverse_dynamics(q, v, v),
        "gravity": lambda: dyn.gravity(q),
        "energy": lambda: dyn.energy(q, v),
        "regressor": lambda: dyn.regressor(q, v, v),
        "frame_placement": lambda: dyn.frame_placement(q, "arm"),
        "frame_jacobian": lambda: dyn.frame_jacobian(q, "arm"),
        "frame_velocity": lambda: dyn.frame_velocity(q, v, "arm"),
        "external_forces": lambda: dyn.external_forces(q, fext),
        "integrate": lambda: dyn.integrate(q, v, 0.1),
        "difference q0": lambda: dyn.difference(q, dyn.neutral()),
        "difference q1": lambda: dyn.difference(dyn.neutral(), q),
        "coriolis_matrix": lambda: dyn.coriolis_matrix(q, v),
        "inverse_dynamics_derivatives": lambda: dyn.inverse_dynamics_derivatives(q, v, v),
        "forward_dynamics_derivatives": lambda: dyn.forward_dynamics_derivatives(q, v, v),
        "linearize": lambda: dyn.linearize(q, v, v),
    }


@pytest.mark.parametrize("backend", ["compiled", "lambdify"])
@pytest.mark.parametrize("case", list(BAD_QUATERNIONS))
def test_a_quaternion_that_cannot_be_normalised_is_refused_everywhere(tumblers, backend,
                                                                      case):
    dyn = tumblers[backend]
    quat, says = BAD_QUATERNIONS[case]
    q = dyn.neutral()
    q[3:7] = quat
    stacked = np.array([dyn.neutral(), q])
    for name, call in every_method(dyn, q).items():
        error = refused(call, ValueError, says)
        assert "base_qx, base_qy, base_qz, base_qw" in str(error), name
        assert "quaternion of floating joint 'base'" in str(error), name
    error = refused(lambda: dyn.mass_matrix(stacked), ValueError, "row 1")
    assert "q[3:7]" in str(error)


@pytest.mark.parametrize("method", ["dopri5", "RK45", "rk4"])
@pytest.mark.parametrize("case", ["overflows", "underflows", "zero"])
def test_simulate_refuses_such_an_initial_quaternion(tumblers, method, case):
    dyn = tumblers["compiled"]
    q0 = dyn.neutral()
    q0[3:7] = BAD_QUATERNIONS[case][0]
    error = refused(lambda: gagen.simulate(dyn, (0.0, 0.1), q0, method=method), ValueError,
                    BAD_QUATERNIONS[case][1])
    assert str(error).startswith("q0[3:7] (base_qx")
    batch = np.array([dyn.neutral(), q0])
    refused(lambda: gagen.simulate_batch(dyn, (0.0, 0.1), batch), ValueError, "q0\\[3:7\\]")


@pytest.mark.parametrize("backend", ["compiled", "lambdify"])
def test_small_and_large_quaternions_that_can_be_normalised_still_work(tumblers, backend):
    """The bound is double precision's, not a tolerance: tiny and huge quaternions whose
    squared norm is a normal double give the unit quaternion's results."""
    dyn = tumblers[backend]
    q = np.array([0.1, -0.2, 0.3, 0.2, -0.4, 0.1, 0.8, 0.5])
    q[3:7] /= np.linalg.norm(q[3:7])
    reference = dyn.gravity(q)
    for scale in (1e-150, 1e-100, 1e100, 1e150):
        scaled = q.copy()
        scaled[3:7] *= scale
        assert np.allclose(dyn.gravity(scaled), reference, rtol=1e-12, atol=1e-12), scale


@pytest.mark.parametrize("backend", ["compiled", "lambdify"])
@pytest.mark.parametrize("entry", [np.nan, np.inf, -np.inf])
def test_nan_in_a_quaternion_is_the_nan_error(tumblers, backend, entry):
    """A floating base's orientation does not enter its mass matrix, so the dynamics' own
    NaN check would miss it: the quaternion check names it."""
    dyn = tumblers[backend]
    q = dyn.neutral()
    q[4] = entry
    for call in every_method(dyn, q).values():
        refused(call, NonFiniteStateError, r"q\d?\[3:7\] .* holds NaN or inf")


def test_integrate_refuses_a_step_that_overflows(tumblers):
    dyn = tumblers["compiled"]
    refused(lambda: dyn.integrate(dyn.neutral(), np.full(7, 1e200), 1e200), ValueError,
            "overflows")
    refused(lambda: dyn.integrate(dyn.neutral(), np.r_[0, 0, 0, 1e155, 1e155, 0, 0]),
            ValueError, "rotation vector")
    refused(lambda: dyn.integrate(dyn.neutral(), np.zeros(7), np.inf), ValueError, "dt")
    refused(lambda: dyn.integrate(dyn.neutral(), np.zeros(7), [0.1, 0.2]), TypeError, "dt")


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # NumPy on the hostile numbers
@pytest.mark.parametrize("backend", ["compiled", "lambdify"])
def test_parameters_whose_products_overflow_are_not_blamed_on_q(backend):
    """A finite q with parameters whose products overflow: the message says so, where it
    used to say q holds NaN or inf."""
    dyn = gagen.load("rrr", backend=backend)
    big = {"m1": 1e300, "L1": 1e300}
    for q in (np.zeros(3), np.zeros((2, 3))):
        error = refused(lambda q=q: dyn.forward_dynamics(q, np.zeros(3), np.zeros(3), p=big),
                        NonFiniteStateError, "product of the parameters and q's entries")
        assert "q holds" not in str(error)
    refused(lambda: dyn.forward_dynamics([0.0, np.nan, 0.0], np.zeros(3), np.zeros(3)),
            NonFiniteStateError, r"q holds NaN or inf \(q\[1\] is nan\)")


def test_mjcf_gravity_is_normed_without_overflow(tmp_path):
    path = write(tmp_path, "m.xml", mjcf().replace("<mujoco>", '<mujoco><option gravity='
                                                                 '"1e200 1e200 0"/>'))
    model = resolve_model(path)
    assert model.parameters["g"] == pytest.approx(np.sqrt(2) * 1e200, rel=1e-15)


# ======================================================================= 3. shapes

@pytest.mark.parametrize("backend", ["compiled", "lambdify"])
def test_integrate_and_difference_check_sizes_like_every_method(tumblers, backend):
    dyn = tumblers[backend]  # nq = 8, nv = 7
    q, v = dyn.neutral(), np.zeros(7)
    cases = {
        "v of nq entries": (lambda: dyn.integrate(q, np.zeros(8)),
                            r"v must have shape \(7,\) or \(N, 7\); got \(8,\)"),
        "q of nv entries": (lambda: dyn.integrate(np.zeros(7), v), r"q must have shape \(8,\)"),
        "q1 of nv entries": (lambda: dyn.difference(q, np.zeros(7)),
                             r"q1 must have shape \(8,\) or \(N, 8\); got \(7,\)"),
        "q0 of nv entries": (lambda: dyn.difference(np.zeros(7), q), r"q0 must have shape"),
        "stacked rows disagree": (lambda: dyn.difference(np.tile(q, (3, 1)), np.tile(q, (2, 1))),
                                  "q1 has 2 rows"),
        "three dimensions": (lambda: dyn.integrate(np.zeros((2, 2, 8)), v), "q must have shape"),
        "tau of nq with fext": (lambda: dyn.forward_dynamics(q, v, np.zeros(8),
                                                             fext={"arm": np.zeros(6)}),
                                r"tau must have shape \(7,\)"),
        "qd of nq": (lambda: dyn.frame_velocity(q, np.zeros(8), "arm"), r"qd must have shape"),
    }
    for call, match in cases.values():
        refused(call, ValueError, match)
    # the same message as the dynamics' own check
    with pytest.raises(ValueError) as own:
        dyn.mass_matrix(np.zeros(7))
    assert str(own.value) == r"q must have shape (8,) or (N, 8); got (7,)"


def test_integrate_and_difference_still_match_for_stacked_states(tumblers):
    dyn = tumblers["compiled"]
    rng = np.random.default_rng(3)
    q = np.tile(dyn.neutral(), (4, 1))
    v = rng.normal(size=(4, 7))
    moved = dyn.integrate(q, v, 0.3)
    assert np.allclose(dyn.difference(q, moved), 0.3 * v, atol=1e-12)
    assert np.allclose(dyn.integrate(dyn.neutral(), v[0], 0.3), moved[0], atol=1e-15)


# =========================================================================== 4. CSV

CSV_PAYLOADS = {
    "duplicated column": (b"t,q1,q2,q3,q1,tau_q1,tau_q2,tau_q3\n0,0,0,0,0,0,0,0\n",
                          r"column 'q1' appears twice \(columns 2 and 5\)"),
    "duplicated once unescaped": (b"t,'=q1,=q1,tau_q1\n0,0,0,0\n",
                                  r"column '=q1' appears twice \(columns 2 and 3\)"),
    "header and no rows": (b"t,q1,q2,q3,tau_q1,tau_q2,tau_q3\n", "header and no rows"),
    "header and blank lines": (b"t,q1,q2,q3,tau_q1,tau_q2,tau_q3\n\n\r\n\n",
                               "header and no rows"),
    "empty file": (b"", "empty file"),
    "Latin-1 byte": (b"t,q1,q2,q3,tau_q1,tau_q2,tau_q3\n0,0,0,0,0,0,0\n0.1,0,0,0,\xe9,0,0\n",
                     "line 3: byte 0xe9 at column 11 is not UTF-8"),
    "UTF-16 file": ("t,q1\n0,1\n".encode("utf-16"), "line 1: byte 0xff"),
    "NUL byte": (b"t,q1,q2,q3,tau_q1,tau_q2,tau_q3\n0,0,\x00,0,0,0,0\n", "line 2"),
    "field past csv's limit": (b"t,q1,q2,q3,tau_q1,tau_q2,tau_q3\n0,0,0,\"" + b"9" * 200_000
                               + b"\",0,0,0\n", "line 2: not readable as CSV"),
}


@pytest.mark.parametrize("case", list(CSV_PAYLOADS))
def test_identify_reads_careless_csv_with_one_line_errors(tmp_path, case):
    data, match = CSV_PAYLOADS[case]
    path = write(tmp_path, "data.csv", data)
    error = refused(lambda: read_measurements(path, ["q1", "q2", "q3"]), ValueError, match)
    assert str(path) in str(error)


def test_a_csv_with_a_byte_order_mark_and_crlf_reads(tmp_path):
    path = write(tmp_path, "data.csv", b"\xef\xbb\xbft,q1,q1_d,q1_dd,tau_q1\r\n0,1,2,3,4\r\n")
    data = read_measurements(path, ["q1"])
    assert data.q.tolist() == [[1.0]] and data.tau.tolist() == [[4.0]]


def test_the_cli_says_the_same_for_identify(tmp_path, capsys):
    path = write(tmp_path, "data.csv", CSV_PAYLOADS["duplicated column"][0])
    line = cli_error(["identify", "rrr", str(path), "--out", str(tmp_path / "out"), "--quiet"],
                     capsys, 2)
    assert line.startswith(f"gagen: error: {path}: column 'q1'")
    assert not (tmp_path / "out").exists()


# names a description may give joints and bodies: each would be a formula in a spreadsheet
FORMULAS = ["=HYPERLINK(\"http://x\",\"y\")", "+1+1", "-2+3", "@SUM(A1:A2)", "\t=1", "\r=1",
            "'=1", "plain"]


def cells(path: Path) -> list[list[str]]:
    import csv

    with path.open(newline="") as fh:
        return list(csv.reader(fh))


def assert_inert(cell: str) -> None:
    assert not cell.startswith(("=", "+", "-", "@", "\t", "\r")), cell


def test_simulate_csv_escapes_names_and_identify_reads_them_back(tmp_path):
    names = FORMULAS
    n = len(names)
    t = np.linspace(0.0, 2.0, 401)
    q = np.outer(np.sin(t), np.arange(1, n + 1)) - 1.5
    result = gagen.SimulationResult(t, q, np.gradient(q, t, axis=0), np.full((401, n), -0.25),
                                    names)
    path = result.to_csv(tmp_path / "run.csv")
    header, first = cells(path)[:2]
    for cell in header:
        assert_inert(cell)
    assert header[1:n + 1] == ["'" + name if name != "plain" else name for name in names]
    assert first[1] == "-1.5"  # numbers stay numbers
    data = read_measurements(path, names)
    assert np.allclose(data.q, q[len(q) - len(data.q) - (len(q) - len(data.q)) // 2:][
        :len(data.q)], atol=1e-9)
    assert np.allclose(data.tau, -0.25)


def test_every_csv_gagen_writes_escapes_text_cells(tmp_path):
    from gagen.app.runs import InverseRun, _write_inverse_csv
    from gagen.app.sweep import SweepRun, write_statistics
    from gagen.ident.identification import IdentificationResult

    model = SimpleNamespace(coordinates=FORMULAS[:3])
    run = InverseRun(model, np.zeros(2), *(np.full((2, 3), -1.0) for _ in range(4)), 0.0)
    inverse = _write_inverse_csv(run, tmp_path / "inverse.csv")
    stats = SweepRun(model, 1, 0, np.zeros((1, 3)), np.zeros(3), 0.0)
    stats.statistics = [{"coordinate": name, "unit": "deg", "nominal": -1.0}
                        for name in FORMULAS[:3]]
    final = write_statistics(stats, tmp_path / "final.csv")
    k = 3
    result = IdentificationResult(FORMULAS[:k], ["-m_a + m_b", "@x", "=1"], -np.ones(k),
                                  np.ones(k), np.eye(k), np.zeros((2, 1)), np.zeros(1), 1.0,
                                  1.0, None, np.zeros(1))
    identified = result.to_csv(tmp_path / "identified.csv")
    for path, text_columns in ((inverse, None), (final, {0}), (identified, {0, 4})):
        rows = cells(path)
        for cell in rows[0]:
            assert_inert(cell)
        for row in rows[1:]:
            for column, cell in enumerate(row):
                if text_columns is not None and column in text_columns:
                    assert_inert(cell)
    assert cells(identified)[1][1] == "-1.0"  # the value: a number, not escaped


# ======================================================================== 5. the CLI

def cli_error(argv, capsys, code=None) -> str:
    """Run the CLI; its stderr's one error line (checked: one line, within 2 s)."""
    start = time.perf_counter()
    returned = cli_main(argv)
    seconds = time.perf_counter() - start
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.startswith("gagen: error:")]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    assert returned == (code if code is not None else returned) and returned in (1, 2)
    assert seconds < REFUSAL_SECONDS, f"{argv}: {seconds:.2f} s"
    return lines[0]


def test_a_sweep_too_large_for_memory_is_refused_before_the_model_is_built(tmp_path, capsys):
    cache = tmp_path / "cache"
    out = tmp_path / "out" / "mc.npz"
    line = cli_error(["sweep", "chain:7", "--runs", "100000000", "--points", "10000000",
                      "--out", str(out), "--cache-dir", str(cache)], capsys, 2)
    assert "--runs 100,000,000 x --points 10,000,000" in line and "memory" in line
    assert not cache.exists() and not out.parent.exists()  # nothing built, nothing written


def test_a_sweep_too_large_for_the_disk_is_refused(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(sweep, "free_disk", lambda path: 10 * 2**20)
    line = cli_error(["sweep", "rrr", "--runs", "10000", "--out", str(tmp_path / "mc.zarr"),
                      "--cache-dir", str(tmp_path / "cache")], capsys, 2)
    assert "on disk" in line and "--out" in line and "10.5 MB is free" in line
    assert not (tmp_path / "mc.zarr").exists() and not (tmp_path / "cache").exists()


def test_the_store_estimate_counts_runs_samples_and_coordinates():
    size = sweep.store_size(1000, 501, 8, 7, 20)
    assert size.results == 8 * 1000 * 501 * (8 + 14)
    assert size.in_memory(".npz") - size.in_memory(".zarr") == size.on_disk
    assert sweep.store_size(2000, 501, 8, 7, 20).results == 2 * size.results


@pytest.mark.parametrize("argv, says", [
    (["sweep", "rrr", "--runs", "3", "--vary", "m1=-1e308:1e308"], "--vary 'm1=-1e308:1e308'"),
    (["sweep", "rrr", "--runs", "3", "--vary", "q0=-1.7e308:1.7e308"], "HI - LO overflows"),
])
def test_overflowing_ranges_are_one_line_naming_the_option(argv, says, capsys):
    assert says in cli_error(argv, capsys, 2)


@pytest.mark.parametrize("argv, says", [
    (["sweep", "rrr", "--seed", "-1"], "argument --seed"),
    (["sweep", "rrr", "--seed", "1e3"], "argument --seed"),
    (["sweep", "rrr", "--threads", "0"], "argument --threads"),
    (["identify", "rrr", "x.csv", "--polyorder", "99"], "argument --polyorder"),
])
def test_numpy_never_gets_to_complain_about_an_option(argv, says, capsys):
    with pytest.raises(SystemExit) as exit_info:
        cli_main(argv)
    err = capsys.readouterr().err
    assert exit_info.value.code == 2 and says in err and "Traceback" not in err


@pytest.mark.parametrize("missing, extra", [("zarr", "zarr"), ("distributed", "dask"),
                                            ("mujoco", "mjcf"), ("pinocchio", "bench")])
def test_a_missing_extra_says_what_to_install(missing, extra, capsys, monkeypatch):
    def needs_it(args):
        raise ModuleNotFoundError(f"No module named '{missing}'", name=missing)

    monkeypatch.setitem(cli.COMMANDS, "info", cli.Command(needs_it, "", cli._info_arguments))
    line = cli_error(["info", "rrr"], capsys, 1)
    assert f"pip install 'gagen[{extra}]'" in line


def test_the_zarr_store_says_what_to_install(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "zarr", None)
    line = cli_error(["sweep", "rrr", "--runs", "2", "--points", "3", "--duration", "0.01",
                      "--out", str(tmp_path / "x.zarr"), "--no-plot"], capsys, 1)
    assert "pip install 'gagen[zarr]'" in line


@pytest.mark.parametrize("raised, says", [
    (MemoryError(), "out of memory running 'sweep': --runs and --points"),
    (OverflowError("Range exceeds valid bounds"), "overflowed"),
    (FloatingPointError("overflow encountered"), "overflowed"),
])
def test_memory_and_arithmetic_errors_are_one_line(raised, says, capsys, monkeypatch):
    def fails(*args, **kwargs):
        raise raised

    monkeypatch.setattr(sweep, "run_sweep", fails)
    assert says in cli_error(["sweep", "rrr"], capsys)


OUT_OF_MEMORY_CLI = textwrap.dedent("""
    import resource, sys
    import matplotlib, numpy
    import gagen.app.runs
    from gagen.app.cli import main
    status = open("/proc/self/status").read().splitlines()
    size = next(int(line.split()[1]) * 1024 for line in status if line.startswith("VmSize:"))
    resource.setrlimit(resource.RLIMIT_AS, (size + 300 * 2**20, size + 300 * 2**20))
    sys.exit(main(sys.argv[1:]))
""")


def test_a_real_memory_error_is_one_line(tmp_path):
    """simulate with 10 million samples (0.5 GB of states) with 300 MB of address space
    left: NumPy's allocation fails, and the CLI says so in one line naming the options."""
    result = subprocess.run(
        [sys.executable, "-c", OUT_OF_MEMORY_CLI, "simulate", "rrr", "--points", "10000000",
         "--out", str(tmp_path), "--quiet"], capture_output=True, text=True, timeout=300, check=False)
    assert result.returncode == 1, result.stderr[-2000:]
    assert result.stderr.strip() == ("gagen: error: out of memory running 'simulate': "
                                     "--points and --duration decide how much it takes")


# ====================================================================== 6. the cache

SWAP = textwrap.dedent("""
    import hashlib, sys
    from pathlib import Path
    victim, other = Path(sys.argv[1]), Path(sys.argv[2])
    tmp = victim.with_name(victim.name + ".new")
    tmp.write_bytes(other.read_bytes())
    tmp.replace(victim)  # a new file, as a copy tool writes it
    data = victim.read_bytes()
    (victim.parent / "module.sha256").write_text(
        f"{hashlib.sha256(data).hexdigest()} {len(data)} {victim.name}\\n")
""")

LOAD = textwrap.dedent("""
    import sys, warnings
    import numpy as np, gagen
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        dyn = gagen.load(sys.argv[1], cache_dir=sys.argv[2], derivation=sys.argv[3])
        m = dyn.mass_matrix(np.full(dyn.nq, 0.3))
        c = dyn.coriolis_matrix(np.full(dyn.nq, 0.3), np.ones(dyn.nv))
    print(dyn.module.KEY, dyn.derivative_module.EQUATIONS_KEY == dyn.module.KEY)
    print(repr(m.ravel().tolist()), repr(c.ravel().tolist()))
    print(" | ".join(f"{type(w.message).__name__} {w.filename}: {w.message}" for w in caught))
""")


def load_in_a_fresh_process(model: str, cache: Path, derivation: str = "auto"):
    result = subprocess.run([sys.executable, "-c", LOAD, model, str(cache), derivation],
                            capture_output=True, text=True, timeout=600, check=False)
    assert result.returncode == 0, result.stderr[-3000:]
    key, values, caught = (result.stdout.splitlines() + [""])[:3]
    return key, values, caught


def swap(victim: Path, other: Path) -> None:
    subprocess.run([sys.executable, "-c", SWAP, str(victim), str(other)], check=True)


@pytest.fixture(scope="module")
def two_models(tmp_path_factory):
    """A cache with chain:1's main and derivative modules, and chain:2's derivative module
    (another model's modules: the shipped rrr's, chain:2's derivatives); chain:1's results
    as the loading process prints them."""
    from gagen.building.builder import load_derivative_module

    cache = tmp_path_factory.mktemp("cache")
    dyn = gagen.load("chain:1", cache_dir=cache, derivatives=True)
    load_derivative_module(resolve_model("chain:2"), cache_dir=cache)
    m = dyn.mass_matrix(np.full(dyn.nq, 0.3))
    c = dyn.coriolis_matrix(np.full(dyn.nq, 0.3), np.ones(dyn.nv))
    return cache, (f"{dyn.module.KEY} True", f"{m.ravel().tolist()!r} {c.ravel().tolist()!r}")


def module_file(cache: Path, model: str, derivatives: bool) -> Path:
    if model == "rrr":
        import gagen.shipped

        return next(Path(gagen.shipped.__file__).parent.glob("gagen_rrr_*.so"))
    prefix = {"chain:1": "gagen_chain1_", "chain:2": "gagen_chain2_"}[model]
    for entry in cache.iterdir():
        if entry.name.startswith(prefix) and ("_derivatives" in entry.name) == derivatives:
            return next(entry.glob("*.so"))
    raise FileNotFoundError(model)


@pytest.mark.parametrize("which, other", [("main", "rrr"), ("derivatives", "chain:2")])
def test_another_models_module_with_its_checksum_updated_is_rebuilt(two_models, which,
                                                                    other):
    cache, expected = two_models
    derivatives = which == "derivatives"
    swap(module_file(cache, "chain:1", derivatives), module_file(cache, other, derivatives))
    key, values, caught = load_in_a_fresh_process("chain:1", cache)
    assert (key, values) == expected
    assert "CacheWarning" in caught and "does not import" in caught and "rebuilding" in caught
    assert "<string>" in caught  # the warning points at the user's line, not gagen's
    again = load_in_a_fresh_process("chain:1", cache)
    assert again[:2] == expected and again[2] == ""


@pytest.mark.slow
def test_a_module_of_another_build_is_found_out_by_its_key(two_models):
    """The same module name (chain:1 derived two ways), so it imports: only the key inside
    it tells it is not the module the index names."""
    cache, _ = two_models
    gibbs = load_in_a_fresh_process("chain:1", cache, "gibbs-appell")
    recursive = load_in_a_fresh_process("chain:1", cache, "recursive")
    assert gibbs[0] != recursive[0]
    swap(module_file_for_key(cache, recursive[0]), module_file_for_key(cache, gibbs[0]))
    key, values, caught = load_in_a_fresh_process("chain:1", cache, "recursive")
    assert key.split()[0] == recursive[0].split()[0] and values == recursive[1]
    assert "is not the module its cache entry names" in caught
    assert load_in_a_fresh_process("chain:1", cache, "recursive")[2] == ""


def module_file_for_key(cache: Path, key_line: str) -> Path:
    key = key_line.split()[0]
    for entry in cache.iterdir():
        for so in entry.glob("gagen_chain1_*[!s].cpython*.so"):
            if key.encode() in so.read_bytes():
                return so
    raise FileNotFoundError(key)


def test_an_index_record_of_an_earlier_gagen_still_loads(two_models):
    cache, expected = two_models
    for record in (cache / "index").iterdir():
        data = json.loads(record.read_text())
        data.pop("key", None)
        record.write_text(json.dumps(data))
    assert load_in_a_fresh_process("chain:1", cache)[:2] == expected
    rerecorded = [r for r in (cache / "index").iterdir() if "key" in json.loads(r.read_text())]
    assert len(rerecorded) == 2  # the main and the derivative module, with their keys


FALLBACK = textwrap.dedent("""
    import sys, warnings
    import numpy as np, gagen
    from gagen.building import cache
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        dyn = gagen.load("rrr", cache_dir=sys.argv[1])  # shipped: nothing to build
    print(cache._fallback_cache)
    print(caught[0].filename)
""")


def test_the_temporary_cache_of_an_unwritable_one_is_removed_at_exit(tmp_path):
    blocker = write(tmp_path, "a-file", "not a folder")
    result = subprocess.run([sys.executable, "-c", FALLBACK, str(blocker / "cache")],
                            capture_output=True, text=True, timeout=600, check=False)
    assert result.returncode == 0, result.stderr[-2000:]
    folder, filename = result.stdout.splitlines()
    assert "gagen-cache-" in folder and not Path(folder).exists()
    assert filename == "<string>"


# ==================================================================== 7. messages

@pytest.fixture(scope="module")
def rrr():
    return gagen.load("rrr")


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # NumPy on the hostile numbers
@pytest.mark.parametrize("method", ["dopri5", "rk4", "RK45"])
@pytest.mark.parametrize("qd0, names", [([1e200, 0, 0], "qd0[0] (q1) = 1e+200"),
                                        ([0, 1e155, -1e155], "qd0[1] (q2) = 1e+155")])
def test_a_nan_from_the_initial_state_says_so(rrr, method, qd0, names):
    error = refused(lambda: gagen.simulate(rrr, (0.0, 1.0), np.zeros(3), qd0, method=method),
                    NonFiniteStateError, "velocity terms at the initial qd0")
    assert names in str(error)
    assert "controller" not in str(error) and "mass matrix" not in str(error)


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # NumPy on the hostile numbers
def test_a_nan_from_the_controller_at_the_start_says_so(rrr):
    pd = gagen.PD(kp=1e308, kd=0.0, target=[-1e308, 0, 0])
    for method in ("dopri5", "RK45"):
        refused(lambda m=method: gagen.simulate(rrr, (0.0, 1.0), np.zeros(3), None, pd,
                                                method=m),
                NonFiniteStateError, "controller's torques at the initial state")


def test_batch_messages_trace_the_nan_per_run(rrr):
    qd0 = np.array([[0, 0, 0], [1e200, 0, 0], [0, 0, 0]])
    res = gagen.simulate_batch(rrr, (0.0, 0.2), np.zeros(3), qd0)
    assert res.ok.tolist() == [True, False, True]
    assert res.message[1] == ("dopri5 failed before the first sample: the velocity terms at "
                              "the initial qd0 are not finite: qd0[0] (q1) = 1e+200 is too "
                              "large for their products (its square overflows)")


@pytest.mark.parametrize("method, options", [("dopri5", {}), ("rk4", {"h": 1e-3})])
def test_simulate_batch_takes_wrenches_and_gives_simulate_s_numbers(tumblers, method,
                                                                   options):
    dyn = tumblers["compiled"]
    fext = {"arm": [0.0, 3.0, 30.0, 0.0, 1.0, 0.0], "box": [1.0, 0, 0, 0, 0, 0.5]}
    q0 = np.tile(dyn.neutral(), (3, 1))
    q0[1, 0] = 0.5
    qd0 = np.zeros((3, 7))
    qd0[2, 3] = 1.0
    res = gagen.simulate_batch(dyn, (0.0, 0.5), q0, qd0, method=method, fext=fext, **options)
    without = gagen.simulate_batch(dyn, (0.0, 0.5), q0, qd0, method=method, **options)
    for i in range(3):
        one = gagen.simulate(dyn, (0.0, 0.5), q0[i], qd0[i], method=method, fext=fext,
                             **options)
        assert np.array_equal(res.q[i], one.q) and np.array_equal(res.qd[i], one.qd)
    assert np.abs(res.q - without.q).max() > 0.1  # the wrenches acted
    refused(lambda: gagen.simulate_batch(dyn, (0.0, 0.5), q0, fext={"nowhere": np.zeros(6)}),
            KeyError, "unknown frame")
    refused(lambda: gagen.simulate_batch(dyn, (0.0, 0.5), q0, fext={"arm": [np.inf] * 6}),
            ValueError, "finite")


ALMOST_PHYSICAL = """<robot name="r">
  <link name="base"/>
  <link name="arm"><inertial><mass value="1"/>
    <inertia ixx="0.1" iyy="0.1" izz="0.21" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="j" type="revolute"><parent link="base"/><child link="arm"/>
    <axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
</robot>"""


def test_warnings_point_at_the_users_line(tmp_path, monkeypatch):
    path = write(tmp_path, "r.urdf", ALMOST_PHYSICAL)
    blocker = write(tmp_path, "a-file", "x")
    monkeypatch.setattr("gagen.building.cache._fallback_cache", tmp_path / "fallback")
    (tmp_path / "fallback").mkdir()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        resolve_model(path)
        line = sys._getframe().f_lineno - 1
        from gagen.building.cache import usable_cache_dir
        usable_cache_dir(blocker / "cache")
    kinds = {type(w.message).__name__: (w.filename, w.lineno) for w in caught}
    assert kinds["InertiaWarning"] == (__file__, line)
    assert kinds["CacheWarning"][0] == __file__


def test_the_checks_keep_the_dynamics_exact(tumblers):
    """The checks changed no number: the compiled floating model against its lambdify twin
    at random states with quaternions of any scale."""
    rng = np.random.default_rng(7)
    q = np.tile(tumblers["compiled"].neutral(), (5, 1))
    q[:, :3] = rng.normal(size=(5, 3))
    q[:, 3:7] = rng.normal(size=(5, 4)) * np.array([[1e-120], [1e-3], [1], [1e3], [1e120]])
    v = rng.normal(size=(5, 7))
    for name in ("gravity", "mass_matrix"):
        a = getattr(tumblers["compiled"], name)(q)
        b = getattr(tumblers["lambdify"], name)(q)
        assert np.allclose(a, b, rtol=1e-10, atol=1e-12)
    assert np.allclose(tumblers["compiled"].integrate(q, v, 0.1),
                       tumblers["lambdify"].integrate(q, v, 0.1), rtol=0, atol=1e-15)
