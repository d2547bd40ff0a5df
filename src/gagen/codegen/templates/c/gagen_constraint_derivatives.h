/*
 * gagen_constraint_derivatives.h -- the derivatives of the constrained forward dynamics,
 * for one state, in plain C99 (no allocation, no globals; the caller gives the workspace).
 *
 * One implementation for both users: each model with constraints has
 * <model>_constrained_forward_dynamics_derivatives (constrained_derivatives.c, generated
 * next to its sources), which fills a gagen_cd_model with the model's own kernels and
 * tables and calls gagen_cd_state; gagen's runtime (gagen.runtime._constraint_terms) fills
 * the same struct from a compiled model's API tables and calls the same functions.
 * gagen.runtime.constraint_derivatives has the equations (its docstring) and the NumPy
 * they follow; docs/constraints.md their summary.
 *
 * Per state: the model's kernels (M, the bias forces, placements and frame Jacobians, and
 * the derivative module's inverse dynamics derivatives); the constrained frames' chains
 * (their twists, velocities and accelerations, O(chain) each), which give the active rows'
 * J and drift; the constrained forward dynamics through M's tree-sparse factors
 * M = L^T D L (no fill-in outside each coordinate's ancestors, as the model's gagen_ltdl)
 * and the Delassus matrix's G = (J L^-1) D^-1 (J L^-1)^T = Lg Dg Lg^T, with the model's
 * pivot tests; then the constraint terms and the KKT solves for all 3 nv right-hand sides
 * at once on the same factors.
 */
#ifndef GAGEN_CONSTRAINT_DERIVATIVES_H
#define GAGEN_CONSTRAINT_DERIVATIVES_H

#include <float.h>
#include <stddef.h>
#include <string.h>

/* gagen_cd_state's returns (besides 0 and a frame_jacobians error) */
#define GAGEN_CD_NOT_POSITIVE_DEFINITE (-1) /* a pivot of M = L^T D L not clearly > 0 */
#define GAGEN_CD_SINGULAR (-2)              /* a pivot of the Delassus matrix */
#define GAGEN_CD_QUATERNION (-3)            /* a quaternion whose squared norm is not normal */

/* the frame Jacobians' reference (the model's GAGEN_LOCAL_WORLD_ALIGNED) */
#define GAGEN_CD_WORLD_ALIGNED 2
/* a constraint's row of the table: frame A, frame B (-1: the world), holds a frame (its
   rows are a twist's) or a point, local (1) or world-aligned (0), its number of axes, then
   its axes (0-2 translation, 3-5 rotation); frames are numbers into the frame lists */
#define GAGEN_CD_TABLE 11

/* Doubles of one state's workspace (gagen_cd_state's layout) for nv coordinates, nb bodies,
   nf constrained frames, m active rows of nrows declared ones. */
#define GAGEN_CD_WORKSPACE(nv, nb, nf, m, nrows) \
    ((nv) + ((nrows) > (nv) ? (nrows) : (nv)) + (m) + 3 * (nv) * (nv) + 15 * (nb) \
     + (nf) * 6 * (nv) + 12 * (nf) + 6 * (nf) * (nv) * 6 + 18 * (nf) \
     + 18 * ((nv) + 1) + ((nv) + (m)) * 3 * (nv) + (m) * (nv) + (m) * (m) + 2 * (nv) + (m))
/* ints of one state's workspace */
#define GAGEN_CD_INTS(nv, m) ((nv) + (m) + 1)
/* ints and doubles gagen_cd_select may need for an active set's tables */
#define GAGEN_CD_SELECT_INTS(nv, nf, nc, nrows) \
    (4 * (nf) + (nc) * GAGEN_CD_TABLE + (nrows) + 3 * (nf) * (nv) + 1)
#define GAGEN_CD_SELECT_DOUBLES(nv, nf) ((nf) * (nv) * (nv) + 1)

/* A model: its kernels, its tree and its declared constraints and their frames. */
typedef struct {
    int nq, nv, nb;
    int nframes_model;  /* the model's frames (frame_offsets writes 12 each) */
    void (*mass_matrix)(const double *q, const double *p, double *M);
    void (*forcing)(const double *q, const double *qd, const double *tau, const double *p,
                    double *F);
    void (*placements)(const double *q, const double *p, double *X);
    void (*frame_offsets)(const double *p, double *F);
    int (*frame_jacobians)(const double *q, const double *p, int count, const int *frames,
                           int reference, double *J);
    void (*inverse_dynamics_derivatives)(const double *q, const double *qd, const double *qdd,
                                         const double *p, double *dtau_dq, double *dtau_dqd);
    const int *parent;    /* (nv) each coordinate's parent coordinate (-1: the root) */
    const int *desc_ptr;  /* (nv + 1) CSR of each coordinate's descendants */
    const int *desc;
    int nquat;
    const int *quat;      /* (nquat) where each quaternion starts in q */
    /* the declared constraints: nc rows of the table, nrows rows of forces in all */
    int nc, nrows;
    const int *table;     /* (nc, GAGEN_CD_TABLE), frames numbered among these nf */
    /* their distinct frames, in order of first appearance */
    int nf;
    const int *frames;    /* (nf) the frames' numbers in the model */
    const int *bodies;    /* (nf) their bodies (-1: the world) */
    const int *chain;     /* (nf, nv) each frame's chain's coordinates, root first */
    const int *chain_len; /* (nf) */
    const int *group_start; /* (nf, nv) per chain position, its joint's first position */
    const int *group_end;   /* (nf, nv) and the position after its joint's last */
    const double *order;  /* (nf, nv, nv) 1 where k and j are on the chain, k at or above j */
} gagen_cd_model;

/* One active set of a model: the active constraints, their frames and rows. */
typedef struct {
    const gagen_cd_model *model;
    int nf, nc, m;
    const int *frames, *bodies, *table, *rows, *chain, *chain_len, *group_start, *group_end;
    const double *order;
} gagen_cd_set;

/* The active set of `active` (one flag per declared constraint; NULL: all) into `set`, its
   tables in ints (GAGEN_CD_SELECT_INTS) and doubles (GAGEN_CD_SELECT_DOUBLES) where they
   are not the model's own: the active constraints in their order, their frames in order of
   first appearance, their rows among the declared ones. */
