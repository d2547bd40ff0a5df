"""The table of gagen's CasADi functions: one entry per function, naming the model's C
kernel that computes its value and how its Jacobian is computed.

An entry's C is fixed text of gagen's (never a description's): the body of a function
that computes the outputs from the inputs, and the body of one that fills the Jacobian's
blocks. The generator (`gagen.casadi.generate`) wraps both into CasADi's external-function
API, once per entry (or once per frame), with and without the parameters as an input.

Conventions of the C bodies (see templates/casadi.c.j2):

- Inputs and outputs are named after their ports: `q`, `qd`, ... and `p` (always there:
  the defaults, or the call's input), outputs `qdd`, `M`, ... Matrices are row-major, as
  gagen's kernels write them; the generated wrapper turns them into CasADi's column-major
  order. `frame` is the frame's number for the per-frame entries.
- A Jacobian body fills one block `D_<output>_<input>` per pair (row-major: one row per
  entry of the output in row-major order, one column per coordinate of the input). The
  block of q has `nv` columns, the derivative along the velocity directions that gagen's
  derivative kernels compute (Pinocchio's convention for a floating joint); the wrapper maps
  them onto q's `nq` entries (`tangent` below). An entry without a Jacobian body gets central
  differences of its value body, by every input's entries.
- The blocks by `p`, column by column, by what the parameter is to the entry (the classes
  below; `gagen.casadi.build.parameter_classes` tells a model's, and the wrapper's
  `gc_p_columns` picks the method, templates/casadi.c.j2):
  * a class the entry's `depends` does not name: the column is zero by structure, written
    without an evaluation (frame kinematics do not depend on masses nor on gravity; M, C,
    the centroidal quantities and the Delassus matrix not on gravity; only the inverse and
    forward dynamics on damping and friction);
  * gravity `g`: every quantity depends on it affinely (the dynamics see gravity only as
    the base's acceleration -g), so (X(g + h) - X(g)) / h is the column, one evaluation,
    exact up to rounding;
  * the inertial classes (body, armature, drag: parameters that the regressor Y and the
    placements do not depend on, and on which pi depends as a polynomial of degree 4 or
    less): the entry's `p_jacobian` body where it has one (dtau/dp = Y dpi/dp through the
    regressor, -M^-1 dtau/dp, dM/dp = (Y(q, 0, e_j) - Y(q, 0, 0)) dpi/dp, the Delassus
    matrix's -Y^T dM Y); else `inertia` says how: "polynomial" (a value linear in pi, hence
    of pi's degree in each parameter: the stencil exact for that degree, a central
    difference for <= 2, the five-point one for <= 4, whatever its step), or "quotient" (a
    centroidal value X = P / D, D the total mass, P quadratic in pi: the stencil of D X,
    and dX = (d(D X) - X dD) / D; by a parameter D does not depend on, X's own stencil);
  * kinematic (lengths, angles of a model file's joints; anything else): the five-point
    stencil with a small step: exact for values of degree <= 4 in the parameter (a length
    enters translations linearly and inertias as m L^2), O(h^4) otherwise.
- `GC_LWA` after a frame number passes LOCAL_WORLD_ALIGNED to the frame kernels that take
  a reference (and nothing to those that do not).
- `GC_TAKE(ptr, n)` takes n doubles of CasADi's work vector (the function fails, returning
  1, if the table's `work` was too small: the wrapper never writes past it); the kernels'
  status codes are returned as they are (non-zero: CasADi reports the evaluation failed).

To add a function (e.g. a new method of `Dynamics`, once its kernel is in the model's C),
add one `Entry` here: its ports, the C call of its kernel, and its Jacobian (a body using
gagen's derivative kernels, or None for central differences).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass


class Param(enum.IntFlag):
    """The classes of parameters (the same numbers in templates/casadi.c.j2): a parameter
    is of one class; an entry's `depends` is the union of those its value depends on."""

    KINEMATIC = 1       # lengths, angles: the placements depend on it (or anything else)
    GRAVITY = 2         # the model's gravity g
    BODY = 4            # a body's mass, centre of mass, inertia (pi's ten per body)
    ARMATURE = 8
    DRAG = 16           # joint damping and friction
    SIMULATION = 32     # coulomb_width: the width of the smoothed sign of friction that
                        # only simulations use (no function here: they take sign(qd))


