# cython: language_level=3, boundscheck=False, wraparound=False, initializedcheck=False
# cython: cdivision=True, embedsignature=True
"""gagen's compiled runtime: the Python face of every model's compiled kernels.

Compiled once, when gagen is installed. A model's extension module (generated from
codegen/templates/model/module.c.j2) holds only the model's C and a table of its functions
(gagen_api.h), exported as the capsule `API`; the classes here call the kernels through
that table. So a model's build compiles its own C and nothing else: no Cython, no NumPy
headers, no wrapper of its own.

gagen.runtime.compiled.CompiledDynamics binds CompiledModel's methods (their documentation
is gagen.runtime.dynamics.Dynamics's); gagen.sim runs CompiledSimulation and CompiledBatch.
"""

import numpy as np
cimport numpy as cnp
from cpython.dict cimport PyDict_GetItem
from cpython.exc cimport PyErr_CheckSignals
from cpython.object cimport PyObject
from cpython.pycapsule cimport PyCapsule_GetPointer
from libc.float cimport DBL_MAX, DBL_MIN
from libc.math cimport NAN, isfinite
from libc.stdint cimport int32_t, int64_t
from libc.stdlib cimport free, malloc

from gagen.errors import NonFiniteStateError, SingularMassMatrixError
from gagen.runtime.inputs import as_float_array, as_states, nonfinite_cause, quaternion_error
from gagen.runtime.taskspace import KINDS, REFERENCES, kind_code, reference_code

cnp.import_array()

cdef extern from "integrator.h" nogil:
    ctypedef struct gagen_ode_stats:
        long nfev, nsteps, naccepted, nrejected
        int status
    ctypedef struct gagen_control:
        int kind
        const double *kp
        const double *kd
        const double *target
        int gravity_compensation
        const double *traj_q0
        const double *traj_qf
        double traj_Tp
        int (*poll)(void *ctx) noexcept nogil
        void *poll_ctx
        const double *feedforward
        int nframes
        const int *frames
        const double *wrenches
    enum:
        GAGEN_METHOD_DOPRI5
        GAGEN_METHOD_RK4

cdef extern from "gagen_api.h" nogil:
    enum:
        GAGEN_API_VERSION
    ctypedef struct gagen_model_api:
        int version
        const char *ident
        int nq, nv, nb, nf, np, nreg
        int err_nonfinite
        const double *parameter_defaults
        void (*mass_matrix)(const double *q, const double *p, double *M) noexcept nogil
        void (*forcing)(const double *q, const double *qd, const double *tau,
                        const double *p, double *F) noexcept nogil
        int (*forward_dynamics)(const double *q, const double *qd, const double *tau,
                                const double *p, double *qdd) noexcept nogil
        void (*inverse_dynamics)(const double *q, const double *qd, const double *qdd,
                                 const double *p, double *tau) noexcept nogil
        void (*energy)(const double *q, const double *qd, const double *p,
                       double *TV) noexcept nogil
        void (*gravity)(const double *q, const double *p, double *G) noexcept nogil
        void (*placements)(const double *q, const double *p, double *X) noexcept nogil
        void (*frame_offsets)(const double *p, double *F) noexcept nogil
        int (*frame_placement)(const double *q, const double *p, int frame, double *R,
                               double *pos) noexcept nogil
        int (*frame_jacobian)(const double *q, const double *p, int frame, int reference,
                              double *J) noexcept nogil
        int (*frame_velocity)(const double *q, const double *qd, const double *p, int frame,
                              int reference, double *v) noexcept nogil
        void (*regressor)(const double *q, const double *qd, const double *qdd,
                          const double *p, double *Y) noexcept nogil
        void (*regressor_parameters)(const double *p, double *pi) noexcept nogil
        int (*simulate)(int method, const gagen_control *c, const double *p, double t0,
                        double t1, const double *y0, double rtol, const double *atol,
                        double first_step, double max_step, long max_steps, double h,
                        const double *t_eval, int n_eval, double *y_out,
                        gagen_ode_stats *stats) noexcept nogil
        int (*control_torques)(const gagen_control *c, const double *p, long m,
                               const double *t, const double *y,
                               double *tau) noexcept nogil
        void (*center_of_mass)(const double *q, const double *p, double *com) noexcept nogil
        void (*com_velocity)(const double *q, const double *qd, const double *p,
                             double *vcom) noexcept nogil
        void (*com_jacobian)(const double *q, const double *p, double *J) noexcept nogil
        void (*centroidal_map)(const double *q, const double *p, double *Ag) noexcept nogil
        void (*centroidal_momentum)(const double *q, const double *qd, const double *p,
                                    double *hg) noexcept nogil
        void (*centroidal_map_time_variation)(const double *q, const double *qd,
                                              const double *p, double *dAg) noexcept nogil
        void (*centroidal_bias)(const double *q, const double *qd, const double *p,
                                double *b) noexcept nogil
        int (*frame_jacobians)(const double *q, const double *p, int count, const int *frames,
                               int reference, double *J) noexcept nogil
        int (*frame_acceleration)(const double *q, const double *qd, const double *qdd,
                                  const double *p, int frame, int reference, int kind,
                                  double *a) noexcept nogil
        int (*frame_jacobian_time_variation)(const double *q, const double *qd,
                                             const double *p, int frame, int reference,
                                             double *dJ) noexcept nogil
        int (*delassus)(const double *q, const double *p, int count, const int *frames,
                        int dims, double *work, double *G) noexcept nogil
        int (*operational_space_inertia)(const double *q, const double *p, int count,
                                         const int *frames, int dims, double *work,
                                         double *Lambda) noexcept nogil
        int nc, ncrows
        int (*constraint_jacobian)(const double *q, const double *p,
                                   const unsigned char *active, double *J) noexcept nogil
        int (*constraint_drift)(const double *q, const double *qd, const double *p,
                                const unsigned char *active, double *drift) noexcept nogil
        int (*constraint_error)(const double *q, const double *p, const unsigned char *active,
                                double *error) noexcept nogil
        int (*constrained_forward_dynamics)(const double *q, const double *qd,
                                            const double *tau, const double *p,
                                            const unsigned char *active, double kp,
                                            double kd, double damping, double *qdd,
                                            double *forces) noexcept nogil
        int (*impulse_dynamics)(const double *q, const double *qd_minus, const double *p,
                                const unsigned char *active, double restitution,
                                double damping, double *qd_plus,
                                double *impulses) noexcept nogil
        int (*simulate_constrained)(int method, const gagen_control *c, const double *p,
                                    const unsigned char *active, double kp, double kd,
                                    double damping, double t0, double t1, const double *y0,
                                    double rtol, const double *atol, double first_step,
                                    double max_step, long max_steps, double h,
                                    const double *t_eval, int n_eval, double *y_out,
                                    gagen_ode_stats *stats) noexcept nogil
        int (*constrained_outputs)(const gagen_control *c, const double *p,
                                   const unsigned char *active, double kp, double kd,
                                   double damping, long m, const double *t, const double *y,
                                   double *forces, double *errors) noexcept nogil
    ctypedef struct gagen_derivatives_api:
        int version
        const char *ident
        int nq, nv, np
        int err_nonfinite
        const double *parameter_defaults
        void (*inverse_dynamics_derivatives)(const double *q, const double *qd,
                                             const double *qdd, const double *p,
                                             double *dtau_dq, double *dtau_dqd) noexcept nogil
        void (*coriolis_matrix)(const double *q, const double *qd, const double *p,
                                double *C) noexcept nogil
        int (*forward_dynamics_derivatives)(const double *q, const double *qd,
                                            const double *tau, const double *p,
                                            double *dqdd_dq, double *dqdd_dqd,
                                            double *Minv) noexcept nogil
        int (*linearize)(const double *q, const double *qd, const double *tau,
                         const double *p, double *A, double *B) noexcept nogil

cdef extern from *:
    """
    #include <string.h>
    #if defined(__SSE2__)
    #include <emmintrin.h>
    #endif
    /* dst[0 .. n) = src[0 .. n), with streaming (non-temporal) stores where the CPU has them
       (SSE2, every x86-64): a large batch's output is written once, so fetching each cache
       line before overwriting it (what an ordinary store does) would double the memory
       traffic; dst need only be 8-byte aligned. */
    static void gagen_stream_copy(double *dst, const double *src, Py_ssize_t n)
    {
    #if defined(__SSE2__)
        Py_ssize_t k = 0;
        if (n > 0 && ((size_t)dst & 15) != 0) {
            dst[0] = src[0];
            k = 1;
        }
        for (; k + 1 < n; k += 2)
            _mm_stream_pd(dst + k, _mm_loadu_pd(src + k));
        for (; k < n; ++k)
            dst[k] = src[k];
    #else
        memcpy(dst, src, (size_t)n * sizeof(double));
    #endif
    }

    /* the streaming stores done, before anyone reads their memory */
    static void gagen_stream_fence(void)
    {
    #if defined(__SSE2__)
        _mm_sfence();
    #endif
    }
    """
    void gagen_stream_copy(double *dst, const double *src, Py_ssize_t n) noexcept nogil
    void gagen_stream_fence() noexcept nogil

# A stacked call writes each state's result into a small buffer that stays in the cache and
# streams it to the output (gagen_stream_copy) when the output is large: at least
# STREAM_STATE doubles per state and STREAM_BYTES in all (chain:50's mass matrices: 20 kB
# per state, 20 MB per 1000 states). Smaller outputs stay in the cache for the caller.
STREAM_STATE = 256
STREAM_BYTES = 4 << 20

# the default Baumgarte gains of the constrained dynamics (no correction): a call that keeps
# them skips their checks
_NO_GAINS = (0.0, 0.0)

MODEL_CAPSULE = "gagen.model_api"
DERIVATIVES_CAPSULE = "gagen.derivatives_api"


