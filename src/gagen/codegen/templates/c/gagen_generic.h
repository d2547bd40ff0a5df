/*
 * gagen_generic.h -- gagen's integrators for any ODE dy/dt = f(t, y) given as a function
 * pointer (plain C99, header only): Dormand-Prince 5(4) with scipy's RK45 steps and
 * classical RK4, as static functions. integrator.c makes them gagen_dopri5 and gagen_rk4
 * (integrator.h has the contract); a model's simulation.c includes them for its
 * constrained simulation, so that a model's own C files need no other file of gagen's.
 */
#ifndef GAGEN_GENERIC_H
#define GAGEN_GENERIC_H

#include <float.h>
#include <math.h>
#include <stddef.h>

#include "integrator.h"
#include "gagen_ode.h"

/* ---- Dormand-Prince 5(4), scipy RK45 ---------------------------------- */

/* work: 14 n doubles (K, 7 stages; y, y_new, stage input; dense-output Q, 4 columns) */
static int gagen_generic_dopri5(gagen_ode_fn f, void *ctx, int n, double t0, double t1,
                                const double *y0, double rtol, const double *atol,
                                double first_step, double max_step, long max_steps,
                                const double *t_eval, int n_eval, double *y_out, double *work,
                                gagen_ode_stats *stats)
{
    gagen_ode_stats st = {0, 0, 0, 0, 0};
    double *K, *y, *y_new, *ytmp, *Q, *swap;
    double direction = (t1 != t0) ? (t1 > t0 ? 1.0 : -1.0) : 1.0;
    double t, h_abs, root_n = pow((double)n, 0.5);
    int s, rc, ie = 0;

    rc = gagen_check_span(n, t0, t1, y0, t_eval, n_eval, y_out);
    if (rc == GAGEN_OK && (f == NULL || (n > 0 && work == NULL))) rc = GAGEN_ERR_BAD_ARG;
    if (rc == GAGEN_OK) rc = gagen_dp_check_tolerances(n, &rtol, atol);
    if (rc != GAGEN_OK) return gagen_finish(stats, &st, rc, y_out, 0, n_eval, n);

    if (n == 0) return gagen_finish(stats, &st, GAGEN_OK, y_out, 0, n_eval, n);

    if (!(max_step > 0) || isinf(max_step)) max_step = INFINITY;

    K = work;
    y = work + 7L * n;
    y_new = work + 8L * n;
    ytmp = work + 9L * n;
    Q = work + 10L * n;

    gagen_copy(n, y0, y);
    rc = f(ctx, t0, y, K);
    ++st.nfev;
    if (rc != 0) return gagen_finish(stats, &st, rc, y_out, 0, n_eval, n);

    if (first_step > 0) {
        h_abs = first_step;
    } else if (t1 == t0) {
        h_abs = 0.0;
    } else {
        /* select_initial_step, with ytmp as scale, y_new as y1 and K[1] as f1 */
        double d1, interval = fabs(t1 - t0);
        double h0 = gagen_dp_initial_trial(n, y, K, direction, rtol, atol, interval, ytmp,
                                           y_new, &d1);
        rc = f(ctx, t0 + h0 * direction, y_new, K + n);
        ++st.nfev;
        if (rc != 0) return gagen_finish(stats, &st, rc, y_out, 0, n_eval, n);
        h_abs = gagen_dp_initial_step(n, K, K + n, ytmp, h0, d1, interval, max_step, y_new);
    }

    /* Exact y0 rather than the interpolant at x=0 (scipy gives the same). */
    ie = gagen_output_exact(n, t0, y0, t_eval, n_eval, ie, y_out);

    t = t0;
    while (direction * (t - t1) < 0) {
        double min_step = gagen_dp_min_step(t, direction);
        double h = 0.0, t_new = t;
        int step_rejected = 0;

        h_abs = gagen_dp_clip_step(h_abs, min_step, max_step);

        for (;;) {
            double error_norm;

            rc = gagen_dp_attempt(&h_abs, min_step, &st.nsteps, max_steps, t, t1, direction,
                                  &h, &t_new);
            if (rc != GAGEN_OK) return gagen_finish(stats, &st, rc, y_out, ie, n_eval, n);

            for (s = 1; s < GAGEN_DP_NSTAGES; ++s) {
                gagen_dp_stage_input(n, 0, n, s, K, y, h, ytmp);
                rc = f(ctx, t + gagen_dp_C[s] * h, ytmp, K + (long)s * n);
                ++st.nfev;
                if (rc != 0) return gagen_finish(stats, &st, rc, y_out, ie, n_eval, n);
            }
            gagen_dp_solution(n, 0, n, K, y, h, y_new);
            /* scipy evaluates at t + h, not at the clipped t_new. */
            rc = f(ctx, t + h, y_new, K + (long)GAGEN_DP_NSTAGES * n);
            ++st.nfev;
            if (rc != 0) return gagen_finish(stats, &st, rc, y_out, ie, n_eval, n);

            error_norm = gagen_dp_error_norm(n, K, y, y_new, h, rtol, atol, root_n);
            /* Accepted: write this step's output first.  It does not depend on the pow() of
             * the step-size control, so the processor overlaps the two; the next step has to
             * wait for pow()'s new step size anyway. */
            if (error_norm < 1)
                ie = gagen_dp_dense_output(n, K, y, y_new, t, h, t_new, direction, t_eval,
                                           n_eval, ie, y_out, Q);
            if (gagen_dp_control(error_norm, &step_rejected, &h_abs, &st.nrejected)) break;
        }
        ++st.naccepted;

        /* FSAL: the last stage becomes the first stage of the next step. */
        gagen_copy(n, K + (long)GAGEN_DP_NSTAGES * n, K);
        swap = y;
        y = y_new;
        y_new = swap;
        t = t_new;
    }

    /* Only reachable with points beyond the last step, i.e. t0 == t1. */
    while (ie < n_eval) {
        gagen_copy(n, y, y_out + (long)ie * n);
        ++ie;
    }
    return gagen_finish(stats, &st, GAGEN_OK, y_out, ie, n_eval, n);
}