INERTIAL = Param.BODY | Param.ARMATURE | Param.DRAG
EVERY = Param.KINEMATIC | Param.GRAVITY | INERTIAL
# how an entry without a `p_jacobian` body gets its columns by the inertial parameters
INERTIA_METHODS = ("p_jacobian", "polynomial", "quotient")


@dataclass(frozen=True)
class Port:
    """An input or output: its name and shape; sizes are numbers or the model's `nq`,
    `nv`, `np` (parameters)."""

    name: str
    rows: int | str
    cols: int | str = 1


@dataclass(frozen=True)
class Entry:
    """One CasADi function of the table (module docstring for the C conventions)."""

    name: str
    inputs: tuple[Port, ...]
    outputs: tuple[Port, ...]
    value: str
    jacobian: str | None = None
    p_jacobian: str | None = None
    # the doubles of work the Jacobian's body and the p Jacobian's body take (GC_TAKE), as
    # functions of the model's sizes
    work: object = None
    p_work: object = None
    per_frame: bool = False
    # the parameter classes the value depends on (module docstring); the method for the
    # inertial ones when there is no `p_jacobian` body
    depends: Param = EVERY
    inertia: str = "polynomial"
    # the Jacobian by q is along the velocity directions (nv columns), as gagen's
    # derivative kernels give it; False: the body fills q's nq columns itself
    tangent: bool = True
    # the model's kernels (<ident>_<name>) the bodies call: an entry whose kernels a model's
    # C does not declare is left out of its library
    requires: tuple[str, ...] = ()
    doc: str = ""

    def __post_init__(self):
        if self.inertia not in INERTIA_METHODS:
            raise ValueError(f"{self.name}: inertia '{self.inertia}' is none of "
                             f"{INERTIA_METHODS}")
        if (self.inertia == "p_jacobian") != (self.p_jacobian is not None):
            raise ValueError(f"{self.name}: inertia='p_jacobian' goes with a p_jacobian body")
        if self.depends & ~EVERY:  # nothing here depends on Param.SIMULATION
            raise ValueError(f"{self.name}: depends has unknown classes")

    def work_size(self, sizes: dict[str, int], with_p: bool) -> int:
        total = int(self.work(sizes)) if self.work is not None else 0
        if with_p and self.p_work is not None:
            total += int(self.p_work(sizes))
        return total


def _q(name: str = "q") -> Port:
    return Port(name, "nq")


def _v(name: str) -> Port:
    return Port(name, "nv")


FORWARD_DYNAMICS = Entry(
    name="forward_dynamics",
    inputs=(_q(), _v("qd"), _v("tau")),
    outputs=(_v("qdd"),),
    value="return {ident}_forward_dynamics(q, qd, tau, p, qdd);",
    # dqdd/dq, dqdd/dqd and M^-1 from the derivative module's kernel
    jacobian="return {ident}_forward_dynamics_derivatives(q, qd, tau, p, D_qdd_q, D_qdd_qd, "
             "D_qdd_tau);",
    # dqdd/dp = -M^-1 dtau/dp at qdd = forward_dynamics(q, qd, tau)
    p_jacobian="""
    double *acc, *dtau;
    int status;
    GC_TAKE(acc, NV);
    GC_TAKE(dtau, NV * NP);
    status = {ident}_forward_dynamics(q, qd, tau, p, acc);
    if (status) return status;
    status = gc_regressor_dp(q, qd, acc, p, dtau, ws);
    if (status) return status;
    gc_matmul(NV, NV, NP, D_qdd_tau, dtau, -1.0, D_qdd_p);
    return 0;""",
    p_work=lambda s: s["nv"] + s["nv"] * s["np"] + s["regressor_dp"],
    inertia="p_jacobian",
    requires=("forward_dynamics", "forward_dynamics_derivatives", "regressor",
              "regressor_parameters"),
    doc="qdd = forward_dynamics(q, qd, tau): the Jacobian from forward_dynamics_derivatives",
)