cdef void *_table(object capsule, str name) except NULL:
    """The kernel table a model's module exports as `API` (a capsule named `name`), checked
    to be of this runtime's version."""
    cdef void *table = PyCapsule_GetPointer(capsule, name.encode())
    cdef int version = (<int *>table)[0]  # every table starts with its version
    if version != GAGEN_API_VERSION:
        raise ImportError(f"the compiled module's kernel table is version {version}, this "
                          f"gagen's runtime reads version {GAGEN_API_VERSION}: rebuild it")
    return table


# --- inputs, shared by the model's kernels and its derivatives ----------------------------

def _converted(x, name):
    """The slow path (lists, other dtypes, non-contiguous arrays): gagen's one input check."""
    return np.ascontiguousarray(as_float_array(x, name))


cdef inline cnp.ndarray _state(object x, str name, Py_ssize_t size):
    """x as a C-contiguous float64 array of shape (size,) or (rows, size)."""
    cdef cnp.ndarray a
    if type(x) is np.ndarray and cnp.PyArray_TYPE(<cnp.ndarray>x) == cnp.NPY_DOUBLE \
            and cnp.PyArray_IS_C_CONTIGUOUS(<cnp.ndarray>x):
        a = <cnp.ndarray>x
    else:
        a = _converted(x, name)
    cdef int nd = cnp.PyArray_NDIM(a)
    if nd == 1:
        if cnp.PyArray_DIM(a, 0) == size:
            return a
    elif nd == 2:
        if cnp.PyArray_DIM(a, 1) == size:
            return a
    raise ValueError(f"{name} must have shape ({size},) or (N, {size}); got {np.shape(a)}")


cdef inline Py_ssize_t _rows(cnp.ndarray a, Py_ssize_t rows, str name) except -2:
    """Combine the row count of one input with the others' (-1: not stacked)."""
    if cnp.PyArray_NDIM(a) == 1:
        return rows
    cdef Py_ssize_t r = cnp.PyArray_DIM(a, 0)
    if rows >= 0 and r != rows:
        raise ValueError(f"{name} has {r} rows, the other inputs have {rows}")
    return r


cdef inline bint _all_finite(const double *x, Py_ssize_t n) noexcept:
    cdef Py_ssize_t k
    for k in range(n):
        if not isfinite(x[k]):
            return False
    return True


cdef int _bad_quaternion(const double *q, Py_ssize_t rows, Py_ssize_t step,
                         const int *offsets, int count, Py_ssize_t *row) noexcept nogil:
    """The first quaternion (its index in offsets; its row in *row) whose squared norm is
    not a finite normal double (NaN or inf entries included), or -1
    (gagen.runtime.inputs.check_quaternions says why)."""
    cdef Py_ssize_t i
    cdef int k
    cdef const double *x
    cdef double n2
    for i in range(rows):
        for k in range(count):
            x = q + i * step + offsets[k]
            n2 = x[0] * x[0] + x[1] * x[1] + x[2] * x[2] + x[3] * x[3]
            if not (n2 >= DBL_MIN and n2 <= DBL_MAX):
                row[0] = i
                return k
    return -1


cdef inline double *_data(cnp.ndarray a) noexcept:
    return <double *>cnp.PyArray_DATA(a)


cdef inline double *_data_or_null(object a):
    return NULL if a is None else <double *>cnp.PyArray_DATA(<cnp.ndarray>a)


cdef inline Py_ssize_t _step(cnp.ndarray a) noexcept:
    return cnp.PyArray_DIM(a, 1) if cnp.PyArray_NDIM(a) == 2 else 0


cdef inline cnp.ndarray _matrix(Py_ssize_t rows, Py_ssize_t cols):
    cdef cnp.npy_intp dims[2]
    dims[0] = rows
    dims[1] = cols
    return cnp.PyArray_EMPTY(2, dims, cnp.NPY_DOUBLE, 0)


cdef inline cnp.ndarray _vectors(Py_ssize_t rows, Py_ssize_t n):
    """A fresh (n,) array, or (rows, n) when rows >= 0."""
    cdef cnp.npy_intp dims[1]
    if rows < 0:
        dims[0] = n
        return cnp.PyArray_EMPTY(1, dims, cnp.NPY_DOUBLE, 0)
    return _matrix(rows, n)


cdef inline cnp.ndarray _matrices(Py_ssize_t rows, Py_ssize_t r, Py_ssize_t c):
    """A fresh (r, c) array, or (rows, r, c) when rows >= 0."""
    cdef cnp.npy_intp dims[3]
    if rows < 0:
        dims[0] = r
        dims[1] = c
        return cnp.PyArray_EMPTY(2, dims, cnp.NPY_DOUBLE, 0)
    dims[0], dims[1], dims[2] = rows, r, c
    return cnp.PyArray_EMPTY(3, dims, cnp.NPY_DOUBLE, 0)


def _raise_not_positive_definite(str ident, int err_nonfinite, row, status=1, q=None):
    where = "" if row < 0 else f" (stacked input, row {row})"
    if status == err_nonfinite:
        raise NonFiniteStateError(
            f"the mass matrix of model '{ident}' is NaN or inf at this state{where}: "
            + nonfinite_cause(q))
    raise SingularMassMatrixError(
        f"the mass matrix of model '{ident}' is singular or not positive definite at this "
        f"state{where}; check the state for NaN or inf and the parameters for zero or "
        "negative masses and inertias")


cdef class _Evaluator:
    """What every class of kernels holds: the model's identifier, its default parameters
    (in its module), and parameter_vector, which turns the p= forms other than a float64
    array into one (None, a dict of overrides, a list)."""

    cdef const double *_defaults
    cdef int np_, err_nonfinite
    cdef readonly str ident
    cdef readonly object parameter_vector
    cdef object _capsule  # keeps the module's table (and the module) alive
    cdef int *_quaternions  # where each floating joint's quaternion starts in q
    cdef int _nquaternions
    cdef readonly tuple quaternions  # (first entry in q, description) of each

    cdef void _adopt(self, object capsule, const char *ident, int np_, int err_nonfinite,
                     const double *defaults):
        self._capsule = capsule
        self.ident = ident.decode()
        self.np_ = np_
        self.err_nonfinite = err_nonfinite
        self._defaults = defaults

    cdef int _set_quaternions(self, object quaternions, int nq) except -1:
        """The quaternions that q's checks look at (ModelInfo.quaternions())."""
        self.quaternions = tuple((int(offset), str(label)) for offset, label in quaternions)
        if any(not 0 <= offset <= nq - 4 for offset, _ in self.quaternions):
            raise ValueError(f"a quaternion must lie within q's {nq} entries")
        self._nquaternions = len(self.quaternions)
        if self._nquaternions:
            self._quaternions = <int *>malloc(self._nquaternions * sizeof(int))
            if self._quaternions == NULL:
                raise MemoryError()
            for k, (offset, _) in enumerate(self.quaternions):
                self._quaternions[k] = offset
        return 0

    def __dealloc__(self):
        free(self._quaternions)

    cdef int _check_quaternions(self, cnp.ndarray q, Py_ssize_t rows, str name) except -1:
        """ValueError for a quaternion of q that cannot be normalised (one state, or
        `rows` stacked ones)."""
        if self._nquaternions == 0:
            return 0
        cdef Py_ssize_t row = 0
        cdef int k = _bad_quaternion(_data(q), rows if rows >= 0 else 1, _step(q),
                                     self._quaternions, self._nquaternions, &row)
        if k >= 0:
            offset, label = self.quaternions[k]
            values = q[row] if rows >= 0 else q
            raise quaternion_error(name, label, row if rows >= 0 else -1,
                                   values[offset: offset + 4])
        return 0

    cdef cnp.ndarray _parameters(self, object p):
        if type(p) is np.ndarray and cnp.PyArray_TYPE(<cnp.ndarray>p) == cnp.NPY_DOUBLE \
                and cnp.PyArray_IS_C_CONTIGUOUS(<cnp.ndarray>p) \
                and cnp.PyArray_NDIM(<cnp.ndarray>p) == 1 \
                and cnp.PyArray_DIM(<cnp.ndarray>p, 0) == self.np_ \
                and _all_finite(<const double *>cnp.PyArray_DATA(<cnp.ndarray>p), self.np_):
            return <cnp.ndarray>p
        return _converted(self.parameter_vector(p), "p")

    cdef const double *_parameter_data(self, object p, list keep) except? NULL:
        """The parameters' data: the defaults for None, else p's (kept alive in `keep`)."""
        if p is None:
            return self._defaults
        cdef cnp.ndarray pa = self._parameters(p)
        keep.append(pa)
        return <const double *>cnp.PyArray_DATA(pa)

    cdef _failed(self, Py_ssize_t row, int status, cnp.ndarray q):
        """Raise for a kernel's failure at one state (row -1) or a stacked one's row."""
        _raise_not_positive_definite(self.ident, self.err_nonfinite, row, status,
                                     q if row < 0 else q[row])


# --- the model's kernels ------------------------------------------------------------------

# the model's kernels of (up to) three state arrays, called by _run
cdef enum Kernel:
    MASS_MATRIX, FORCING, FORWARD_DYNAMICS, INVERSE_DYNAMICS, ENERGY, GRAVITY, PLACEMENTS, \
        REGRESSOR


cdef inline int _call(const gagen_model_api *api, Kernel kernel, const double *a,
                      const double *b, const double *c, const double *p,
                      double *out) noexcept nogil:
    """One kernel at one state: a (q), b and c (rates) as the kernel reads them; its status
    (only forward dynamics can fail)."""
    if kernel == FORWARD_DYNAMICS:
        return api.forward_dynamics(a, b, c, p, out)
    if kernel == MASS_MATRIX:
        api.mass_matrix(a, p, out)
    elif kernel == INVERSE_DYNAMICS:
        api.inverse_dynamics(a, b, c, p, out)
    elif kernel == FORCING:
        api.forcing(a, b, c, p, out)
    elif kernel == GRAVITY:
        api.gravity(a, p, out)
    elif kernel == ENERGY:
        api.energy(a, b, p, out)
    elif kernel == PLACEMENTS:
        api.placements(a, p, out)
    else:
        api.regressor(a, b, c, p, out)
    return 0