static void gagen_cd_select(const gagen_cd_model *model, const unsigned char *active,
                            gagen_cd_set *set, int *ints, double *doubles)
{
    int c, k, f, all = 1, row = 0, nf = 0, m = 0, nv = model->nv;
    int *map = ints, *rows, *frames, *bodies, *table, *chain, *chain_len, *start, *end;
    for (c = 0; c < model->nc; ++c)
        if (active != NULL && !active[c]) all = 0;
    set->model = model;
    if (all) {  /* the model's own tables; the rows 0 .. nrows - 1 */
        rows = ints;
        for (k = 0; k < model->nrows; ++k) rows[k] = k;
        set->nf = model->nf;
        set->nc = model->nc;
        set->m = model->nrows;
        set->frames = model->frames;
        set->bodies = model->bodies;
        set->table = model->table;
        set->rows = rows;
        set->chain = model->chain;
        set->chain_len = model->chain_len;
        set->group_start = model->group_start;
        set->group_end = model->group_end;
        set->order = model->order;
        return;
    }
    for (f = 0; f < model->nf; ++f) map[f] = -1;
    for (c = 0; c < model->nc; ++c) {  /* the active constraints' frames, first seen first */
        const int *tb = model->table + GAGEN_CD_TABLE * c;
        if (!active[c]) continue;
        if (map[tb[0]] < 0) map[tb[0]] = nf++;
        if (tb[1] >= 0 && map[tb[1]] < 0) map[tb[1]] = nf++;
    }
    frames = map + model->nf;
    bodies = frames + nf;
    table = bodies + nf;
    rows = table + GAGEN_CD_TABLE * model->nc;
    chain = rows + model->nrows;
    start = chain + nf * nv;
    end = start + nf * nv;
    chain_len = end + nf * nv;
    set->nc = 0;
    for (c = 0; c < model->nc; ++c) {
        const int *tb = model->table + GAGEN_CD_TABLE * c;
        if (active[c]) {
            int *to = table + GAGEN_CD_TABLE * set->nc++;
            for (k = 0; k < GAGEN_CD_TABLE; ++k) to[k] = tb[k];
            to[0] = map[tb[0]];
            to[1] = tb[1] >= 0 ? map[tb[1]] : -1;
            for (k = 0; k < tb[4]; ++k) rows[m++] = row + k;
        }
        row += tb[4];
    }
    for (f = 0; f < model->nf; ++f) {
        int g = map[f];
        if (g < 0) continue;
        frames[g] = model->frames[f];
        bodies[g] = model->bodies[f];
        chain_len[g] = model->chain_len[f];
        for (k = 0; k < nv; ++k) {
            chain[g * nv + k] = model->chain[f * nv + k];
            start[g * nv + k] = model->group_start[f * nv + k];
            end[g * nv + k] = model->group_end[f * nv + k];
        }
        memcpy(doubles + (size_t)g * nv * nv, model->order + (size_t)f * nv * nv,
               (size_t)nv * nv * sizeof(double));
    }
    set->nf = nf;
    set->m = m;
    set->frames = frames;
    set->bodies = bodies;
    set->table = table;
    set->rows = rows;
    set->chain = chain;
    set->chain_len = chain_len;
    set->group_start = start;
    set->group_end = end;
    set->order = doubles;
}

/* the solves' steps, the small vector helpers and a row's derivative are inlined where they
   are used, so their 3- and 6-vectors stay in registers */
#if defined(__GNUC__) || defined(__clang__)
#define GAGEN_CD_INLINE static inline __attribute__((always_inline))
#else
#define GAGEN_CD_INLINE static inline
#endif

/* On x86-64 with GCC or clang under glibc, the functions that do the work (one state, its
   frames' pass and terms, and gagen_cd_gather) are built twice, for any x86-64 and for CPUs
   with fused multiply-add (chosen when the library loads), as the model's GAGEN_KERNEL
   kernels are: the FMA version is about 6% faster, its sums rounded once per
   multiply-add, so its results differ from the other's in the last bits (a machine gives
   the same bits for the same state, one state or stacked). Compiled for FMA already (-mfma,
   as gagen builds a model's C on an FMA machine), or with GAGEN_NO_CLONES, one version. */
#if defined(__x86_64__) && defined(__linux__) && (defined(__GNUC__) || defined(__clang__)) \
    && !defined(GAGEN_NO_CLONES) && !defined(__FMA__)
#define GAGEN_CD_CLONES __attribute__((target_clones("fma", "default")))
#else
#define GAGEN_CD_CLONES
#endif

/* y <- pre y - sum_t coef[t] * base[off[t] ...], over len entries (off[t]: where the source
   row starts in base; pre 1.0 changes nothing): each block of y's entries is read and
   written once, its sources' rows summed in registers (a row axpy per source would load
   and store y once for each). The widest blocks hold 24 entries (12 SSE2 or 6 AVX
   registers: no spill), so a row of 3 nv right-hand sides takes few passes over the
   sources; a block's width changes no entry's sum. */
#define GAGEN_CD_LOAD4(o) \
    double a##o##0 = y[c + 4 * o] * pre, a##o##1 = y[c + 4 * o + 1] * pre, \
           a##o##2 = y[c + 4 * o + 2] * pre, a##o##3 = y[c + 4 * o + 3] * pre
#define GAGEN_CD_SUB4(o) \
    a##o##0 -= w * x[4 * o]; a##o##1 -= w * x[4 * o + 1]; a##o##2 -= w * x[4 * o + 2]; \
    a##o##3 -= w * x[4 * o + 3]
#define GAGEN_CD_STORE4(o) \
    y[c + 4 * o] = a##o##0; y[c + 4 * o + 1] = a##o##1; y[c + 4 * o + 2] = a##o##2; \
    y[c + 4 * o + 3] = a##o##3
GAGEN_CD_CLONES
static void gagen_cd_gather(double *y, double pre, const double *base, const int *off,
                            const double *coef, int count, ptrdiff_t len)
{
    ptrdiff_t c = 0;
    int t;
    if (count == 0 && pre == 1.0) return;
    for (; c + 24 <= len; c += 24) {
        GAGEN_CD_LOAD4(0); GAGEN_CD_LOAD4(1); GAGEN_CD_LOAD4(2);
        GAGEN_CD_LOAD4(3); GAGEN_CD_LOAD4(4); GAGEN_CD_LOAD4(5);
        for (t = 0; t < count; ++t) {
            const double *x = base + off[t] + c, w = coef[t];
            GAGEN_CD_SUB4(0); GAGEN_CD_SUB4(1); GAGEN_CD_SUB4(2);
            GAGEN_CD_SUB4(3); GAGEN_CD_SUB4(4); GAGEN_CD_SUB4(5);
        }
        GAGEN_CD_STORE4(0); GAGEN_CD_STORE4(1); GAGEN_CD_STORE4(2);
        GAGEN_CD_STORE4(3); GAGEN_CD_STORE4(4); GAGEN_CD_STORE4(5);
    }
    for (; c + 8 <= len; c += 8) {
        GAGEN_CD_LOAD4(0); GAGEN_CD_LOAD4(1);
        for (t = 0; t < count; ++t) {
            const double *x = base + off[t] + c, w = coef[t];
            GAGEN_CD_SUB4(0); GAGEN_CD_SUB4(1);
        }
        GAGEN_CD_STORE4(0); GAGEN_CD_STORE4(1);
    }
    for (; c + 4 <= len; c += 4) {
        GAGEN_CD_LOAD4(0);
        for (t = 0; t < count; ++t) {
            const double *x = base + off[t] + c, w = coef[t];
            GAGEN_CD_SUB4(0);
        }
        GAGEN_CD_STORE4(0);
    }
    for (; c + 2 <= len; c += 2) {
        double a0 = y[c] * pre, a1 = y[c + 1] * pre;
        for (t = 0; t < count; ++t) {
            const double *x = base + off[t] + c, w = coef[t];
            a0 -= w * x[0]; a1 -= w * x[1];
        }
        y[c] = a0; y[c + 1] = a1;
    }
    for (; c < len; ++c) {
        double a0 = y[c] * pre;
        for (t = 0; t < count; ++t) a0 -= coef[t] * base[off[t] + c];
        y[c] = a0;
    }
}
#undef GAGEN_CD_LOAD4
#undef GAGEN_CD_SUB4
#undef GAGEN_CD_STORE4

GAGEN_CD_INLINE void gagen_cd_cross3(const double *a, const double *b, double *out)
{
    double x = a[1] * b[2] - a[2] * b[1];
    double y = a[2] * b[0] - a[0] * b[2];
    double z = a[0] * b[1] - a[1] * b[0];
    out[0] = x;
    out[1] = y;
    out[2] = z;
}

