# cython: boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
# cython: language_level=3
"""The constrained forward dynamics' derivatives in C, one call from Python for one state or
stacked ones: gagen.runtime.constraint_derivatives's equations (its docstring; its NumPy is
the reference this follows, and the path of the lambdify backend).

Per state, with the GIL released and one workspace per call: the model's kernels through
its API tables (gagen_api.h, as _native.pyx calls them: M, the bias forces, placements and
frame Jacobians, and the derivative module's inverse dynamics derivatives); the
constrained frames' chains (their twists, velocities and accelerations, O(chain) each),
which give the active rows' J and drift; the constrained forward dynamics through M's
tree-sparse factors M = Lᵀ D L (no fill-in outside each coordinate's ancestors, as the
model's gagen_ltdl) and the Delassus matrix's G = (J L⁻¹) D⁻¹ (J L⁻¹)ᵀ = Lg Dg Lgᵀ, with
the model's pivot tests (a state they refuse goes back to the caller, whose checked path
raises the model's error); then the constraint terms and the KKT solves for all 3 nv
right-hand sides at once on the same factors."""

import numpy as np
cimport numpy as cnp

from cpython.pycapsule cimport PyCapsule_GetPointer
from libc.float cimport DBL_MAX, DBL_MIN
from libc.math cimport sqrt
from libc.stdlib cimport free, malloc
from libc.string cimport memset

cnp.import_array()

cdef extern from *:
    """
    /* y -= sum_t coef[t] * (row idx[t] of base, stride apart), over len entries: each block
       of y's entries is read and written once, its sources' rows summed in registers (a
       row axpy per source would load and store y once for each). On x86-64 with GCC or
       clang under glibc, a clone for AVX2 CPUs (chosen when the module loads) runs the same
       operations in the same order four wide: its results are the default's, bit for bit
       (no FMA contraction: the target adds no "fma"). */
    #if defined(__x86_64__) && defined(__linux__) && (defined(__GNUC__) || defined(__clang__)) \
        && !defined(GAGEN_NO_CLONES)
    __attribute__((target_clones("avx2", "default")))
    #endif
    static void gagen_ct_gather(double *y, const double *base, Py_ssize_t stride,
                                const int *idx, const double *coef, int count,
                                Py_ssize_t len)
    {
        Py_ssize_t c = 0;
        int t;
        if (count == 0) return;
        for (; c + 8 <= len; c += 8) {
            double a0 = y[c], a1 = y[c + 1], a2 = y[c + 2], a3 = y[c + 3];
            double a4 = y[c + 4], a5 = y[c + 5], a6 = y[c + 6], a7 = y[c + 7];
            for (t = 0; t < count; ++t) {
                const double *x = base + idx[t] * stride + c, w = coef[t];
                a0 -= w * x[0]; a1 -= w * x[1]; a2 -= w * x[2]; a3 -= w * x[3];
                a4 -= w * x[4]; a5 -= w * x[5]; a6 -= w * x[6]; a7 -= w * x[7];
            }
            y[c] = a0; y[c + 1] = a1; y[c + 2] = a2; y[c + 3] = a3;
            y[c + 4] = a4; y[c + 5] = a5; y[c + 6] = a6; y[c + 7] = a7;
        }
        for (; c + 2 <= len; c += 2) {
            double a0 = y[c], a1 = y[c + 1];
            for (t = 0; t < count; ++t) {
                const double *x = base + idx[t] * stride + c, w = coef[t];
                a0 -= w * x[0]; a1 -= w * x[1];
            }
            y[c] = a0; y[c + 1] = a1;
        }
        for (; c < len; ++c) {
            double a0 = y[c];
            for (t = 0; t < count; ++t) a0 -= coef[t] * base[idx[t] * stride + c];
            y[c] = a0;
        }
    }
    """
    void gagen_ct_gather(double *y, const double *base, Py_ssize_t stride, const int *idx,
                         const double *coef, int count, Py_ssize_t len) noexcept nogil


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

# the frame Jacobians' reference (the model's GAGEN_LOCAL_WORLD_ALIGNED)
cdef int LOCAL_WORLD_ALIGNED = 2
# the table of a constraint: [frame A, frame B or -1, holds a frame, local, axes, axes...]
cdef int TABLE = 11


cdef inline void cross3(const double *a, const double *b, double *out) noexcept nogil:
    cdef double x = a[1] * b[2] - a[2] * b[1]
    cdef double y = a[2] * b[0] - a[0] * b[2]
    cdef double z = a[0] * b[1] - a[1] * b[0]
    out[0] = x
    out[1] = y
    out[2] = z


cdef inline void mcross(const double *a, const double *b, double *out) noexcept nogil:
    """The spatial cross product of twists a × b (linear first)."""
    cdef double t1[3]
    cdef double t2[3]
    cdef double t3[3]
    cross3(a + 3, b, t1)
    cross3(a, b + 3, t2)
    cross3(a + 3, b + 3, t3)
    cdef int i
    for i in range(3):
        out[i] = t1[i] + t2[i]
        out[3 + i] = t3[i]


cdef inline void fcross(const double *a, const double *f, double *out) noexcept nogil:
    """The dual cross product a ×* f of a twist and a wrench (linear first):
    (a_w × f_l, a_w × f_τ + a_l × f_l)."""
    cdef double t1[3]
    cdef double t2[3]
    cdef double t3[3]
    cross3(a + 3, f, t1)
    cross3(a + 3, f + 3, t2)
    cross3(a, f, t3)
    cdef int i
    for i in range(3):
        out[i] = t1[i]
        out[3 + i] = t2[i] + t3[i]


cdef inline void add_cross(const double *a, const double *b, double scale,
                           double *out) noexcept nogil:
    """out += scale (a × b)."""
    cdef double t[3]
    cross3(a, b, t)
    out[0] += scale * t[0]
    out[1] += scale * t[1]
    out[2] += scale * t[2]


cdef inline void axpy(double *y, const double *x, double a, Py_ssize_t n) noexcept nogil:
    cdef Py_ssize_t i
    for i in range(n):
        y[i] += a * x[i]