/* ---- classical RK4 ------------------------------------------------------ */

/* work: 8 n doubles (y, y_new, k1 = f at y, k2, k3, k4, stage input, f at y_new) */
static int gagen_generic_rk4(gagen_ode_fn f, void *ctx, int n, double t0, double t1,
                             const double *y0, double h, const double *t_eval, int n_eval,
                             double *y_out, double *work, gagen_ode_stats *stats)
{
    gagen_ode_stats st = {0, 0, 0, 0, 0};
    double direction = (t1 >= t0) ? 1.0 : -1.0;
    double *y, *y_new, *k1, *k2, *k3, *k4, *ytmp, *f_new, *swap;
    double t, span, dt;
    long nstep_total, k;
    int i, rc, ie = 0;

    rc = gagen_check_span(n, t0, t1, y0, t_eval, n_eval, y_out);
    if (rc == GAGEN_OK && (f == NULL || (n > 0 && work == NULL))) rc = GAGEN_ERR_BAD_ARG;
    if (rc == GAGEN_OK && !(h > 0 && isfinite(h))) rc = GAGEN_ERR_BAD_ARG;
    if (rc != GAGEN_OK) return gagen_finish(stats, &st, rc, y_out, 0, n_eval, n);
    if (n == 0) return gagen_finish(stats, &st, GAGEN_OK, y_out, 0, n_eval, n);

    y = work;
    y_new = work + 1L * n;
    k1 = work + 2L * n;
    k2 = work + 3L * n;
    k3 = work + 4L * n;
    k4 = work + 5L * n;
    ytmp = work + 6L * n;
    f_new = work + 7L * n;

    span = fabs(t1 - t0);
    nstep_total = gagen_rk4_steps(span, h);
    if (nstep_total == 0) return gagen_finish(stats, &st, GAGEN_ERR_BAD_ARG, y_out, 0, n_eval, n);

    gagen_copy(n, y0, y);
    ie = gagen_output_exact(n, t0, y0, t_eval, n_eval, ie, y_out);
    if (span == 0.0) {
        while (ie < n_eval) gagen_copy(n, y0, y_out + (long)(ie++) * n);
        return gagen_finish(stats, &st, GAGEN_OK, y_out, ie, n_eval, n);
    }

    rc = f(ctx, t0, y, k1);
    ++st.nfev;
    if (rc != 0) return gagen_finish(stats, &st, rc, y_out, ie, n_eval, n);

    t = t0;
    for (k = 0; k < nstep_total; ++k) {
        double t_new = gagen_rk4_step_end(t0, t1, direction, h, k, nstep_total);
        int last = (k + 1 == nstep_total);
        dt = t_new - t;

        for (i = 0; i < n; ++i) ytmp[i] = y[i] + 0.5 * dt * k1[i];
        rc = f(ctx, t + 0.5 * dt, ytmp, k2);
        ++st.nfev;
        if (rc != 0) break;
        for (i = 0; i < n; ++i) ytmp[i] = y[i] + 0.5 * dt * k2[i];
        rc = f(ctx, t + 0.5 * dt, ytmp, k3);
        ++st.nfev;
        if (rc != 0) break;
        for (i = 0; i < n; ++i) ytmp[i] = y[i] + dt * k3[i];
        rc = f(ctx, t_new, ytmp, k4);
        ++st.nfev;
        if (rc != 0) break;
        gagen_rk4_solution(0, n, y, dt, k1, k2, k3, k4, y_new);
        ++st.nsteps;
        ++st.naccepted;

        /* f(t_new, y_new) is the next step's k1; on the last step it is only
         * needed for interpolation, so don't spend an evaluation otherwise. */
        if (!last || (ie < n_eval && direction * (t_eval[ie] - t_new) < 0)) {
            rc = f(ctx, t_new, y_new, f_new);
            ++st.nfev;
            if (rc != 0) break;
        }
        ie = gagen_rk4_output(n, t, t_new, direction, y, k1, y_new, f_new, t_eval, n_eval, ie,
                              y_out);

        swap = y;
        y = y_new;
        y_new = swap;
        swap = k1;
        k1 = f_new;
        f_new = swap;
        t = t_new;
    }
    if (rc != 0) return gagen_finish(stats, &st, rc, y_out, ie, n_eval, n);
    return gagen_finish(stats, &st, GAGEN_OK, y_out, ie, n_eval, n);
}

#endif /* GAGEN_GENERIC_H */
