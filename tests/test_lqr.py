"""The LQR example of docs/lqr.md (docs/lqr.py): a gain designed on dyn.linearize at an
unstable equilibrium of the paper's robot stabilises the nonlinear simulation."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest
from conftest import REPO

import gagen


@pytest.fixture(scope="module")
def example():
    spec = importlib.util.spec_from_file_location("lqr_example", REPO / "docs" / "lqr.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def dyn():
    return gagen.load("rrr", backend="lambdify")


def test_the_equilibrium_is_unstable_and_the_lqr_closes_the_loop(example, dyn):
    design = example.design_lqr(dyn)
    n = dyn.n
    np.testing.assert_allclose(dyn.forward_dynamics(design.q_eq, np.zeros(n), design.tau_eq),
                               0, atol=1e-12)
    assert np.linalg.eigvals(design.A).real.max() > 1.0          # it falls without control
    assert np.linalg.eigvals(design.A - design.B @ design.K).real.max() < -1.0

    closed = example.simulate_from(dyn, design, design.controller(), 2.0)
    start = np.abs(example.PERTURBATION).max()
    error = np.concatenate([closed.q[-1] - design.q_eq, closed.qd[-1]])
    assert np.abs(error).max() < 1e-4 * start
    open_loop = example.simulate_from(dyn, design, design.hold(), 1.0)
    assert np.abs(open_loop.q[-1] - design.q_eq).max() > 10 * start


def test_the_script_writes_its_figure(example, tmp_path, capsys):
    out = tmp_path / "lqr.png"
    assert example.main(["--out", str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "closed-loop eigenvalues" in capsys.readouterr().out
