/*
 * gagen_second_order.h -- a robot's simulation: its controllers and gagen's integrators,
 * specialised for the state y = [q, qd] of one model (plain C99, header only).
 *
 * A model's generated simulation.c includes this file once, after defining
 *
 *   GAGEN_SO_NQ        the size of q (constants: the loops unroll)
 *   GAGEN_SO_NV        the number of velocity coordinates, the size of qd (NQ exceeds it by
 *                      one per floating joint, whose orientation is a quaternion)
 *   GAGEN_SO_NS        the size of a position stage S (doubles)
 *   GAGEN_SO_GRAVITY   where the gravity torques g(q) start in S
 *   static int  gagen_so_position(const double *q, const double *p, double *S);
 *                      everything of qdd(q, qd, u) that depends on q alone: sin and cos,
 *                      M(q) and its factors, g(q); returns 0 or the model's error code
 *   static void gagen_so_velocity(const double *S, const double *q, const double *qd,
 *                                 const double *u, const double *p, double *qdd);
 *                      the rest: qdd under the joint torques u
 *   static void gagen_so_gravity(const double *q, const double *p, double *G);
 *   static void gagen_so_inverse(const double *q, const double *qd, const double *qdd,
 *                                const double *p, double *tau);
 *   static void gagen_so_qdot(const double *q, const double *qd, double *dq);
 *                      dq/dt: qd itself, but for floating joints (a quaternion's rate)
 *   static void gagen_so_error(const double *q, const double *target, double *e);
 *                      a PD law's error per velocity coordinate (0 for floating joints)
 *   static void gagen_so_unactuated(double *u);
 *                      zeroes the torques no actuator gives: a floating joint's wrench
 *   static void gagen_so_wrenches(const double *q, const double *p, int count,
 *                                 const int *frames, const double *wrenches, double *u);
 *                      adds J^T w of wrenches on frames (gagen_control's nframes ...)
 *
 * and gets gagen_so_dopri5, gagen_so_rk4 and gagen_so_torques.
 *
 * Why a second-order form: each integrator stage needs qdd at a new state, and the
 * positions of stage s + 1 are known as soon as the velocities of stage s are, before its
 * accelerations: dq/dt = qd (for a floating joint a function of q and qd).  So stage s + 1's position stage (sin, cos, the mass matrix
 * and its factorisation) is computed while stage s's velocity stage runs, instead of after
 * it; and with the state size a constant and the stages written out, the integrator's own
 * loops unroll.  The arithmetic is gagen_ode.h's, the same as the generic gagen_dopri5 and
 * gagen_rk4: the same steps as scipy's RK45 (dopri5) and the same grid (rk4).
 */
#ifndef GAGEN_SECOND_ORDER_H
#define GAGEN_SECOND_ORDER_H

#include "gagen_ode.h"

/* gagen_math.h builds the integrators like the kernels, for CPUs with and without FMA */
#ifndef GAGEN_KERNEL
#define GAGEN_KERNEL
#endif

/* Small helpers go inline into each integrator (and so into its FMA clone). */
#if defined(__GNUC__) || defined(__clang__)
#define GAGEN_SO_INLINE static inline __attribute__((always_inline))
#else
#define GAGEN_SO_INLINE static inline
#endif

#define GAGEN_SO_NY (GAGEN_SO_NQ + GAGEN_SO_NV)

/* A gagen_control read once: its arrays copied, NULL ones as zeros. */
typedef struct {
    int kind, gravity_compensation;
    double kp[GAGEN_SO_NV], kd[GAGEN_SO_NV], target[GAGEN_SO_NV], ff[GAGEN_SO_NV];
    double q0[GAGEN_SO_NQ], qf[GAGEN_SO_NQ], Tp;
    int nframes;
    const int *frames;
    const double *wrenches;
    gagen_poll_fn poll;
    void *poll_ctx;
} gagen_so_law;

static void gagen_so_copy_or_zero(const double *src, double *dst, int n)
{
    int i;
    for (i = 0; i < n; ++i) dst[i] = src ? src[i] : 0.0;
}

