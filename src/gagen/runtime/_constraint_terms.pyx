# cython: boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
# cython: language_level=3
"""The constrained forward dynamics' derivatives in C, one call from Python for one state or
stacked ones: a thin wrapper of gagen_constraint_derivatives.h (the C every model with
constraints also has as <model>_constrained_forward_dynamics_derivatives), which follows
gagen.runtime.constraint_derivatives's equations (its docstring; its NumPy is the
reference, and the path of the lambdify backend).

A Plan fills the header's gagen_cd_model from a compiled model's API tables (gagen_api.h,
as _native.pyx calls them: M, the bias forces, placements and frame Jacobians, and the
derivative module's inverse dynamics derivatives) and the layout of its declared
constraints, and selects an active set once (gagen_cd_select); `derivatives` runs the
header's gagen_cd_state per state with the GIL released and one workspace per call. A
state it refuses goes back to the caller, whose checked path raises the model's error."""

import numpy as np
cimport numpy as cnp

from cpython.pycapsule cimport PyCapsule_GetPointer
from libc.stdlib cimport free, malloc

cnp.import_array()


cdef extern from "gagen_api.h" nogil:
    enum:
        GAGEN_API_VERSION
    # the entries used here (the C compiler lays the structs out from the header)
    ctypedef struct gagen_model_api:
        int version
        int nq, nv, nb, nf, np
        const double *parameter_defaults
        void (*mass_matrix)(const double *q, const double *p, double *M) noexcept nogil
        void (*forcing)(const double *q, const double *qd, const double *tau,
                        const double *p, double *F) noexcept nogil
        void (*placements)(const double *q, const double *p, double *X) noexcept nogil
        void (*frame_offsets)(const double *p, double *F) noexcept nogil
        int (*frame_jacobians)(const double *q, const double *p, int count, const int *frames,
                               int reference, double *J) noexcept nogil
        int nc, ncrows
    ctypedef struct gagen_derivatives_api:
        int version
        int nq, nv, np
        void (*inverse_dynamics_derivatives)(const double *q, const double *qd,
                                             const double *qdd, const double *p,
                                             double *dtau_dq, double *dtau_dqd) noexcept nogil


cdef extern from "gagen_constraint_derivatives.h" nogil:
    enum:
        GAGEN_CD_TABLE
    ctypedef struct gagen_cd_model:
        int nq, nv, nb
        int nframes_model
        void (*mass_matrix)(const double *q, const double *p, double *M) noexcept nogil
        void (*forcing)(const double *q, const double *qd, const double *tau,
                        const double *p, double *F) noexcept nogil
        void (*placements)(const double *q, const double *p, double *X) noexcept nogil
        void (*frame_offsets)(const double *p, double *F) noexcept nogil
        int (*frame_jacobians)(const double *q, const double *p, int count, const int *frames,
                               int reference, double *J) noexcept nogil
        void (*inverse_dynamics_derivatives)(const double *q, const double *qd,
                                             const double *qdd, const double *p,
                                             double *dtau_dq, double *dtau_dqd) noexcept nogil
        const int *parent
        const int *desc_ptr
        const int *desc
        int nquat
        const int *quat
        int nc, nrows
        const int *table
        int nf
        const int *frames
        const int *bodies
        const int *chain
        const int *chain_len
        const int *group_start
        const int *group_end
        const double *order
    ctypedef struct gagen_cd_set:
        const gagen_cd_model *model
        int nf, nc, m
    Py_ssize_t GAGEN_CD_WORKSPACE(Py_ssize_t nv, Py_ssize_t nb, Py_ssize_t nf, Py_ssize_t m,
                                  Py_ssize_t nrows)
    Py_ssize_t GAGEN_CD_INTS(Py_ssize_t nv, Py_ssize_t m)
    Py_ssize_t GAGEN_CD_SELECT_INTS(Py_ssize_t nv, Py_ssize_t nf, Py_ssize_t nc,
                                    Py_ssize_t nrows)
    Py_ssize_t GAGEN_CD_SELECT_DOUBLES(Py_ssize_t nv, Py_ssize_t nf)
    void gagen_cd_select(const gagen_cd_model *model, const unsigned char *active,
                         gagen_cd_set *set, int *ints, double *doubles)
    int gagen_cd_state(const gagen_cd_set *c, const double *q, const double *qd,
                       const double *tau, const double *p, const double *Fo, double kd,
                       double damping, double *ws, int *ints, double *o0, double *o1,
                       double *o2, double *o3, double *o4, double *o5)