cdef void *_table(object capsule, str name) except NULL:
    """A model's (or derivative module's) API table, its version checked."""
    cdef void *table = PyCapsule_GetPointer(capsule, name.encode())
    if (<int *>table)[0] != GAGEN_API_VERSION:
        raise ImportError(f"the module's API version {(<int *>table)[0]} is not the "
                          f"runtime's {GAGEN_API_VERSION}; rebuild the model")
    return table


cdef struct Ctx:
    # one active set of one model, fixed for a call
    const gagen_model_api *api
    const gagen_derivatives_api *dapi
    int nv, nb, nf, nfm, m, nrows, nquat
    const int *frames      # (nf,) the constrained frames' numbers
    const int *bodies      # (nf,) their bodies (-1: the world)
    const int *table       # (nc, TABLE) the active constraints
    int nc
    const int *parent      # (nv,) each coordinate's parent (λ)
    const int *desc_ptr    # (nv + 1,) CSR of each coordinate's descendants (k: i ∈ λ*(k))
    const int *desc
    const int *rows        # (m,) the active rows among every declared row
    const int *quat        # (nquat,) where each quaternion starts in q
    const int *chain       # (nf, nv) each frame's chain's coordinates, root first
    const int *chain_len   # (nf,)
    const int *group_start  # (nf, nv) per chain position, its joint's first position
    const int *group_end        # (nf, nv) and the position after its joint's last
    const double *order    # (nf, nv, nv) the chains' relation (k on or above j)
    const unsigned char *active


cdef class Plan:
    """The C's view of one model and active set (gagen.runtime.constraint_derivatives
    keeps one per model and set): the two API tables and the layout arrays."""

    cdef Ctx c
    cdef object _keep
    cdef readonly int nq, nv, nrows
    cdef double[::1] _offsets  # the frames' offsets at the default parameters

    def __init__(self, model_capsule, derivative_capsule, int[::1] frames, int[::1] bodies,
                 int[:, ::1] table, int[::1] parent, int[::1] rows, int[::1] quat,
                 int[:, ::1] chain, int[::1] chain_len, int[:, ::1] group_start,
                 int[:, ::1] group_end, double[:, :, ::1] order, unsigned char[::1] active,
                 int[::1] desc_ptr, int[::1] desc):
        cdef const gagen_model_api *api = <const gagen_model_api *>_table(
            model_capsule, "gagen.model_api")
        cdef const gagen_derivatives_api *dapi = <const gagen_derivatives_api *>_table(
            derivative_capsule, "gagen.derivatives_api")
        if dapi.nv != api.nv or dapi.nq != api.nq or dapi.np != api.np:
            raise ValueError("the derivative module's sizes are not the model's")
        if parent.shape[0] != api.nv or active.shape[0] != api.nc or (
                frames.shape[0] and order.shape[1] != api.nv):
            raise ValueError("the layout's sizes are not the model's")
        self._keep = (model_capsule, derivative_capsule, frames, bodies, table, parent, rows,
                      quat, chain, chain_len, group_start, group_end, order, active,
                      desc_ptr, desc)
        self.nq, self.nv, self.nrows = api.nq, api.nv, api.ncrows
        self.c.api, self.c.dapi = api, dapi
        self.c.nv, self.c.nb, self.c.nfm = api.nv, api.nb, api.nf
        self.c.nf, self.c.nc, self.c.m = frames.shape[0], table.shape[0], rows.shape[0]
        self.c.nrows, self.c.nquat = api.ncrows, quat.shape[0]
        self.c.frames = &frames[0] if frames.shape[0] else NULL
        self.c.bodies = &bodies[0] if bodies.shape[0] else NULL
        self.c.table = &table[0, 0] if table.shape[0] else NULL
        self.c.parent = &parent[0] if parent.shape[0] else NULL
        self.c.rows = &rows[0] if rows.shape[0] else NULL
        self.c.quat = &quat[0] if quat.shape[0] else NULL
        self.c.chain = &chain[0, 0] if chain.shape[0] else NULL
        self.c.chain_len = &chain_len[0] if chain_len.shape[0] else NULL
        self.c.group_start = &group_start[0, 0] if group_start.shape[0] else NULL
        self.c.group_end = &group_end[0, 0] if group_end.shape[0] else NULL
        self.c.order = &order[0, 0, 0] if order.shape[0] else NULL
        self.c.active = &active[0] if active.shape[0] else NULL
        if desc_ptr.shape[0] != api.nv + 1 or desc.shape[0] < desc_ptr[api.nv]:
            raise ValueError("the descendants' sizes are not the model's")
        self.c.desc_ptr = &desc_ptr[0]
        self.c.desc = &desc[0] if desc.shape[0] else NULL
        self._offsets = np.zeros(12 * api.nf + 1)
        api.frame_offsets(api.parameter_defaults, &self._offsets[0])


cdef inline Py_ssize_t _workspace_size(const Ctx *c) noexcept nogil:
    """Doubles of one state's workspace (_state's layout)."""
    cdef Py_ssize_t n = c.nv, f = c.nf, m = c.m
    return (n + (c.nrows if c.nrows > n else n) + m + 3 * n * n + 15 * c.nb + f * 6 * n
            + m * n + 12 * f + 7 * f * n * 6 + 12 * f + n * n * 6 + 18 * (n + 1)
            + m * 3 * n + n * n + (n + m) * 3 * n + m * n + m * m + n + n + m)