/* Reads c into law; GAGEN_ERR_BAD_ARG for an unknown controller or one that lacks data. */
static int gagen_so_law_init(gagen_so_law *law, const gagen_control *c)
{
    if (c == NULL) return GAGEN_ERR_BAD_ARG;
    if (c->kind != GAGEN_CTRL_NONE && c->kind != GAGEN_CTRL_PD &&
        c->kind != GAGEN_CTRL_COMPUTED_TORQUE)
        return GAGEN_ERR_BAD_ARG;
    if (c->kind == GAGEN_CTRL_COMPUTED_TORQUE && (c->traj_q0 == NULL || c->traj_qf == NULL))
        return GAGEN_ERR_BAD_ARG;
    /* eq. 11 moves every coordinate along a line: no floating joint */
    if (c->kind == GAGEN_CTRL_COMPUTED_TORQUE && GAGEN_SO_NQ != GAGEN_SO_NV)
        return GAGEN_ERR_BAD_ARG;
    law->kind = c->kind;
    law->gravity_compensation = c->kind == GAGEN_CTRL_PD && c->gravity_compensation;
    gagen_so_copy_or_zero(c->kp, law->kp, GAGEN_SO_NV);
    gagen_so_copy_or_zero(c->kd, law->kd, GAGEN_SO_NV);
    gagen_so_copy_or_zero(c->target, law->target, GAGEN_SO_NV);
    gagen_so_copy_or_zero(c->traj_q0, law->q0, GAGEN_SO_NQ);
    gagen_so_copy_or_zero(c->traj_qf, law->qf, GAGEN_SO_NQ);
    gagen_so_copy_or_zero(c->kind == GAGEN_CTRL_PD ? c->feedforward : NULL, law->ff,
                          GAGEN_SO_NV);
    if (c->nframes < 0 || (c->nframes > 0 && (c->frames == NULL || c->wrenches == NULL)))
        return GAGEN_ERR_BAD_ARG;
    law->nframes = c->nframes;
    law->frames = c->frames;
    law->wrenches = c->wrenches;
    law->Tp = c->traj_Tp;
    law->poll = c->poll;
    law->poll_ctx = c->poll_ctx;
    return GAGEN_OK;
}

/* GAGEN_ERR_INTERRUPTED when the law's poll function, due every GAGEN_POLL_STEPS steps,
 * says stop. */
GAGEN_SO_INLINE int gagen_so_poll(const gagen_so_law *law, long step)
{
    if (law->poll != NULL && step % GAGEN_POLL_STEPS == 0 && law->poll(law->poll_ctx) != 0)
        return GAGEN_ERR_INTERRUPTED;
    return GAGEN_OK;
}

static int gagen_so_all_finite(const double *x, int n)
{
    int i;
    for (i = 0; i < n; ++i)
        if (!isfinite(x[i])) return 0;
    return 1;
}

/* Eq. 11: q_r(t) = q0 + (qf - q0)/Tp * (t - Tp/(2 pi) sin(2 pi t/Tp)) on [0, Tp], held at q0
 * for t < 0 and at qf for t > Tp (zero velocity and acceleration). */
GAGEN_SO_INLINE void gagen_so_eq11(const gagen_so_law *law, double t, double *q, double *qd,
                                   double *qdd)
{
    int i;
    if (t < 0 || !(law->Tp > 0) || t > law->Tp) {
        const double *hold = (t < 0) ? law->q0 : law->qf;
        for (i = 0; i < GAGEN_SO_NQ; ++i) {
            q[i] = hold[i];
            qd[i] = 0.0;
            qdd[i] = 0.0;
        }
        return;
    }
    {
        double w = GAGEN_TWO_PI / law->Tp;
        double sn = sin(w * t), cs = cos(w * t);
        for (i = 0; i < GAGEN_SO_NQ; ++i) {
            double slope = (law->qf[i] - law->q0[i]) / law->Tp;
            q[i] = law->q0[i] + slope * (t - sn / w);
            qd[i] = slope * (1.0 - cs);
            qdd[i] = slope * w * sn;
        }
    }
}

/* The torques u = tau(t, q, qd) of the law (controllers.py has the same formulas); G is
 * g(q) when the law compensates gravity. */