/* the spatial cross product of twists a x b (linear first) */
GAGEN_CD_INLINE void gagen_cd_mcross(const double *a, const double *b, double *out)
{
    double t1[3], t2[3], t3[3];
    int i;
    gagen_cd_cross3(a + 3, b, t1);
    gagen_cd_cross3(a, b + 3, t2);
    gagen_cd_cross3(a + 3, b + 3, t3);
    for (i = 0; i < 3; ++i) {
        out[i] = t1[i] + t2[i];
        out[3 + i] = t3[i];
    }
}

/* the dual cross product a x* f of a twist and a wrench (linear first):
   (a_w x f_l, a_w x f_t + a_l x f_l) */
GAGEN_CD_INLINE void gagen_cd_fcross(const double *a, const double *f, double *out)
{
    double t1[3], t2[3], t3[3];
    int i;
    gagen_cd_cross3(a + 3, f, t1);
    gagen_cd_cross3(a + 3, f + 3, t2);
    gagen_cd_cross3(a, f, t3);
    for (i = 0; i < 3; ++i) {
        out[i] = t1[i];
        out[3 + i] = t2[i] + t3[i];
    }
}

/* out += scale (a x b) */
GAGEN_CD_INLINE void gagen_cd_add_cross(const double *a, const double *b, double scale, double *out)
{
    double t[3];
    gagen_cd_cross3(a, b, t);
    out[0] += scale * t[0];
    out[1] += scale * t[1];
    out[2] += scale * t[2];
}

/* M = L^T D L in place (the model's gagen_ltdl: the same steps, from the last coordinate
   up, only along each coordinate's ancestors, and its test of a pivot against M's diagonal
   entry); -1 at a pivot not clearly positive. */
GAGEN_CD_INLINE int gagen_cd_ltdl(double *M, const int *parent, ptrdiff_t n, double *diagonal)
{
    ptrdiff_t k, i, j;
    double d, x;
    for (k = 0; k < n; ++k) diagonal[k] = M[n * k + k];
    for (k = n - 1; k >= 0; --k) {
        d = M[n * k + k];
        if (!(d > 1e-13 * diagonal[k] && diagonal[k] > 0.0)) return -1;
        for (i = parent[k]; i >= 0; i = parent[i]) {
            x = M[n * k + i] / d;
            for (j = i; j >= 0; j = parent[j]) M[n * i + j] -= M[n * k + j] * x;
            M[n * k + i] = x;
        }
    }
    return 0;
}

/* x <- L^-T x: from the last coordinate up, each to its ancestors (gagen_cn_back) */
GAGEN_CD_INLINE void gagen_cd_back(const double *L, const int *parent, ptrdiff_t n, double *x)
{
    ptrdiff_t k, i;
    for (k = n - 1; k >= 0; --k)
        if (x[k] != 0.0)
            for (i = parent[k]; i >= 0; i = parent[i]) x[i] -= L[n * k + i] * x[k];
}

/* x <- L^-1 x: from the first coordinate down (gagen_cn_forward) */
GAGEN_CD_INLINE void gagen_cd_forward(const double *L, const int *parent, ptrdiff_t n, double *x)
{
    ptrdiff_t k, i;
    double s;
    for (k = 0; k < n; ++k) {
        s = x[k];
        for (i = parent[k]; i >= 0; i = parent[i]) s -= L[n * k + i] * x[i];
        x[k] = s;
    }
}

/* G = Y D^-1 Y^T + damping I (Yt = Y^T, nv rows of m) factored in place as Lg Dg Lg^T
   (Lg's unit lower triangle below the diagonal, Dg on it); -1 at a pivot not above
   GAGEN_TS_PIVOT (1e-11) times its diagonal entry (the model's constrained dynamics then
   answers with its error). Row a of G's lower triangle is one gagen_cd_gather of the rows
   j of Yt that row a of Y moves, Y_aj D^-1_j each (off, coef: nv scratch each). */
GAGEN_CD_INLINE int gagen_cd_delassus(const double *Yt, const double *Dinv, ptrdiff_t n,
                                      ptrdiff_t m, double damping, double *G, int *off,
                                      double *coef)
{
    ptrdiff_t a, b, j, k;
    int count;
    double s, d, diag;
    for (a = 0; a < m; ++a) {
        count = 0;
        for (j = 0; j < n; ++j) {
            if (Yt[m * j + a] != 0.0) {
                off[count] = (int)(m * j);
                coef[count] = -(Yt[m * j + a] * Dinv[j]);
                count += 1;
            }
        }
        for (b = 0; b <= a; ++b) G[m * a + b] = 0.0;
        gagen_cd_gather(G + m * a, 1.0, Yt, off, coef, count, a + 1);
    }
    for (a = 0; a < m; ++a) G[m * a + a] += damping;
    for (j = 0; j < m; ++j) {  /* the lower triangle, column by column (gagen_cn_kkt's steps) */
        diag = G[m * j + j];
        d = diag;
        for (k = 0; k < j; ++k) d -= G[m * j + k] * G[m * j + k] * G[m * k + k];
        if (!(d > 1e-11 * diag)) return -1;
        G[m * j + j] = d;
        for (a = j + 1; a < m; ++a) {
            s = G[m * a + j];
            for (k = 0; k < j; ++k) s -= G[m * a + k] * G[m * j + k] * G[m * k + k];
            G[m * a + j] = s / d;
        }
    }
    return 0;
}

/* x <- G^-1 x with G = Lg Dg Lg^T (gagen_cd_delassus) */
GAGEN_CD_INLINE void gagen_cd_solve_ldlt(const double *G, ptrdiff_t m, double *x)
{
    ptrdiff_t a, b;
    double s;
    for (a = 0; a < m; ++a) {
        s = x[a];
        for (b = 0; b < a; ++b) s -= G[m * a + b] * x[b];
        x[a] = s;
    }
    for (a = 0; a < m; ++a) x[a] /= G[m * a + a];
    for (a = m - 1; a >= 0; --a) {
        s = x[a];
        for (b = a + 1; b < m; ++b) s -= G[m * b + a] * x[b];
        x[a] = s;
    }
}

/* Each frame's axes R = R_b R_f and origin p_b + R_b p_f (frames.pose) */
GAGEN_CD_INLINE void gagen_cd_placements(const gagen_cd_set *c, const double *X, const double *Fo,
                                double *R, double *P)
{
    int f, i, j, k, b, fr;
    for (f = 0; f < c->nf; ++f) {
        b = c->bodies[f];
        fr = c->frames[f];
        for (i = 0; i < 3; ++i) {
            if (b < 0) {
                P[3 * f + i] = Fo[12 * fr + 9 + i];
            } else {
                P[3 * f + i] = X[15 * b + 9 + i];
                for (k = 0; k < 3; ++k) P[3 * f + i] += X[15 * b + 3 * i + k] * Fo[12 * fr + 9 + k];
            }
            for (j = 0; j < 3; ++j) {
                if (b < 0) {
                    R[9 * f + 3 * i + j] = Fo[12 * fr + 3 * i + j];
                } else {
                    R[9 * f + 3 * i + j] = 0.0;
                    for (k = 0; k < 3; ++k)
                        R[9 * f + 3 * i + j] += X[15 * b + 3 * i + k] * Fo[12 * fr + 3 * k + j];
                }
            }
        }
    }
}

/* the frames' arrays: J (f, 6, nv), P (f, 3), S, dVq, dAq, dAv, dW (f, nv, 6), V, A, W (f, 6);
   order the set's (f, nv, nv), whose diagonal says which coordinates are on a chain */