cdef inline void _call_centroidal(const gagen_model_api *api, int which, const double *q,
                                  const double *qd, const double *p,
                                  double *out) noexcept nogil:
    """One centroidal kernel (CompiledModel.centroidal's numbering) at one state."""
    if which == 0:
        api.center_of_mass(q, p, out)
    elif which == 1:
        api.com_velocity(q, qd, p, out)
    elif which == 2:
        api.com_jacobian(q, p, out)
    elif which == 3:
        api.centroidal_map(q, p, out)
    elif which == 4:
        api.centroidal_momentum(q, qd, p, out)
    elif which == 5:
        api.centroidal_map_time_variation(q, qd, p, out)
    else:
        api.centroidal_bias(q, qd, p, out)


cdef class CompiledModel(_Evaluator):
    """The compiled kernels of a model's module, from its capsule `API`;
    `parameter_vector` turns the p= forms other than a float64 array into one,
    `external_forces(q, fext, p)` gives the joint forces of wrenches on frames."""

    cdef const gagen_model_api *api
    cdef readonly object external_forces
    cdef dict _frame_numbers  # frame name -> number
    cdef object _frame_index  # (frame) -> number, or the error that names the choices
    cdef object _constraints  # the per-call arguments' checks (runtime.constraints.Arguments)

    def __init__(self, capsule, parameter_vector, external_forces=None, quaternions=(),
                 frame_numbers=None, frame_index=None, constraints=None):
        self.api = <const gagen_model_api *>_table(capsule, MODEL_CAPSULE)
        self._adopt(capsule, self.api.ident, self.api.np, self.api.err_nonfinite,
                    self.api.parameter_defaults)
        self._set_quaternions(quaternions, self.api.nq)
        self.parameter_vector = parameter_vector
        self.external_forces = external_forces
        self._frame_numbers = dict(frame_numbers or {})
        self._frame_index = frame_index
        self._constraints = constraints

    # --- constraints (conventions: gagen.constraints; equations: gagen.runtime.constraints)

    def constrained_forward_dynamics(self, q, qd, tau, active=None, baumgarte=_NO_GAINS,
                                     fext=None, damping=0.0, p=None):
        """(qdd, forces) of the constrained forward dynamics (Dynamics's documentation)."""
        cdef const gagen_model_api *api = self.api
        cdef double kp = 0.0, kd = 0.0, dmp = 0.0
        cdef object mask = None
        if active is not None:
            mask = self._constraints.rows(active)[0]
        if baumgarte is not _NO_GAINS:
            kp, kd = self._constraints.gains(baumgarte)
        if not (type(damping) is float and damping == 0.0):
            dmp = self._constraints.damping(damping)
        if fext is not None:
            (q, tau), _ = as_states((api.nq, api.nv), q, tau, names=("q", "tau"))
            tau = tau + self.external_forces(q, fext, p)
        cdef cnp.ndarray a = _state(q, "q", api.nq)
        cdef cnp.ndarray b = _state(qd, "qd", api.nv)
        cdef cnp.ndarray c = _state(tau, "tau", api.nv)
        cdef list keep = None if p is None else []
        cdef const double *pp = self._parameter_data(p, keep)
        cdef Py_ssize_t rows = _rows(c, _rows(b, _rows(a, -1, "q"), "qd"), "tau")
        self._check_quaternions(a, rows, "q")
        cdef cnp.ndarray qdd = _vectors(rows, api.nv)
        cdef cnp.ndarray forces = _vectors(rows, api.ncrows)
        cdef const unsigned char *act = NULL if mask is None \
            else <const unsigned char *>cnp.PyArray_DATA(<cnp.ndarray>mask)
        cdef double *pa_ = _data(a)
        cdef double *pb = _data(b)
        cdef double *pc = _data(c)
        cdef double *po = _data(qdd)
        cdef double *pf = _data(forces)
        cdef Py_ssize_t sa = _step(a), sb = _step(b), sc = _step(c), i, failed = -1
        cdef int nv = api.nv, nr = api.ncrows, code, status = 0
        if rows < 0:  # one state: releasing the GIL would cost more than the kernel
            status = api.constrained_forward_dynamics(pa_, pb, pc, pp, act, kp, kd, dmp, po, pf)
        else:
            with nogil:
                for i in range(rows):
                    code = api.constrained_forward_dynamics(pa_ + i * sa, pb + i * sb,
                                                            pc + i * sc, pp, act, kp, kd, dmp,
                                                            po + i * nv, pf + i * nr)
                    if code != 0 and failed < 0:
                        failed = i
                        status = code
        if status:
            self._constraint_failure(status, failed if rows >= 0 else -1, a, mask, dmp, p)
        return qdd, forces

    def impulse_dynamics(self, q, qd_minus, active=None, restitution=0.0, damping=0.0,
                         p=None):
        """(qd_plus, impulses) at an impact (Dynamics's documentation)."""
        cdef const gagen_model_api *api = self.api
        cdef object mask = None
        cdef double r = 0.0, dmp = 0.0
        # the defaults (every constraint, no restitution, no damping) need no checks
        if not (active is None and type(restitution) is float and restitution == 0.0
                and type(damping) is float and damping == 0.0):
            mask, _, r, dmp = self._constraints.impulse_arguments(active, restitution, damping)
        cdef cnp.ndarray a = _state(q, "q", api.nq)
        cdef cnp.ndarray b = _state(qd_minus, "qd_minus", api.nv)
        cdef list keep = None if p is None else []
        cdef const double *pp = self._parameter_data(p, keep)
        cdef Py_ssize_t rows = _rows(b, _rows(a, -1, "q"), "qd_minus")
        self._check_quaternions(a, rows, "q")
        cdef cnp.ndarray out = _vectors(rows, api.nv)
        cdef cnp.ndarray impulses = _vectors(rows, api.ncrows)
        cdef const unsigned char *act = NULL if mask is None \
            else <const unsigned char *>cnp.PyArray_DATA(<cnp.ndarray>mask)
        cdef double *pa_ = _data(a)
        cdef double *pb = _data(b)
        cdef double *po = _data(out)
        cdef double *pf = _data(impulses)
        cdef double rr = r, dd = dmp
        cdef Py_ssize_t sa = _step(a), sb = _step(b), i, failed = -1
        cdef int nv = api.nv, nr = api.ncrows, code, status = 0
        if rows < 0:  # one state: releasing the GIL would cost more than the kernel
            status = api.impulse_dynamics(pa_, pb, pp, act, rr, dd, po, pf)
        else:
            with nogil:
                for i in range(rows):
                    code = api.impulse_dynamics(pa_ + i * sa, pb + i * sb, pp, act, rr, dd,
                                                po + i * nv, pf + i * nr)
                    if code != 0 and failed < 0:
                        failed = i
                        status = code
        if status:
            self._constraint_failure(status, failed if rows >= 0 else -1, a, mask, dd, p)
        return out, impulses

    def constraint_rows(self, int which, q, qd=None, active=None, p=None):
        """The active constraints' Jacobian (which 0: (m, NV)), drift (1: (m,), at qd) or
        position error (2: (m,)), at one state or stacked states."""
        cdef const gagen_model_api *api = self.api
        mask, m = self._constraints.rows(active)
        cdef cnp.ndarray a = _state(q, "q", api.nq)
        cdef cnp.ndarray b = _state(qd, "qd", api.nv) if which == 1 else a
        cdef list keep = None if p is None else []
        cdef const double *pp = self._parameter_data(p, keep)
        cdef Py_ssize_t rows = _rows(a, -1, "q")
        if which == 1:
            rows = _rows(b, rows, "qd")
        self._check_quaternions(a, rows, "q")
        cdef Py_ssize_t nout = m * api.nv if which == 0 else m
        cdef cnp.ndarray out = _matrices(rows, m, api.nv) if which == 0 else _vectors(rows, m)
        cdef const unsigned char *act = NULL if mask is None \
            else <const unsigned char *>cnp.PyArray_DATA(<cnp.ndarray>mask)
        cdef double *pa_ = _data(a)
        cdef double *pb = _data(b)
        cdef double *po = _data(out)
        cdef Py_ssize_t sa = _step(a), sb = _step(b), i
        cdef Py_ssize_t count = rows if rows >= 0 else 1
        with nogil:
            for i in range(count):
                if which == 0:
                    api.constraint_jacobian(pa_ + i * sa, pp, act, po + i * nout)
                elif which == 1:
                    api.constraint_drift(pa_ + i * sa, pb + i * sb, pp, act, po + i * nout)
                else:
                    api.constraint_error(pa_ + i * sa, pp, act, po + i * nout)
        return out

    cdef _constraint_failure(self, int status, Py_ssize_t row, cnp.ndarray q, object mask,
                             double damping, object p):
        """Raise for a constrained kernel's failure at one state (row -1) or a stacked row:
        M's errors as forward dynamics's, dependent rows naming them."""
        if status == 1 or status == self.err_nonfinite:
            self._failed(row, status, q)
        if status == 4:
            self._constraints.singular(q if row < 0 else q[row], mask, damping, row, p)
        raise ValueError(f"the constrained dynamics of model '{self.ident}' refused its "
                         f"arguments (status {status})")

    cdef object _run(self, Kernel kernel, Py_ssize_t nout, object x, object y, object z,
                     object p, str nx, str ny, str nz):
        """Evaluate a kernel at one state or at stacked states (one C loop, GIL released)."""
        cdef const gagen_model_api *api = self.api
        cdef cnp.ndarray a = _state(x, nx, api.nq)
        cdef cnp.ndarray b = _state(y, ny, api.nv) if ny is not None else a
        cdef cnp.ndarray c = _state(z, nz, api.nv) if nz is not None else a
        cdef list keep = []
        cdef const double *pp = self._parameter_data(p, keep)
        cdef Py_ssize_t rows = _rows(a, -1, nx)
        if ny is not None:
            rows = _rows(b, rows, ny)
        if nz is not None:
            rows = _rows(c, rows, nz)
        self._check_quaternions(a, rows, nx)
        cdef cnp.ndarray out = _vectors(rows, nout)
        cdef int status = 0
        if rows < 0:
            status = _call(api, kernel, _data(a), _data(b), _data(c), pp, _data(out))
            if status:
                self._failed(-1, status, a)
            return out
        cdef double *pa_ = _data(a)
        cdef double *pb = _data(b)
        cdef double *pc = _data(c)
        cdef double *po = _data(out)
        cdef Py_ssize_t sa = _step(a), sb = _step(b), sc = _step(c), i
        cdef Py_ssize_t failed = -1
        cdef int code
        cdef double *scratch = NULL
        if nout >= STREAM_STATE and rows * nout * sizeof(double) >= STREAM_BYTES:
            scratch = <double *>malloc(nout * sizeof(double))
            if scratch == NULL:
                raise MemoryError()
        with nogil:
            for i in range(rows):
                if scratch == NULL:
                    code = _call(api, kernel, pa_ + i * sa, pb + i * sb, pc + i * sc, pp,
                                 po + i * nout)
                else:
                    code = _call(api, kernel, pa_ + i * sa, pb + i * sb, pc + i * sc, pp,
                                 scratch)
                    gagen_stream_copy(po + i * nout, scratch, nout)
                if code != 0 and failed < 0:
                    failed = i
                    status = code
            if scratch != NULL:
                gagen_stream_fence()
        free(scratch)
        if failed >= 0:
            self._failed(failed, status, a)
        return out

    def mass_matrix(self, q, p=None):
        """M(q), shape (n, n), or (N, n, n) for stacked q."""
        cdef int nv = self.api.nv
        out = self._run(MASS_MATRIX, nv * nv, q, None, None, p, "q", None, None)
        if cnp.PyArray_NDIM(<cnp.ndarray>out) == 1:
            return out.reshape(nv, nv)
        return out.reshape(-1, nv, nv)

    def forcing(self, q, qd, tau, p=None):
        """F(q, qd, tau) such that M(q) qdd = F."""
        return self._run(FORCING, self.api.nv, q, qd, tau, p, "q", "qd", "tau")

    def forward_dynamics(self, q, qd, tau, p=None, fext=None):
        """qdd = M(q)^-1 F(q, qd, tau [+ J^T w of the wrenches fext])."""
        if fext is not None:
            (q, tau), _ = as_states((self.api.nq, self.api.nv), q, tau, names=("q", "tau"))
            tau = tau + self.external_forces(q, fext, p)
        return self._run(FORWARD_DYNAMICS, self.api.nv, q, qd, tau, p, "q", "qd", "tau")

    def inverse_dynamics(self, q, qd, qdd, p=None, fext=None):
        """The joint torques (forces for prismatic joints) that give qdd [under fext]."""
        tau = self._run(INVERSE_DYNAMICS, self.api.nv, q, qd, qdd, p, "q", "qd", "qdd")
        if fext is not None:
            tau = tau - self.external_forces(q, fext, p)
        return tau

    def placements(self, q, p=None):
        """Per body, its orientation (row-major), origin and joint axis in the world."""
        return self._run(PLACEMENTS, 15 * self.api.nb, q, None, None, p, "q", None, None)

    def frame_offsets(self, p=None):
        """Per frame, its axes (row-major) and origin in its body's frame."""
        cdef list keep = []
        cdef const double *pp = self._parameter_data(p, keep)
        cdef cnp.npy_intp dims[1]
        dims[0] = 12 * self.api.nf
        cdef cnp.ndarray out = cnp.PyArray_EMPTY(1, dims, cnp.NPY_DOUBLE, 0)
        self.api.frame_offsets(pp, _data(out))
        return out

    def frame(self, int which, int frame, q, qd, p=None, int reference=2):
        """A frame's placement (which 0: R and origin, 12 values), Jacobian (1: 6 x NV) or
        velocity (2: 6 values) at one state or stacked states; the last two in `reference`
        (0 WORLD, 1 LOCAL, 2 LOCAL_WORLD_ALIGNED)."""
        return self._frame(which, frame, q, qd, p, reference)

    cdef object _frame(self, int which, int frame, object q, object qd, object p,
                       int reference):
        cdef const gagen_model_api *api = self.api
        if not 0 <= frame < api.nf:
            raise IndexError(f"frame {frame} out of range (0 .. {api.nf - 1})")
        if not 0 <= reference <= 2:
            raise ValueError(f"reference {reference} is not 0, 1 or 2")
        cdef cnp.ndarray a = _state(q, "q", api.nq)
        cdef cnp.ndarray b = _state(qd, "qd", api.nv) if which == 2 else a
        cdef list keep = None if p is None else []
        cdef const double *pp = self._parameter_data(p, keep)
        cdef Py_ssize_t rows = _rows(a, -1, "q")
        if which == 2:
            rows = _rows(b, rows, "qd")
        self._check_quaternions(a, rows, "q")
        cdef int nout = 12 if which == 0 else (6 * api.nv if which == 1 else 6)
        # allocated in its final shape (a reshape or a row view afterwards costs more than
        # the kernel on a small robot)
        cdef cnp.ndarray out = _matrices(rows, 6, api.nv) if which == 1 else _vectors(rows, nout)
        cdef double *pa_ = _data(a)
        cdef double *pb = _data(b)
        cdef double *po = _data(out)
        cdef Py_ssize_t sa = _step(a), sb = _step(b)
        if rows < 0:  # one state: releasing the GIL would cost more than the kernel
            _frame_loop(api, which, frame, reference, pa_, sa, pb, sb, pp, po, nout, 1)
        else:
            with nogil:
                _frame_loop(api, which, frame, reference, pa_, sa, pb, sb, pp, po, nout, rows)
        return out

    # --- task space: frames' accelerations, Jacobians' time variation and the
    # operational-space inertia (conventions: gagen.runtime.taskspace) --------------------

    # The frame methods by name (CompiledDynamics binds them: their documentation is
    # Dynamics's): a frame's name and the reference and kind are looked up in dicts
    # first, anything else takes the checked path, which names what is wrong.

    cdef int _frame_number(self, object frame) except -1:
        cdef PyObject *k = PyDict_GetItem(self._frame_numbers, frame) \
            if type(frame) is str else NULL
        if k == NULL:
            return self._frame_index(frame)
        return <object>k

    def frame_jacobian(self, q, frame, reference="local_world_aligned", p=None):
        """The frame's Jacobian (a list of frames: theirs) in `reference`."""
        if type(frame) is list or type(frame) is tuple:
            return self.frame_jacobians([self._frame_index(f) for f in frame],
                                        _reference_number(reference), q, p)
        return self._frame(1, self._frame_number(frame), q, None, p,
                           _reference_number(reference))

    def frame_velocity(self, q, qd, frame, reference="local_world_aligned", p=None):
        """The frame's velocity in `reference`."""
        return self._frame(2, self._frame_number(frame), q, qd, p,
                           _reference_number(reference))

    def frame_acceleration(self, q, qd, qdd, frame, reference="local_world_aligned",
                           kind="classical", p=None):
        """The frame's acceleration at qdd in `reference`, classical or spatial."""
        return self._frame_rates(0, self._frame_number(frame), _reference_number(reference),
                                 _kind_number(kind), q, qd, qdd, p)

    def frame_bias_acceleration(self, q, qd, frame, reference="local_world_aligned",
                                kind="classical", p=None):
        """The frame's acceleration at qdd = 0 (J̇ qd in that convention)."""
        return self._frame_rates(1, self._frame_number(frame), _reference_number(reference),
                                 _kind_number(kind), q, qd, None, p)

    def frame_jacobian_time_variation(self, q, qd, frame, reference="local_world_aligned",
                                      p=None):
        """dJ/dt of the frame's Jacobian in `reference` along qd."""
        return self._frame_rates(2, self._frame_number(frame), _reference_number(reference),
                                 0, q, qd, None, p)

    def frame_rates(self, int which, int frame, int reference, int kind, q, qd, qdd=None,
                    p=None):
        """Frame `frame`'s acceleration at qdd (which 0: 6 values, kind 0 classical or 1
        spatial), its bias acceleration at qdd = 0 (1), or its Jacobian's time variation
        (2: 6 x NV), in `reference` (0 WORLD, 1 LOCAL, 2 LOCAL_WORLD_ALIGNED), at one state
        or stacked states."""
        return self._frame_rates(which, frame, reference, kind, q, qd, qdd, p)

    cdef object _frame_rates(self, int which, int frame, int reference, int kind, object q,
                             object qd, object qdd, object p):
        cdef const gagen_model_api *api = self.api
        if not 0 <= frame < api.nf:
            raise IndexError(f"frame {frame} out of range (0 .. {api.nf - 1})")
        if not (0 <= reference <= 2 and 0 <= kind <= 1 and 0 <= which <= 2):
            raise ValueError(f"which {which}, reference {reference} or kind {kind} out of range")
        cdef cnp.ndarray a = _state(q, "q", api.nq)
        cdef cnp.ndarray b = _state(qd, "qd", api.nv)
        cdef cnp.ndarray c = _state(qdd, "qdd", api.nv) if which == 0 else b
        cdef list keep = None if p is None else []
        cdef const double *pp = self._parameter_data(p, keep)
        cdef Py_ssize_t rows = _rows(b, _rows(a, -1, "q"), "qd")
        if which == 0:
            rows = _rows(c, rows, "qdd")
        self._check_quaternions(a, rows, "q")
        cdef int nout = 6 * api.nv if which == 2 else 6
        cdef cnp.ndarray out = _matrices(rows, 6, api.nv) if which == 2 else _vectors(rows, 6)
        cdef double *pa_ = _data(a)
        cdef double *pb = _data(b)
        cdef double *pc = _data(c) if which == 0 else NULL
        cdef double *po = _data(out)
        cdef Py_ssize_t sa = _step(a), sb = _step(b), sc = _step(c)
        if rows < 0:  # one state: releasing the GIL would cost more than the kernel
            _frame_rates_loop(api, which, frame, reference, kind, pa_, sa, pb, sb, pc, sc,
                              pp, po, nout, 1)
        else:
            with nogil:
                _frame_rates_loop(api, which, frame, reference, kind, pa_, sa, pb, sb, pc,
                                  sc, pp, po, nout, rows)
        return out

    def frame_jacobians(self, frames, int reference, q, p=None):
        """The Jacobians of several frames (frame numbers) in `reference`, their common
        ancestors placed once: (k, 6, NV), or (N, k, 6, NV) for stacked q."""
        cdef const gagen_model_api *api = self.api
        if not 0 <= reference <= 2:
            raise ValueError(f"reference {reference} is not 0, 1 or 2")
        cdef cnp.ndarray fr = _frame_numbers(frames, api.nf)
        cdef int k = <int>cnp.PyArray_SIZE(fr)
        cdef cnp.ndarray a = _state(q, "q", api.nq)
        cdef list keep = []
        cdef const double *pp = self._parameter_data(p, keep)
        cdef Py_ssize_t rows = _rows(a, -1, "q")
        self._check_quaternions(a, rows, "q")
        cdef object shape = (k, 6, api.nv)
        if rows >= 0:
            shape = (rows,) + shape
        cdef cnp.ndarray out = np.empty(shape)
        cdef const int *pf = <const int *>cnp.PyArray_DATA(fr)
        cdef double *pa_ = _data(a)
        cdef double *po = _data(out)
        cdef Py_ssize_t sa = _step(a), nout = 6 * k * api.nv, i
        cdef Py_ssize_t count = rows if rows >= 0 else 1
        with nogil:
            for i in range(count):
                api.frame_jacobians(pa_ + i * sa, pp, k, pf, reference, po + i * nout)
        return out

    def task_matrix(self, int which, frames, int dims, q, p=None):
        """For the stacked rows (the first `dims` of each frame's LOCAL_WORLD_ALIGNED
        Jacobian) of several frames: J M^-1 J^T (which 0) or its inverse, the
        operational-space inertia (1); (m, m) or (N, m, m), m = dims * frames. Returns
        (matrix, status, row): status 0, or the C's code for dependent rows at that row
        (-1: not stacked); M's failures raise as forward dynamics's."""
        cdef const gagen_model_api *api = self.api
        if dims != 3 and dims != 6:
            raise ValueError(f"dims must be 3 or 6; got {dims}")
        cdef cnp.ndarray fr = _frame_numbers(frames, api.nf)
        cdef int k = <int>cnp.PyArray_SIZE(fr)
        if k < 1:
            raise ValueError("frames must name at least one frame")
        cdef cnp.ndarray a = _state(q, "q", api.nq)
        cdef list keep = []
        cdef const double *pp = self._parameter_data(p, keep)
        cdef Py_ssize_t rows = _rows(a, -1, "q"), m = dims * k
        self._check_quaternions(a, rows, "q")
        cdef cnp.ndarray out = _matrices(rows, m, m)
        cdef const int *pf = <const int *>cnp.PyArray_DATA(fr)
        cdef double *pa_ = _data(a)
        cdef double *po = _data(out)
        cdef Py_ssize_t sa = _step(a), i, failed = -1
        cdef Py_ssize_t count = rows if rows >= 0 else 1
        cdef int code, status = 0
        cdef double *work = <double *>malloc(m * api.nv * sizeof(double))
        if work == NULL:
            raise MemoryError()
        with nogil:
            for i in range(count):
                if which == 0:
                    code = api.delassus(pa_ + i * sa, pp, k, pf, dims, work, po + i * m * m)
                else:
                    code = api.operational_space_inertia(pa_ + i * sa, pp, k, pf, dims, work,
                                                         po + i * m * m)
                if code != 0 and failed < 0:
                    failed = i
                    status = code
        free(work)
        if status != 0 and (status == self.err_nonfinite or status == 1):
            self._failed(failed if rows >= 0 else -1, status, a)
        return out, status, (failed if rows >= 0 else -1)

    cdef object _centroidal(self, int which, object q, object qd, object p):
        """A centroidal kernel (_call_centroidal's numbering) at one state or stacked
        states, into a fresh array of its final shape."""
        cdef const gagen_model_api *api = self.api
        cdef bint rates = qd is not None
        cdef cnp.ndarray a = _state(q, "q", api.nq)
        cdef cnp.ndarray b = _state(qd, "qd", api.nv) if rates else a
        cdef list keep = []
        cdef const double *pp = self._parameter_data(p, keep)
        cdef Py_ssize_t rows = _rows(a, -1, "q")
        if rates:
            rows = _rows(b, rows, "qd")
        cdef int height = 3 if which <= 2 else 6
        cdef bint matrix = which == 2 or which == 3 or which == 5
        cdef int nout = height * api.nv if matrix else height
        cdef cnp.ndarray out = _matrices(rows, height, api.nv) if matrix \
            else _vectors(rows, height)
        cdef double *pa_ = _data(a)
        cdef double *pb = _data(b)
        cdef double *po = _data(out)
        cdef Py_ssize_t sa = _step(a), sb = _step(b), i
        if rows < 0:  # one state: releasing the GIL would cost more than the kernel saves
            _call_centroidal(api, which, pa_, pb, pp, po)
            return out
        with nogil:
            for i in range(rows):
                _call_centroidal(api, which, pa_ + i * sa, pb + i * sb, pp, po + i * nout)
        return out

    def center_of_mass(self, q, p=None):
        """The centre of mass in the world, (3,) or (N, 3)."""
        return self._centroidal(0, q, None, p)

    def com_velocity(self, q, qd, p=None):
        """The centre of mass's velocity, (3,) or (N, 3)."""
        return self._centroidal(1, q, qd, p)

    def com_jacobian(self, q, p=None):
        """J_com, (3, nv) or (N, 3, nv): com_velocity = J_com qd."""
        return self._centroidal(2, q, None, p)

    def centroidal_map(self, q, p=None):
        """A_g, (6, nv) or (N, 6, nv): h_g = A_g qd."""
        return self._centroidal(3, q, None, p)

    def centroidal_momentum(self, q, qd, p=None):
        """h_g, (6,) or (N, 6): linear momentum, angular momentum about the centre of mass."""
        return self._centroidal(4, q, qd, p)

    def centroidal_map_time_variation(self, q, qd, p=None):
        """d/dt A_g, (6, nv) or (N, 6, nv)."""
        return self._centroidal(5, q, qd, p)

    def centroidal_bias(self, q, qd, p=None):
        """d/dt A_g qd, (6,) or (N, 6): d/dt h_g = A_g qdd + centroidal_bias."""
        return self._centroidal(6, q, qd, p)

    def gravity(self, q, p=None):
        """The gravity torques g(q) = inverse_dynamics(q, 0, 0)."""
        return self._run(GRAVITY, self.api.nv, q, None, None, p, "q", None, None)

    def energy(self, q, qd, p=None):
        """(kinetic, potential): floats, or arrays of shape (N,) for stacked states."""
        out = self._run(ENERGY, 2, q, qd, None, p, "q", "qd", None)
        if cnp.PyArray_NDIM(<cnp.ndarray>out) == 1:
            return float(out[0]), float(out[1])
        return out[:, 0].copy(), out[:, 1].copy()

    def regressor(self, q, qd, qdd, p=None):
        """Y(q, qd, qdd), shape (n, P), or (N, n, P) for stacked states."""
        cdef int nv = self.api.nv, nreg = self.api.nreg
        out = self._run(REGRESSOR, nv * nreg, q, qd, qdd, p, "q", "qd", "qdd")
        if cnp.PyArray_NDIM(<cnp.ndarray>out) == 1:
            return out.reshape(nv, nreg)
        return out.reshape(-1, nv, nreg)

    def regressor_parameters(self, p=None):
        """pi, shape (P,): the dynamic parameters at p."""
        cdef list keep = []
        cdef const double *pp = self._parameter_data(p, keep)
        cdef cnp.npy_intp dims[1]
        dims[0] = self.api.nreg
        cdef cnp.ndarray out = cnp.PyArray_EMPTY(1, dims, cnp.NPY_DOUBLE, 0)
        self.api.regressor_parameters(pp, _data(out))
        return out