GAGEN_SO_INLINE void gagen_so_control(const gagen_so_law *law, const double *p, double t,
                                      const double *q, const double *qd, const double *G,
                                      double *u)
{
    int i;
    if (law->kind == GAGEN_CTRL_PD) {
        double e[GAGEN_SO_NV];
        gagen_so_error(q, law->target, e);
        for (i = 0; i < GAGEN_SO_NV; ++i)
            u[i] = law->ff[i] - law->kp[i] * e[i] - law->kd[i] * qd[i];
        if (law->gravity_compensation)
            for (i = 0; i < GAGEN_SO_NV; ++i) u[i] += G[i];
        gagen_so_unactuated(u);
    } else if (law->kind == GAGEN_CTRL_COMPUTED_TORQUE) {
        /* only when every coordinate is a plain number (gagen_so_law_init): NQ = NV */
        double qr[GAGEN_SO_NQ], qdr[GAGEN_SO_NQ], v[GAGEN_SO_NQ];
        gagen_so_eq11(law, t, qr, qdr, v);
        for (i = 0; i < GAGEN_SO_NV; ++i)
            v[i] = v[i] + law->kd[i] * (qdr[i] - qd[i]) + law->kp[i] * (qr[i] - q[i]);
        gagen_so_inverse(q, qd, v, p, u);
    } else {
        for (i = 0; i < GAGEN_SO_NV; ++i) u[i] = 0.0;
    }
}

/* k = dy/dt = (dq/dt, qdd) at (t, y), S being the position stage of y's q. */
GAGEN_SO_INLINE void gagen_so_derivative(const gagen_so_law *law, const double *p, double t,
                                         const double *S, const double *y, double *k)
{
    double u[GAGEN_SO_NV];
    gagen_so_control(law, p, t, y, y + GAGEN_SO_NQ, S + GAGEN_SO_GRAVITY, u);
    if (law->nframes > 0) gagen_so_wrenches(y, p, law->nframes, law->frames, law->wrenches, u);
    gagen_so_qdot(y, y + GAGEN_SO_NQ, k);
    gagen_so_velocity(S, y, y + GAGEN_SO_NQ, u, p, k + GAGEN_SO_NQ);
}

/* k = dy/dt at (t, y), both stages: the right-hand side where nothing overlaps. */
static int gagen_so_rhs(const gagen_so_law *law, const double *p, double t, const double *y,
                        double *k)
{
    double S[GAGEN_SO_NS];
    int rc = gagen_so_position(y, p, S);
    if (rc != 0) return rc;
    gagen_so_derivative(law, p, t, S, y, k);
    return 0;
}

/* ---- Dormand-Prince 5(4) -------------------------------------------------- */

/* Stage s (1..5) of a step from (t, y) of size h.  ytmp holds the stage's positions, and
 * S their position stage.  Forms the stage's velocities, the positions of stage s + 1 (of
 * y_new after stage 5) into y_new, then K[s], then the next position stage into S_next;
 * returns that stage's status and leaves the next positions in ytmp. */
GAGEN_SO_INLINE int gagen_so_dp_stage(int s, const gagen_so_law *law, const double *p,
                                      double t, double h, const double *y, double *K,
                                      double *ytmp, double *y_new, const double *S,
                                      double *S_next)
{
    enum { NQ = GAGEN_SO_NQ, NY = GAGEN_SO_NY };
    double *k = K + s * NY;
    int i, rc;
    gagen_dp_stage_input(NY, NQ, NY, s, K, y, h, ytmp);
    gagen_so_qdot(ytmp, ytmp + NQ, k);
    if (s + 1 < GAGEN_DP_NSTAGES)
        gagen_dp_stage_input(NY, 0, NQ, s + 1, K, y, h, y_new);
    else
        gagen_dp_solution(NY, 0, NQ, K, y, h, y_new);
    gagen_so_derivative(law, p, t + gagen_dp_C[s] * h, S, ytmp, k);
    rc = gagen_so_position(y_new, p, S_next);
    for (i = 0; i < NQ; ++i) ytmp[i] = y_new[i];
    return rc;
}

/*
 * gagen_dopri5 (integrator.h) for this robot, step for step.  In a step of size h the
 * stage inputs are y + h sum_j A[s][j] K[j], and K[j]'s position half is stage j's
 * velocity: so stage s + 1's positions follow from stage s's velocities, and their
 * position stage overlaps stage s's velocity stage.  A failed position stage is reported
 * when its velocity stage would run, as the generic integrator reports the evaluation.
 */