def derivatives(Plan plan, q, qd, tau, p, double kd, double damping):
    """(∂q̈/∂q, ∂q̈/∂q̇, ∂q̈/∂τ, ∂forces/∂q, ∂forces/∂q̇, ∂forces/∂τ), fresh arrays, at one
    state (q (nq,), qd, tau (nv,)) or stacked states ((N, ·), one C loop without the GIL);
    p None (the defaults) or the full parameter vector. None where an input is not a
    C-contiguous float64 array of the plan's shape, or where a state fails (a quaternion
    that cannot be normalised, a kernel's error, a pivot <= 0): the caller's own path then
    raises its error or answers."""
    cdef Ctx *c = &plan.c
    cdef Py_ssize_t n = c.nv, nq = plan.nq, R = c.nrows, count, i
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
    cdef const double *pp = c.api.parameter_defaults
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
    cdef Py_ssize_t size = _workspace_size(c) + 12 * c.nfm
    cdef double *ws = <double *>malloc(size * sizeof(double))
    cdef int *ints = <int *>malloc((n + c.m + 1) * sizeof(int))
    cdef int status = 0
    if ws == NULL or ints == NULL:
        free(ws)
        free(ints)
        raise MemoryError()
    cdef double *Fo = &plan._offsets[0]
    cdef bint given = p is not None
    with nogil:
        if given:
            Fo = ws + _workspace_size(c)
            c.api.frame_offsets(pp, Fo)
        for i in range(count):
            status = _state(c, qa + i * nq, qb + i * n, qt + i * n, pp, Fo, kd, damping,
                            ws, ints, o[0] + i * n * n, o[1] + i * n * n, o[2] + i * n * n,
                            o[3] + i * R * n, o[4] + i * R * n, o[5] + i * R * n)
            if status:
                break
    free(ws)
    free(ints)
    if status:
        return None
    return tuple(outs)


cdef int _ltdl(double *M, const int *parent, Py_ssize_t n, double *diagonal) noexcept nogil:
    """M = Lᵀ D L in place (the model's gagen_ltdl: the same steps, from the last
    coordinate up, only along each coordinate's ancestors, and its test of a pivot against
    M's diagonal entry); -1 at a pivot not clearly positive."""
    cdef Py_ssize_t k, i, j
    cdef double d, x
    for k in range(n):
        diagonal[k] = M[n * k + k]
    for k in range(n - 1, -1, -1):
        d = M[n * k + k]
        if not (d > 1e-13 * diagonal[k] and diagonal[k] > 0.0):
            return -1
        i = parent[k]
        while i >= 0:
            x = M[n * k + i] / d
            j = i
            while j >= 0:
                M[n * i + j] -= M[n * k + j] * x
                j = parent[j]
            M[n * k + i] = x
            i = parent[i]
    return 0


cdef inline void _back(const double *L, const int *parent, Py_ssize_t n,
                       double *x) noexcept nogil:
    """x ← L⁻ᵀ x: from the last coordinate up, each to its ancestors (gagen_cn_back)."""
    cdef Py_ssize_t k, i
    for k in range(n - 1, -1, -1):
        if x[k] != 0.0:
            i = parent[k]
            while i >= 0:
                x[i] -= L[n * k + i] * x[k]
                i = parent[i]


cdef inline void _forward(const double *L, const int *parent, Py_ssize_t n,
                          double *x) noexcept nogil:
    """x ← L⁻¹ x: from the first coordinate down (gagen_cn_forward)."""
    cdef Py_ssize_t k, i
    cdef double s
    for k in range(n):
        s = x[k]
        i = parent[k]
        while i >= 0:
            s -= L[n * k + i] * x[i]
            i = parent[i]
        x[k] = s


cdef int _delassus(const double *Y, const double *Dinv, Py_ssize_t n, Py_ssize_t m,
                   double damping, double *G) noexcept nogil:
    """G = Y D⁻¹ Yᵀ + damping I factored in place as Lg Dg Lgᵀ (Lg's unit lower triangle
    below the diagonal, Dg on it); -1 at a pivot not above GAGEN_TS_PIVOT (1e-11) times its
    diagonal entry (the model's constrained dynamics then answers with its error)."""
    cdef Py_ssize_t a, b, j, k
    cdef double s, d, diag
    for a in range(m):
        for b in range(a + 1):
            s = 0.0
            for j in range(n):
                s += Y[n * a + j] * Dinv[j] * Y[n * b + j]
            G[m * a + b] = s
        G[m * a + a] += damping
    for j in range(m):  # the lower triangle, column by column (gagen_cn_kkt's steps)
        diag = G[m * j + j]
        d = diag
        for k in range(j):
            d -= G[m * j + k] * G[m * j + k] * G[m * k + k]
        if not d > 1e-11 * diag:
            return -1
        G[m * j + j] = d
        for a in range(j + 1, m):
            s = G[m * a + j]
            for k in range(j):
                s -= G[m * a + k] * G[m * j + k] * G[m * k + k]
            G[m * a + j] = s / d
    return 0


cdef void _solve_ldlt(const double *G, Py_ssize_t m, double *x) noexcept nogil:
    """x ← G⁻¹ x with G = Lg Dg Lgᵀ (_delassus)."""
    cdef Py_ssize_t a, b
    cdef double s
    for a in range(m):
        s = x[a]
        for b in range(a):
            s -= G[m * a + b] * x[b]
        x[a] = s
    for a in range(m):
        x[a] /= G[m * a + a]
    for a in range(m - 1, -1, -1):
        s = x[a]
        for b in range(a + 1, m):
            s -= G[m * b + a] * x[b]
        x[a] = s