typedef struct {
    ptrdiff_t nv;
    const double *J;
    const double *P;
    const double *order;
    double *S, *V, *A, *dVq, *dAq, *dAv, *W, *dW;
} gagen_cd_frames;

/* row k of frame f's (nv, 6) block of base */
GAGEN_CD_INLINE double *gagen_cd_col(const gagen_cd_frames *F, double *base, int f, ptrdiff_t k)
{
    return base + (f * F->nv + k) * 6;
}

/* the classical acceleration and the velocity of point p (V, A at the origin) */
GAGEN_CD_INLINE void gagen_cd_classical(const double *V, const double *A, const double *p, double *acc,
                               double *vel)
{
    int i;
    for (i = 0; i < 3; ++i) {
        vel[i] = V[i];
        acc[i] = A[i];
    }
    gagen_cd_add_cross(&V[3], p, 1.0, vel);
    gagen_cd_add_cross(&A[3], p, 1.0, acc);
    gagen_cd_add_cross(&V[3], vel, 1.0, acc);
}

/* a_c (+ kd J qd) of a constraint, world axes, before its rotation and its axes */
GAGEN_CD_INLINE void gagen_cd_row_value(const gagen_cd_frames *F, int fa, int fb, int frame6, int local,
                               double kd, double *x)
{
    double xa[6], xb[6], va[6], vb[6], t[6];
    int i;
    if (!frame6) {
        gagen_cd_classical(&F->V[6 * fa], &F->A[6 * fa], &F->P[3 * fa], xa, va);
        for (i = 0; i < 3; ++i) {
            x[i] = xa[i] + kd * va[i];
            x[3 + i] = 0.0;
        }
        if (fb >= 0) {
            gagen_cd_classical(&F->V[6 * fb], &F->A[6 * fb], &F->P[3 * fb], xb, vb);
            for (i = 0; i < 3; ++i) x[i] -= xb[i] + kd * vb[i];
        }
        return;
    }
    for (i = 0; i < 6; ++i) {
        xa[i] = F->A[6 * fa + i] - (fb >= 0 ? F->A[6 * fb + i] : 0.0);
        va[i] = F->V[6 * fa + i] - (fb >= 0 ? F->V[6 * fb + i] : 0.0);
    }
    if (fb >= 0 && local) {
        gagen_cd_mcross(&F->V[6 * fa], &F->V[6 * fb], t);
        for (i = 0; i < 6; ++i) xa[i] += t[i];
    }
    for (i = 0; i < 6; ++i) x[i] = xa[i] + kd * va[i];
    gagen_cd_add_cross(&x[3], &F->P[3 * fa], 1.0, x);  /* at pA: lin + ang x p */
}

GAGEN_CD_INLINE void gagen_cd_motion_derivative(const gagen_cd_frames *F, int f, ptrdiff_t d, double *dV,
                                       double *dA)
{
    int i;
    const double *sv, *sa;
    if (d < F->nv) {
        sv = gagen_cd_col(F, F->dVq, f, d);
        sa = gagen_cd_col(F, F->dAq, f, d);
    } else {
        sv = gagen_cd_col(F, F->S, f, d - F->nv);
        sa = gagen_cd_col(F, F->dAv, f, d - F->nv);
    }
    for (i = 0; i < 6; ++i) {
        dV[i] = sv[i];
        dA[i] = sa[i];
    }
}

GAGEN_CD_INLINE void gagen_cd_velocity_derivative(const gagen_cd_frames *F, int f, ptrdiff_t d,
                                         double *dV)
{
    int i;
    const double *src = d < F->nv ? gagen_cd_col(F, F->dVq, f, d)
                                  : gagen_cd_col(F, F->S, f, d - F->nv);
    for (i = 0; i < 6; ++i) dV[i] = src[i];
}

/* the angular part of a frame row's value (at the origin), for its shift's derivative */
GAGEN_CD_INLINE void gagen_cd_value_angular(const gagen_cd_frames *F, int fa, int fb, int local,
                                   double kd, double *w)
{
    double t[6];
    int i;
    for (i = 0; i < 3; ++i)
        w[i] = F->A[6 * fa + 3 + i] - (fb >= 0 ? F->A[6 * fb + 3 + i] : 0.0)
               + kd * (F->V[6 * fa + 3 + i] - (fb >= 0 ? F->V[6 * fb + 3 + i] : 0.0));
    if (fb >= 0 && local) {
        gagen_cd_mcross(&F->V[6 * fa], &F->V[6 * fb], t);
        for (i = 0; i < 3; ++i) w[i] += t[3 + i];
    }
}

/* d of acc = a_O + alpha x p + omega x vp and vel = vp = v_O + omega x p */
GAGEN_CD_INLINE void gagen_cd_classical_derivative(const gagen_cd_frames *F, int f, ptrdiff_t d,
                                          double *dacc, double *dvel)
{
    double dV[6], dA[6], dp[3], vp[3];
    int i;
    ptrdiff_t nv = F->nv;
    const double *V = &F->V[6 * f], *A = &F->A[6 * f], *p = &F->P[3 * f];
    gagen_cd_motion_derivative(F, f, d, dV, dA);
    for (i = 0; i < 3; ++i) {
        dp[i] = d < nv ? F->J[(6 * f + i) * nv + d] : 0.0;
        vp[i] = V[i];
        dvel[i] = dV[i];
        dacc[i] = dA[i];
    }
    gagen_cd_add_cross(&V[3], p, 1.0, vp);
    gagen_cd_add_cross(&dV[3], p, 1.0, dvel);
    gagen_cd_add_cross(&V[3], dp, 1.0, dvel);
    gagen_cd_add_cross(&dA[3], p, 1.0, dacc);
    gagen_cd_add_cross(&A[3], dp, 1.0, dacc);
    gagen_cd_add_cross(&dV[3], vp, 1.0, dacc);
    gagen_cd_add_cross(&V[3], dvel, 1.0, dacc);
}

/* the derivative of gagen_cd_row_value along direction d (q's k = d, or qd's k = d - nv) */
GAGEN_CD_INLINE void gagen_cd_row_derivative(const gagen_cd_frames *F, int fa, int fb, int frame6,
                                    int local, double kd, ptrdiff_t d, double *dx)
{
    double da[6], db[6], dva[6], dvb[6], t[6], dpa[3];
    int i;
    ptrdiff_t nv = F->nv;
    if (!frame6) {
        gagen_cd_classical_derivative(F, fa, d, da, dva);
        for (i = 0; i < 3; ++i) {
            dx[i] = da[i] + kd * dva[i];
            dx[3 + i] = 0.0;
        }
        if (fb >= 0) {
            gagen_cd_classical_derivative(F, fb, d, db, dvb);
            for (i = 0; i < 3; ++i) dx[i] -= db[i] + kd * dvb[i];
        }
        return;
    }
    gagen_cd_motion_derivative(F, fa, d, dva, da);
    if (fb >= 0) {
        gagen_cd_motion_derivative(F, fb, d, dvb, db);
        for (i = 0; i < 6; ++i) {
            da[i] -= db[i];
            dva[i] -= dvb[i];
        }
        if (local) {  /* d(V_A x V_B) */
            gagen_cd_velocity_derivative(F, fa, d, t);
            gagen_cd_mcross(t, &F->V[6 * fb], db);
            for (i = 0; i < 6; ++i) da[i] += db[i];
            gagen_cd_velocity_derivative(F, fb, d, t);
            gagen_cd_mcross(&F->V[6 * fa], t, db);
            for (i = 0; i < 6; ++i) da[i] += db[i];
        }
    }
    for (i = 0; i < 6; ++i) dx[i] = da[i] + kd * dva[i];
    gagen_cd_add_cross(&dx[3], &F->P[3 * fa], 1.0, dx);
    if (d < nv) {  /* the point pA moves: the value's angular part x dpA */
        for (i = 0; i < 3; ++i) dpa[i] = F->J[(6 * fa + i) * nv + d];
        gagen_cd_value_angular(F, fa, fb, local, kd, t);
        gagen_cd_add_cross(t, dpa, 1.0, dx);
    }
}