GAGEN_KERNEL
static int gagen_so_dopri5(const gagen_control *c, const double *p, double t0, double t1,
                           const double *y0, double rtol, const double *atol,
                           double first_step, double max_step, long max_steps,
                           const double *t_eval, int n_eval, double *y_out,
                           gagen_ode_stats *stats)
{
    enum { NQ = GAGEN_SO_NQ, NY = GAGEN_SO_NY };
    gagen_ode_stats st = {0, 0, 0, 0, 0};
    gagen_so_law law;
    double K[(GAGEN_DP_NSTAGES + 1) * NY], ya[NY], yb[NY], ytmp[NY], Q[4 * NY];
    double Sa[GAGEN_SO_NS], Sb[GAGEN_SO_NS];
    double *y = ya, *y_new = yb, *swap;
    double direction = (t1 != t0) ? (t1 > t0 ? 1.0 : -1.0) : 1.0;
    double t, h_abs, root_n = pow((double)NY, 0.5);
    int rc, ie = 0;

    rc = gagen_check_span(NY, t0, t1, y0, t_eval, n_eval, y_out);
    if (rc == GAGEN_OK) rc = gagen_dp_check_tolerances(NY, &rtol, atol);
    if (rc == GAGEN_OK) rc = gagen_so_law_init(&law, c);
    if (rc != GAGEN_OK) return gagen_finish(stats, &st, rc, y_out, 0, n_eval, NY);
    if (!(max_step > 0) || isinf(max_step)) max_step = INFINITY;

    gagen_copy(NY, y0, y);
    rc = gagen_so_rhs(&law, p, t0, y, K);
    ++st.nfev;
    if (rc != 0) return gagen_finish(stats, &st, rc, y_out, 0, n_eval, NY);

    if (first_step > 0) {
        h_abs = first_step;
    } else if (t1 == t0) {
        h_abs = 0.0;
    } else {
        double d1, interval = fabs(t1 - t0);
        double h0 = gagen_dp_initial_trial(NY, y, K, direction, rtol, atol, interval, ytmp,
                                           y_new, &d1);
        rc = gagen_so_rhs(&law, p, t0 + h0 * direction, y_new, K + NY);
        ++st.nfev;
        if (rc != 0) return gagen_finish(stats, &st, rc, y_out, 0, n_eval, NY);
        h_abs = gagen_dp_initial_step(NY, K, K + NY, ytmp, h0, d1, interval, max_step, y_new);
    }
    ie = gagen_output_exact(NY, t0, y0, t_eval, n_eval, ie, y_out);

    t = t0;
    while (direction * (t - t1) < 0) {
        double min_step = gagen_dp_min_step(t, direction);
        double h = 0.0, t_new = t;
        int step_rejected = 0;

        h_abs = gagen_dp_clip_step(h_abs, min_step, max_step);

        for (;;) {
            double error_norm;
            int pending;

            rc = gagen_dp_attempt(&h_abs, min_step, &st.nsteps, max_steps, t, t1, direction,
                                  &h, &t_new);
            if (rc == GAGEN_OK) rc = gagen_so_poll(&law, st.nsteps);
            if (rc != GAGEN_OK) return gagen_finish(stats, &st, rc, y_out, ie, n_eval, NY);

            gagen_dp_stage_input(NY, 0, NQ, 1, K, y, h, ytmp);
            pending = gagen_so_position(ytmp, p, Sa);
            /* the stages, their position stages alternating between Sa and Sb */
#define GAGEN_SO_DP_STAGE(s, S, S_next)                                                    \
    ++st.nfev;                                                                             \
    if (pending != 0) return gagen_finish(stats, &st, pending, y_out, ie, n_eval, NY);     \
    pending = gagen_so_dp_stage(s, &law, p, t, h, y, K, ytmp, y_new, S, S_next)
            GAGEN_SO_DP_STAGE(1, Sa, Sb);
            GAGEN_SO_DP_STAGE(2, Sb, Sa);
            GAGEN_SO_DP_STAGE(3, Sa, Sb);
            GAGEN_SO_DP_STAGE(4, Sb, Sa);
            GAGEN_SO_DP_STAGE(5, Sa, Sb);
#undef GAGEN_SO_DP_STAGE
            gagen_dp_solution(NY, NQ, NY, K, y, h, y_new);
            ++st.nfev;
            if (pending != 0) return gagen_finish(stats, &st, pending, y_out, ie, n_eval, NY);
            /* scipy evaluates at t + h, not at the clipped t_new. */
            gagen_so_derivative(&law, p, t + h, Sb, y_new, K + GAGEN_DP_NSTAGES * NY);

            error_norm = gagen_dp_error_norm(NY, K, y, y_new, h, rtol, atol, root_n);
            /* NaN would only shrink the step until it is too small: say what happened */
            if (isnan(error_norm))
                return gagen_finish(stats, &st, GAGEN_ERR_NONFINITE, y_out, ie, n_eval, NY);
            if (error_norm < 1)
                ie = gagen_dp_dense_output(NY, K, y, y_new, t, h, t_new, direction, t_eval,
                                           n_eval, ie, y_out, Q);
            if (gagen_dp_control(error_norm, &step_rejected, &h_abs, &st.nrejected)) break;
        }
        ++st.naccepted;

        gagen_copy(NY, K + GAGEN_DP_NSTAGES * NY, K);
        swap = y;
        y = y_new;
        y_new = swap;
        t = t_new;
    }
    while (ie < n_eval) {
        gagen_copy(NY, y, y_out + (long)ie * NY);
        ++ie;
    }
    return gagen_finish(stats, &st, GAGEN_OK, y_out, ie, n_eval, NY);
}

