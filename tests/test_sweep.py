"""`python -m gagen sweep` (issue 17): the draws, the stores (Zarr streamed in blocks, NPZ),
the figure and the statistics; every stored run is gagen.simulate's run of its inputs."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import zarr

import gagen
from gagen.app.cli import main
from gagen.app.sweep import parse_variation, run_sweep


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