cdef int _state(const Ctx *c, const double *q, const double *qd, const double *tau,
                const double *p, const double *Fo, double kd, double damping, double *ws,
                int *ints, double *o0, double *o1, double *o2, double *o3, double *o4,
                double *o5) noexcept nogil:
    """One state's six derivatives into o0..o5; 0, or non-zero where the state fails."""
    cdef Py_ssize_t n = c.nv, nf = c.nf, m = c.m, n3 = 3 * c.nv, R = c.nrows
    cdef Py_ssize_t i, j, k, r
    cdef int rc
    cdef double n2
    cdef const double *x
    for k in range(c.nquat):  # as the runtime's check: a squared norm that is a normal double
        x = q + c.quat[k]
        n2 = x[0] * x[0] + x[1] * x[1] + x[2] * x[2] + x[3] * x[3]
        if not (n2 >= DBL_MIN and n2 <= DBL_MAX):
            return -2
    # the workspace (_workspace_size's sum)
    cdef double *qdd = ws
    cdef double *forces = qdd + n
    cdef double *lam = forces + (R if R > n else n)
    cdef double *dIq = lam + m
    cdef double *dIv = dIq + n * n
    cdef double *L = dIv + n * n
    cdef double *X = L + n * n
    cdef double *J = X + 15 * c.nb
    cdef double *Jc = J + nf * 6 * n
    cdef double *P = Jc + m * n
    cdef double *Rf = P + 3 * nf
    cdef double *S = Rf + 9 * nf
    cdef double *Vb = S + nf * n * 6
    cdef double *Sd = Vb + nf * n * 6
    cdef double *dVq = Sd + nf * n * 6
    cdef double *dAq = dVq + nf * n * 6
    cdef double *dAv = dAq + nf * n * 6
    cdef double *dW = dAv + nf * n * 6
    cdef double *V = dW + nf * n * 6
    cdef double *A = V + 6 * nf
    cdef double *W = A + 6 * nf
    cdef double *T = W + 6 * nf  # 6 nf: V, A, W; 12 f counted for them and P, R's 12 f
    cdef double *r2 = T + n * n * 6 + 18 * (n + 1)
    cdef double *dJtl = r2 + m * n3
    cdef double *out = dJtl + n * n
    cdef double *Y = out + (n + m) * n3
    cdef double *G = Y + m * n
    cdef double *Dinv = G + m * m
    # the constrained forward dynamics (the model's constrained_forward_dynamics: the same
    # steps, on factors the derivatives reuse): M = Lᵀ D L, f = L⁻ᵀ (τ − bias), Y = J L⁻¹,
    # G = Y D⁻¹ Yᵀ + damping I = Lg Dg Lgᵀ, λ = G⁻¹ (−drift − kd J q̇ − Y D⁻¹ f),
    # q̈ = L⁻¹ D⁻¹ (f + Yᵀ λ)
    c.api.mass_matrix(q, p, L)
    if _ltdl(L, c.parent, n, Dinv):
        return -1
    for j in range(n):
        Dinv[j] = 1.0 / L[n * j + j]
    c.api.forcing(q, qd, tau, p, qdd)
    _back(L, c.parent, n, qdd)
    if nf:  # the frames' chains at q̈ = 0: J and −(drift + kd J q̇) of the active rows
        c.api.placements(q, p, X)
        rc = c.api.frame_jacobians(q, p, <int>nf, c.frames, LOCAL_WORLD_ALIGNED, J)
        if rc != 0:
            return rc
        _placements(c, X, Fo, Rf, P)
        _motion(c, J, Rf, P, S, Vb, Sd, V, A, T, qd, kd, Jc, lam)
    if m:
        for r in range(m):  # Y's rows: L⁻ᵀ of J's
            for j in range(n):
                Y[n * r + j] = Jc[n * r + j]
            _back(L, c.parent, n, Y + n * r)
            n2 = 0.0
            for j in range(n):
                n2 += Y[n * r + j] * Dinv[j] * qdd[j]
            lam[r] -= n2
        if _delassus(Y, Dinv, n, m, damping, G):
            return -1
        _solve_ldlt(G, m, lam)
        for j in range(n):
            n2 = qdd[j]
            for r in range(m):
                n2 += Y[n * r + j] * lam[r]
            forces[j] = n2 * Dinv[j]  # (forces: scratch here)
    else:
        for j in range(n):
            forces[j] = qdd[j] * Dinv[j]
    for j in range(n):
        qdd[j] = forces[j]
    _forward(L, c.parent, n, qdd)
    c.dapi.inverse_dynamics_derivatives(q, qd, qdd, p, dIq, dIv)
    memset(dJtl, 0, n * n * sizeof(double))
    if nf:
        _terms(c, J, Rf, P, S, Vb, Sd, dVq, dAq, dAv, dW, V, A, W, T, qd, qdd, lam, kd, r2,
               dJtl)
    # r1 = [∂(Jᵀλ)/∂q − ∂ID/∂q | −∂ID/∂q̇ | I]
    for i in range(n):
        for j in range(n):
            out[n3 * i + j] = dJtl[n * i + j] - dIq[n * i + j]
            out[n3 * i + n + j] = -dIv[n * i + j]
            out[n3 * i + 2 * n + j] = 0.0
        out[n3 * i + 2 * n + i] = 1.0
    _kkt(c, L, r2, out, Y, G, Dinv, Dinv + n, ints)
    # the outputs: q̈'s three blocks; the forces' over every declared row (inactive: zero)
    for i in range(n):
        for j in range(n):
            o0[n * i + j] = out[n3 * i + j]
            o1[n * i + j] = out[n3 * i + n + j]
            o2[n * i + j] = out[n3 * i + 2 * n + j]
    if R:
        memset(o3, 0, R * n * sizeof(double))
        memset(o4, 0, R * n * sizeof(double))
        memset(o5, 0, R * n * sizeof(double))
    for r in range(m):
        k = c.rows[r]
        for j in range(n):
            o3[n * k + j] = out[n3 * (n + r) + j]
            o4[n * k + j] = out[n3 * (n + r) + n + j]
            o5[n * k + j] = out[n3 * (n + r) + 2 * n + j]
    return 0


cdef void _placements(const Ctx *c, const double *X, const double *Fo, double *R,
                      double *P) noexcept nogil:
    """Each frame's axes R = R_b R_f and origin p_b + R_b p_f (frames.pose)."""
    cdef Py_ssize_t f, i, j, k
    cdef int b, fr
    for f in range(c.nf):
        b, fr = c.bodies[f], c.frames[f]
        for i in range(3):
            if b < 0:
                P[3 * f + i] = Fo[12 * fr + 9 + i]
            else:
                P[3 * f + i] = X[15 * b + 9 + i]
                for k in range(3):
                    P[3 * f + i] += X[15 * b + 3 * i + k] * Fo[12 * fr + 9 + k]
            for j in range(3):
                if b < 0:
                    R[9 * f + 3 * i + j] = Fo[12 * fr + 3 * i + j]
                else:
                    R[9 * f + 3 * i + j] = 0.0
                    for k in range(3):
                        R[9 * f + 3 * i + j] += X[15 * b + 3 * i + k] * Fo[12 * fr + 3 * k + j]
cdef struct Frames:
    # the frames' arrays as C pointers (passing memoryviews to each helper costs their
    # reference counts): J (f, 6, nv), P (f, 3), S, dVq, dAq, dAv, dW (f, nv, 6), V, A, W (f, 6)
    Py_ssize_t nv
    double *J
    double *P
    double *S
    double *V
    double *A
    double *dVq
    double *dAq
    double *dAv
    double *W
    double *dW


