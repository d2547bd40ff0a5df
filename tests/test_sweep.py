"""`python -m gagen sweep` (issue 17): the draws, the stores (Zarr streamed in blocks, NPZ),
the figure and the statistics; every stored run is gagen.simulate's run of its inputs."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import zarr
from conftest import SHARED_URDF

import gagen
from gagen.app.cli import main
from gagen.app.sweep import parse_variation, run_sweep
from gagen.sim.controllers import default_controller


@pytest.mark.parametrize("text, expected", [
    ("m3=40:60", ("m3", None, 40.0, 60.0, None)),
    ("m[123]=20%", ("m[123]", None, None, None, 20.0)),
    ("q0.q2=-5:5", ("q0", "q2", -5.0, 5.0, None)),
    ("kp = 10%", ("kp", None, None, None, 10.0)),
])
def test_variations_are_parsed(text, expected):
    v = parse_variation(text)
    assert (v.name, v.coordinate, v.low, v.high, v.percent) == expected


@pytest.mark.parametrize("text", ["m3", "m3=1", "m3=2:1", "m3=a:b", "m3=100%", "m3=-1%",
                                  "m3=1:inf"])
def test_malformed_variations_are_refused(text):
    with pytest.raises(ValueError, match="--vary"):
        parse_variation(text)


def _stored_run(group, i):
    """gagen.simulate with the inputs the sweep stored for run i."""
    dyn = gagen.load("rrr")
    ctrl = gagen.PD(kp=group["kp"][i], kd=group["kd"][i], target=group["target"][i],
                    gravity_compensation=True)
    t = np.asarray(group["t"][:])
    return gagen.simulate(dyn, (0.0, t[-1]), group["q0"][i], group["qd0"][i], ctrl,
                          method="dopri5", p=np.asarray(group["p"][i]), t_eval=t)


def test_sweep_writes_a_zarr_store_the_figure_and_statistics(tmp_path, cache_dir, capsys):
    out = tmp_path / "mc.zarr"
    code = main(["sweep", "rrr", "--runs", "12", "--vary", "m[23]=20%", "--vary",
                 "q0.q2=-5:5", "--vary", "kp=10%", "--duration", "1", "--points", "21",
                 "--threads", "2", "--out", str(out), "--cache-dir", str(cache_dir)])
    assert code == 0
    stdout, stderr = capsys.readouterr()
    assert "12 runs in" in stdout and "0 failed" in stdout and "sweep [" in stderr
    group = zarr.open_group(str(out), mode="r")
    assert group["q"].shape == (12, 21, 3) and list(group.attrs["vary"]) == [
        "m[23]=20%", "q0.q2=-5:5", "kp=10%"]
    p = np.asarray(group["p"][:])
    names = list(group.attrs["parameters"])
    defaults = gagen.load("rrr").parameters
    for k, name in enumerate(names):
        varied = name in ("m2", "m3")
        assert (np.ptp(p[:, k]) > 0) == varied
        if varied:
            assert np.all(np.abs(p[:, k] / defaults[name] - 1) <= 0.2)
    q0 = np.asarray(group["q0"][:])
    assert np.all(np.abs(q0[:, 1]) <= math.radians(5)) and np.all(q0[:, [0, 2]] == 0)
    for i in (0, 7):
        one = _stored_run(group, i)
        assert np.array_equal(group["q"][i], one.q) and np.array_equal(group["tau"][i], one.tau)
    assert (np.asarray(group["status"][:]) == 0).all()
    stats = (tmp_path / "mc_final.csv").read_text().splitlines()
    assert stats[0].startswith("coordinate,unit,nominal,mean") and len(stats) == 4
    assert (tmp_path / "mc_fan.png").stat().st_size > 10_000


def test_streaming_in_blocks_gives_the_same_file_as_one_block(tmp_path, cache_dir):
    args = {"runs": 9, "variations": ["m3=40:60", "qd0=-20:20"], "duration": 0.5,
            "points": 11, "plot": False, "cache_dir": cache_dir}
    blocks = run_sweep("rrr", out=tmp_path / "blocks.zarr", block_runs=4, **args)
    one = run_sweep("rrr", out=tmp_path / "one.npz", **args)
    assert one.failed == blocks.failed == 0
    a = zarr.open_group(str(tmp_path / "blocks.zarr"), mode="r")
    with np.load(tmp_path / "one.npz") as b:
        for name in ("t", "q", "qd", "tau", "status", "nfev", "p", "q0", "qd0"):
            assert np.array_equal(np.asarray(a[name][:]), b[name]), name
        assert json.loads(str(b["attrs"]))["runs"] == 9


def test_sweep_errors_are_one_line(tmp_path, capsys):
    assert main(["sweep", "rrr", "--runs", "2", "--vary", "m9=1:2",
                 "--out", str(tmp_path / "x.npz")]) == 2
    assert "no parameter matches 'm9'" in capsys.readouterr().err
    assert main(["-q", "sweep", "rrr", "--runs", "2", "--out", str(tmp_path / "x.txt")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and ".zarr or .npz" in err
    (tmp_path / "not-a-store.zarr").mkdir()
    assert main(["-q", "sweep", "rrr", "--runs", "2", "--no-plot",
                 "--out", str(tmp_path / "not-a-store.zarr")]) == 1
    assert "not a Zarr store" in capsys.readouterr().err


# ------------------------------------------------------------------ a floating base

DOUBLE_PENDULUM = SHARED_URDF / "double_pendulum.urdf"
FLOATING_VARY = ["q0=-10:10", "q0.root_joint_z=0:1", "qd0=-20:20", "qd0.root_joint_wx=-30:30",
                 "m_link[12]=20%", "kp=10%"]


@pytest.fixture(scope="module")
def floating(cache_dir):
    """The double pendulum with a floating base: nq = 9 (the base's position and unit
    quaternion, two joints), nv = 8."""
    dyn = gagen.load(DOUBLE_PENDULUM, floating_base=True, cache_dir=cache_dir)
    assert (dyn.nq, dyn.nv) == (9, 8)
    return dyn


def _read_npz(path):
    with np.load(path) as f:
        arrays = {name: f[name] for name in f.files}
    return arrays, json.loads(str(arrays.pop("attrs")))


def test_a_floating_sweep_stores_q_by_configuration_and_gives_simulate_s_numbers(
        floating, tmp_path, cache_dir, capsys):
    """q (runs, samples, nq) named by `configuration`, qd and tau (runs, samples, nv) named
    by `coordinates`, in .npz and .zarr; the draws vary the joints and the named base
    entries, the quaternion starts at the identity; every run is simulate_batch's and
    gagen.simulate's run of its stored inputs, bit for bit; the statistics cover q."""
    dyn, runs, points = floating, 5, 11
    vary = [a for v in FLOATING_VARY for a in ("--vary", v)]
    assert main(["sweep", str(DOUBLE_PENDULUM), "--floating-base", "--runs", str(runs), *vary,
                 "--duration", "0.5", "--points", str(points), "--seed", "3", "--threads", "2",
                 "--out", str(tmp_path / "mc.npz"), "--cache-dir", str(cache_dir)]) == 0
    assert "5 runs in" in capsys.readouterr().out
    blocks = run_sweep(DOUBLE_PENDULUM, floating_base=True, runs=runs, variations=FLOATING_VARY,
                       duration=0.5, points=points, seed=3, out=tmp_path / "mc.zarr",
                       block_runs=2, plot=False, cache_dir=cache_dir)
    assert blocks.failed == 0 and blocks.final.shape == (runs, dyn.nq)
    npz, attrs = _read_npz(tmp_path / "mc.npz")
    group = zarr.open_group(str(tmp_path / "mc.zarr"), mode="r")
    for store, names in ((npz, attrs), (group, dict(group.attrs))):
        assert list(names["configuration"]) == dyn.configuration
        assert list(names["coordinates"]) == dyn.coordinates
        assert store["q"].shape == (runs, points, dyn.nq) and store["q0"].shape == (runs, dyn.nq)
        for name in ("qd", "tau"):
            assert store[name].shape == (runs, points, dyn.nv), name
        for name in ("qd0", "kp", "kd", "target"):
            assert store[name].shape == (runs, dyn.nv), name
    for name in ("t", "q", "qd", "tau", "status", "nfev", "p", "q0", "qd0", "kp", "kd", "target"):
        assert np.array_equal(np.asarray(group[name][:]), npz[name]), name
    assert (npz["status"] == 0).all()

    q0, qd0 = npz["q0"], npz["qd0"]
    entry = {name: k for k, name in enumerate(dyn.configuration)}
    assert np.array_equal(q0[:, 3:7], np.tile([0.0, 0.0, 0.0, 1.0], (runs, 1)))  # identity
    assert np.all(q0[:, [entry["root_joint_x"], entry["root_joint_y"]]] == 0)
    z = q0[:, entry["root_joint_z"]]
    assert np.all((0 <= z) & (z <= 1)) and np.ptp(z) > 0
    joints = q0[:, [entry["joint1"], entry["joint2"]]]
    assert np.all(np.abs(joints) <= math.radians(10)) and np.ptp(joints, axis=0).min() > 0
    coordinate = {name: k for k, name in enumerate(dyn.coordinates)}
    wx = qd0[:, coordinate["root_joint_wx"]]
    assert np.all(np.abs(wx) <= math.radians(30)) and np.ptp(wx) > 0
    assert np.all(qd0[:, :6][:, [0, 1, 2, 4, 5]] == 0)  # the other base rates: at rest
    assert np.all(np.abs(qd0[:, 6:]) <= math.radians(20)) and np.ptp(qd0[:, 6:], axis=0).min() > 0
    assert np.all(npz["kp"][:, 6:] != default_controller(dyn).kp[6:])

    t = npz["t"]
    controllers = [gagen.PD(kp=npz["kp"][i], kd=npz["kd"][i], target=npz["target"][i],
                            gravity_compensation=True) for i in range(runs)]
    batch = gagen.simulate_batch(dyn, (0.0, t[-1]), q0, qd0, controllers, p=npz["p"],
                                 t_eval=t, threads=2)
    for name in ("q", "qd", "tau"):
        assert np.array_equal(getattr(batch, name), npz[name]), name
    for i in (0, runs - 1):
        one = gagen.simulate(dyn, (0.0, t[-1]), q0[i], qd0[i], controllers[i],
                             method="dopri5", p=npz["p"][i], t_eval=t)
        for name in ("q", "qd", "tau"):
            assert np.array_equal(getattr(one, name), npz[name][i]), (name, i)

    rows = (tmp_path / "mc_final.csv").read_text().splitlines()
    table = [row.split(",") for row in rows[1:]]
    assert [row[0] for row in table] == dyn.configuration
    assert [row[1] for row in table] == ["m"] * 3 + ["1"] * 4 + ["deg"] * 2
    final = npz["q"][:, -1]
    nominal = gagen.simulate(dyn, (0.0, t[-1]), dyn.neutral(), None,
                             default_controller(dyn), method="dopri5", t_eval=t).q[-1]
    for k, row in enumerate(table):
        scale = math.degrees(1.0) if row[1] == "deg" else 1.0
        assert float(row[2]) == pytest.approx(nominal[k] * scale, rel=1e-12, abs=1e-15)
        assert float(row[3]) == pytest.approx(final[:, k].mean() * scale, rel=1e-12, abs=1e-15)
    assert (tmp_path / "mc_fan.png").stat().st_size > 10_000  # the joints' fan