/* W += sign (f, p x f + t) on frame fchain's chain, p frame fp's origin, and its
   q-derivative (f and t turn with frame fa's axes when local): nonzero only along fp's
   chain (p moves) and, when local, fa's (the axes turn); dW is zero elsewhere */
GAGEN_CD_INLINE void gagen_cd_wrench_at(const gagen_cd_frames *F, int fp, int fa, int fchain,
                               double sign, const double *fw, const double *tw, int local)
{
    double m[3], df[3], dt[3], dp[3], dm[3];
    double *dW;
    ptrdiff_t k, nv = F->nv;
    int i;
    gagen_cd_cross3(&F->P[3 * fp], fw, m);
    for (i = 0; i < 3; ++i) {
        F->W[6 * fchain + i] += sign * fw[i];
        F->W[6 * fchain + 3 + i] += sign * (m[i] + tw[i]);
    }
    for (k = 0; k < nv; ++k) {
        if (F->order[(fp * nv + k) * nv + k] == 0.0
            && !(local && F->order[(fa * nv + k) * nv + k] != 0.0))
            continue;
        for (i = 0; i < 3; ++i) {
            dp[i] = F->J[(6 * fp + i) * nv + k];
            df[i] = 0.0;
            dt[i] = 0.0;
        }
        if (local) {
            gagen_cd_cross3(&gagen_cd_col(F, F->S, fa, k)[3], fw, df);
            gagen_cd_cross3(&gagen_cd_col(F, F->S, fa, k)[3], tw, dt);
        }
        gagen_cd_cross3(dp, fw, dm);
        gagen_cd_add_cross(&F->P[3 * fp], df, 1.0, dm);
        dW = gagen_cd_col(F, F->dW, fchain, k);
        for (i = 0; i < 3; ++i) {
            dW[i] += sign * df[i];
            dW[3 + i] += sign * (dm[i] + dt[i]);
        }
    }
}

/* x <- R^T x for each of its first `blocks` 3-vectors */
GAGEN_CD_INLINE void gagen_cd_turn(const double *R, double *x, int blocks)
{
    double t[3];
    int h, i;
    for (h = 0; h < blocks; ++h) {
        for (i = 0; i < 3; ++i)
            t[i] = R[i] * x[3 * h] + R[3 + i] * x[3 * h + 1] + R[6 + i] * x[3 * h + 2];
        for (i = 0; i < 3; ++i) x[3 * h + i] = t[i];
    }
}

/* Zeroes what gagen_cd_motion and gagen_cd_terms sum into (dW and V, A, W after it, in
   gagen_cd_state's layout) and, where a loop or a "local" row reads a frame's S, dVq, dAq
   or dAv off its chain, those entries; the rest is written before it is read. */
GAGEN_CD_INLINE void gagen_cd_clear(const gagen_cd_set *c, double *S, double *dVq, double *dAq,
                           double *dAv, double *dW)
{
    ptrdiff_t nv = c->model->nv, nf = c->nf, f, d, h, at;
    int cc, off_chain = 0;
    memset(dW, 0, (size_t)(nf * nv * 6 + 18 * nf) * sizeof(double));
    for (cc = 0; cc < c->nc; ++cc)
        if (c->table[GAGEN_CD_TABLE * cc + 1] >= 0 || c->table[GAGEN_CD_TABLE * cc + 3])
            off_chain = 1;
    for (f = 0; off_chain && f < nf; ++f) {
        for (d = 0; d < nv; ++d) {
            if (c->order[(f * nv + d) * nv + d] != 0.0) continue;
            at = (f * nv + d) * 6;
            for (h = 0; h < 6; ++h) S[at + h] = dVq[at + h] = dAq[at + h] = dAv[at + h] = 0.0;
        }
    }
}

/* Each frame's chain at qdd = 0 (gagen_cd_clear first): S_j (its twists at the world's
   origin), V_j (j's body's velocity), Sd_j = V_j x S_j, V, and
   A = sum Sd_j qd_j; then the active rows' J, as Jt = J^T (nv rows of m), and rhs = -(Jdot qd + kd J qd)
   (gagen_cn_one's rows: a point's velocity, or a frame's twist at A's origin, less B's; in
   A's axes for "local"), the right-hand side of the constrained dynamics. */
GAGEN_CD_CLONES
static void gagen_cd_motion(const gagen_cd_set *c, const double *J, const double *R,
                            const double *P, double *S, double *Sd, double *V,
                            double *A, double *T, const double *v, double kd, double *Jt,
                            double *rhs)
{
    ptrdiff_t nv = c->model->nv, nf = c->nf, m = c->m;
    ptrdiff_t f, i, j, h, n, jj, d;
    int cc, fa, fb, frame6, local, naxes, row = 0;
    const int *ch, *end, *tb;
    double *Sj, *pre = T;
    double tmp[6], x0[6], Vb[6];
    gagen_cd_frames F;
    for (f = 0; f < nf; ++f) {
        ch = c->chain + f * nv;
        n = c->chain_len[f];
        end = c->group_end + f * nv;
        for (jj = 0; jj < n; ++jj) {
            j = ch[jj];
            Sj = S + (f * nv + j) * 6;
            for (i = 0; i < 3; ++i) Sj[3 + i] = J[(6 * f + 3 + i) * nv + j];
            gagen_cd_cross3(Sj + 3, &P[3 * f], tmp);
            for (i = 0; i < 3; ++i) Sj[i] = J[(6 * f + i) * nv + j] - tmp[i];
        }
        for (h = 0; h < 6; ++h) pre[h] = 0.0;
        for (jj = 0; jj < n; ++jj) {
            Sj = S + (f * nv + ch[jj]) * 6;
            for (h = 0; h < 6; ++h) pre[6 * (jj + 1) + h] = pre[6 * jj + h] + Sj[h] * v[ch[jj]];
        }
        for (h = 0; h < 6; ++h) {
            V[6 * f + h] = pre[6 * n + h];
            A[6 * f + h] = 0.0;
        }
        for (jj = 0; jj < n; ++jj) {  /* V_j (its group's end), Sd_j = V_j x S_j, A = sum Sd_j qd_j */
            j = ch[jj];
            for (h = 0; h < 6; ++h) Vb[h] = pre[6 * end[jj] + h];
            gagen_cd_mcross(Vb, &S[(f * nv + j) * 6], &Sd[(f * nv + j) * 6]);
            for (h = 0; h < 6; ++h) A[6 * f + h] += Sd[(f * nv + j) * 6 + h] * v[j];
        }
    }
    F.nv = nv;
    F.J = J;
    F.P = P;
    F.S = S;
    F.V = V;
    F.A = A;
    F.order = c->order;
    F.dVq = F.dAq = F.dAv = F.W = F.dW = NULL;
    for (cc = 0; cc < c->nc; ++cc) {
        tb = c->table + GAGEN_CD_TABLE * cc;
        fa = tb[0];
        fb = tb[1];
        frame6 = tb[2];
        local = tb[3];
        naxes = tb[4];
        gagen_cd_row_value(&F, fa, fb, frame6, local, kd, x0);
        if (local) gagen_cd_turn(R + 9 * fa, x0, frame6 ? 2 : 1);
        for (i = 0; i < naxes; ++i) rhs[row + i] = -x0[tb[5 + i]];
        for (d = 0; d < nv; ++d) {
            if (c->order[(fa * nv + d) * nv + d] == 0.0
                && (fb < 0 || c->order[(fb * nv + d) * nv + d] == 0.0)) {
                for (i = 0; i < naxes; ++i) Jt[d * m + row + i] = 0.0;
                continue;
            }
            Sj = S + (fa * nv + d) * 6;
            for (h = 0; h < 6; ++h) x0[h] = Sj[h];
            if (!frame6) {  /* the points' velocities */
                gagen_cd_add_cross(Sj + 3, &P[3 * fa], 1.0, x0);
                if (fb >= 0) {
                    Sj = S + (fb * nv + d) * 6;
                    for (h = 0; h < 3; ++h) x0[h] -= Sj[h];
                    gagen_cd_add_cross(Sj + 3, &P[3 * fb], -1.0, x0);
                }
            } else {  /* the twists' difference at A's origin */
                if (fb >= 0) {
                    Sj = S + (fb * nv + d) * 6;
                    for (h = 0; h < 6; ++h) x0[h] -= Sj[h];
                }
                gagen_cd_add_cross(x0 + 3, &P[3 * fa], 1.0, x0);
            }
            if (local) gagen_cd_turn(R + 9 * fa, x0, frame6 ? 2 : 1);
            for (i = 0; i < naxes; ++i) Jt[d * m + row + i] = x0[tb[5 + i]];
        }
        row += naxes;
    }
}