# --- simulations: the model's C integrators and controllers --------------------------------

def _vector(x, Py_ssize_t size, str name):
    if x is None:
        return np.zeros(size)
    if type(x) is np.ndarray and cnp.PyArray_TYPE(<cnp.ndarray>x) == cnp.NPY_DOUBLE \
            and cnp.PyArray_IS_C_CONTIGUOUS(<cnp.ndarray>x) and cnp.PyArray_NDIM(<cnp.ndarray>x) == 1 \
            and cnp.PyArray_DIM(<cnp.ndarray>x, 0) == size:
        return x
    arr = np.ascontiguousarray(x, dtype=np.float64).ravel()
    if arr.size == 1 and size > 1:
        arr = np.full(size, arr[0])
    if arr.size != size:
        raise ValueError(f"{name} must have {size} entries, got {arr.size}")
    return arr


cdef inline void _split_states(const double *y, Py_ssize_t m, Py_ssize_t nq, Py_ssize_t nv,
                               double *q, double *qd) noexcept nogil:
    """Rows of y = [q, qd] (m x (nq + nv)) into q (m x nq) and qd (m x nv)."""
    cdef Py_ssize_t r, k, ny = nq + nv
    for r in range(m):
        for k in range(nq):
            q[r * nq + k] = y[r * ny + k]
        for k in range(nv):
            qd[r * nv + k] = y[r * ny + nq + k]


