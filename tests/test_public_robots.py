"""Public robots load, in Pinocchio's order, and match Pinocchio in that order.

- Every shared and test robot (tests/data/urdf), fixed and floating: gagen's joints come
  in the order of `pinocchio.buildModelFromUrdf` of the same file (depth-first, siblings
  by joint name), so a q, qd or tau passes between the two as it is; and the test
  helpers' Pinocchio builder (gagen.reference.pinocchio), which permutes, now has nothing
  to permute.
- In the slow run, a sample of example-robot-data (`pip install example-robot-data`),
  each against Pinocchio's own parse in its own order, with no permutation: M, forward and
  inverse dynamics, every frame's placement and Jacobian to 1e-9. The sample has the
  legged robots and humanoids whose order used to differ, icub (a point-mass link
  written with round-off), alex_psyonic_hands (mimic tags naming no joint), the PR2
  (continuous joints: Pinocchio's q has their cos and sin) and Kinova (angles a few 1e-10
  from quarter turns, taken as written).
"""

from __future__ import annotations

import importlib.metadata
import warnings
from pathlib import Path

import numpy as np
import pytest

import gagen
from gagen.model.resolve import resolve_model
from gagen.reference.pinocchio import (
    compare_with_urdf_parse,
    pinocchio_model,
    urdf_configuration,
    urdf_joint_names,
)

pin = pytest.importorskip("pinocchio")

URDF = Path(__file__).resolve().parent / "data" / "urdf"
TEST_ROBOTS = sorted(p.name for p in URDF.glob("*.urdf"))
RTOL = 1e-9


def pinocchio_parse(path: Path, floating: bool):
    return (pin.buildModelFromUrdf(str(path), pin.JointModelFreeFlyer()) if floating
            else pin.buildModelFromUrdf(str(path)))


def quietly(load, *args, **kwargs):
    """Load without the InertiaWarnings of CAD round-off (the Allegro hand, ANYmal C)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", gagen.InertiaWarning)
        return load(*args, **kwargs)


@pytest.mark.parametrize("floating", [False, True], ids=["fixed", "floating"])
@pytest.mark.parametrize("filename", TEST_ROBOTS)
def test_joint_order_is_pinocchios(filename, floating):
    pm = pinocchio_parse(URDF / filename, floating)
    model = quietly(resolve_model, URDF / filename, floating_base=floating)
    assert urdf_joint_names(model) == list(pm.names)[1:]
    # every joint starts at Pinocchio's velocity index: qd, qdd and tau pass as they are
    starts = [iv for _, iv in model.indices().values()]
    assert starts == list(pm.idx_vs)[1:]
    # the test helpers' builder walks the tree depth-first in gagen's body order: identity
    built = pinocchio_model(model)
    np.testing.assert_array_equal(built.gagen_order, np.arange(model.nv))
    np.testing.assert_array_equal(built.gagen_configuration_order, np.arange(model.nq))


def test_a_root_link_called_world_floats_as_world_link():
    """The UR5's root link is `world` (welded to base_link): with floating_base=True
    Pinocchio floats that link, and gagen does too, as `world_link`."""
    dyn = gagen.load(URDF / "ur5_robot.urdf", backend="lambdify", floating_base=True)
    pm = pinocchio_parse(URDF / "ur5_robot.urdf", True)
    assert "world_link" in dyn.frames and dyn.nq == pm.nq == 13
    errors = compare_with_urdf_parse(dyn, pm, np.random.default_rng(1), states=2)
    assert max(errors.values()) < RTOL, errors
    q = urdf_configuration(pm, dyn.neutral())
    q[:3] = [0.3, -0.2, 1.0]
    data = pm.createData()
    pin.framesForwardKinematics(pm, data, q)
    R, p = dyn.frame_placement(q, "world_link")  # Pinocchio's BODY frame "world"
    placed = data.oMf[pm.getFrameId("world", pin.BODY)]
    np.testing.assert_allclose(p, placed.translation, atol=1e-12)
    np.testing.assert_allclose(R, placed.rotation, atol=1e-12)


def test_a_continuous_joint_is_one_angle_where_pinocchio_has_cos_and_sin():
    """The one difference of q left (README): Pinocchio's unbounded revolute joints."""
    pm = pin.buildModelFromUrdf(str(URDF / "talos_reduced.urdf"))
    model = resolve_model(URDF / "talos_reduced.urdf")
    assert pm.nq == pm.nv == model.nq  # Talos has no continuous joint: q passes as it is
    text = (URDF / "double_pendulum.urdf").read_text().replace('type="revolute"',
                                                              'type="continuous"', 1)
    pm = pin.buildModelFromXML(text)
    assert (pm.nq, pm.nv) == (3, 2)
    q = np.array([0.3, -0.7])
    np.testing.assert_allclose(urdf_configuration(pm, q), [np.cos(0.3), np.sin(0.3), -0.7])


# --- example-robot-data, in the slow run ------------------------------------------------------

# (path under robots/, floating base): legged robots and humanoids whose order differed
# from Pinocchio's, and the special cases of the module's docstring
SAMPLE = (
    ("a1_description/urdf/a1.urdf", True),
    ("solo_description/robots/solo12.urdf", True),
    ("icub_description/robots/icub_reduced.urdf", True),
    ("baxter_description/urdf/baxter.urdf", False),
    ("pr2_description/urdf/pr2.urdf", False),
    ("kinova_description/robots/kinova.urdf", False),
    ("alex_description/urdf/alex_psyonic_hands.urdf", False),
)


def example_robot_data() -> Path:
    """example-robot-data's robots/ folder (a cmeel package: data, no Python module)."""
    try:
        dist = importlib.metadata.distribution("example-robot-data")
    except importlib.metadata.PackageNotFoundError:
        pytest.skip("example-robot-data is not installed (pip install example-robot-data)")
    return Path(dist.locate_file("cmeel.prefix/share/example-robot-data/robots"))


@pytest.mark.slow
@pytest.mark.parametrize("path, floating", SAMPLE, ids=[p.split("/")[-1] for p, _ in SAMPLE])
def test_example_robot_data_matches_pinocchio_in_its_own_order(path, floating):
    urdf = example_robot_data() / path
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        dyn = gagen.load(urdf, backend="lambdify", floating_base=floating)
    # only the CAD round-off of welded parts warns (InertiaWarning: the PR2's head, the
    # Psyonic hands' bases); icub's round-off around a zero inertia is no defect
    mimics = [str(w.message) for w in record if not issubclass(w.category,
                                                                gagen.InertiaWarning)]
    if "alex_psyonic" in path:  # each of the 8 dangling mimic tags, naming its joint
        assert len(mimics) == 8 and all("mimics unknown joint" in m for m in mimics)
        assert any("joint 'Left_index_q2', mimic: mimics unknown joint 'index_q1'" in m
                   for m in mimics)
    else:
        assert mimics == []
    if "icub" in path:
        assert record == []
    errors = compare_with_urdf_parse(dyn, pinocchio_parse(urdf, floating),
                                     np.random.default_rng(0), states=2)
    assert max(errors.values()) < RTOL, errors