/* r2 = [-da_c/dq | -da_c/dqd | 0] (m rows of 3 nv) and r1 += d(J^T lambda)/dq in its first
   nv columns (nv rows of 3 nv), lambda held (the module docstring of gagen.runtime.constraint_derivatives has the sums) */
GAGEN_CD_CLONES
static void gagen_cd_terms(const gagen_cd_set *c, const double *J, const double *R, double *P,
                           double *S, double *Sd, double *dVq, double *dAq,
                           double *dAv, double *dW, double *V, double *A, double *W, double *T,
                           const double *v, const double *a, const double *lam, double kd,
                           double *r2, double *r1)
{
    ptrdiff_t nv = c->model->nv, nf = c->nf, n3 = 3 * c->model->nv;
    ptrdiff_t f, i, j, k, d, h, n, jj, kk;
    int cc, fa, fb, frame6, local, naxes, row = 0;
    const double *order;
    const int *ch, *start, *tb;
    double u[6], e0[6], e2[6], tmp[6], x0[6], dx[6], full[6], fw[3], tw[3];
    double *e1, *Sj;
    const double *x;
    int on;
    /* each frame's A and the derivatives of V and A along its chain (root first; a floating
       joint's six coordinates are one group, each on or above the others). With the
       chain's sums V_j = sum_{i <= j} S_i qd_i (j's body, gagen_cd_motion's), Vp_k (k's
       joint's parent body), Vv_k = sum_{j >= k} S_j qd_j and
       Aa_k = sum_{j >= k} S_j a_j + Sd_j qd_j, the module docstring's sums close by the
       Jacobi identity into dV/dq_k = S_k x Vv_k and dA/dq_k = S_k x Aa_k - (S_k x Vp_k) x
       Vv_k: O(chain) per frame. */
    double *pre = T;                  /* (n + 1, 6) prefix sums of S_j qd_j */
    double *sv = T + 6 * (nv + 1);    /* (n + 1, 6) suffix sums of S_j qd_j */
    double *sa = sv + 6 * (nv + 1);   /* (n + 1, 6) suffix sums of S_j a_j + Sd_j qd_j */
    gagen_cd_frames F;
    for (f = 0; f < nf; ++f) {
        ch = c->chain + f * nv;
        n = c->chain_len[f];
        start = c->group_start + f * nv;
        for (h = 0; h < 6; ++h) {
            pre[h] = 0.0;
            sv[6 * n + h] = 0.0;
            sa[6 * n + h] = 0.0;
        }
        for (jj = 0; jj < n; ++jj) {
            Sj = S + (f * nv + ch[jj]) * 6;
            for (h = 0; h < 6; ++h) pre[6 * (jj + 1) + h] = pre[6 * jj + h] + Sj[h] * v[ch[jj]];
        }
        for (jj = n - 1; jj >= 0; --jj) {
            j = ch[jj];
            Sj = S + (f * nv + j) * 6;
            for (h = 0; h < 6; ++h) {
                sv[6 * jj + h] = sv[6 * (jj + 1) + h] + Sj[h] * v[j];
                sa[6 * jj + h] = sa[6 * (jj + 1) + h] + Sj[h] * a[j]
                                 + Sd[(f * nv + j) * 6 + h] * v[j];
            }
        }
        for (h = 0; h < 6; ++h) A[6 * f + h] = sa[h];
        for (kk = 0; kk < n; ++kk) {
            k = ch[kk];
            Sj = S + (f * nv + k) * 6;
            gagen_cd_mcross(Sj, &sv[6 * start[kk]], &dVq[(f * nv + k) * 6]);
            gagen_cd_mcross(Sj, &sa[6 * start[kk]], &dAq[(f * nv + k) * 6]);
            gagen_cd_mcross(Sj, &pre[6 * start[kk]], e0);
            gagen_cd_mcross(e0, &sv[6 * start[kk]], e2);
            for (h = 0; h < 6; ++h) {
                dAq[(f * nv + k) * 6 + h] -= e2[h];
                dAv[(f * nv + k) * 6 + h] = dVq[(f * nv + k) * 6 + h] + Sd[(f * nv + k) * 6 + h];
            }
        }
    }
    /* the rows' derivatives and the wrenches */
    F.nv = nv;
    F.J = J;
    F.P = P;
    F.order = c->order;
    F.S = S;
    F.V = V;
    F.A = A;
    F.dVq = dVq;
    F.dAq = dAq;
    F.dAv = dAv;
    F.W = W;
    F.dW = dW;
    for (cc = 0; cc < c->nc; ++cc) {
        tb = c->table + GAGEN_CD_TABLE * cc;
        fa = tb[0];
        fb = tb[1];
        frame6 = tb[2];
        local = tb[3];
        naxes = tb[4];
        gagen_cd_row_value(&F, fa, fb, frame6, local, kd, x0);
        for (d = 0; d < 2 * nv; ++d) {
            k = d < nv ? d : d - nv;
            if (c->order[(fa * nv + k) * nv + k] == 0.0
                && (fb < 0 || c->order[(fb * nv + k) * nv + k] == 0.0)) {
                /* a coordinate on neither frame's chain moves neither */
                for (i = 0; i < naxes; ++i) r2[(row + i) * n3 + d] = 0.0;
                continue;
            }
            gagen_cd_row_derivative(&F, fa, fb, frame6, local, kd, d, dx);
            if (local) {  /* R^T (dx - w x x0) per 3-block */
                for (h = 0; h < (frame6 ? 2 : 1); ++h) {
                    if (d < nv) gagen_cd_add_cross(&S[(fa * nv + d) * 6 + 3], &x0[3 * h], -1.0,
                                                   &dx[3 * h]);
                    for (i = 0; i < 3; ++i)
                        tmp[i] = R[9 * fa + i] * dx[3 * h] + R[9 * fa + 3 + i] * dx[3 * h + 1]
                                 + R[9 * fa + 6 + i] * dx[3 * h + 2];
                    for (i = 0; i < 3; ++i) dx[3 * h + i] = tmp[i];
                }
            }
            for (i = 0; i < naxes; ++i) r2[(row + i) * n3 + d] = -dx[tb[5 + i]];
        }
        for (i = 0; i < naxes; ++i)  /* tau moves no row */
            for (d = 2 * nv; d < n3; ++d) r2[(row + i) * n3 + d] = 0.0;
        /* the wrench: f, t in world axes, on A at pA (and -W on B at pB or pA) */
        for (i = 0; i < 6; ++i) full[i] = 0.0;
        for (i = 0; i < naxes; ++i) full[tb[5 + i]] = lam[row + i];
        for (i = 0; i < 3; ++i) {
            if (local) {
                fw[i] = R[9 * fa + 3 * i] * full[0] + R[9 * fa + 3 * i + 1] * full[1]
                        + R[9 * fa + 3 * i + 2] * full[2];
                tw[i] = R[9 * fa + 3 * i] * full[3] + R[9 * fa + 3 * i + 1] * full[4]
                        + R[9 * fa + 3 * i + 2] * full[5];
            } else {
                fw[i] = full[i];
                tw[i] = full[3 + i];
            }
        }
        gagen_cd_wrench_at(&F, fa, fa, fa, 1.0, fw, tw, local);
        if (fb >= 0)  /* -W on B's chain, at pB (a point loop) or pA (a frame loop) */
            gagen_cd_wrench_at(&F, frame6 ? fa : fb, fa, fb, -1.0, fw, tw, local);
        row += naxes;
    }
    /* d(sum S^T W)/dq: [j, k] = S_j . (dW_f/dq_k - S_k x* W_f), the second term for j at or
       below k on the frame's chain ((S_k x S_j) . W_f = -S_j . (S_k x* W_f)) */
    for (f = 0; f < nf; ++f) {
        order = c->order + f * nv * nv;
        ch = c->chain + f * nv;
        n = c->chain_len[f];
        for (k = 0; k < nv; ++k) {
            e1 = dW + (f * nv + k) * 6;
            on = order[k * nv + k] != 0.0;  /* k on the frame's chain */
            if (!on && e1[0] == 0.0 && e1[1] == 0.0 && e1[2] == 0.0 && e1[3] == 0.0
                && e1[4] == 0.0 && e1[5] == 0.0)
                continue;  /* (k on no chain that the frame's wrenches turn or move with) */
            for (h = 0; h < 6; ++h) u[h] = 0.0;
            if (on) gagen_cd_fcross(&S[(f * nv + k) * 6], &W[6 * f], u);
            for (h = 0; h < 6; ++h) e0[h] = e1[h] - u[h];
            for (jj = 0; jj < n; ++jj) {
                j = ch[jj];
                Sj = S + (f * nv + j) * 6;
                x = order[k * nv + j] != 0.0 ? e0 : e1;
                r1[j * n3 + k] += Sj[0] * x[0] + Sj[1] * x[1] + Sj[2] * x[2] + Sj[3] * x[3]
                                  + Sj[4] * x[4] + Sj[5] * x[5];
            }
        }
    }
}