INVERSE_DYNAMICS = Entry(
    name="inverse_dynamics",
    inputs=(_q(), _v("qd"), _v("qdd")),
    outputs=(_v("tau"),),
    value="{ident}_inverse_dynamics(q, qd, qdd, p, tau);\n    return 0;",
    jacobian="""
    {ident}_inverse_dynamics_derivatives(q, qd, qdd, p, D_tau_q, D_tau_qd);
    {ident}_mass_matrix(q, p, D_tau_qdd);
    return 0;""",
    p_jacobian="return gc_regressor_dp(q, qd, qdd, p, D_tau_p, ws);",
    p_work=lambda s: s["regressor_dp"],
    inertia="p_jacobian",
    requires=("inverse_dynamics", "inverse_dynamics_derivatives", "mass_matrix",
              "regressor", "regressor_parameters"),
    doc="tau = inverse_dynamics(q, qd, qdd): the Jacobian from "
        "inverse_dynamics_derivatives and the mass matrix",
)

MASS_MATRIX = Entry(
    name="mass_matrix",
    inputs=(_q(),),
    outputs=(Port("M", "nv", "nv"),),
    value="{ident}_mass_matrix(q, p, M);\n    return 0;",
    # column j of M is tau(q, 0, e_j) - tau(q, 0, 0), so its derivative is the same
    # difference of dtau/dq (damping and friction vanish at qd = 0)
    jacobian="""
    double *g, *dq, *dqd, *e;
    int i, j, k;
    GC_TAKE(g, NV * NV);
    GC_TAKE(dq, NV * NV);
    GC_TAKE(dqd, NV * NV);
    GC_TAKE(e, NV);
    for (k = 0; k < NV; ++k) e[k] = 0.0;
    {ident}_inverse_dynamics_derivatives(q, e, e, p, g, dqd);
    for (j = 0; j < NV; ++j) {{
        e[j] = 1.0;
        {ident}_inverse_dynamics_derivatives(q, gc_zeros, e, p, dq, dqd);
        e[j] = 0.0;
        for (i = 0; i < NV; ++i)
            for (k = 0; k < NV; ++k)
                D_M_q[(i * NV + j) * NV + k] = dq[i * NV + k] - g[i * NV + k];
    }}
    return 0;""",
    work=lambda s: 3 * s["nv"] ** 2 + s["nv"],
    # column j of M is (Y(q, 0, e_j) - Y(q, 0, 0)) pi: dM/dp through the regressor (nv + 1
    # regressors, cheaper than the five-point stencil's 4 M per parameter on ANYmal C)
    p_jacobian="return gc_mass_matrix_dp(q, p, D_M_p, ws);",
    p_work=lambda s: s["mass_matrix_dp"],
    inertia="p_jacobian",
    depends=Param.KINEMATIC | Param.BODY | Param.ARMATURE,
    requires=("mass_matrix", "inverse_dynamics_derivatives", "regressor",
              "regressor_parameters"),
    doc="M = mass_matrix(q): the Jacobian from inverse_dynamics_derivatives at qd = 0, "
        "qdd = e_j",
)

