/*
 * gagen: generic ODE integrators and robot controllers (plain C99).
 * See integrator.h for the contract.
 *
 * The Dormand-Prince integrator is a line-by-line transcription of
 * scipy/integrate/_ivp/rk.py (RungeKutta._step_impl, rk_step, RkDenseOutput)
 * and common.py (select_initial_step, norm, validate_tol), including the
 * order of floating-point operations where that is cheap, so that the step
 * sequence (and therefore nfev and the accept/reject counts) is identical.
 */
#include <float.h>
#include <limits.h>
#include <math.h>
#include <stddef.h>

#include "integrator.h"

/* M_PI is POSIX, not C99. */
#define GAGEN_TWO_PI 6.283185307179586476925286766559

/* Python's min()/max() semantics: the first argument wins unless the second
 * compares strictly smaller/larger.  This matters for NaN error norms, which
 * must shrink the step exactly as scipy does. */
static double gagen_pymin(double a, double b) { return (b < a) ? b : a; }
static double gagen_pymax(double a, double b) { return (b > a) ? b : a; }

/* numpy.maximum propagates NaN (fmax would drop it). */
static double gagen_npmaximum(double a, double b)
{
    if (a != a) return a;
    return (a >= b) ? a : b;
}

/* common.norm: ||x|| / sqrt(n), with x given as a/b elementwise. */
static double gagen_rms_ratio(int n, const double *a, const double *b)
{
    double s = 0.0;
    int i;
    for (i = 0; i < n; ++i) {
        double r = a[i] / b[i];
        s += r * r;
    }
    return sqrt(s) / pow((double)n, 0.5);
}

static void gagen_fill_nan(double *y_out, int from, int n_eval, int n)
{
    long i;
    if (y_out == NULL) return;
    for (i = (long)from * n; i < (long)n_eval * n; ++i) y_out[i] = NAN;
}

static void gagen_copy(int n, const double *src, double *dst)
{
    int i;
    for (i = 0; i < n; ++i) dst[i] = src[i];
}

static int gagen_finish(gagen_ode_stats *out, gagen_ode_stats *st, int status,
                        double *y_out, int from, int n_eval, int n)
{
    if (status != GAGEN_OK) gagen_fill_nan(y_out, from, n_eval, n);
    st->status = status;
    if (out != NULL) *out = *st;
    return status;
}

/* Shared argument checks for both integrators.  t_eval must stay inside the
 * interval and be monotone in the integration direction, because output is
 * produced in a single forward sweep. */
static int gagen_check_common(gagen_ode_fn f, int n, double t0, double t1, const double *y0,
                              const double *t_eval, int n_eval, double *y_out, double *work)
{
    double lo = (t0 < t1) ? t0 : t1, hi = (t0 < t1) ? t1 : t0;
    double direction = (t1 >= t0) ? 1.0 : -1.0;
    int i;
    if (f == NULL || n < 0 || n_eval < 0) return GAGEN_ERR_BAD_ARG;
    if (!isfinite(t0) || !isfinite(t1)) return GAGEN_ERR_BAD_ARG;
    if (n > 0 && (y0 == NULL || work == NULL)) return GAGEN_ERR_BAD_ARG;
    if (n_eval > 0 && (t_eval == NULL || (n > 0 && y_out == NULL))) return GAGEN_ERR_BAD_ARG;
    for (i = 0; i < n_eval; ++i) {
        if (!(t_eval[i] >= lo && t_eval[i] <= hi)) return GAGEN_ERR_BAD_ARG;
        if (i > 0 && direction * (t_eval[i] - t_eval[i - 1]) < 0) return GAGEN_ERR_BAD_ARG;
    }
    return GAGEN_OK;
}

/* ---- Dormand-Prince 5(4), scipy RK45 ---------------------------------- */

#define GAGEN_DP_NSTAGES 6