def _frame_wrenches(frames, wrenches, int nf):
    """Frame numbers (int32) and their wrenches ((count, 6) float64), checked."""
    fr = np.ascontiguousarray(np.zeros(0) if frames is None else frames, dtype=np.int32).ravel()
    wr = np.ascontiguousarray(np.zeros((0, 6)) if wrenches is None else wrenches,
                              dtype=np.float64).reshape(-1, 6)
    if wr.shape[0] != fr.size or np.any(fr < 0) or np.any(fr >= nf) \
            or not np.all(np.isfinite(wr)):
        raise ValueError(f"frames must be frame numbers in 0 .. {nf - 1}, one finite wrench "
                         "(6 values) each")
    return fr, wr


cdef dict _REFERENCES = REFERENCES
cdef dict _KINDS = KINDS


cdef int _reference_number(object reference) except -1:
    """A reference's number (Pinocchio's: 0 WORLD, 1 LOCAL, 2 LOCAL_WORLD_ALIGNED)."""
    cdef PyObject *code = PyDict_GetItem(_REFERENCES, reference) \
        if type(reference) is str else NULL
    return reference_code(reference) if code == NULL else <object>code


cdef int _kind_number(object kind) except -1:
    """An acceleration kind's number (0 classical, 1 spatial)."""
    cdef PyObject *code = PyDict_GetItem(_KINDS, kind) if type(kind) is str else NULL
    return kind_code(kind) if code == NULL else <object>code