GRAVITY = Entry(
    name="gravity",
    inputs=(_q(),),
    outputs=(_v("g"),),
    value="{ident}_gravity(q, p, g);\n    return 0;",
    jacobian="""
    double *dqd;
    GC_TAKE(dqd, NV * NV);
    {ident}_inverse_dynamics_derivatives(q, gc_zeros, gc_zeros, p, D_g_q, dqd);
    return 0;""",
    p_jacobian="return gc_regressor_dp(q, gc_zeros, gc_zeros, p, D_g_p, ws);",
    work=lambda s: s["nv"] ** 2,
    p_work=lambda s: s["regressor_dp"],
    inertia="p_jacobian",
    # damping and friction vanish at qd = 0, armature at qdd = 0
    depends=Param.KINEMATIC | Param.GRAVITY | Param.BODY,
    requires=("gravity", "inverse_dynamics_derivatives", "regressor",
              "regressor_parameters"),
    doc="g = gravity(q) = inverse_dynamics(q, 0, 0): the Jacobian from "
        "inverse_dynamics_derivatives",
)

CORIOLIS_MATRIX = Entry(
    name="coriolis_matrix",
    inputs=(_q(), _v("qd")),
    outputs=(Port("C", "nv", "nv"),),
    value="{ident}_coriolis_matrix(q, qd, p, C);\n    return 0;",
    # by q and qd the model's kernel coriolis_matrix_derivatives (Pinocchio's C differentiated
    # in forward mode by spatial algebra: each coordinate moves its subtree rigidly; by qd
    # it is C(q, e_k), C being linear in qd)
    jacobian="return {ident}_coriolis_matrix_derivatives(q, qd, p, NULL, D_C_q, D_C_qd);",
    # linear in the bodies' pi (Christoffel symbols of M); armature is constant in M
    depends=Param.KINEMATIC | Param.BODY,
    requires=("coriolis_matrix", "coriolis_matrix_derivatives"),
    doc="C = coriolis_matrix(q, qd): the Jacobian from coriolis_matrix_derivatives",
)

FRAME_PLACEMENT = Entry(
    name="frame_placement",
    inputs=(_q(),),
    outputs=(Port("R", 3, 3), Port("pos", 3)),
    value="return {ident}_frame_placement(q, p, frame, R, pos);",
    # d pos/dq_k is the frame Jacobian's linear column k; dR/dq_k = [w_k]x R with w_k its
    # angular column
    jacobian="""
    double *J;
    int a, b, k, status;
    GC_TAKE(J, 6 * NV);
    status = {ident}_frame_jacobian(q, p, frame GC_LWA, J);
    if (status) return status;
    status = {ident}_frame_placement(q, p, frame, R, pos);
    if (status) return status;
    for (k = 0; k < NV; ++k) {{
        const double w[3] = {{J[3 * NV + k], J[4 * NV + k], J[5 * NV + k]}};
        for (b = 0; b < 3; ++b) {{
            const double c[3] = {{R[b], R[3 + b], R[6 + b]}};
            double wc[3];
            gc_cross(w, c, wc);
            for (a = 0; a < 3; ++a) D_R_q[(3 * a + b) * NV + k] = wc[a];
        }}
        for (a = 0; a < 3; ++a) D_pos_q[a * NV + k] = J[a * NV + k];
    }}
    return 0;""",
    work=lambda s: 6 * s["nv"],
    per_frame=True,
    depends=Param.KINEMATIC,
    requires=("frame_placement", "frame_jacobian"),
    doc="(R, pos) = frame_placement(q, frame): the Jacobian from the frame Jacobian",
)

FRAME_JACOBIAN = Entry(
    name="frame_jacobian",
    inputs=(_q(),),
    outputs=(Port("J", 6, "nv"),),
    value="return {ident}_frame_jacobian(q, p, frame GC_LWA, J);",
    jacobian="""
    int status = {ident}_frame_jacobian(q, p, frame GC_LWA, J);
    if (status) return status;
    gc_jacobian_derivative(frame, J, D_J_q);
    return 0;""",
    per_frame=True,
    depends=Param.KINEMATIC,
    requires=("frame_jacobian",),
    doc="J = frame_jacobian(q, frame) (LOCAL_WORLD_ALIGNED): dJ/dq from J's own columns "
        "(each joint's twist moves the columns above it rigidly and the frame's point for "
        "those below)",
)