cdef inline double *col(const Frames *F, double *base, int f, Py_ssize_t k) noexcept nogil:
    """Row k of frame f's (nv, 6) block of base."""
    return base + (f * F.nv + k) * 6


cdef void _row_value(const Frames *F, int fa, int fb, int frame6, int local, double kd,
                     double *x) noexcept nogil:
    """a_c (+ kd J q̇) of a constraint, world axes, before its rotation and its axes."""
    cdef double xa[6]
    cdef double xb[6]
    cdef double va[6]
    cdef double vb[6]
    cdef double t[6]
    cdef int i
    if not frame6:
        _classical(&F.V[6 * fa], &F.A[6 * fa], &F.P[3 * fa], xa, va)
        for i in range(3):
            x[i] = xa[i] + kd * va[i]
            x[3 + i] = 0.0
        if fb >= 0:
            _classical(&F.V[6 * fb], &F.A[6 * fb], &F.P[3 * fb], xb, vb)
            for i in range(3):
                x[i] -= xb[i] + kd * vb[i]
        return
    for i in range(6):
        xa[i] = F.A[6 * fa + i] - (F.A[6 * fb + i] if fb >= 0 else 0.0)
        va[i] = F.V[6 * fa + i] - (F.V[6 * fb + i] if fb >= 0 else 0.0)
    if fb >= 0 and local:
        mcross(&F.V[6 * fa], &F.V[6 * fb], t)
        for i in range(6):
            xa[i] += t[i]
    for i in range(6):
        x[i] = xa[i] + kd * va[i]
    add_cross(&x[3], &F.P[3 * fa], 1.0, x)  # at pA: lin + ang × p


cdef void _classical(const double *V, const double *A, const double *p, double *acc,
                     double *vel) noexcept nogil:
    """The classical acceleration and the velocity of point p (V, A at the origin)."""
    cdef int i
    for i in range(3):
        vel[i] = V[i]
        acc[i] = A[i]
    add_cross(&V[3], p, 1.0, vel)
    add_cross(&A[3], p, 1.0, acc)
    add_cross(&V[3], vel, 1.0, acc)


cdef void _row_derivative(const Frames *F, int fa, int fb, int frame6, int local, double kd,
                          Py_ssize_t d, double *dx) noexcept nogil:
    """The derivative of _row_value along direction d (q's k = d, or q̇'s k = d − nv)."""
    cdef double da[6]
    cdef double db[6]
    cdef double dva[6]
    cdef double dvb[6]
    cdef double t[6]
    cdef double dpa[3]
    cdef int i
    cdef Py_ssize_t nv = F.nv
    if not frame6:
        _classical_derivative(F, fa, d, da, dva)
        for i in range(3):
            dx[i] = da[i] + kd * dva[i]
            dx[3 + i] = 0.0
        if fb >= 0:
            _classical_derivative(F, fb, d, db, dvb)
            for i in range(3):
                dx[i] -= db[i] + kd * dvb[i]
        return
    _motion_derivative(F, fa, d, dva, da)
    if fb >= 0:
        _motion_derivative(F, fb, d, dvb, db)
        for i in range(6):
            da[i] -= db[i]
            dva[i] -= dvb[i]
        if local:  # d(V_A × V_B)
            _velocity_derivative(F, fa, d, t)
            mcross(t, &F.V[6 * fb], db)
            for i in range(6):
                da[i] += db[i]
            _velocity_derivative(F, fb, d, t)
            mcross(&F.V[6 * fa], t, db)
            for i in range(6):
                da[i] += db[i]
    for i in range(6):
        dx[i] = da[i] + kd * dva[i]
    add_cross(&dx[3], &F.P[3 * fa], 1.0, dx)
    if d < nv:  # the point pA moves: the value's angular part × dpA
        for i in range(3):
            dpa[i] = F.J[(6 * fa + i) * nv + d]
        _value_angular(F, fa, fb, local, kd, t)
        add_cross(t, dpa, 1.0, dx)


cdef void _velocity_derivative(const Frames *F, int f, Py_ssize_t d, double *dV) noexcept nogil:
    cdef int i
    cdef double *src = col(F, F.dVq, f, d) if d < F.nv else col(F, F.S, f, d - F.nv)
    for i in range(6):
        dV[i] = src[i]


cdef void _value_angular(const Frames *F, int fa, int fb, int local, double kd,
                         double *w) noexcept nogil:
    """The angular part of a frame row's value (at the origin), for its shift's derivative."""
    cdef double t[6]
    cdef int i
    for i in range(3):
        w[i] = F.A[6 * fa + 3 + i] - (F.A[6 * fb + 3 + i] if fb >= 0 else 0.0) \
            + kd * (F.V[6 * fa + 3 + i] - (F.V[6 * fb + 3 + i] if fb >= 0 else 0.0))
    if fb >= 0 and local:
        mcross(&F.V[6 * fa], &F.V[6 * fb], t)
        for i in range(3):
            w[i] += t[3 + i]


cdef void _motion_derivative(const Frames *F, int f, Py_ssize_t d, double *dV,
                             double *dA) noexcept nogil:
    cdef int i
    cdef double *sv
    cdef double *sa
    if d < F.nv:
        sv, sa = col(F, F.dVq, f, d), col(F, F.dAq, f, d)
    else:
        sv, sa = col(F, F.S, f, d - F.nv), col(F, F.dAv, f, d - F.nv)
    for i in range(6):
        dV[i] = sv[i]
        dA[i] = sa[i]


cdef void _classical_derivative(const Frames *F, int f, Py_ssize_t d, double *dacc,
                                double *dvel) noexcept nogil:
    """d of acc = a_O + α × p + ω × vp and vel = vp = v_O + ω × p."""
    cdef double dV[6]
    cdef double dA[6]
    cdef double dp[3]
    cdef double vp[3]
    cdef int i
    cdef Py_ssize_t nv = F.nv
    cdef const double *V = &F.V[6 * f]
    cdef const double *A = &F.A[6 * f]
    cdef const double *p = &F.P[3 * f]
    _motion_derivative(F, f, d, dV, dA)
    for i in range(3):
        dp[i] = F.J[(6 * f + i) * nv + d] if d < nv else 0.0
        vp[i] = V[i]
        dvel[i] = dV[i]
        dacc[i] = dA[i]
    add_cross(&V[3], p, 1.0, vp)
    add_cross(&dV[3], p, 1.0, dvel)
    add_cross(&V[3], dp, 1.0, dvel)
    add_cross(&dA[3], p, 1.0, dacc)
    add_cross(&A[3], dp, 1.0, dacc)
    add_cross(&dV[3], vp, 1.0, dacc)
    add_cross(&V[3], dvel, 1.0, dacc)