static const double gagen_dp_C[GAGEN_DP_NSTAGES] = {0.0, 1.0 / 5, 3.0 / 10, 4.0 / 5, 8.0 / 9,
                                                    1.0};
static const double gagen_dp_A[GAGEN_DP_NSTAGES][GAGEN_DP_NSTAGES - 1] = {
    {0.0, 0.0, 0.0, 0.0, 0.0},
    {1.0 / 5, 0.0, 0.0, 0.0, 0.0},
    {3.0 / 40, 9.0 / 40, 0.0, 0.0, 0.0},
    {44.0 / 45, -56.0 / 15, 32.0 / 9, 0.0, 0.0},
    {19372.0 / 6561, -25360.0 / 2187, 64448.0 / 6561, -212.0 / 729, 0.0},
    {9017.0 / 3168, -355.0 / 33, 46732.0 / 5247, 49.0 / 176, -5103.0 / 18656}};
static const double gagen_dp_B[GAGEN_DP_NSTAGES] = {35.0 / 384,     0.0,          500.0 / 1113,
                                                    125.0 / 192,    -2187.0 / 6784, 11.0 / 84};
static const double gagen_dp_E[GAGEN_DP_NSTAGES + 1] = {
    -71.0 / 57600, 0.0, 71.0 / 16695, -71.0 / 1920, 17253.0 / 339200, -22.0 / 525, 1.0 / 40};
/* Shampine's quartic dense output with the optimum c_6, as in scipy's RK45.P
 * (rows: stages, columns: coefficients of x, x^2, x^3, x^4). */
static const double gagen_dp_P[GAGEN_DP_NSTAGES + 1][4] = {
    {1.0, -8048581381.0 / 2820520608, 8663915743.0 / 2820520608,
     -12715105075.0 / 11282082432},
    {0.0, 0.0, 0.0, 0.0},
    {0.0, 131558114200.0 / 32700410799, -68118460800.0 / 10900136933,
     87487479700.0 / 32700410799},
    {0.0, -1754552775.0 / 470086768, 14199869525.0 / 1410260304,
     -10690763975.0 / 1880347072},
    {0.0, 127303824393.0 / 49829197408, -318862633887.0 / 49829197408,
     701980252875.0 / 199316789632},
    {0.0, -282668133.0 / 205662961, 2019193451.0 / 616988883, -1453857185.0 / 822651844},
    {0.0, 40617522.0 / 29380423, -110615467.0 / 29380423, 69997945.0 / 29380423}};

#define GAGEN_DP_SAFETY 0.9
#define GAGEN_DP_MIN_FACTOR 0.2
#define GAGEN_DP_MAX_FACTOR 10.0
/* -1 / (error_estimator_order + 1) with error_estimator_order = 4 */
#define GAGEN_DP_ERROR_EXPONENT (-1.0 / 5.0)

long gagen_dopri5_work_size(int n)
{
    /* K (7 stages), y, y_new, stage input, dense-output Q (4 columns) */
    return n > 0 ? 14L * n : 0L;
}