cdef void *_table(object capsule, str name) except NULL:
    """A model's (or derivative module's) API table, its version checked."""
    cdef void *table = PyCapsule_GetPointer(capsule, name.encode())
    if (<int *>table)[0] != GAGEN_API_VERSION:
        raise ImportError(f"the module's API version {(<int *>table)[0]} is not the "
                          f"runtime's {GAGEN_API_VERSION}; rebuild the model")
    return table


cdef const void *_first(x):
    """The address of a contiguous array's first entry (NULL for an empty one)."""
    cdef cnp.ndarray a = x
    return cnp.PyArray_DATA(a) if a.size else NULL


cdef class Plan:
    """The C's view of one model and active set (gagen.runtime.constraint_derivatives
    keeps one per model and set): the header's model (the two API tables and the layout
    of every declared constraint) and the active set gagen_cd_select chose from it."""

    cdef gagen_cd_model model
    cdef gagen_cd_set c
    cdef object _keep
    cdef readonly int nq, nv, nrows
    cdef double[::1] _offsets  # the frames' offsets at the default parameters
    cdef const double *defaults

    def __init__(self, model_capsule, derivative_capsule, frames, bodies, table, parent, quat,
                 chain, chain_len, group_start, group_end, order, active, desc_ptr, desc):
        """The layout of every declared constraint (constraint_derivatives._layout with
        every one active; C-contiguous int32, order float64) and `active` (uint8, one per
        constraint)."""
        cdef const gagen_model_api *api = <const gagen_model_api *>_table(
            model_capsule, "gagen.model_api")
        cdef const gagen_derivatives_api *dapi = <const gagen_derivatives_api *>_table(
            derivative_capsule, "gagen.derivatives_api")
        if dapi.nv != api.nv or dapi.nq != api.nq or dapi.np != api.np:
            raise ValueError("the derivative module's sizes are not the model's")
        ints = (frames, bodies, table, parent, quat, chain, chain_len, group_start,
                group_end, desc_ptr, desc)
        for x in ints:
            if type(x) is not np.ndarray or x.dtype != np.int32 or not x.flags.c_contiguous:
                raise TypeError("the layout's arrays are C-contiguous int32 arrays")
        if type(order) is not np.ndarray or order.dtype != np.float64 \
                or not order.flags.c_contiguous or type(active) is not np.ndarray \
                or active.dtype != np.uint8 or not active.flags.c_contiguous:
            raise TypeError("order is a C-contiguous float64 array, active a uint8 one")
        cdef int nv = api.nv, nf = frames.shape[0]
        if parent.shape[0] != nv or active.shape[0] != api.nc or table.shape[0] != api.nc \
                or (api.nc and table.shape[1] != GAGEN_CD_TABLE) or bodies.shape[0] != nf \
                or chain.size != nf * nv or group_start.size != nf * nv \
                or group_end.size != nf * nv or chain_len.shape[0] != nf \
                or order.size != nf * nv * nv:
            raise ValueError("the layout's sizes are not the model's")
        if desc_ptr.shape[0] != nv + 1 or desc.shape[0] < desc_ptr[nv]:
            raise ValueError("the descendants' sizes are not the model's")
        if np.any(frames >= api.nf) or np.any(table[:, :2] >= nf) or np.any(
                table[:, 4] > 6) or (api.nc and table[:, 4].sum() != api.ncrows):
            raise ValueError("the constraint table is not the model's")
        cdef int[::1] picked = np.zeros(GAGEN_CD_SELECT_INTS(nv, nf, api.nc, api.ncrows),
                                        dtype=np.int32)
        cdef double[::1] chosen = np.zeros(GAGEN_CD_SELECT_DOUBLES(nv, nf))
        self._keep = (model_capsule, derivative_capsule, ints, order, active, picked, chosen)
        self.nq, self.nv, self.nrows = api.nq, api.nv, api.ncrows
        self.defaults = api.parameter_defaults
        m = &self.model
        m.nq, m.nv, m.nb, m.nframes_model = api.nq, api.nv, api.nb, api.nf
        m.mass_matrix, m.forcing, m.placements = api.mass_matrix, api.forcing, api.placements
        m.frame_offsets, m.frame_jacobians = api.frame_offsets, api.frame_jacobians
        m.inverse_dynamics_derivatives = dapi.inverse_dynamics_derivatives
        m.parent = <const int *>_first(parent)
        m.desc_ptr = <const int *>_first(desc_ptr)
        m.desc = <const int *>_first(desc)
        m.nquat, m.quat = quat.shape[0], <const int *>_first(quat)
        m.nc, m.nrows, m.table = api.nc, api.ncrows, <const int *>_first(table)
        m.nf, m.frames, m.bodies = nf, <const int *>_first(frames), <const int *>_first(bodies)
        m.chain, m.chain_len = <const int *>_first(chain), <const int *>_first(chain_len)
        m.group_start = <const int *>_first(group_start)
        m.group_end = <const int *>_first(group_end)
        m.order = <const double *>_first(order)
        gagen_cd_select(m, <const unsigned char *>_first(active), &self.c, &picked[0],
                        &chosen[0])
        self._offsets = np.zeros(12 * api.nf + 1)
        api.frame_offsets(api.parameter_defaults, &self._offsets[0])