FRAME_VELOCITY = Entry(
    name="frame_velocity",
    inputs=(_q(), _v("qd")),
    outputs=(Port("v", 6),),
    value="return {ident}_frame_velocity(q, qd, p, frame GC_LWA, v);",
    jacobian="""
    double *dJ;
    int r, j, k, status;
    GC_TAKE(dJ, 6 * NV * NV);
    status = {ident}_frame_jacobian(q, p, frame GC_LWA, D_v_qd);
    if (status) return status;
    gc_jacobian_derivative(frame, D_v_qd, dJ);
    for (r = 0; r < 6; ++r)
        for (k = 0; k < NV; ++k) {{
            double s = 0.0;
            for (j = 0; j < NV; ++j) s += dJ[(r * NV + j) * NV + k] * qd[j];
            D_v_q[r * NV + k] = s;
        }}
    return 0;""",
    work=lambda s: 6 * s["nv"] ** 2,
    per_frame=True,
    depends=Param.KINEMATIC,
    requires=("frame_velocity", "frame_jacobian"),
    doc="v = frame_velocity(q, qd, frame) = J qd: dv/dqd = J, dv/dq = (dJ/dq) qd",
)

# --- the centre of mass and centroidal dynamics (where the model's C has them) -------------
# Their Jacobians by q are the model's analytic centroidal derivative kernels
# (model/centroidal_derivatives.c.j2: the motion subspaces' spatial algebra), along the
# velocity directions; by qd the maps themselves, or the kernels where a map depends on qd.
# By the bodies' inertial parameters each is P / D with D the moving bodies' total mass and
# P a polynomial in pi (the centre of mass is the mass-weighted mean of the bodies'; the
# centroidal maps take moments about it): the quotient rule on the exact stencil of D X.

CENTER_OF_MASS = Entry(
    name="center_of_mass",
    inputs=(_q(),),
    outputs=(Port("com", 3),),
    value="{ident}_center_of_mass(q, p, com);\n    return 0;",
    jacobian="{ident}_com_jacobian(q, p, D_com_q);\n    return 0;",
    depends=Param.KINEMATIC | Param.BODY,
    inertia="quotient",
    requires=("center_of_mass", "com_jacobian"),
    doc="com = center_of_mass(q): the Jacobian is com_jacobian",
)

COM_VELOCITY = Entry(
    name="com_velocity",
    inputs=(_q(), _v("qd")),
    outputs=(Port("vcom", 3),),
    value="{ident}_com_velocity(q, qd, p, vcom);\n    return 0;",
    jacobian="""
    {ident}_com_jacobian(q, p, D_vcom_qd);
    {ident}_com_velocity_derivatives(q, qd, p, D_vcom_q);
    return 0;""",
    depends=Param.KINEMATIC | Param.BODY,
    inertia="quotient",
    requires=("com_velocity", "com_jacobian", "com_velocity_derivatives"),
    doc="vcom = com_velocity(q, qd) = J_com qd: by qd J_com, by q com_velocity_derivatives",
)

COM_JACOBIAN = Entry(
    name="com_jacobian",
    inputs=(_q(),),
    outputs=(Port("J", 3, "nv"),),
    value="{ident}_com_jacobian(q, p, J);\n    return 0;",
    jacobian="{ident}_com_jacobian_derivatives(q, p, D_J_q);\n    return 0;",
    depends=Param.KINEMATIC | Param.BODY,
    inertia="quotient",
    requires=("com_jacobian", "com_jacobian_derivatives"),
    doc="J = com_jacobian(q): the Jacobian from com_jacobian_derivatives",
)

CENTROIDAL_MAP = Entry(
    name="centroidal_map",
    inputs=(_q(),),
    outputs=(Port("Ag", 6, "nv"),),
    value="{ident}_centroidal_map(q, p, Ag);\n    return 0;",
    jacobian="{ident}_centroidal_map_derivatives(q, p, D_Ag_q);\n    return 0;",
    depends=Param.KINEMATIC | Param.BODY,
    inertia="quotient",
    requires=("centroidal_map", "centroidal_map_derivatives"),
    doc="Ag = centroidal_map(q): the Jacobian from centroidal_map_derivatives",
)

