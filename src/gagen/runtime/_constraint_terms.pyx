# cython: boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""The constrained forward dynamics' derivatives at one state, in C: the constraint terms
and the KKT solve of gagen.runtime.constraint_derivatives (its docstring has the
equations; its NumPy is the reference this follows line by line, and the one stacked
states take)."""

import numpy as np

from libc.math cimport sqrt


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


cdef inline void add_cross(const double *a, const double *b, double scale,
                           double *out) noexcept nogil:
    """out += scale (a × b)."""
    cdef double t[3]
    cross3(a, b, t)
    out[0] += scale * t[0]
    out[1] += scale * t[1]
    out[2] += scale * t[2]


def derivatives_one(double[:, :, ::1] J, double[::1] X, double[::1] Fo, int[::1] bodies,
                    int[::1] frames, double[:, :, ::1] order, double[::1] v, double[::1] a,
                    int[:, ::1] table, double[::1] lam, double kd,
                    double[:, ::1] M, double[:, ::1] Jc, double[:, ::1] dID_dq,
                    double[:, ::1] dID_dv, double damping, double[:, ::1] out):
    """Fill out (nv + m, 3 nv) with [∂q̈; ∂λ] by [q | q̇ | τ] at one state; 0, or -1 where
    M or the Delassus matrix has a pivot <= 0 (the caller then takes the NumPy path).

    J (f, 6, nv): the frames' Jacobians (LOCAL_WORLD_ALIGNED); X, Fo: the bodies'
    placements and the frames' offsets (gagen.runtime.frames), bodies and frames (f,): each
    frame's body (-1: the world) and index; order (f, nv, nv) their chains' relation;
    table (c, 11): per active constraint [frame A, frame B or -1, holds a frame, local,
    axes count, axes...]."""
    cdef Py_ssize_t nf = J.shape[0], nv = J.shape[2], nc = table.shape[0]
    R_ = np.empty((nf, 3, 3)); P_ = np.empty((nf, 3))
    cdef double[:, :, ::1] R = R_
    cdef double[:, ::1] P = P_
    _placements(X, Fo, bodies, frames, R, P)
    cdef Py_ssize_t m = Jc.shape[0], n3 = 3 * nv
    S_ = np.zeros((nf, nv, 6)); Vb_ = np.zeros((nf, nv, 6)); Sd_ = np.zeros((nf, nv, 6))
    dVq_ = np.zeros((nf, nv, 6)); dAq_ = np.zeros((nf, nv, 6)); dAv_ = np.zeros((nf, nv, 6))
    V_ = np.zeros((nf, 6)); A_ = np.zeros((nf, 6)); T_ = np.zeros((nv, nv, 6))
    cdef double[:, :, ::1] S = S_, Vb = Vb_, Sd = Sd_, dVq = dVq_, dAq = dAq_, dAv = dAv_
    cdef double[:, :, ::1] T = T_
    cdef double[:, ::1] V = V_, A = A_
    cdef Py_ssize_t f, i, j, k, c, d, h, r
    cdef double Ckj[6]
    cdef double e1[6]
    cdef double e2[6]
    cdef double tmp[6]
    # --- each frame: S, V_j, Ṡ_j, V, A and their derivatives (the module docstring's sums),
    # over its chain's coordinates only (ch)
    ch_ = np.zeros(nv, dtype=np.intp)
    cdef Py_ssize_t[::1] ch = ch_
    cdef Py_ssize_t n, ii, jj, kk
    for f in range(nf):
        n = 0
        for j in range(nv):
            if order[f, j, j] != 0.0:
                ch[n] = j
                n += 1
        for jj in range(n):
            j = ch[jj]
            for i in range(3):
                S[f, j, 3 + i] = J[f, 3 + i, j]
            cross3(&S[f, j, 3], &P[f, 0], tmp)
            for i in range(3):
                S[f, j, i] = J[f, i, j] - tmp[i]
        for jj in range(n):
            j = ch[jj]
            for ii in range(n):
                i = ch[ii]
                if order[f, i, j] != 0.0:
                    for h in range(6):
                        Vb[f, j, h] += S[f, i, h] * v[i]
            mcross(&Vb[f, j, 0], &S[f, j, 0], &Sd[f, j, 0])
            for h in range(6):
                V[f, h] += S[f, j, h] * v[j]
                A[f, h] += S[f, j, h] * a[j] + Sd[f, j, h] * v[j]
        for kk in range(n):
            k = ch[kk]
            for ii in range(n):
                i = ch[ii]
                for h in range(6):
                    T[k, i, h] = 0.0
                if order[f, k, i] != 0.0:
                    mcross(&S[f, k, 0], &S[f, i, 0], Ckj)
                    for h in range(6):
                        T[k, i, h] = Ckj[h] * v[i]
                        dVq[f, k, h] += T[k, i, h]
            for h in range(6):
                e1[h] = 0.0  # ∂V_j/∂q_k = Σ_{i ⪯ j} T[k, i]: a running sum down the chain,
            ii = 0           # whose coordinates i ⪯ j are ch[0 .. the last one of j's joint]
            for jj in range(n):
                j = ch[jj]
                while ii < n and order[f, ch[ii], j] != 0.0:
                    for h in range(6):
                        e1[h] += T[k, ch[ii], h]
                    ii += 1
                if order[f, k, j] == 0.0:
                    continue
                mcross(&S[f, k, 0], &S[f, j, 0], Ckj)
                mcross(e1, &S[f, j, 0], tmp)
                mcross(&Vb[f, j, 0], Ckj, e2)
                for h in range(6):
                    dAq[f, k, h] += Ckj[h] * a[j] + (tmp[h] + e2[h]) * v[j]
            for h in range(6):
                dAv[f, k, h] = dVq[f, k, h] + Sd[f, k, h]
    # --- the rows' derivatives: r2 = [−∂a_c/∂q | −∂a_c/∂q̇ | 0] and the wrenches
    r2_ = np.zeros((m, n3))
    dJtl_ = np.zeros((nv, nv))
    W_ = np.zeros((nf, 6)); dW_ = np.zeros((nf, nv, 6))
    cdef double[:, ::1] r2 = r2_, dJtl = dJtl_, W = W_
    cdef double[:, :, ::1] dW = dW_
    cdef Frames F
    F.nv = nv
    if nf:
        F.J, F.P, F.S, F.V, F.A = &J[0, 0, 0], &P[0, 0], &S[0, 0, 0], &V[0, 0], &A[0, 0]
        F.dVq, F.dAq, F.dAv = &dVq[0, 0, 0], &dAq[0, 0, 0], &dAv[0, 0, 0]
        F.W, F.dW = &W[0, 0], &dW[0, 0, 0]
    cdef int fa, fb, frame6, local, naxes, row = 0, lrow = 0
    cdef double x0[6]
    cdef double dx[6]
    cdef double full[6]
    cdef double fw[3]
    cdef double tw[3]
    for c in range(nc):
        fa, fb, frame6, local, naxes = table[c, 0], table[c, 1], table[c, 2], table[c, 3], \
            table[c, 4]
        _row_value(&F, fa, fb, frame6, local, kd, x0)
        for d in range(2 * nv):
            _row_derivative(&F, fa, fb, frame6, local, kd, d, dx)
            if local:  # Rᵀ (dx − w × x0) per 3-block
                for h in range(2 if frame6 else 1):
                    if d < nv:
                        add_cross(&S[fa, d, 3], &x0[3 * h], -1.0, &dx[3 * h])
                    for i in range(3):
                        tmp[i] = R[fa, 0, i] * dx[3 * h] + R[fa, 1, i] * dx[3 * h + 1] \
                            + R[fa, 2, i] * dx[3 * h + 2]
                    for i in range(3):
                        dx[3 * h + i] = tmp[i]
            for i in range(naxes):
                r2[row + i, d] = -dx[table[c, 5 + i]]
        # the wrench: f, t in world axes, on A at pA (and −W on B at pB or pA)
        for i in range(6):
            full[i] = 0.0
        for i in range(naxes):
            full[table[c, 5 + i]] = lam[lrow + i]
        for i in range(3):
            if local:
                fw[i] = R[fa, i, 0] * full[0] + R[fa, i, 1] * full[1] + R[fa, i, 2] * full[2]
                tw[i] = R[fa, i, 0] * full[3] + R[fa, i, 1] * full[4] + R[fa, i, 2] * full[5]
            else:
                fw[i], tw[i] = full[i], full[3 + i]
        _wrench_at(&F, fa, fa, fa, 1.0, fw, tw, local)
        if fb >= 0:  # −W on B's chain, at pB (a point loop) or pA (a frame loop)
            _wrench_at(&F, fa if frame6 else fb, fa, fb, -1.0, fw, tw, local)
        row += naxes
        lrow += naxes
    # ∂(Σ Sᵀ W)/∂q
    for f in range(nf):
        for k in range(nv):
            if order[f, k, k] == 0.0:
                continue
            for j in range(nv):
                if order[f, k, j] != 0.0:
                    mcross(&S[f, k, 0], &S[f, j, 0], Ckj)
                    for h in range(6):
                        dJtl[j, k] += Ckj[h] * W[f, h]
        for j in range(nv):
            if order[f, j, j] == 0.0:
                continue
            for k in range(nv):
                for h in range(6):
                    dJtl[j, k] += S[f, j, h] * dW[f, k, h]
    return _kkt(M, Jc, dID_dq, dID_dv, dJtl, r2, damping, out)


cdef void _placements(double[::1] X, double[::1] Fo, int[::1] bodies, int[::1] frames,
                      double[:, :, ::1] R, double[:, ::1] P) noexcept:
    """Each frame's axes R = R_b R_f and origin p_b + R_b p_f (frames.pose)."""
    cdef Py_ssize_t f, i, j, k
    cdef int b, fr
    for f in range(R.shape[0]):
        b, fr = bodies[f], frames[f]
        for i in range(3):
            if b < 0:
                P[f, i] = Fo[12 * fr + 9 + i]
            else:
                P[f, i] = X[15 * b + 9 + i]
                for k in range(3):
                    P[f, i] += X[15 * b + 3 * i + k] * Fo[12 * fr + 9 + k]
            for j in range(3):
                if b < 0:
                    R[f, i, j] = Fo[12 * fr + 3 * i + j]
                else:
                    R[f, i, j] = 0.0
                    for k in range(3):
                        R[f, i, j] += X[15 * b + 3 * i + k] * Fo[12 * fr + 3 * k + j]


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