/* [dqdd; dlambda] in out ((nv + m) rows of 3 nv) from r1 in its first nv rows and r2 in
   the others, through M = L^T D L and G = J M^-1 J^T (+ damping I) = Lg Dg Lg^T as
   gagen_cd_state factored them, with Y = J L^-1: w = L^-T r1; dlambda = G^-1 (r2 - Y D^-1 w);
   dqdd = L^-1 D^-1 (w + Y^T dlambda). Each row of out is written once per step from the
   rows it needs (gagen_cd_gather, which also scales the row it writes: D^-1 and Dg^-1 take
   no pass of their own), along the tree's ancestors and descendants and the rows' paths
   only (Yt = Y^T, nv rows of m). Offsets into out are ints: (nv + m) 3 nv < 2^31. */
GAGEN_CD_INLINE void gagen_cd_kkt(const gagen_cd_set *c, const double *L, double *out, const double *Yt,
                         const double *G, const double *Dinv, double *coef, int *idx)
{
    const gagen_cd_model *md = c->model;
    ptrdiff_t n = md->nv, m = c->m, n3 = 3 * md->nv, i, j, k, a, b;
    const int *parent = md->parent;
    int t, count;
    double *rhs = out + n3 * n;
    for (i = n - 1; i >= 0; --i) {  /* w = L^-T r1: w_i = r1_i - sum_{k below i} L_ki w_k */
        count = 0;
        for (t = md->desc_ptr[i]; t < md->desc_ptr[i + 1]; ++t) {
            idx[count] = (int)(n3 * md->desc[t]);
            coef[count] = L[n * md->desc[t] + i];
            count += 1;
        }
        gagen_cd_gather(out + n3 * i, 1.0, out, idx, coef, count, n3);
    }
    for (a = 0; a < m; ++a) {  /* r2 - Y D^-1 w, in place */
        count = 0;
        for (j = 0; j < n; ++j) {
            if (Yt[m * j + a] != 0.0) {
                idx[count] = (int)(n3 * j);
                coef[count] = Yt[m * j + a] * Dinv[j];
                count += 1;
            }
        }
        gagen_cd_gather(rhs + n3 * a, 1.0, out, idx, coef, count, n3);
    }
    for (a = 0; a < m; ++a) {  /* dlambda = G^-1 (...), G = Lg Dg Lg^T: forward, Dg^-1, back */
        for (b = 0; b < a; ++b) {
            idx[b] = (int)(n3 * b);
            coef[b] = G[m * a + b];
        }
        gagen_cd_gather(rhs + n3 * a, 1.0, rhs, idx, coef, (int)a, n3);
    }
    for (a = m - 1; a >= 0; --a) {
        count = 0;
        for (b = a + 1; b < m; ++b) {
            idx[count] = (int)(n3 * b);
            coef[count] = G[m * b + a];
            count += 1;
        }
        gagen_cd_gather(rhs + n3 * a, 1.0 / G[m * a + a], rhs, idx, coef, count, n3);
    }
    for (j = 0; j < n; ++j) {  /* z = D^-1 w + D^-1 Y^T dlambda */
        count = 0;
        for (a = 0; a < m; ++a) {
            if (Yt[m * j + a] != 0.0) {
                idx[count] = (int)(n3 * a);
                coef[count] = -Yt[m * j + a] * Dinv[j];
                count += 1;
            }
        }
        gagen_cd_gather(out + n3 * j, Dinv[j], rhs, idx, coef, count, n3);
    }
    for (k = 0; k < n; ++k) {  /* dqdd = L^-1 z: root first, each row from its ancestors */
        count = 0;
        for (i = parent[k]; i >= 0; i = parent[i]) {
            idx[count] = (int)(n3 * i);
            coef[count] = L[n * k + i];
            count += 1;
        }
        gagen_cd_gather(out + n3 * k, 1.0, out, idx, coef, count, n3);
    }
}

/* One state's six derivatives of the active set c: dqdd_dq, dqdd_dqd, dqdd_dtau (nv, nv)
   into o0 .. o2, dforces_dq, _dqd, _dtau (nrows, nv: every declared row, 0 where inactive)
   into o3 .. o5, row-major; p the parameters, Fo the model's frame offsets at p
   (frame_offsets), kd Baumgarte's velocity gain, damping the Delassus matrix's; ws
   GAGEN_CD_WORKSPACE doubles, ints GAGEN_CD_INTS. Returns 0, a GAGEN_CD_* error or
   frame_jacobians's (the outputs then not all written). */