cdef void _wrench_at(const Frames *F, int fp, int fa, int fchain, double sign, double *fw,
                     double *tw, int local) noexcept nogil:
    """W += sign (f, p × f + t) on frame fchain's chain, p frame fp's origin, and its
    q-derivative (f and t turn with frame fa's axes when local)."""
    cdef double m[3]
    cdef double df[3]
    cdef double dt[3]
    cdef double dp[3]
    cdef double dm[3]
    cdef double *dW
    cdef Py_ssize_t k, nv = F.nv
    cdef int i
    cross3(&F.P[3 * fp], fw, m)
    for i in range(3):
        F.W[6 * fchain + i] += sign * fw[i]
        F.W[6 * fchain + 3 + i] += sign * (m[i] + tw[i])
    for k in range(nv):
        for i in range(3):
            dp[i] = F.J[(6 * fp + i) * nv + k]
            df[i] = 0.0
            dt[i] = 0.0
        if local:
            cross3(&col(F, F.S, fa, k)[3], fw, df)
            cross3(&col(F, F.S, fa, k)[3], tw, dt)
        cross3(dp, fw, dm)
        add_cross(&F.P[3 * fp], df, 1.0, dm)
        dW = col(F, F.dW, fchain, k)
        for i in range(3):
            dW[i] += sign * df[i]
            dW[3 + i] += sign * (dm[i] + dt[i])




cdef void _motion(const Ctx *c, const double *J, const double *R, const double *P,
                  double *S, double *Vb, double *Sd, double *V, double *A, double *T,
                  const double *v, double kd, double *Jc, double *rhs) noexcept nogil:
    """Each frame's chain at q̈ = 0 (zeroing S .. W of _state's layout first): S_j (its
    twists at the world's origin), V_j (j's body's velocity), Ṡ_j = V_j × S_j, V, and A = Σ
    Ṡ_j q̇_j; then the active rows' J (m, nv) and rhs = −(J̇ q̇ + kd J q̇) (gagen_cn_one's
    rows: a point's velocity, or a frame's twist at A's origin, less B's; in A's axes for
    "local"), the right-hand side of the constrained dynamics."""
    cdef Py_ssize_t nv = c.nv, nf = c.nf
    cdef Py_ssize_t f, i, j, h, n, jj, d, cc
    cdef const int *ch
    cdef const int *end
    cdef double *Sj
    cdef double *pre = T
    cdef double tmp[6]
    memset(S, 0, (7 * nf * nv * 6 + 18 * nf) * sizeof(double))
    for f in range(nf):
        ch = c.chain + f * nv
        n = c.chain_len[f]
        end = c.group_end + f * nv
        for jj in range(n):
            j = ch[jj]
            Sj = S + (f * nv + j) * 6
            for i in range(3):
                Sj[3 + i] = J[(6 * f + 3 + i) * nv + j]
            cross3(Sj + 3, &P[3 * f], tmp)
            for i in range(3):
                Sj[i] = J[(6 * f + i) * nv + j] - tmp[i]
        for h in range(6):
            pre[h] = 0.0
        for jj in range(n):
            Sj = S + (f * nv + ch[jj]) * 6
            for h in range(6):
                pre[6 * (jj + 1) + h] = pre[6 * jj + h] + Sj[h] * v[ch[jj]]
        for h in range(6):
            V[6 * f + h] = pre[6 * n + h]
            A[6 * f + h] = 0.0
        for jj in range(n):  # V_j (its group's end), Ṡ_j = V_j × S_j, A = Σ Ṡ_j q̇_j
            j = ch[jj]
            for h in range(6):
                Vb[(f * nv + j) * 6 + h] = pre[6 * end[jj] + h]
            mcross(&Vb[(f * nv + j) * 6], &S[(f * nv + j) * 6], &Sd[(f * nv + j) * 6])
            for h in range(6):
                A[6 * f + h] += Sd[(f * nv + j) * 6 + h] * v[j]
    cdef Frames F
    F.nv = nv
    F.J, F.P, F.S, F.V, F.A = <double *>J, <double *>P, S, V, A
    cdef int fa, fb, frame6, local, naxes, row = 0
    cdef const int *tb
    cdef double x0[6]
    for cc in range(c.nc):
        tb = c.table + TABLE * cc
        fa, fb, frame6, local, naxes = tb[0], tb[1], tb[2], tb[3], tb[4]
        _row_value(&F, fa, fb, frame6, local, kd, x0)
        if local:
            _turn(R + 9 * fa, x0, 2 if frame6 else 1)
        for i in range(naxes):
            rhs[row + i] = -x0[tb[5 + i]]
        for d in range(nv):
            if c.order[(fa * nv + d) * nv + d] == 0.0 and (
                    fb < 0 or c.order[(fb * nv + d) * nv + d] == 0.0):
                for i in range(naxes):
                    Jc[(row + i) * nv + d] = 0.0
                continue
            Sj = S + (fa * nv + d) * 6
            for h in range(6):
                x0[h] = Sj[h]
            if not frame6:  # the points' velocities
                add_cross(Sj + 3, &P[3 * fa], 1.0, x0)
                if fb >= 0:
                    Sj = S + (fb * nv + d) * 6
                    for h in range(3):
                        x0[h] -= Sj[h]
                    add_cross(Sj + 3, &P[3 * fb], -1.0, x0)
            else:  # the twists' difference at A's origin
                if fb >= 0:
                    Sj = S + (fb * nv + d) * 6
                    for h in range(6):
                        x0[h] -= Sj[h]
                add_cross(x0 + 3, &P[3 * fa], 1.0, x0)
            if local:
                _turn(R + 9 * fa, x0, 2 if frame6 else 1)
            for i in range(naxes):
                Jc[(row + i) * nv + d] = x0[tb[5 + i]]
        row += naxes