cdef void _frame_loop(const gagen_model_api *api, int which, int frame, int reference,
                      const double *q, Py_ssize_t sq, const double *qd, Py_ssize_t sqd,
                      const double *p, double *out, Py_ssize_t nout,
                      Py_ssize_t count) noexcept nogil:
    """A frame kernel (which 0 placement, 1 Jacobian, 2 velocity) at `count` states."""
    cdef Py_ssize_t i
    for i in range(count):
        if which == 0:
            api.frame_placement(q + i * sq, p, frame, out + i * nout, out + i * nout + 9)
        elif which == 1:
            api.frame_jacobian(q + i * sq, p, frame, reference, out + i * nout)
        else:
            api.frame_velocity(q + i * sq, qd + i * sqd, p, frame, reference,
                               out + i * nout)


cdef void _frame_rates_loop(const gagen_model_api *api, int which, int frame, int reference,
                            int kind, const double *q, Py_ssize_t sq, const double *qd,
                            Py_ssize_t sqd, const double *qdd, Py_ssize_t sqdd,
                            const double *p, double *out, Py_ssize_t nout,
                            Py_ssize_t count) noexcept nogil:
    """A frame's acceleration (which 0), bias acceleration (1, qdd NULL) or Jacobian's
    time variation (2) at `count` states."""
    cdef Py_ssize_t i
    for i in range(count):
        if which == 2:
            api.frame_jacobian_time_variation(q + i * sq, qd + i * sqd, p, frame, reference,
                                              out + i * nout)
        else:
            api.frame_acceleration(q + i * sq, qd + i * sqd,
                                   qdd + i * sqdd if qdd != NULL else NULL, p, frame,
                                   reference, kind, out + i * nout)


cdef cnp.ndarray _frame_numbers(object frames, int nf):
    """Frame numbers (a sequence of ints) as a fresh int32 array, each in 0 .. nf - 1."""
    cdef Py_ssize_t k, n = len(frames)
    cdef cnp.npy_intp dims[1]
    dims[0] = n
    cdef cnp.ndarray fr = cnp.PyArray_EMPTY(1, dims, cnp.NPY_INT32, 0)
    cdef int32_t *data = <int32_t *>cnp.PyArray_DATA(fr)
    cdef long f
    for k in range(n):
        f = frames[k]
        if not 0 <= f < nf:
            raise IndexError(f"frame {f} out of range (0 .. {nf - 1})")
        data[k] = <int32_t>f
    return fr


def _constraint_mask(active, int nc):
    """The active constraints as a fresh uint8 array of nc flags."""
    mask = np.ascontiguousarray(active, dtype=np.uint8).ravel().copy()
    if mask.size != nc:
        raise ValueError(f"active must have {nc} flags, one per constraint; got {mask.size}")
    return mask


cdef int _method_code(str method) except -1:
    if method == "dopri5":
        return GAGEN_METHOD_DOPRI5
    if method == "rk4":
        return GAGEN_METHOD_RK4
    raise ValueError(f"unknown compiled method '{method}' (dopri5 or rk4)")


cdef class CompiledSimulation:
    """The robot, its controller and gagen's C integrators, run without Python per step."""

    cdef const gagen_model_api *api
    cdef gagen_control ctl
    cdef const double *p
    cdef object _keep
    # a constrained run: the active constraints (one byte each), Baumgarte's gains, damping
    cdef object _active
    cdef double kp_c, kd_c, damping_c

    def __init__(self, CompiledModel model, p, int kind, kp=None, kd=None, target=None,
                 bint gravity_compensation=False, traj_q0=None, traj_qf=None,
                 double traj_Tp=1.0, feedforward=None, frames=None, wrenches=None,
                 active=None, baumgarte=(0.0, 0.0), double damping=0.0):
        self.api = model.api
        if active is not None:
            self._active = _constraint_mask(active, self.api.nc)
            self.kp_c, self.kd_c = (float(x) for x in baumgarte)
            self.damping_c = damping
        cdef int nq = self.api.nq, nv = self.api.nv
        params = model._parameters(model.parameter_vector(None) if p is None else p)
        arrays = [params] + [None if v is None else _vector(v, size, name) for v, name, size in
                             ((kp, "kp", nv), (kd, "kd", nv), (target, "target", nv),
                              (traj_q0, "trajectory q0", nq), (traj_qf, "trajectory qf", nq),
                              (feedforward, "feedforward", nv))]
        fr, wr = _frame_wrenches(frames, wrenches, self.api.nf)
        # the C structure points into them (NULL: zeros); the model keeps its table alive
        self._keep = arrays + [fr, wr, model]
        self.ctl.feedforward = _data_or_null(arrays[6])
        self.ctl.nframes = cnp.PyArray_SIZE(fr)
        self.ctl.frames = <const int *>cnp.PyArray_DATA(fr)
        self.ctl.wrenches = _data(wr)
        self.p = _data(arrays[0])
        self.ctl.kind = kind
        self.ctl.kp = _data_or_null(arrays[1])
        self.ctl.kd = _data_or_null(arrays[2])
        self.ctl.target = _data_or_null(arrays[3])
        self.ctl.gravity_compensation = gravity_compensation
        self.ctl.traj_q0 = _data_or_null(arrays[4])
        self.ctl.traj_qf = _data_or_null(arrays[5])
        self.ctl.traj_Tp = traj_Tp
        self.ctl.poll = _poll_signals
        self.ctl.poll_ctx = NULL

    def run(self, str method, double t0, double t1, q0, qd0, t_eval, double rtol=1e-6,
            atol=1e-8, double first_step=0.0, double max_step=0.0, long max_steps=0,
            double h=1e-3):
        """Integrate from (q0, qd0) and add the controller's torques at the samples.

        Returns (q, qd, tau: fresh (m, n) arrays, status, stats dict); on a failed
        integration the rows not reached are NaN and so is all of tau."""
        cdef const gagen_model_api *api = self.api
        cdef int code = _method_code(method)
        cdef int nq = api.nq, nv = api.nv, ny = nq + nv
        cdef cnp.ndarray y0 = np.concatenate([_vector(q0, nq, "q0"), _vector(qd0, nv, "qd0")])
        cdef cnp.ndarray at = np.full(ny, <double>atol) if type(atol) is float \
            else np.array(_vector(atol, ny, "atol"))
        cdef cnp.ndarray te = np.ascontiguousarray(t_eval, dtype=np.float64)
        cdef int m = cnp.PyArray_SIZE(te)
        cdef cnp.ndarray y = _matrix(m, ny)
        cdef cnp.ndarray q = _matrix(m, nq), qd = _matrix(m, nv), tau = _matrix(m, nv)
        cdef double *pt = _data(te)
        cdef double *py = _data(y)
        cdef double *pq = _data(q)
        cdef double *pqd = _data(qd)
        cdef double *ptau = _data(tau)
        cdef double *py0 = _data(y0)
        cdef double *pat = _data(at)
        cdef gagen_ode_stats stats
        cdef int status
        cdef Py_ssize_t i
        raised = []  # what a signal handler raised while the integrator ran (Ctrl-C)
        self.ctl.poll_ctx = <void *>raised
        cdef bint held = self._active is not None
        cdef const unsigned char *act = NULL
        cdef double kc = self.kp_c, dc = self.kd_c, mu = self.damping_c
        cdef cnp.ndarray forces = _matrix(m, api.ncrows), errors = _matrix(m, api.ncrows)
        cdef double *pf = _data(forces)
        cdef double *pe = _data(errors)
        if held:
            act = <const unsigned char *>cnp.PyArray_DATA(<cnp.ndarray>self._active)
        with nogil:
            if held:
                status = api.simulate_constrained(code, &self.ctl, self.p, act, kc, dc, mu, t0,
                                                  t1, py0, rtol, pat, first_step, max_step,
                                                  max_steps, h, pt, m, py, &stats)
            else:
                status = api.simulate(code, &self.ctl, self.p, t0, t1, py0, rtol, pat,
                                      first_step, max_step, max_steps, h, pt, m, py, &stats)
            _split_states(py, m, nq, nv, pq, pqd)
            if status == 0:  # the controller passed the integrator's checks: no new status
                api.control_torques(&self.ctl, self.p, m, pt, py, ptau)
                if held:
                    api.constrained_outputs(&self.ctl, self.p, act, kc, dc, mu, m, pt, py, pf,
                                            pe)
            else:
                for i in range(m * nv):
                    ptau[i] = NAN
                for i in range(m * api.ncrows):
                    pf[i] = NAN
                    pe[i] = NAN
        self.ctl.poll_ctx = NULL
        if raised:
            raise raised[0]
        info = {"nfev": stats.nfev, "nsteps": stats.nsteps, "naccepted": stats.naccepted,
                "nrejected": stats.nrejected}
        if held:
            info["forces"], info["errors"] = forces, errors
        return q, qd, tau, status, info

    def torques(self, t, y):
        """The controller's torques at times t (m,) and states y (m, 2n): (tau, status)."""
        cdef const gagen_model_api *api = self.api
        cdef int ny = api.nq + api.nv
        cdef cnp.ndarray tt = np.ascontiguousarray(t, dtype=np.float64)
        cdef cnp.ndarray yy = np.ascontiguousarray(y, dtype=np.float64)
        cdef Py_ssize_t m = tt.size
        if yy.ndim != 2 or yy.shape[0] != m or yy.shape[1] != ny:
            raise ValueError(f"y must have shape ({m}, {ny})")
        cdef cnp.ndarray res = _matrix(m, api.nv)
        cdef int status
        cdef double *pt = _data(tt)
        cdef double *py = _data(yy)
        cdef double *pr = _data(res)
        with nogil:
            status = api.control_torques(&self.ctl, self.p, m, pt, py, pr)
        return res, status


