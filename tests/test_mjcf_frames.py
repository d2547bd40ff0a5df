"""MJCF body frames are MuJoCo's body frames, whatever the joints' anchors.

dm-control's suite (copies in tests/data/mjcf/dm_control) anchors most joints away from
their body's origin (walker, swimmer, fish, humanoid) and puts several joints on one body
(fish, humanoid). For every body, at random states (free bodies anywhere, any
orientation): gagen's `frame_placement` is MuJoCo's (xmat, xpos), its `frame_jacobian`
is `mj_jacBody`, a wrench on the body's frame (`fext`) is `mj_applyFT` at xpos, all to
1e-9; and the dynamics stay MuJoCo's: M is `mj_fullM`, the inverse dynamics at qdd = 0
without damping and friction is `qfrc_bias` (in gagen's coordinates:
gagen.reference.mujoco).
"""

from __future__ import annotations

import functools
import warnings
from pathlib import Path

import numpy as np
import pytest

import gagen
from gagen.model.mjcf import compile_mjcf
from gagen.reference.mujoco import MujocoState, body_names, random_configuration

mujoco = pytest.importorskip("mujoco")
# cheetah.xml uses MuJoCo's deprecated compiler attribute settotalmass
pytestmark = pytest.mark.filterwarnings("ignore:.*settotalmass:UserWarning")

DM_CONTROL = Path(__file__).resolve().parent / "data" / "mjcf" / "dm_control"
# joints anchored off their body's origin: walker, swimmer, fish, humanoid (cheetah none)
MODELS = ("walker", "swimmer", "fish", "cheetah", "humanoid")
# the humanoid's derivation takes 6-12 s on two cores: in the slow run
PARAMS = [pytest.param(name, marks=pytest.mark.slow) if name == "humanoid" else name
          for name in MODELS]
RTOL = 1e-9
STATES = 3


def close(actual, expected, what: str) -> None:
    actual, expected = np.asarray(actual, dtype=float), np.asarray(expected, dtype=float)
    scale = max(float(np.abs(expected).max()), 1.0)
    np.testing.assert_allclose(actual, expected, rtol=RTOL, atol=RTOL * scale, err_msg=what)


@functools.cache
def load(name: str):
    path = DM_CONTROL / f"{name}.xml"
    return gagen.load(path, backend="lambdify"), mujoco_model(name)


def mujoco_model(name: str):
    """MuJoCo's compiled model; its compiler's warnings (cheetah's deprecated
    settotalmass) as Python warnings, not into ./MUJOCO_LOG.TXT."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return compile_mjcf(DM_CONTROL / f"{name}.xml")


@pytest.fixture(params=PARAMS)
def loaded(request):
    return load(request.param)


def states(mj, seed: int = 0):
    rng = np.random.default_rng(seed)
    for _ in range(STATES):
        yield random_configuration(mj, rng), rng.uniform(-2, 2, mj.nv)


def test_the_suite_anchors_joints_away_from_their_bodies():
    """The models exercise the bug: joints anchored off their body's origin, and bodies
    with several joints."""
    offset, several = set(), set()
    for name in MODELS:
        mj = mujoco_model(name)
        if any(np.any(mj.jnt_pos[j]) for j in range(mj.njnt)):
            offset.add(name)
        if any(mj.body_jntnum[b] > 1 for b in range(mj.nbody)):
            several.add(name)
    assert offset == {"walker", "swimmer", "fish", "humanoid"}
    assert several == set(MODELS)  # the planar roots' three joints; fish's fins, tail;
    # humanoid's abdomen, hips, shoulders


def test_every_body_frame_is_mujocos(loaded):
    dyn, mj = loaded
    names = body_names(mj)
    assert set(names) <= set(dyn.frames)
    for q, qd in states(mj):
        ref = MujocoState(mj, q, qd)
        for body, name in enumerate(names, start=1):
            R, p = dyn.frame_placement(q, name)
            R_ref, p_ref = ref.body_placement(body)
            close(R, R_ref, f"{name}: orientation")
            close(p, p_ref, f"{name}: position")
            J = dyn.frame_jacobian(q, name)
            close(J, ref.body_jacobian(body), f"{name}: Jacobian")
            close(dyn.frame_velocity(q, qd, name), J @ qd, f"{name}: velocity")


def test_a_wrench_on_a_body_frame_is_mujocos(loaded):
    dyn, mj = loaded
    names = body_names(mj)
    rng = np.random.default_rng(4)
    q, qd = next(states(mj, seed=4))
    ref = MujocoState(mj, q, qd)
    qdd = np.zeros(mj.nv)
    free = dyn.inverse_dynamics(q, qd, qdd)
    for body, name in enumerate(names, start=1):
        wrench = rng.normal(size=6)
        pushed = dyn.inverse_dynamics(q, qd, qdd, fext={name: wrench})
        # the wrench does part of the work the joints did
        close(free - pushed, ref.body_wrench_force(body, wrench), f"{name}: fext")


def test_the_dynamics_stay_mujocos(loaded):
    dyn, mj = loaded
    rigid = {k: 0.0 for k in dyn.parameters if k.startswith(("damping_", "friction_"))}
    for q, qd in states(mj, seed=7):
        ref = MujocoState(mj, q, qd)
        close(dyn.mass_matrix(q), ref.mass_matrix(), "M")
        close(dyn.inverse_dynamics(q, qd, np.zeros(mj.nv), p=rigid), ref.bias(), "bias")


def test_a_joint_frame_is_at_its_anchor():
    """The frame of a body's joint is where MuJoCo anchors it (xanchor), the body's frame
    where its origin is (xpos)."""
    dyn, mj = load("walker")
    q = random_configuration(mj, np.random.default_rng(2))
    ref = MujocoState(mj, q)
    joint = mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_JOINT, "right_knee")
    body = int(mj.jnt_bodyid[joint])
    assert np.linalg.norm(mj.jnt_pos[joint]) > 0.1  # anchored 0.25 m off the leg's origin
    close(dyn.frame_placement(q, "right_knee")[1], ref.data.xanchor[joint], "anchor")
    close(dyn.frame_placement(q, "right_leg")[1], ref.data.xpos[body], "origin")


@pytest.mark.slow
def test_compiled_body_frames_are_mujocos(tmp_path):
    """The compiled backend places frames from the same offsets, in C."""
    path = DM_CONTROL / "walker.xml"
    dyn = gagen.load(path, cache_dir=tmp_path, verbose=False)
    mj = mujoco_model("walker")
    for q, qd in states(mj, seed=5):
        ref = MujocoState(mj, q, qd)
        for body, name in enumerate(body_names(mj), start=1):
            R, p = dyn.frame_placement(q, name)
            R_ref, p_ref = ref.body_placement(body)
            close(np.hstack([R, p[:, None]]), np.hstack([R_ref, p_ref[:, None]]), name)
            close(dyn.frame_jacobian(q, name), ref.body_jacobian(body), f"{name}: Jacobian")
            wrench = np.arange(1.0, 7.0)
            close(dyn.inverse_dynamics(q, qd, np.zeros(mj.nv))
                  - dyn.inverse_dynamics(q, qd, np.zeros(mj.nv), fext={name: wrench}),
                  ref.body_wrench_force(body, wrench), f"{name}: fext")