cdef inline void _turn(const double *R, double *x, int blocks) noexcept nogil:
    """x ← Rᵀ x for each of its first `blocks` 3-vectors."""
    cdef double t[3]
    cdef int h, i
    for h in range(blocks):
        for i in range(3):
            t[i] = R[i] * x[3 * h] + R[3 + i] * x[3 * h + 1] + R[6 + i] * x[3 * h + 2]
        for i in range(3):
            x[3 * h + i] = t[i]


cdef void _terms(const Ctx *c, const double *J, const double *R, double *P, double *S,
                 double *Vb, double *Sd, double *dVq, double *dAq, double *dAv, double *dW,
                 double *V, double *A, double *W, double *T, const double *v, const double *a,
                 const double *lam, double kd, double *r2, double *dJtl) noexcept nogil:
    """r2 = [−∂a_c/∂q | −∂a_c/∂q̇ | 0] (m, 3 nv) and dJtl += ∂(Jᵀ λ)/∂q (nv, nv), λ held
    (the module docstring of gagen.runtime.constraint_derivatives has the sums)."""
    cdef Py_ssize_t nv = c.nv, nf = c.nf, n3 = 3 * c.nv, m = c.m
    cdef Py_ssize_t f, i, j, k, cc, d, h, n, jj, kk
    cdef const double *order
    cdef const int *ch
    cdef double u[6]
    cdef double *e1
    cdef double e0[6]
    cdef double e2[6]
    cdef double tmp[6]
    memset(r2, 0, m * n3 * sizeof(double))
    # --- each frame's A and the derivatives of V and A along its chain (root first; a
    # floating joint's six coordinates are one group, each on or above the others). With
    # the chain's sums V_j = Σ_{i ⪯ j} S_i q̇_i (j's body, _motion's), Vp_k (k's joint's
    # parent body), Vv_k = Σ_{j ⪰ k} S_j q̇_j and Aa_k = Σ_{j ⪰ k} S_j a_j + Ṡ_j q̇_j, the
    # module docstring's sums close by the Jacobi identity into ∂V/∂q_k = S_k × Vv_k and
    # ∂A/∂q_k = S_k × Aa_k − (S_k × Vp_k) × Vv_k: O(chain) per frame.
    cdef double *pre = T               # (n + 1, 6) prefix sums of S_j q̇_j
    cdef double *sv = T + 6 * (nv + 1)  # (n + 1, 6) suffix sums of S_j q̇_j
    cdef double *sa = sv + 6 * (nv + 1)  # (n + 1, 6) suffix sums of S_j a_j + Ṡ_j q̇_j
    cdef const int *start
    cdef double *Sj
    for f in range(nf):
        ch = c.chain + f * nv
        n = c.chain_len[f]
        start = c.group_start + f * nv
        for h in range(6):
            pre[h] = 0.0
            sv[6 * n + h] = 0.0
            sa[6 * n + h] = 0.0
        for jj in range(n):
            Sj = S + (f * nv + ch[jj]) * 6
            for h in range(6):
                pre[6 * (jj + 1) + h] = pre[6 * jj + h] + Sj[h] * v[ch[jj]]
        for jj in range(n - 1, -1, -1):
            j = ch[jj]
            Sj = S + (f * nv + j) * 6
            for h in range(6):
                sv[6 * jj + h] = sv[6 * (jj + 1) + h] + Sj[h] * v[j]
                sa[6 * jj + h] = sa[6 * (jj + 1) + h] + Sj[h] * a[j] \
                    + Sd[(f * nv + j) * 6 + h] * v[j]
        for h in range(6):
            A[6 * f + h] = sa[h]
        for kk in range(n):
            k = ch[kk]
            Sj = S + (f * nv + k) * 6
            mcross(Sj, &sv[6 * start[kk]], &dVq[(f * nv + k) * 6])
            mcross(Sj, &sa[6 * start[kk]], &dAq[(f * nv + k) * 6])
            mcross(Sj, &pre[6 * start[kk]], e0)
            mcross(e0, &sv[6 * start[kk]], e2)
            for h in range(6):
                dAq[(f * nv + k) * 6 + h] -= e2[h]
                dAv[(f * nv + k) * 6 + h] = dVq[(f * nv + k) * 6 + h] + Sd[(f * nv + k) * 6 + h]
    # --- the rows' derivatives and the wrenches
    cdef Frames F
    F.nv = nv
    F.J, F.P, F.S, F.V, F.A = <double *>J, P, S, V, A
    F.dVq, F.dAq, F.dAv = dVq, dAq, dAv
    F.W, F.dW = W, dW
    cdef int fa, fb, frame6, local, naxes, row = 0
    cdef const int *tb
    cdef double x0[6]
    cdef double dx[6]
    cdef double full[6]
    cdef double fw[3]
    cdef double tw[3]
    for cc in range(c.nc):
        tb = c.table + TABLE * cc
        fa, fb, frame6, local, naxes = tb[0], tb[1], tb[2], tb[3], tb[4]
        _row_value(&F, fa, fb, frame6, local, kd, x0)
        for d in range(2 * nv):
            k = d if d < nv else d - nv
            if c.order[(fa * nv + k) * nv + k] == 0.0 and (
                    fb < 0 or c.order[(fb * nv + k) * nv + k] == 0.0):
                continue  # a coordinate on neither frame's chain moves neither: r2 stays 0
            _row_derivative(&F, fa, fb, frame6, local, kd, d, dx)
            if local:  # Rᵀ (dx − w × x0) per 3-block
                for h in range(2 if frame6 else 1):
                    if d < nv:
                        add_cross(&S[(fa * nv + d) * 6 + 3], &x0[3 * h], -1.0, &dx[3 * h])
                    for i in range(3):
                        tmp[i] = R[9 * fa + i] * dx[3 * h] + R[9 * fa + 3 + i] * dx[3 * h + 1] \
                            + R[9 * fa + 6 + i] * dx[3 * h + 2]
                    for i in range(3):
                        dx[3 * h + i] = tmp[i]
            for i in range(naxes):
                r2[(row + i) * n3 + d] = -dx[tb[5 + i]]
        # the wrench: f, t in world axes, on A at pA (and −W on B at pB or pA)
        for i in range(6):
            full[i] = 0.0
        for i in range(naxes):
            full[tb[5 + i]] = lam[row + i]
        for i in range(3):
            if local:
                fw[i] = R[9 * fa + 3 * i] * full[0] + R[9 * fa + 3 * i + 1] * full[1] \
                    + R[9 * fa + 3 * i + 2] * full[2]
                tw[i] = R[9 * fa + 3 * i] * full[3] + R[9 * fa + 3 * i + 1] * full[4] \
                    + R[9 * fa + 3 * i + 2] * full[5]
            else:
                fw[i], tw[i] = full[i], full[3 + i]
        _wrench_at(&F, fa, fa, fa, 1.0, fw, tw, local)
        if fb >= 0:  # −W on B's chain, at pB (a point loop) or pA (a frame loop)
            _wrench_at(&F, fa if frame6 else fb, fa, fb, -1.0, fw, tw, local)
        row += naxes
    # ∂(Σ Sᵀ W)/∂q: [j, k] = (S_k × S_j) · W_f = −S_j · (S_k ×* W_f) for j ⪰ k, and S_j · ∂W_f/∂q_k
    for f in range(nf):
        order = c.order + f * nv * nv
        ch = c.chain + f * nv
        n = c.chain_len[f]
        for kk in range(n):
            k = ch[kk]
            fcross(&S[(f * nv + k) * 6], &W[6 * f], u)
            for jj in range(n):
                j = ch[jj]
                if order[k * nv + j] != 0.0:
                    Sj = S + (f * nv + j) * 6
                    dJtl[j * nv + k] -= Sj[0] * u[0] + Sj[1] * u[1] + Sj[2] * u[2] \
                        + Sj[3] * u[3] + Sj[4] * u[4] + Sj[5] * u[5]
        for k in range(nv):
            e1 = dW + (f * nv + k) * 6
            if e1[0] == 0.0 and e1[1] == 0.0 and e1[2] == 0.0 and e1[3] == 0.0 \
                    and e1[4] == 0.0 and e1[5] == 0.0:
                continue  # (k on no chain that the frame's wrenches turn or move with)
            for jj in range(n):
                Sj = S + (f * nv + ch[jj]) * 6
                dJtl[ch[jj] * nv + k] += Sj[0] * e1[0] + Sj[1] * e1[1] + Sj[2] * e1[2] \
                    + Sj[3] * e1[3] + Sj[4] * e1[4] + Sj[5] * e1[5]