def derivatives(Plan plan, q, qd, tau, p, double kd, double damping):
    """(∂q̈/∂q, ∂q̈/∂q̇, ∂q̈/∂τ, ∂forces/∂q, ∂forces/∂q̇, ∂forces/∂τ), fresh arrays, at one
    state (q (nq,), qd, tau (nv,)) or stacked states ((N, ·), one C loop without the GIL);
    p None (the defaults) or the full parameter vector. None where an input is not a
    C-contiguous float64 array of the plan's shape, or where a state fails (a quaternion
    that cannot be normalised, a kernel's error, a pivot <= 0): the caller's own path then
    raises its error or answers."""
    cdef const gagen_cd_set *c = &plan.c
    cdef Py_ssize_t n = plan.nv, nq = plan.nq, R = plan.nrows, count, i
    cdef cnp.ndarray a, b, t, pa
    if not (kd >= 0.0 and damping >= 0.0):
        return None
    for x in (q, qd, tau):
        if type(x) is not np.ndarray or (<cnp.ndarray>x).dtype.num != cnp.NPY_DOUBLE \
                or not cnp.PyArray_IS_C_CONTIGUOUS(<cnp.ndarray>x):
            return None
    a, b, t = q, qd, tau
    cdef int nd = a.ndim
    if b.ndim != nd or t.ndim != nd or nd not in (1, 2) or a.shape[nd - 1] != nq \
            or b.shape[nd - 1] != n or t.shape[nd - 1] != n:
        return None
    if nd == 2:
        count = a.shape[0]
        if b.shape[0] != count or t.shape[0] != count:
            return None
    else:
        count = 1
    cdef const double *pp = plan.defaults
    if p is not None:
        pa = p
        pp = <const double *>cnp.PyArray_DATA(pa)
    cdef cnp.npy_intp dims[3]
    dims[0] = count
    dims[1] = n
    dims[2] = n
    cdef int lead = 1 if nd == 2 else 0
    outs = [cnp.PyArray_EMPTY(2 + lead, &dims[1 - lead], cnp.NPY_DOUBLE, 0) for _ in range(3)]
    dims[1] = R
    outs += [cnp.PyArray_EMPTY(2 + lead, &dims[1 - lead], cnp.NPY_DOUBLE, 0) for _ in range(3)]
    cdef double *o[6]
    for i in range(6):
        o[i] = <double *>cnp.PyArray_DATA(<cnp.ndarray>outs[i])
    cdef const double *qa = <const double *>cnp.PyArray_DATA(a)
    cdef const double *qb = <const double *>cnp.PyArray_DATA(b)
    cdef const double *qt = <const double *>cnp.PyArray_DATA(t)
    cdef Py_ssize_t work = GAGEN_CD_WORKSPACE(n, plan.model.nb, c.nf, c.m, R)
    cdef double *ws = <double *>malloc((work + 12 * plan.model.nframes_model + 1)
                                       * sizeof(double))
    cdef int *ints = <int *>malloc(GAGEN_CD_INTS(n, c.m) * sizeof(int))
    cdef int status = 0
    if ws == NULL or ints == NULL:
        free(ws)
        free(ints)
        raise MemoryError()
    cdef const double *Fo = &plan._offsets[0]
    cdef bint given = p is not None
    with nogil:
        if given:
            plan.model.frame_offsets(pp, ws + work)
            Fo = ws + work
        for i in range(count):
            status = gagen_cd_state(c, qa + i * nq, qb + i * n, qt + i * n, pp, Fo, kd,
                                    damping, ws, ints, o[0] + i * n * n, o[1] + i * n * n,
                                    o[2] + i * n * n, o[3] + i * R * n, o[4] + i * R * n,
                                    o[5] + i * R * n)
            if status:
                break
    free(ws)
    free(ints)
    if status:
        return None
    return tuple(outs)