cdef cnp.ndarray _runs_table(object a, Py_ssize_t runs, Py_ssize_t cols, int typenum,
                             str name):
    """a, a C-contiguous array of the given type and shape (runs, cols) or (1, cols)."""
    if not (type(a) is np.ndarray and cnp.PyArray_TYPE(<cnp.ndarray>a) == typenum
            and cnp.PyArray_IS_C_CONTIGUOUS(<cnp.ndarray>a) and cnp.PyArray_NDIM(<cnp.ndarray>a) == 2
            and cnp.PyArray_DIM(<cnp.ndarray>a, 1) == cols
            and (cnp.PyArray_DIM(<cnp.ndarray>a, 0) == runs or cnp.PyArray_DIM(<cnp.ndarray>a, 0) == 1)):
        raise ValueError(f"{name} must be a C-contiguous array of shape ({runs}, {cols}) or "
                         f"(1, {cols}) and type number {typenum}")
    return <cnp.ndarray>a


cdef double *_output(object a, Py_ssize_t runs, Py_ssize_t m, Py_ssize_t size,
                     str name) except NULL:
    """The data of a C-contiguous float64 array of shape (runs, m, size), written in place."""
    if not (type(a) is np.ndarray and cnp.PyArray_TYPE(<cnp.ndarray>a) == cnp.NPY_DOUBLE
            and cnp.PyArray_IS_C_CONTIGUOUS(<cnp.ndarray>a) and a.shape == (runs, m, size)):
        raise ValueError(f"{name} must be a C-contiguous float64 array of shape "
                         f"({runs}, {m}, {size})")
    return _data(<cnp.ndarray>a)


cdef inline Py_ssize_t _row_step(cnp.ndarray a) noexcept:
    """Rows of a _runs_table to advance per run: 0 for one row shared by every run."""
    return 1 if cnp.PyArray_DIM(a, 0) > 1 else 0


cdef class CompiledBatch:
    """Runs of one method over one time grid, each with its own initial state, parameters
    and controller (a table has one row per run, or one row for all), written into rows of
    preallocated arrays q (N, m, nq), qd, tau (N, m, nv) and stats (N, 5: status, nfev, nsteps,
    naccepted, nrejected). Every run is the C call of CompiledSimulation.run, so it gives
    the same numbers. run(start, stop) integrates a slice without the GIL: threads may run
    disjoint slices at once; stop() makes them all return at their next poll."""

    cdef const gagen_model_api *api
    cdef int code, m, nq, nv, np_
    cdef Py_ssize_t N
    cdef double t0, t1, rtol, first_step, max_step, h
    cdef long max_steps
    cdef const double *at
    cdef int stop_flag
    cdef object _keep
    cdef const double *te
    cdef const double *y0
    cdef const double *p
    cdef const int32_t *kind
    cdef const int32_t *gc
    cdef const double *kp
    cdef const double *kd
    cdef const double *target
    cdef const double *tq0
    cdef const double *tqf
    cdef const double *ff
    cdef int nframes
    cdef const int *frames
    cdef const double *wrenches
    cdef const double *tTp
    cdef Py_ssize_t y_step, p_step, c_step
    cdef double *q
    cdef double *qd
    cdef double *tau
    cdef int64_t *stats
    # a constrained batch: the active constraints, gains, damping, and where the forces and
    # errors go ((N, m, rows) each)
    cdef const unsigned char *active
    cdef double kp_c, kd_c, damping_c
    cdef double *forces
    cdef double *errors

    def __init__(self, CompiledModel model, str method, double t0, double t1, t_eval,
                 double rtol, atol, double first_step, double max_step, long max_steps,
                 double h, y0, p, kind, gravity_compensation, kp, kd, target, traj_q0,
                 traj_qf, traj_Tp, q, qd, tau, stats, feedforward=None, frames=None,
                 wrenches=None, active=None, baumgarte=(0.0, 0.0), double damping=0.0,
                 forces=None, errors=None):
        self.api = model.api
        self.code = _method_code(method)
        cdef int nq = self.api.nq, nv = self.api.nv, ny = nq + nv
        self.nq, self.nv, self.np_ = nq, nv, self.api.np
        cdef cnp.ndarray at = np.array(_vector(atol, ny, "atol"))
        cdef cnp.ndarray te = np.ascontiguousarray(t_eval, dtype=np.float64)
        self.m = cnp.PyArray_SIZE(te)
        self.N = np.shape(q)[0]
        cdef Py_ssize_t N = self.N
        cdef cnp.ndarray y = _runs_table(y0, N, ny, cnp.NPY_DOUBLE, "y0")
        cdef cnp.ndarray pp = _runs_table(p, N, self.np_, cnp.NPY_DOUBLE, "p")
        cdef cnp.ndarray kd_ = _runs_table(kind, N, 1, cnp.NPY_INT32, "kind")
        cdef cnp.ndarray gc = _runs_table(gravity_compensation, N, 1, cnp.NPY_INT32,
                                          "gravity_compensation")
        cdef cnp.ndarray tp = _runs_table(traj_Tp, N, 1, cnp.NPY_DOUBLE, "traj_Tp")
        if feedforward is None:
            feedforward = np.zeros((np.shape(kp)[0], nv))
        cs = [_runs_table(v, N, size, cnp.NPY_DOUBLE, name) for v, name, size in
              ((kp, "kp", nv), (kd, "kd", nv), (target, "target", nv),
               (traj_q0, "traj_q0", nq), (traj_qf, "traj_qf", nq),
               (feedforward, "feedforward", nv))]
        fr, wr = _frame_wrenches(frames, wrenches, self.api.nf)
        if len({c.shape[0] for c in cs + [kd_, gc, tp]}) != 1:
            raise ValueError("the controller tables must all have one row, or one per run")
        self.q = _output(q, N, self.m, nq, "q")
        self.qd = _output(qd, N, self.m, nv, "qd")
        self.tau = _output(tau, N, self.m, nv, "tau")
        cdef cnp.ndarray st = _runs_table(stats, N, 5, cnp.NPY_INT64, "stats")
        if st.shape[0] != N:
            raise ValueError(f"stats must have shape ({N}, 5)")
        mask = None
        if active is not None:
            mask = _constraint_mask(active, self.api.nc)
            self.active = <const unsigned char *>cnp.PyArray_DATA(<cnp.ndarray>mask)
            self.kp_c, self.kd_c = (float(x) for x in baumgarte)
            self.damping_c = damping
            self.forces = _output(forces, N, self.m, self.api.ncrows, "forces")
            self.errors = _output(errors, N, self.m, self.api.ncrows, "errors")
        # pointed into; the model keeps its table alive
        self._keep = [te, y, pp, kd_, gc, tp, cs, q, qd, tau, st, fr, wr, at, model, mask,
                      forces, errors]
        self.t0, self.t1, self.rtol, self.h = t0, t1, rtol, h
        self.first_step, self.max_step, self.max_steps = first_step, max_step, max_steps
        self.at = _data(at)
        self.te = _data(te)
        self.y0, self.y_step = _data(y), _row_step(y)
        self.p, self.p_step = _data(pp), _row_step(pp)
        self.kind = <const int32_t *>cnp.PyArray_DATA(kd_)
        self.gc = <const int32_t *>cnp.PyArray_DATA(gc)
        self.kp = _data(<cnp.ndarray>cs[0])
        self.kd = _data(<cnp.ndarray>cs[1])
        self.target = _data(<cnp.ndarray>cs[2])
        self.tq0 = _data(<cnp.ndarray>cs[3])
        self.tqf = _data(<cnp.ndarray>cs[4])
        self.ff = _data(<cnp.ndarray>cs[5])
        self.nframes = cnp.PyArray_SIZE(fr)
        self.frames = <const int *>cnp.PyArray_DATA(fr)
        self.wrenches = _data(wr)
        self.tTp = _data(tp)
        self.c_step = _row_step(tp)
        self.stats = <int64_t *>cnp.PyArray_DATA(st)
        self.stop_flag = 0

    def run(self, Py_ssize_t start, Py_ssize_t stop):
        """Integrate runs start .. stop-1 without the GIL; False if stop() ended it early."""
        if not 0 <= start <= stop <= self.N:
            raise ValueError(f"runs {start}:{stop} are not within 0:{self.N}")
        cdef double *y = <double *>malloc((self.m + 1) * (self.nq + self.nv) * sizeof(double))
        if y == NULL:
            raise MemoryError()
        cdef Py_ssize_t i
        with nogil:
            for i in range(start, stop):
                if self.stop_flag:
                    break
                self._one(i, y)
        free(y)
        return not self.stop_flag

    def stop(self):
        """Make every run() in progress return at its next poll (every 256 steps)."""
        self.stop_flag = 1

    cdef void _one(self, Py_ssize_t i, double *y) noexcept nogil:
        cdef gagen_control ctl
        cdef gagen_ode_stats st
        cdef Py_ssize_t c = i * self.c_step, k, m = self.m
        cdef int nq = self.nq, nv = self.nv
        cdef const double *p = self.p + i * self.p_step * self.np_
        cdef double *q = self.q + i * m * nq
        cdef double *qd = self.qd + i * m * nv
        cdef double *tau = self.tau + i * m * nv
        ctl.kind = self.kind[c]
        ctl.gravity_compensation = self.gc[c]
        ctl.kp = self.kp + c * nv
        ctl.kd = self.kd + c * nv
        ctl.target = self.target + c * nv
        ctl.traj_q0 = self.tq0 + c * nq
        ctl.traj_qf = self.tqf + c * nq
        ctl.traj_Tp = self.tTp[c]
        ctl.feedforward = self.ff + c * nv
        ctl.nframes = self.nframes
        ctl.frames = self.frames
        ctl.wrenches = self.wrenches
        ctl.poll = _poll_flag
        ctl.poll_ctx = <void *>&self.stop_flag
        st.nfev = st.nsteps = st.naccepted = st.nrejected = 0
        cdef int status
        cdef Py_ssize_t rows = self.api.ncrows
        if self.active != NULL:
            status = self.api.simulate_constrained(
                self.code, &ctl, p, self.active, self.kp_c, self.kd_c, self.damping_c, self.t0,
                self.t1, self.y0 + i * self.y_step * (nq + nv), self.rtol, self.at,
                self.first_step, self.max_step, self.max_steps, self.h, self.te, m, y, &st)
        else:
            status = self.api.simulate(self.code, &ctl, p, self.t0, self.t1,
                                       self.y0 + i * self.y_step * (nq + nv), self.rtol,
                                       self.at, self.first_step, self.max_step,
                                       self.max_steps, self.h, self.te, m, y, &st)
        _split_states(y, m, nq, nv, q, qd)
        if status == 0:
            self.api.control_torques(&ctl, p, m, self.te, y, tau)
            if self.active != NULL:
                self.api.constrained_outputs(&ctl, p, self.active, self.kp_c, self.kd_c,
                                             self.damping_c, m, self.te, y,
                                             self.forces + i * m * rows,
                                             self.errors + i * m * rows)
        else:
            for k in range(m * nv):
                tau[k] = NAN
            if self.active != NULL:
                for k in range(m * rows):
                    self.forces[i * m * rows + k] = NAN
                    self.errors[i * m * rows + k] = NAN
        cdef int64_t *s = self.stats + i * 5
        s[0] = status
        s[1] = st.nfev
        s[2] = st.nsteps
        s[3] = st.naccepted
        s[4] = st.nrejected