cdef int _cholesky(double[:, ::1] A, Py_ssize_t n) noexcept:
    """A's lower Cholesky factor in place (its upper triangle left); -1 at a pivot <= 0."""
    cdef Py_ssize_t i, j, k
    cdef double s
    for j in range(n):
        s = A[j, j]
        for k in range(j):
            s -= A[j, k] * A[j, k]
        if not s > 0.0:
            return -1
        s = sqrt(s)
        A[j, j] = s
        for i in range(j + 1, n):
            A[i, j] = A[i, j]
            for k in range(j):
                A[i, j] -= A[i, k] * A[j, k]
            A[i, j] /= s
    return 0


cdef inline void axpy(double *y, const double *x, double a, Py_ssize_t n) noexcept nogil:
    cdef Py_ssize_t i
    for i in range(n):
        y[i] += a * x[i]


cdef void _solve(double[:, ::1] L, Py_ssize_t n, double[:, ::1] B, Py_ssize_t cols,
                 int forward_only) noexcept:
    """B ← L⁻ᵀ L⁻¹ B in place (its first n rows), or L⁻¹ B with forward_only; by whole
    rows of B (contiguous, so the compiler vectorises them)."""
    cdef Py_ssize_t i, k, c
    cdef double *b = &B[0, 0]
    cdef Py_ssize_t stride = B.shape[1]
    cdef double inv
    for i in range(n):
        for k in range(i):
            axpy(b + i * stride, b + k * stride, -L[i, k], cols)
        inv = 1.0 / L[i, i]
        for c in range(cols):
            b[i * stride + c] *= inv
    if forward_only:
        return
    for i in range(n - 1, -1, -1):
        for k in range(i + 1, n):
            axpy(b + i * stride, b + k * stride, -L[k, i], cols)
        inv = 1.0 / L[i, i]
        for c in range(cols):
            b[i * stride + c] *= inv