GAGEN_CD_CLONES
static int gagen_cd_state(const gagen_cd_set *c, const double *q, const double *qd,
                          const double *tau, const double *p, const double *Fo, double kd,
                          double damping, double *ws, int *ints, double *o0, double *o1,
                          double *o2, double *o3, double *o4, double *o5)
{
    const gagen_cd_model *md = c->model;
    ptrdiff_t n = md->nv, nf = c->nf, m = c->m, n3 = 3 * md->nv, R = md->nrows;
    ptrdiff_t i, j, k, r;
    int rc;
    double n2;
    const double *x;
    double *qdd, *forces, *lam, *dIq, *dIv, *L, *X, *J, *P, *Rf, *S, *Sd, *dVq, *dAq;
    double *dAv, *dW, *V, *A, *W, *T, *out, *Yt, *G, *Dinv;
    int t, count;
    for (k = 0; k < md->nquat; ++k) {  /* as the runtime's check: a squared norm that is a
                                          normal double */
        x = q + md->quat[k];
        n2 = x[0] * x[0] + x[1] * x[1] + x[2] * x[2] + x[3] * x[3];
        if (!(n2 >= DBL_MIN && n2 <= DBL_MAX)) return GAGEN_CD_QUATERNION;
    }
    /* the workspace (GAGEN_CD_WORKSPACE's sum) */
    qdd = ws;
    forces = qdd + n;
    lam = forces + (R > n ? R : n);
    dIq = lam + m;
    dIv = dIq + n * n;
    L = dIv + n * n;
    X = L + n * n;
    J = X + 15 * md->nb;
    P = J + nf * 6 * n;
    Rf = P + 3 * nf;
    S = Rf + 9 * nf;
    Sd = S + nf * n * 6;
    dVq = Sd + nf * n * 6;
    dAq = dVq + nf * n * 6;
    dAv = dAq + nf * n * 6;
    dW = dAv + nf * n * 6;
    V = dW + nf * n * 6;
    A = V + 6 * nf;
    W = A + 6 * nf;
    T = W + 6 * nf;
    out = T + 18 * (n + 1);
    Yt = out + (n + m) * n3;
    G = Yt + m * n;
    Dinv = G + m * m;
    /* the constrained forward dynamics (the model's constrained_forward_dynamics: the same
       steps, on factors the derivatives reuse): M = L^T D L, f = L^-T (tau - bias),
       Y = J L^-1, G = Y D^-1 Y^T + damping I = Lg Dg Lg^T,
       lambda = G^-1 (-drift - kd J qd - Y D^-1 f), qdd = L^-1 D^-1 (f + Y^T lambda) */
    md->mass_matrix(q, p, L);
    if (gagen_cd_ltdl(L, md->parent, n, Dinv)) return GAGEN_CD_NOT_POSITIVE_DEFINITE;
    for (j = 0; j < n; ++j) Dinv[j] = 1.0 / L[n * j + j];
    md->forcing(q, qd, tau, p, qdd);
    gagen_cd_back(L, md->parent, n, qdd);
    if (nf) {  /* the frames' chains at qdd = 0: J and -(drift + kd J qd) of the active rows */
        md->placements(q, p, X);
        rc = md->frame_jacobians(q, p, (int)nf, c->frames, GAGEN_CD_WORLD_ALIGNED, J);
        if (rc != 0) return rc;
        gagen_cd_placements(c, X, Fo, Rf, P);
        gagen_cd_clear(c, S, dVq, dAq, dAv, dW);
        gagen_cd_motion(c, J, Rf, P, S, Sd, V, A, T, qd, kd, Yt, lam);
    }
    if (m) {
        for (i = n - 1; i >= 0; --i) {  /* Y^T = L^-T J^T in place (gagen_cd_back's steps,
                                           all rows at once) */
            count = 0;
            for (t = md->desc_ptr[i + 1] - 1; t >= md->desc_ptr[i]; --t) {
                ints[count] = (int)(m * md->desc[t]);
                Dinv[n + count] = L[n * md->desc[t] + i];
                count += 1;
            }
            gagen_cd_gather(Yt + m * i, 1.0, Yt, ints, Dinv + n, count, m);
        }
        for (r = 0; r < m; ++r) {
            n2 = 0.0;
            for (j = 0; j < n; ++j) n2 += Yt[m * j + r] * Dinv[j] * qdd[j];
            lam[r] -= n2;
        }
        if (gagen_cd_delassus(Yt, Dinv, n, m, damping, G, ints, Dinv + n)) return GAGEN_CD_SINGULAR;
        gagen_cd_solve_ldlt(G, m, lam);
        for (j = 0; j < n; ++j) {
            n2 = qdd[j];
            for (r = 0; r < m; ++r) n2 += Yt[m * j + r] * lam[r];
            forces[j] = n2 * Dinv[j];  /* (forces: scratch here) */
        }
    } else {
        for (j = 0; j < n; ++j) forces[j] = qdd[j] * Dinv[j];
    }
    for (j = 0; j < n; ++j) qdd[j] = forces[j];
    gagen_cd_forward(L, md->parent, n, qdd);
    md->inverse_dynamics_derivatives(q, qd, qdd, p, dIq, dIv);
    /* r1 = [d(J^T lambda)/dq - dID/dq | -dID/dqd | I] in out's first nv rows (terms adds
       the first), r2 in its last m */
    for (i = 0; i < n; ++i) {
        for (j = 0; j < n; ++j) {
            out[n3 * i + j] = -dIq[n * i + j];
            out[n3 * i + n + j] = -dIv[n * i + j];
            out[n3 * i + 2 * n + j] = 0.0;
        }
        out[n3 * i + 2 * n + i] = 1.0;
    }
    if (nf)
        gagen_cd_terms(c, J, Rf, P, S, Sd, dVq, dAq, dAv, dW, V, A, W, T, qd, qdd, lam, kd,
                       out + n3 * n, out);
    gagen_cd_kkt(c, L, out, Yt, G, Dinv, Dinv + n, ints);
    /* the outputs: qdd's three blocks; the forces' over every declared row (inactive: 0;
       c->rows is increasing) */
    for (i = 0; i < n; ++i) {
        memcpy(o0 + n * i, out + n3 * i, (size_t)n * sizeof(double));
        memcpy(o1 + n * i, out + n3 * i + n, (size_t)n * sizeof(double));
        memcpy(o2 + n * i, out + n3 * i + 2 * n, (size_t)n * sizeof(double));
    }
    for (k = 0, r = 0; k < R; ++k) {
        if (r < m && c->rows[r] == k) {
            x = out + n3 * (n + r);
            memcpy(o3 + n * k, x, (size_t)n * sizeof(double));
            memcpy(o4 + n * k, x + n, (size_t)n * sizeof(double));
            memcpy(o5 + n * k, x + 2 * n, (size_t)n * sizeof(double));
            r += 1;
        } else {
            memset(o3 + n * k, 0, (size_t)n * sizeof(double));
            memset(o4 + n * k, 0, (size_t)n * sizeof(double));
            memset(o5 + n * k, 0, (size_t)n * sizeof(double));
        }
    }
    return 0;
}

#endif /* GAGEN_CONSTRAINT_DERIVATIVES_H */