cdef void _kkt(const Ctx *c, const double *L, const double *r2, double *out,
               const double *Y, const double *G, const double *Dinv, double *coef,
               int *idx) noexcept nogil:
    """[∂q̈; ∂λ] in out ((nv + m) rows of 3 nv) from r1 in its first nv rows and r2, through
    M = Lᵀ D L and G = J M⁻¹ Jᵀ (+ damping I) = Lg Dg Lgᵀ as _state factored them, with
    Y = J L⁻¹: w = L⁻ᵀ r1, z = D⁻¹ w; ∂λ = G⁻¹ (r2 − Y z); ∂q̈ = L⁻¹ (z + D⁻¹ Yᵀ ∂λ).
    Each row of out is written once per step from the rows it needs (gagen_ct_gather),
    along the tree's ancestors and descendants and the rows' paths only."""
    cdef Py_ssize_t n = c.nv, m = c.m, n3 = 3 * c.nv, i, j, k, a, b
    cdef const int *parent = c.parent
    cdef int t, count
    cdef double s
    cdef double *rhs = out + n3 * n
    for i in range(n - 1, -1, -1):  # w = L⁻ᵀ r1: w_i = r1_i − Σ_{k below i} L_ki w_k
        count = 0
        for t in range(c.desc_ptr[i], c.desc_ptr[i + 1]):
            idx[count] = c.desc[t]
            coef[count] = L[n * c.desc[t] + i]
            count += 1
        gagen_ct_gather(out + n3 * i, out, n3, idx, coef, count, n3)
    for j in range(n):  # z = D⁻¹ w
        for k in range(n3):
            out[n3 * j + k] *= Dinv[j]
    if m:
        for a in range(m):  # r2 − Y z, into out's last m rows
            for k in range(n3):
                rhs[n3 * a + k] = r2[n3 * a + k]
            count = 0
            for j in range(n):
                if Y[n * a + j] != 0.0:
                    idx[count] = <int>j
                    coef[count] = Y[n * a + j]
                    count += 1
            gagen_ct_gather(rhs + n3 * a, out, n3, idx, coef, count, n3)
        for a in range(m):  # ∂λ = G⁻¹ (…), G = Lg Dg Lgᵀ: forward, Dg⁻¹, then back
            for b in range(a):
                idx[b] = <int>b
                coef[b] = G[m * a + b]
            gagen_ct_gather(rhs + n3 * a, rhs, n3, idx, coef, <int>a, n3)
        for a in range(m - 1, -1, -1):
            s = 1.0 / G[m * a + a]
            for k in range(n3):
                rhs[n3 * a + k] *= s
            count = 0
            for b in range(a + 1, m):
                idx[count] = <int>b
                coef[count] = G[m * b + a]
                count += 1
            gagen_ct_gather(rhs + n3 * a, rhs, n3, idx, coef, count, n3)
        for j in range(n):  # z += D⁻¹ Yᵀ ∂λ
            count = 0
            for a in range(m):
                if Y[n * a + j] != 0.0:
                    idx[count] = <int>a
                    coef[count] = -Y[n * a + j] * Dinv[j]
                    count += 1
            gagen_ct_gather(out + n3 * j, rhs, n3, idx, coef, count, n3)
    for k in range(n):  # ∂q̈ = L⁻¹ z: root first, each row from its ancestors
        count = 0
        i = parent[k]
        while i >= 0:
            idx[count] = <int>i
            coef[count] = L[n * k + i]
            count += 1
            i = parent[i]
        gagen_ct_gather(out + n3 * k, out, n3, idx, coef, count, n3)