cdef int _poll_flag(void *ctx) noexcept nogil:
    """A batch's poll: stop once the flag at ctx is set. The batch's threads cannot run
    Python's signal handlers (only the main thread does), so the main thread catches Ctrl-C
    and sets the flag (CompiledBatch.stop)."""
    return (<int *>ctx)[0]


cdef int _poll_signals(void *ctx) noexcept nogil:
    """Run Python's signal handlers (briefly taking the GIL); keep what they raise in the
    list ctx and tell the integrator to stop."""
    with gil:
        try:
            PyErr_CheckSignals()
        except BaseException as exc:
            (<list>ctx).append(exc)
            return 1
    return 0


# --- the derivative module's kernels -------------------------------------------------------

# the derivative module's kernels, called by CompiledDerivatives._run
cdef enum Derivative:
    INVERSE_DERIVATIVES, FORWARD_DERIVATIVES, CORIOLIS, LINEARIZE


cdef inline int _call_derivative(const gagen_derivatives_api *api, Derivative kernel,
                                 const double *a, const double *b, const double *c,
                                 const double *p, double *o0, double *o1,
                                 double *o2) noexcept nogil:
    """One derivative kernel at one state, into up to three matrices; its status."""
    if kernel == FORWARD_DERIVATIVES:
        return api.forward_dynamics_derivatives(a, b, c, p, o0, o1, o2)
    if kernel == LINEARIZE:
        return api.linearize(a, b, c, p, o0, o1)
    if kernel == INVERSE_DERIVATIVES:
        api.inverse_dynamics_derivatives(a, b, c, p, o0, o1)
    else:
        api.coriolis_matrix(a, b, p, o0)
    return 0


cdef class CompiledDerivatives(_Evaluator):
    """The compiled derivative kernels of a model's derivative module, from its capsule
    `API`. gagen.runtime.compiled.CompiledDynamics binds these methods (their documentation
    is gagen.runtime.dynamics.Dynamics's)."""

    cdef const gagen_derivatives_api *api

    def __init__(self, capsule, parameter_vector, quaternions=()):
        self.api = <const gagen_derivatives_api *>_table(capsule, DERIVATIVES_CAPSULE)
        self._adopt(capsule, self.api.ident, self.api.np, self.api.err_nonfinite,
                    self.api.parameter_defaults)
        self._set_quaternions(quaternions, self.api.nq)
        self.parameter_vector = parameter_vector

    cdef tuple _run(self, Derivative kernel, int count, Py_ssize_t r0, Py_ssize_t c0,
                    Py_ssize_t r1, Py_ssize_t c1, object x, object y, object z, object p,
                    str nx, str ny, str nz):
        """`count` fresh matrices, the first (r0, c0) and the others (r1, c1), from a kernel
        at one state or at stacked states (one C loop, GIL released)."""
        cdef const gagen_derivatives_api *api = self.api
        cdef cnp.ndarray a = _state(x, nx, api.nq)
        cdef cnp.ndarray b = _state(y, ny, api.nv) if ny is not None else a
        cdef cnp.ndarray c = _state(z, nz, api.nv) if nz is not None else a
        cdef list keep = []
        cdef const double *pp = self._parameter_data(p, keep)
        cdef Py_ssize_t rows = _rows(a, -1, nx)
        if ny is not None:
            rows = _rows(b, rows, ny)
        if nz is not None:
            rows = _rows(c, rows, nz)
        self._check_quaternions(a, rows, nx)
        cdef cnp.ndarray m0 = _matrices(rows, r0, c0)
        cdef cnp.ndarray m1 = _matrices(rows, r1, c1) if count > 1 else m0
        cdef cnp.ndarray m2 = _matrices(rows, r1, c1) if count > 2 else m0
        cdef double *pa_ = _data(a)
        cdef double *pb = _data(b)
        cdef double *pc = _data(c)
        cdef double *p0 = _data(m0)
        cdef double *p1 = _data(m1)
        cdef double *p2 = _data(m2)
        # the kernels leave the outputs beyond `count` alone: those point at m0, standing still
        cdef Py_ssize_t sa = _step(a), sb = _step(b), sc = _step(c), s0 = r0 * c0
        cdef Py_ssize_t s1 = r1 * c1 if count > 1 else 0
        cdef Py_ssize_t s2 = r1 * c1 if count > 2 else 0
        cdef Py_ssize_t i, failed = -1
        cdef int code, status = 0
        if rows < 0:
            status = _call_derivative(api, kernel, pa_, pb, pc, pp, p0, p1, p2)
        else:
            with nogil:
                for i in range(rows):
                    code = _call_derivative(api, kernel, pa_ + i * sa, pb + i * sb,
                                            pc + i * sc, pp, p0 + i * s0, p1 + i * s1,
                                            p2 + i * s2)
                    if code != 0 and failed < 0:
                        failed = i
                        status = code
        if status:
            self._failed(failed, status, a)
        if count == 1:
            return (m0,)
        if count == 2:
            return (m0, m1)
        return (m0, m1, m2)

    def inverse_dynamics_derivatives(self, q, qd, qdd, p=None):
        """(dtau_dq, dtau_dqd) of tau = inverse_dynamics(q, qd, qdd)."""
        cdef Py_ssize_t nv = self.api.nv
        return self._run(INVERSE_DERIVATIVES, 2, nv, nv, nv, nv, q, qd, qdd, p,
                         "q", "qd", "qdd")

    def forward_dynamics_derivatives(self, q, qd, tau, p=None):
        """(dqdd_dq, dqdd_dqd, dqdd_dtau = M^-1) of qdd = forward_dynamics(q, qd, tau)."""
        cdef Py_ssize_t nv = self.api.nv
        return self._run(FORWARD_DERIVATIVES, 3, nv, nv, nv, nv, q, qd, tau, p,
                         "q", "qd", "tau")

    def coriolis_matrix(self, q, qd, p=None):
        """C(q, qd): C qd = the velocity terms, Mdot - 2C skew-symmetric."""
        cdef Py_ssize_t nv = self.api.nv
        return self._run(CORIOLIS, 1, nv, nv, nv, nv, q, qd, None, p, "q", "qd", None)[0]

    def linearize(self, q, qd, tau, p=None):
        """(A, B) of x' = f(x, tau) at x = (q, qd)."""
        cdef Py_ssize_t nv = self.api.nv
        return self._run(LINEARIZE, 2, 2 * nv, 2 * nv, 2 * nv, nv, q, qd, tau, p,
                         "q", "qd", "tau")