CENTROIDAL_MOMENTUM = Entry(
    name="centroidal_momentum",
    inputs=(_q(), _v("qd")),
    outputs=(Port("hg", 6),),
    value="{ident}_centroidal_momentum(q, qd, p, hg);\n    return 0;",
    jacobian="""
    {ident}_centroidal_map(q, p, D_hg_qd);
    {ident}_centroidal_momentum_derivatives(q, qd, p, D_hg_q);
    return 0;""",
    depends=Param.KINEMATIC | Param.BODY,
    inertia="quotient",
    requires=("centroidal_momentum", "centroidal_map", "centroidal_momentum_derivatives"),
    doc="hg = centroidal_momentum(q, qd) = Ag qd: by qd Ag, by q "
        "centroidal_momentum_derivatives",
)

CENTROIDAL_MAP_TIME_VARIATION = Entry(
    name="centroidal_map_time_variation",
    inputs=(_q(), _v("qd")),
    outputs=(Port("dAg", 6, "nv"),),
    value="{ident}_centroidal_map_time_variation(q, qd, p, dAg);\n    return 0;",
    jacobian="{ident}_centroidal_map_time_variation_derivatives(q, qd, p, D_dAg_q, "
             "D_dAg_qd);\n    return 0;",
    depends=Param.KINEMATIC | Param.BODY,
    inertia="quotient",
    requires=("centroidal_map_time_variation", "centroidal_map_time_variation_derivatives"),
    doc="dAg = centroidal_map_time_variation(q, qd): the Jacobian from "
        "centroidal_map_time_variation_derivatives (by qd: dAg/dq)",
)

CENTROIDAL_BIAS = Entry(
    name="centroidal_bias",
    inputs=(_q(), _v("qd")),
    outputs=(Port("b", 6),),
    value="{ident}_centroidal_bias(q, qd, p, b);\n    return 0;",
    jacobian="{ident}_centroidal_bias_derivatives(q, qd, p, D_b_q, D_b_qd);\n    return 0;",
    depends=Param.KINEMATIC | Param.BODY,
    inertia="quotient",
    requires=("centroidal_bias", "centroidal_bias_derivatives"),
    doc="b = centroidal_bias(q, qd) = dAg qd: the Jacobian from centroidal_bias_derivatives",
)

# --- task space (where the model's C has it): LOCAL_WORLD_ALIGNED, classical accelerations ---

FRAME_ACCELERATION = Entry(
    name="frame_acceleration",
    inputs=(_q(), _v("qd"), _v("qdd")),
    outputs=(Port("a", 6),),
    value="return {ident}_frame_acceleration(q, qd, qdd, p, frame, GAGEN_LOCAL_WORLD_ALIGNED, "
          "GAGEN_CLASSICAL, a);",
    # a = J qdd + dJ/dt qd: by qdd the frame Jacobian; by q and qd the task-space derivative
    # kernel (spatial algebra on the frame's path)
    jacobian="""
    int rc = {ident}_frame_jacobian(q, p, frame GC_LWA, D_a_qdd);
    if (rc) return rc;
    return {ident}_frame_acceleration_derivatives(q, qd, qdd, p, frame, D_a_q, D_a_qd);""",
    per_frame=True,
    depends=Param.KINEMATIC,
    requires=("frame_acceleration", "frame_jacobian", "frame_acceleration_derivatives"),
    doc="a = frame_acceleration(q, qd, qdd, frame) (classical, LOCAL_WORLD_ALIGNED): by qdd "
        "the frame Jacobian, by q and qd frame_acceleration_derivatives",
)