/* common.select_initial_step; f1 and y1 are scratch vectors. */
static int gagen_dp_initial_step(gagen_ode_fn f, void *ctx, int n, double t0, const double *y0,
                                 double t_bound, double max_step, const double *f0,
                                 double direction, double rtol, const double *atol,
                                 double *scale, double *y1, double *f1, long *nfev,
                                 double *h_out)
{
    double interval_length = fabs(t_bound - t0);
    double d0, d1, d2, h0, h1, h;
    int i, rc;

    if (interval_length == 0.0) {
        *h_out = 0.0;
        return GAGEN_OK;
    }
    for (i = 0; i < n; ++i) scale[i] = atol[i] + fabs(y0[i]) * rtol;
    d0 = gagen_rms_ratio(n, y0, scale);
    d1 = gagen_rms_ratio(n, f0, scale);
    if (d0 < 1e-5 || d1 < 1e-5)
        h0 = 1e-6;
    else
        h0 = 0.01 * d0 / d1;
    h0 = gagen_pymin(h0, interval_length);
    for (i = 0; i < n; ++i) y1[i] = y0[i] + h0 * direction * f0[i];
    rc = f(ctx, t0 + h0 * direction, y1, f1);
    ++*nfev;
    if (rc != 0) return rc;
    for (i = 0; i < n; ++i) y1[i] = f1[i] - f0[i]; /* reuse y1 for the difference */
    d2 = gagen_rms_ratio(n, y1, scale) / h0;
    if (d1 <= 1e-15 && d2 <= 1e-15)
        h1 = gagen_pymax(1e-6, h0 * 1e-3);
    else
        h1 = pow(0.01 / gagen_pymax(d1, d2), 1.0 / 5.0);
    h = gagen_pymin(100 * h0, h1);
    h = gagen_pymin(h, interval_length);
    h = gagen_pymin(h, max_step);
    *h_out = h;
    return GAGEN_OK;
}

/* Output after the accepted step from (t, y) to (t_new, y_new), h = t_new - t, as
 * solve_ivp writes it after each step: the rows of y_out for t_eval in (t, t_new) from
 * scipy's dense output (RkDenseOutput), then the exact y_new for t_eval == t_new.
 * Returns the new ie.
 *
 * Q = K.T @ P is stored by columns, Q[c*n + i], so that the evaluation loop runs over
 * contiguous memory, and built in one pass over the elements, each sum in np.dot's
 * order.  The zero entries of P (row 1, and column 0 below row 0) are skipped: after an
 * accepted step every K[s][i] is finite (a non-finite one makes the error norm NaN or
 * inf, which rejects the step), so those terms are exact zeros and leave the sums
 * unchanged (a sum started at +0.0 never becomes -0.0). */
static int gagen_dp_dense_output(int n, double *const K[GAGEN_DP_NSTAGES + 1],
                                 const double *y, const double *y_new, double t, double h,
                                 double t_new, double direction, const double *t_eval,
                                 int n_eval, int ie, double *y_out, double *restrict Q)
{
    int i, c;
    if (ie < n_eval && direction * (t_eval[ie] - t_new) < 0) {
        const double *q0 = Q, *q1 = Q + n, *q2 = Q + 2L * n, *q3 = Q + 3L * n;
        for (i = 0; i < n; ++i) {
            double k0 = K[0][i], k2 = K[2][i], k3 = K[3][i], k4 = K[4][i], k5 = K[5][i];
            double k6 = K[6][i];
            Q[i] = 0.0 + k0 * gagen_dp_P[0][0];
            for (c = 1; c < 4; ++c) {
                double acc = 0.0 + k0 * gagen_dp_P[0][c];
                acc += k2 * gagen_dp_P[2][c];
                acc += k3 * gagen_dp_P[3][c];
                acc += k4 * gagen_dp_P[4][c];
                acc += k5 * gagen_dp_P[5][c];
                Q[(long)c * n + i] = acc + k6 * gagen_dp_P[6][c];
            }
        }
        do {
            double x = (t_eval[ie] - t) / h;
            double p0 = x, p1 = p0 * x, p2 = p1 * x, p3 = p2 * x;
            double *yo = y_out + (long)ie * n;
            for (i = 0; i < n; ++i)
                yo[i] = y[i] + h * (q0[i] * p0 + q1[i] * p1 + q2[i] * p2 + q3[i] * p3);
            ++ie;
        } while (ie < n_eval && direction * (t_eval[ie] - t_new) < 0);
    }
    /* Exact step value at the step end (in particular at t1). */
    while (ie < n_eval && t_eval[ie] == t_new) {
        gagen_copy(n, y_new, y_out + (long)ie * n);
        ++ie;
    }
    return ie;
}