@pytest.mark.parametrize("vary, says", [
    ("q0.root_joint_qx=-5:5", ("root_joint_qx is an entry of the unit quaternion of floating "
                               "joint 'root_joint' (root_joint_qx, root_joint_qy, "
                               "root_joint_qz, root_joint_qw)")),
    ("q0.root_joint_qw=0:1", "root_joint_qw is an entry of the unit quaternion"),
    ("kp.root_joint_vx=10%", "floating joint 'root_joint', which has no actuator"),
    ("target.root_joint_wz=-5:5", "which has no actuator: its target is not used"),
    ("q0.root_joint_vx=0:1", "no entry of q 'root_joint_vx' (q0: root_joint_x, "),
    ("qd0.root_joint_qx=0:1", "no coordinate 'root_joint_qx' (qd0: root_joint_vx, "),
])
def test_a_floating_base_s_quaternion_cannot_be_varied(floating, vary, says, tmp_path,
                                                       cache_dir, capsys):
    out = tmp_path / "x.npz"
    assert main(["-q", "sweep", str(DOUBLE_PENDULUM), "--floating-base", "--runs", "2",
                 "--vary", vary, "--no-plot", "--out", str(out),
                 "--cache-dir", str(cache_dir)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and says in err, err
    assert not out.exists()


def test_sweep_passes_floating_base_on(tmp_path, capsys):
    """--floating-base reaches the model's loading (a built-in model refuses it), as in
    `simulate`, instead of being ignored."""
    assert main(["-q", "sweep", "rrr", "--floating-base", "--runs", "2",
                 "--out", str(tmp_path / "x.npz")]) == 2
    assert "floating_base=True applies to a URDF" in capsys.readouterr().err


@pytest.mark.filterwarnings("error")
def test_a_diverging_rk4_run_is_reported_by_its_status_without_a_numpy_warning(
        floating, tmp_path, cache_dir):
    """rk4 (h = 0.2 ms) with joint2's kp drawn up to 1e6: runs 4 and 5 blow up through
    quaternions too large to square (their raw samples checked here), 0 and 1 otherwise.
    Each failed run says so in its status and message, as gagen.simulate raises it; no
    NumPy warning; every sample it reached keeps a unit quaternion (the norm overflowed to
    inf before, and the quaternion became 0)."""
    dyn, h = floating, 2e-4
    run = run_sweep(DOUBLE_PENDULUM, floating_base=True, runs=6, variations=["kp.joint2=1e3:1e6"],
                    method="rk4", step=h, duration=0.2, points=1001, seed=0,
                    out=tmp_path / "div.npz", plot=False, cache_dir=cache_dir)
    npz, attrs = _read_npz(tmp_path / "div.npz")
    assert list(npz["status"]) == [-105, -105, 0, 0, 2, 2] and run.failed == 4
    assert sorted(attrs["failures"]) == ["0", "1", "4", "5"]
    assert np.isnan(run.final[[0, 1, 4, 5]]).all() and np.isfinite(run.final[[2, 3]]).all()
    t = npz["t"]
    for i in (4, 5):  # the case this test is for: squared norms that overflow
        raw = _raw_rk4_samples(dyn, npz, i, t, h)
        reached = raw[~np.isnan(raw).any(axis=1)]
        assert np.abs(reached[:, 3:7]).max() > 1e155, "no longer overflows: pick other draws"
    for i in range(6):
        q = npz["q"][i]
        reached = q[~np.isnan(q).any(axis=1)]
        assert np.abs(np.linalg.norm(reached[:, 3:7], axis=1) - 1).max() < 1e-15, i
        if npz["status"][i]:
            ctrl = gagen.PD(kp=npz["kp"][i], kd=npz["kd"][i], target=npz["target"][i],
                            gravity_compensation=True)
            with pytest.raises(gagen.NonFiniteStateError) as info:
                gagen.simulate(dyn, (0.0, t[-1]), npz["q0"][i], npz["qd0"][i], ctrl,
                               method="rk4", h=h, t_eval=t)
            assert attrs["failures"][str(i)] == str(info.value)
            assert "rk4 failed after t = " in str(info.value)


def _raw_rk4_samples(dyn, npz, i, t, h):
    """Run i's samples as the compiled integrator leaves them (quaternions not normalised)."""
    from gagen.runtime import _native
    from gagen.sim.simulate import controller_spec

    ctrl = gagen.PD(kp=npz["kp"][i], kd=npz["kd"][i], target=npz["target"][i],
                    gravity_compensation=True)
    sim = _native.CompiledSimulation(dyn.kernels, npz["p"][0],
                                     **controller_spec(ctrl, "rk4", dyn.nv, dyn=dyn))
    q, *_ = sim.run("rk4", 0.0, float(t[-1]), npz["q0"][i], npz["qd0"][i], t, h=h)
    return q


@pytest.mark.filterwarnings("error")
def test_unit_quaternions_of_extreme_samples_need_no_warning():
    from gagen.runtime.manifold import unit_quaternion

    quat = np.array([[1e300, 0.0, -1e300, 0.0], [3e-200, 4e-200, 0.0, 0.0],
                     [1.7e308, -1.7e308, 1.7e308, 1.7e308], [1.0, 2.0, 3.0, 4.0],
                     [0.0, 0.0, 0.0, 0.0], [np.inf, 0.0, 0.0, 1.0], [np.nan, 0.0, 0.0, 1.0]])
    got = unit_quaternion(quat)
    s = math.sqrt(0.5)
    np.testing.assert_allclose(got[:4], [[s, 0, -s, 0], [0.6, 0.8, 0, 0], [0.5, -0.5, 0.5, 0.5],
                                         np.array([1, 2, 3, 4]) / math.sqrt(30)], rtol=1e-15)
    assert np.array_equal(got[3], quat[3] / np.linalg.norm(quat[3]))  # the usual case: as before
    assert np.isnan(got[4:]).all()