FRAME_BIAS_ACCELERATION = Entry(
    name="frame_bias_acceleration",
    inputs=(_q(), _v("qd")),
    outputs=(Port("a", 6),),
    value="return {ident}_frame_bias_acceleration(q, qd, p, frame, "
          "GAGEN_LOCAL_WORLD_ALIGNED, GAGEN_CLASSICAL, a);",
    jacobian="return {ident}_frame_acceleration_derivatives(q, qd, NULL, p, frame, D_a_q, "
             "D_a_qd);",
    per_frame=True,
    depends=Param.KINEMATIC,
    requires=("frame_bias_acceleration", "frame_acceleration_derivatives"),
    doc="a = frame_bias_acceleration(q, qd, frame) = dJ/dt qd (classical, "
        "LOCAL_WORLD_ALIGNED): frame_acceleration_derivatives at qdd = 0",
)

FRAME_JACOBIAN_TIME_VARIATION = Entry(
    name="frame_jacobian_time_variation",
    inputs=(_q(), _v("qd")),
    outputs=(Port("dJ", 6, "nv"),),
    value="return {ident}_frame_jacobian_time_variation(q, qd, p, frame, "
          "GAGEN_LOCAL_WORLD_ALIGNED, dJ);",
    jacobian="return {ident}_frame_jacobian_time_variation_derivatives(q, qd, p, frame, "
             "D_dJ_q, D_dJ_qd);",
    per_frame=True,
    depends=Param.KINEMATIC,
    requires=("frame_jacobian_time_variation",
              "frame_jacobian_time_variation_derivatives"),
    doc="dJ = frame_jacobian_time_variation(q, qd, frame) (LOCAL_WORLD_ALIGNED): "
        "frame_jacobian_time_variation_derivatives (by qd it is dJ/dq)",
)

# The operational-space inertia is G's inverse: singular wherever a frame has fewer than six
# independent directions (most frames of most robots), where a CasADi function could only
# fail mid-optimisation; users solve with G instead (docs/casadi.md).
DELASSUS = Entry(
    name="delassus",
    inputs=(_q(),),
    outputs=(Port("G", 6, 6),),
    value="""double work[6 * NV];
    return {ident}_delassus(q, p, 1, &frame, 6, work, G);""",
    # dG = dJ Y + Y^T dJ^T - Y^T dM Y with Y = M^-1 J^T, in the model's C
    jacobian="return {ident}_delassus_derivatives(q, p, frame, NULL, D_G_q);",
    # by the inertial parameters dG = -Y^T dM Y (J does not depend on them), dM as
    # mass_matrix's
    p_jacobian="return gc_delassus_dp(q, p, frame, D_G_p, ws);",
    p_work=lambda s: s["delassus_dp"],
    inertia="p_jacobian",
    per_frame=True,
    depends=Param.KINEMATIC | Param.BODY | Param.ARMATURE,
    requires=("delassus", "delassus_derivatives", "mass_matrix", "frame_jacobian",
              "regressor", "regressor_parameters"),
    doc="G = delassus(q, frame) = J M^-1 J^T of the frame's LOCAL_WORLD_ALIGNED Jacobian "
        "(M factorised, never inverted): dG from delassus_derivatives",
)

# The table: the order of the dictionary gagen.casadi.functions returns.
ENTRIES: tuple[Entry, ...] = (FORWARD_DYNAMICS, INVERSE_DYNAMICS, MASS_MATRIX, GRAVITY,
                              CORIOLIS_MATRIX, FRAME_PLACEMENT, FRAME_JACOBIAN, FRAME_VELOCITY,
                              CENTER_OF_MASS, COM_VELOCITY, COM_JACOBIAN, CENTROIDAL_MAP,
                              CENTROIDAL_MOMENTUM, CENTROIDAL_MAP_TIME_VARIATION,
                              CENTROIDAL_BIAS, FRAME_ACCELERATION, FRAME_BIAS_ACCELERATION,
                              FRAME_JACOBIAN_TIME_VARIATION, DELASSUS)