int gagen_dopri5(gagen_ode_fn f, void *ctx, int n, double t0, double t1, const double *y0,
                 double rtol, const double *atol, double first_step, double max_step,
                 long max_steps, const double *t_eval, int n_eval, double *y_out,
                 double *work, gagen_ode_stats *stats)
{
    gagen_ode_stats st = {0, 0, 0, 0, 0};
    double *K[GAGEN_DP_NSTAGES + 1], *y, *y_new, *ytmp, *Q, *swap;
    double direction = (t1 != t0) ? (t1 > t0 ? 1.0 : -1.0) : 1.0;
    double t, h_abs, root_n = pow((double)n, 0.5);
    int i, j, s, rc, ie = 0;

    rc = gagen_check_common(f, n, t0, t1, y0, t_eval, n_eval, y_out, work);
    if (rc == GAGEN_OK && n > 0 && atol == NULL) rc = GAGEN_ERR_BAD_ARG;
    if (rc == GAGEN_OK && rtol != rtol) rc = GAGEN_ERR_BAD_ARG;
    for (i = 0; rc == GAGEN_OK && i < n; ++i)
        if (!(atol[i] >= 0)) rc = GAGEN_ERR_BAD_ARG;
    if (rc != GAGEN_OK) return gagen_finish(stats, &st, rc, y_out, 0, n_eval, n);

    if (n == 0) return gagen_finish(stats, &st, GAGEN_OK, y_out, 0, n_eval, n);

    /* validate_tol */
    if (rtol < 100 * DBL_EPSILON) rtol = 100 * DBL_EPSILON;
    if (!(max_step > 0) || isinf(max_step)) max_step = INFINITY;

    for (s = 0; s <= GAGEN_DP_NSTAGES; ++s) K[s] = work + (long)s * n;
    y = work + 7L * n;
    y_new = work + 8L * n;
    ytmp = work + 9L * n;
    Q = work + 10L * n;

    gagen_copy(n, y0, y);
    rc = f(ctx, t0, y, K[0]);
    ++st.nfev;
    if (rc != 0) return gagen_finish(stats, &st, rc, y_out, 0, n_eval, n);

    if (first_step > 0) {
        h_abs = first_step;
    } else {
        rc = gagen_dp_initial_step(f, ctx, n, t0, y, t1, max_step, K[0], direction, rtol, atol,
                                   ytmp, y_new, K[1], &st.nfev, &h_abs);
        if (rc != 0) return gagen_finish(stats, &st, rc, y_out, 0, n_eval, n);
    }

    /* Exact y0 rather than the interpolant at x=0 (scipy gives the same). */
    while (ie < n_eval && t_eval[ie] == t0) {
        gagen_copy(n, y0, y_out + (long)ie * n);
        ++ie;
    }

    t = t0;
    while (direction * (t - t1) < 0) {
        double min_step = 10 * fabs(nextafter(t, direction * INFINITY) - t);
        double h = 0.0, t_new = t;
        int step_rejected = 0;

        if (h_abs > max_step)
            h_abs = max_step;
        else if (h_abs < min_step)
            h_abs = min_step;

        for (;;) {
            double error_norm, ssq = 0.0;

            if (h_abs < min_step)
                return gagen_finish(stats, &st, GAGEN_ERR_STEP_TOO_SMALL, y_out, ie, n_eval, n);
            if (max_steps > 0 && st.nsteps >= max_steps)
                return gagen_finish(stats, &st, GAGEN_ERR_MAX_STEPS, y_out, ie, n_eval, n);

            h = h_abs * direction;
            t_new = t + h;
            if (direction * (t_new - t1) > 0) t_new = t1;
            h = t_new - t;
            h_abs = fabs(h);
            ++st.nsteps;

            /* rk_step: dy = (K[:s].T @ a[:s]) * h */
            for (s = 1; s < GAGEN_DP_NSTAGES; ++s) {
                for (i = 0; i < n; ++i) {
                    double acc = 0.0;
                    for (j = 0; j < s; ++j) acc += K[j][i] * gagen_dp_A[s][j];
                    ytmp[i] = y[i] + acc * h;
                }
                rc = f(ctx, t + gagen_dp_C[s] * h, ytmp, K[s]);
                ++st.nfev;
                if (rc != 0) return gagen_finish(stats, &st, rc, y_out, ie, n_eval, n);
            }
            for (i = 0; i < n; ++i) {
                double acc = 0.0;
                for (j = 0; j < GAGEN_DP_NSTAGES; ++j) acc += K[j][i] * gagen_dp_B[j];
                y_new[i] = y[i] + h * acc;
            }
            /* scipy evaluates at t + h, not at the clipped t_new. */
            rc = f(ctx, t + h, y_new, K[GAGEN_DP_NSTAGES]);
            ++st.nfev;
            if (rc != 0) return gagen_finish(stats, &st, rc, y_out, ie, n_eval, n);

            for (i = 0; i < n; ++i) {
                double acc = 0.0, scale, r;
                for (j = 0; j <= GAGEN_DP_NSTAGES; ++j) acc += K[j][i] * gagen_dp_E[j];
                scale = atol[i] + gagen_npmaximum(fabs(y[i]), fabs(y_new[i])) * rtol;
                r = (acc * h) / scale;
                ssq += r * r;
            }
            error_norm = sqrt(ssq) / root_n;

            if (error_norm < 1) {
                double factor;
                /* Accepted: write this step's output first.  It does not depend on the
                 * pow() below, so the processor overlaps the two; the next step has to
                 * wait for pow()'s new step size anyway. */
                ie = gagen_dp_dense_output(n, K, y, y_new, t, h, t_new, direction, t_eval,
                                           n_eval, ie, y_out, Q);
                if (error_norm == 0)
                    factor = GAGEN_DP_MAX_FACTOR;
                else
                    factor = gagen_pymin(GAGEN_DP_MAX_FACTOR, GAGEN_DP_SAFETY *
                                         pow(error_norm, GAGEN_DP_ERROR_EXPONENT));
                if (step_rejected) factor = gagen_pymin(1, factor);
                h_abs *= factor;
                break;
            }
            h_abs *= gagen_pymax(GAGEN_DP_MIN_FACTOR,
                                 GAGEN_DP_SAFETY * pow(error_norm, GAGEN_DP_ERROR_EXPONENT));
            step_rejected = 1;
            ++st.nrejected;
        }
        ++st.naccepted;

        /* FSAL: the last stage becomes the first stage of the next step. */
        swap = K[0];
        K[0] = K[GAGEN_DP_NSTAGES];
        K[GAGEN_DP_NSTAGES] = swap;
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

long gagen_rk4_work_size(int n)
{
    /* y, y_new, k1 (= f at y), k2, k3, k4, stage input, f at y_new */
    return n > 0 ? 8L * n : 0L;
}

int gagen_rk4(gagen_ode_fn f, void *ctx, int n, double t0, double t1, const double *y0,
              double h, const double *t_eval, int n_eval, double *y_out, double *work,
              gagen_ode_stats *stats)
{
    gagen_ode_stats st = {0, 0, 0, 0, 0};
    double direction = (t1 >= t0) ? 1.0 : -1.0;
    double *y, *y_new, *k1, *k2, *k3, *k4, *ytmp, *f_new, *swap;
    double t, span, dt;
    long nstep_total, k;
    int i, rc, ie = 0;

    rc = gagen_check_common(f, n, t0, t1, y0, t_eval, n_eval, y_out, work);
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

    /* Grid points are t0 + k*h (no accumulated drift); the tolerance keeps an
     * exact multiple from producing a spurious sliver of a final step. */
    span = fabs(t1 - t0);
    {
        double steps = ceil(span / h - 1e-9);
        if (steps < 1) steps = 1;
        if (steps > (double)LONG_MAX)
            return gagen_finish(stats, &st, GAGEN_ERR_BAD_ARG, y_out, 0, n_eval, n);
        nstep_total = (long)steps;
    }

    gagen_copy(n, y0, y);
    while (ie < n_eval && t_eval[ie] == t0) {
        gagen_copy(n, y0, y_out + (long)ie * n);
        ++ie;
    }
    if (span == 0.0) {
        while (ie < n_eval) gagen_copy(n, y0, y_out + (long)(ie++) * n);
        return gagen_finish(stats, &st, GAGEN_OK, y_out, ie, n_eval, n);
    }

    rc = f(ctx, t0, y, k1);
    ++st.nfev;
    if (rc != 0) return gagen_finish(stats, &st, rc, y_out, ie, n_eval, n);

    t = t0;
    for (k = 0; k < nstep_total; ++k) {
        double t_new = (k + 1 == nstep_total) ? t1 : t0 + direction * (double)(k + 1) * h;
        int last = (k + 1 == nstep_total);
        int need_interp;
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
        for (i = 0; i < n; ++i)
            y_new[i] = y[i] + dt / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
        ++st.nsteps;
        ++st.naccepted;

        need_interp = (ie < n_eval && direction * (t_eval[ie] - t_new) < 0);
        /* f(t_new, y_new) is the next step's k1; on the last step it is only
         * needed for interpolation, so don't spend an evaluation otherwise. */
        if (!last || need_interp) {
            rc = f(ctx, t_new, y_new, f_new);
            ++st.nfev;
            if (rc != 0) break;
        }
        while (ie < n_eval && direction * (t_eval[ie] - t_new) < 0) {
            double s = (t_eval[ie] - t) / dt, s2 = s * s, s3 = s2 * s;
            double h00 = 2 * s3 - 3 * s2 + 1, h10 = s3 - 2 * s2 + s;
            double h01 = -2 * s3 + 3 * s2, h11 = s3 - s2;
            double *yo = y_out + (long)ie * n;
            for (i = 0; i < n; ++i)
                yo[i] = h00 * y[i] + h10 * dt * k1[i] + h01 * y_new[i] + h11 * dt * f_new[i];
            ++ie;
        }
        while (ie < n_eval && t_eval[ie] == t_new) {
            gagen_copy(n, y_new, y_out + (long)ie * n);
            ++ie;
        }

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

/* ---- robot controllers ------------------------------------------------ */

void gagen_eq11(const double *q0, const double *qf, double Tp, int n, double t, double *q,
                double *qd, double *qdd)
{
    int i;
    if (t < 0 || !(Tp > 0) || t > Tp) {
        const double *hold = (t < 0) ? q0 : qf;
        for (i = 0; i < n; ++i) {
            q[i] = hold[i];
            if (qd != NULL) qd[i] = 0.0;
            if (qdd != NULL) qdd[i] = 0.0;
        }
        return;
    }
    {
        double w = GAGEN_TWO_PI / Tp;
        double sn = sin(w * t), cs = cos(w * t);
        for (i = 0; i < n; ++i) {
            double slope = (qf[i] - q0[i]) / Tp;
            q[i] = q0[i] + slope * (t - sn / w);
            if (qd != NULL) qd[i] = slope * (1.0 - cs);
            if (qdd != NULL) qdd[i] = slope * w * sn;
        }
    }
}

long gagen_robot_scratch_size(int n) { return n > 0 ? 4L * n : 0L; }

/* -kp*(q - target) - kd*qd for joint i */
static double gagen_pd_feedback(const gagen_robot_ctx *c, int i, const double *q,
                                const double *qd)
{
    double kp = c->kp ? c->kp[i] : 0.0, kd = c->kd ? c->kd[i] : 0.0;
    double target = c->target ? c->target[i] : 0.0;
    return -kp * (q[i] - target) - kd * qd[i];
}

int gagen_controller_torque(gagen_robot_ctx *c, double t, const double *q, const double *qd,
                            double *tau)
{
    int i, n;
    double *w1, *w2, *w3;
    if (c == NULL || q == NULL || qd == NULL || tau == NULL || c->n < 0) return GAGEN_ERR_BAD_ARG;
    n = c->n;
    if (c->kind == GAGEN_CTRL_NONE) {
        for (i = 0; i < n; ++i) tau[i] = 0.0;
        return GAGEN_OK;
    }
    if (c->scratch == NULL) return GAGEN_ERR_BAD_ARG;
    /* scratch[0..n) is left to the caller (gagen_robot_rhs keeps tau there). */
    w1 = c->scratch + n;
    w2 = c->scratch + 2L * n;
    w3 = c->scratch + 3L * n;

    switch (c->kind) {

    case GAGEN_CTRL_PD: {
        int rc;
        if (c->gravity_compensation) {
            if (c->gravity != NULL) {
                rc = c->gravity(q, c->p, w2);
            } else {
                if (c->id == NULL) return GAGEN_ERR_BAD_ARG;
                for (i = 0; i < n; ++i) w1[i] = 0.0;
                /* Gravity torque = id(q, qd=0, qdd=0); one zero vector serves both. */
                rc = c->id(q, w1, w1, c->p, w2);
            }
            if (rc != 0) return rc;
        }
        for (i = 0; i < n; ++i) {
            tau[i] = gagen_pd_feedback(c, i, q, qd);
            if (c->gravity_compensation) tau[i] += w2[i];
        }
        return GAGEN_OK;
    }

    case GAGEN_CTRL_COMPUTED_TORQUE:
        if (c->id == NULL || c->traj_q0 == NULL || c->traj_qf == NULL) return GAGEN_ERR_BAD_ARG;
        gagen_eq11(c->traj_q0, c->traj_qf, c->traj_Tp, n, t, w1, w2, w3);
        for (i = 0; i < n; ++i) {
            double kp = c->kp ? c->kp[i] : 0.0, kd = c->kd ? c->kd[i] : 0.0;
            w3[i] = w3[i] + kd * (w2[i] - qd[i]) + kp * (w1[i] - q[i]);
        }
        return c->id(q, qd, w3, c->p, tau);

    default:
        return GAGEN_ERR_BAD_ARG;
    }
}

/* PD plus gravity compensation through fd_gc, which adds g(q) from its own pass over the
 * model: tau = PD + g(q) and F + tau are formed in the same order as on the general path. */
static int gagen_pd_gravity_rhs(gagen_robot_ctx *c, const double *q, const double *qd,
                                double *dydt)
{
    int i, n = c->n;
    double *u = c->scratch;
    for (i = 0; i < n; ++i) {
        u[i] = gagen_pd_feedback(c, i, q, qd);
        dydt[i] = qd[i];
    }
    return c->fd_gc(q, qd, u, c->p, dydt + n);
}

int gagen_robot_rhs(void *ctx, double t, const double *y, double *dydt)
{
    gagen_robot_ctx *c = (gagen_robot_ctx *)ctx;
    const double *q, *qd;
    double *tau;
    int i, n, rc;
    if (c == NULL || c->fd == NULL || c->scratch == NULL) return GAGEN_ERR_BAD_ARG;
    n = c->n;
    q = y;
    qd = y + n;
    if (c->fd_gc != NULL && c->kind == GAGEN_CTRL_PD && c->gravity_compensation)
        return gagen_pd_gravity_rhs(c, q, qd, dydt);
    tau = c->scratch;
    rc = gagen_controller_torque(c, t, q, qd, tau);
    if (rc != 0) return rc;
    for (i = 0; i < n; ++i) dydt[i] = qd[i];
    return c->fd(q, qd, tau, c->p, dydt + n);
}