cdef int _kkt(double[:, ::1] M, double[:, ::1] Jc, double[:, ::1] dID_dq,
              double[:, ::1] dID_dv, double[:, ::1] dJtl, double[:, ::1] r2, double damping,
              double[:, ::1] out):
    """[∂q̈; ∂λ] = the KKT system's solution for the right-hand sides r1 = [−∂ID/∂q +
    ∂(Jᵀλ)/∂q | −∂ID/∂q̇ | I] and r2: u = M⁻¹ r1, K = M⁻¹ Jᵀ, G = J K (+ damping I),
    ∂λ = G⁻¹ (r2 − J u), ∂q̈ = u + K ∂λ."""
    cdef Py_ssize_t nv = M.shape[0], m = Jc.shape[0], n3 = 3 * nv, i, j, k
    L_ = np.array(M)
    cdef double[:, ::1] L = L_
    if _cholesky(L, nv):
        return -1
    for i in range(nv):
        for j in range(n3):
            out[i, j] = 0.0
        for j in range(nv):
            out[i, j] = dJtl[i, j] - dID_dq[i, j]
            out[i, nv + j] = -dID_dv[i, j]
        out[i, 2 * nv + i] = 1.0
    _solve(L, nv, out, n3, 0)  # u in out's first nv rows
    if m == 0:
        return 0
    K_ = np.ascontiguousarray(np.asarray(Jc).T)  # (nv, m) → M⁻¹ Jᵀ
    G_ = np.empty((m, m))
    cdef double[:, ::1] K = K_, G = G_
    _solve(L, nv, K, m, 0)
    for i in range(m):
        for j in range(m):
            G[i, j] = 0.0
            for k in range(nv):
                G[i, j] += Jc[i, k] * K[k, j]
        G[i, i] += damping
    if _cholesky(G, m):
        return -1
    for i in range(m):  # r2 − J u, into out's last m rows
        for j in range(n3):
            out[nv + i, j] = r2[i, j]
        for k in range(nv):
            axpy(&out[nv + i, 0], &out[k, 0], -Jc[i, k], n3)
    _solve(G, m, out[nv:, :], n3, 0)  # ∂λ
    for i in range(nv):  # u + K ∂λ
        for k in range(m):
            axpy(&out[i, 0], &out[nv + k, 0], K[i, k], n3)
    return 0