/* ---- classical RK4 ------------------------------------------------------ */

/* An RK4 stage at time ts: k = f(ts, [q, y_v + a dt k_prev_v]) with q's position stage in
 * S; on the way, the next stage's positions y_q + b dt k[q-half] go into q_next and their
 * position stage into S_next (its status returned).  For the last stage (b = 0) the
 * caller supplies q_next itself: y_new's positions. */
GAGEN_SO_INLINE int gagen_so_rk4_stage(const gagen_so_law *law, const double *p, double ts,
                                       double a, double b, double dt, const double *y,
                                       const double *k_prev, const double *q,
                                       const double *S, double *k, double *q_next,
                                       double *S_next)
{
    enum { NQ = GAGEN_SO_NQ, NY = GAGEN_SO_NY };
    double stage[NY];
    int i;
    for (i = 0; i < NQ; ++i) stage[i] = q[i];
    for (i = NQ; i < NY; ++i) stage[i] = y[i] + a * dt * k_prev[i];
    if (b != 0) {
        gagen_so_qdot(stage, stage + NQ, k);
        for (i = 0; i < NQ; ++i) q_next[i] = y[i] + b * dt * k[i];
    }
    gagen_so_derivative(law, p, ts, S, stage, k);
    return gagen_so_position(q_next, p, S_next);
}

/*
 * gagen_rk4 (integrator.h) for this robot, on the same grid with the same arithmetic.
 * The positions of stages 2, 3 and 4 and of y_new are y + c dt K[.][q-half], K's position
 * half being the previous stage's velocities, so each position stage overlaps the velocity
 * stage before it, as in gagen_so_dopri5.
 */
GAGEN_KERNEL
static int gagen_so_rk4(const gagen_control *c, const double *p, double t0, double t1,
                        const double *y0, double h, const double *t_eval, int n_eval,
                        double *y_out, gagen_ode_stats *stats)
{
    enum { NQ = GAGEN_SO_NQ, NY = GAGEN_SO_NY };
    gagen_ode_stats st = {0, 0, 0, 0, 0};
    gagen_so_law law;
    double direction = (t1 >= t0) ? 1.0 : -1.0;
    double ya[NY], yb[NY], ka[NY], kb[NY], k2[NY], k3[NY], k4[NY], q2[NQ], q3[NQ], q4[NQ];
    double Sa[GAGEN_SO_NS], Sb[GAGEN_SO_NS];
    double *y = ya, *y_new = yb, *k1 = ka, *f_new = kb, *swap;
    double t, span;
    long nstep_total, k;
    int i, rc, pending = 0, ie = 0;

    rc = gagen_check_span(NY, t0, t1, y0, t_eval, n_eval, y_out);
    if (rc == GAGEN_OK && !(h > 0 && isfinite(h))) rc = GAGEN_ERR_BAD_ARG;
    if (rc == GAGEN_OK) rc = gagen_so_law_init(&law, c);
    if (rc != GAGEN_OK) return gagen_finish(stats, &st, rc, y_out, 0, n_eval, NY);
    span = fabs(t1 - t0);
    nstep_total = gagen_rk4_steps(span, h);
    if (nstep_total == 0)
        return gagen_finish(stats, &st, GAGEN_ERR_BAD_ARG, y_out, 0, n_eval, NY);

    gagen_copy(NY, y0, y);
    ie = gagen_output_exact(NY, t0, y0, t_eval, n_eval, ie, y_out);
    if (span == 0.0) {
        while (ie < n_eval) gagen_copy(NY, y0, y_out + (long)(ie++) * NY);
        return gagen_finish(stats, &st, GAGEN_OK, y_out, ie, n_eval, NY);
    }
    rc = gagen_so_rhs(&law, p, t0, y, k1);
    ++st.nfev;
    if (rc != 0) return gagen_finish(stats, &st, rc, y_out, ie, n_eval, NY);

    t = t0;
    for (k = 0; k < nstep_total; ++k) {
        double t_new = gagen_rk4_step_end(t0, t1, direction, h, k, nstep_total);
        double dt = t_new - t;
        int last = (k + 1 == nstep_total);

        if ((rc = gagen_so_poll(&law, k + 1)) != GAGEN_OK) break;

        for (i = 0; i < NQ; ++i) q2[i] = y[i] + 0.5 * dt * k1[i];
        ++st.nfev;
        if ((rc = gagen_so_position(q2, p, Sa)) != 0) break;
        pending = gagen_so_rk4_stage(&law, p, t + 0.5 * dt, 0.5, 0.5, dt, y, k1, q2, Sa, k2,
                                     q3, Sb);
        ++st.nfev;
        if ((rc = pending) != 0) break;
        pending = gagen_so_rk4_stage(&law, p, t + 0.5 * dt, 0.5, 1.0, dt, y, k2, q3, Sb, k3,
                                     q4, Sa);
        ++st.nfev;
        if ((rc = pending) != 0) break;
        /* y_new's positions need k4's position half, dq/dt at stage 4's state */
        for (i = NQ; i < NY; ++i) k4[i] = y[i] + dt * k3[i];
        gagen_so_qdot(q4, k4 + NQ, k4);
        gagen_rk4_solution(0, NQ, y, dt, k1, k2, k3, k4, y_new);
        pending = gagen_so_rk4_stage(&law, p, t_new, 1.0, 0.0, dt, y, k3, q4, Sa, k4, y_new,
                                     Sb);
        gagen_rk4_solution(NQ, NY, y, dt, k1, k2, k3, k4, y_new);
        ++st.nsteps;
        ++st.naccepted;
        if (!gagen_so_all_finite(y_new, NY)) {
            rc = GAGEN_ERR_NONFINITE;
            break;
        }

        /* f(t_new, y_new) is the next step's k1; on the last step it is only
         * needed for interpolation, so don't spend an evaluation otherwise. */
        if (!last || (ie < n_eval && direction * (t_eval[ie] - t_new) < 0)) {
            ++st.nfev;
            if ((rc = pending) != 0) break;
            gagen_so_derivative(&law, p, t_new, Sb, y_new, f_new);
        }
        ie = gagen_rk4_output(NY, t, t_new, direction, y, k1, y_new, f_new, t_eval, n_eval, ie,
                              y_out);
        swap = y;
        y = y_new;
        y_new = swap;
        swap = k1;
        k1 = f_new;
        f_new = swap;
        t = t_new;
    }
    return gagen_finish(stats, &st, rc, y_out, ie, n_eval, NY);
}

/* The controller's torques at m samples: times t (m), states y (m x (nq + nv)), tau
 * (m x nv). */
static int gagen_so_torques(const gagen_control *c, const double *p, long m, const double *t,
                            const double *y, double *tau)
{
    gagen_so_law law;
    double G[GAGEN_SO_NV];
    long r;
    int i, rc = gagen_so_law_init(&law, c);
    if (rc != GAGEN_OK) return rc;
    for (i = 0; i < GAGEN_SO_NV; ++i) G[i] = 0.0;
    for (r = 0; r < m; ++r) {
        const double *q = y + r * GAGEN_SO_NY;
        if (law.gravity_compensation) gagen_so_gravity(q, p, G);
        gagen_so_control(&law, p, t[r], q, q + GAGEN_SO_NQ, G, tau + r * GAGEN_SO_NV);
    }
    return GAGEN_OK;
}

#endif /* GAGEN_SECOND_ORDER_H */
