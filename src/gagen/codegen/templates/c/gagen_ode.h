/*
 * gagen_ode.h -- the arithmetic that gagen's integrators share (plain C99, header only).
 *
 * Two integrators use it: the generic ones of integrator.c (any ODE, through a function
 * pointer, state size known at run time) and the model-specialised second-order ones of
 * gagen_second_order.h (a robot's [q, qd], state size known at compile time, which the
 * compiler then unrolls). Both take exactly the steps of scipy's RK45 because both do the
 * same arithmetic, the functions below: a transcription of scipy/integrate/_ivp/rk.py
 * (RungeKutta._step_impl, rk_step, RkDenseOutput) and common.py (select_initial_step,
 * norm), including the order of floating-point operations where that is cheap.
 *
 * Everything is static inline; the only data are the constant tableaus.
 */
#ifndef GAGEN_ODE_H
#define GAGEN_ODE_H

#include <float.h>
#include <math.h>
#include <stddef.h>

#include "integrator.h"

/* M_PI is POSIX, not C99. */
#define GAGEN_TWO_PI 6.283185307179586476925286766559

/* Python's min()/max() semantics: the first argument wins unless the second
 * compares strictly smaller/larger.  This matters for NaN error norms, which
 * must shrink the step exactly as scipy does. */
static inline double gagen_pymin(double a, double b) { return (b < a) ? b : a; }
static inline double gagen_pymax(double a, double b) { return (b > a) ? b : a; }

/* numpy.maximum propagates NaN (fmax would drop it). */
static inline double gagen_npmaximum(double a, double b)
{
    if (a != a) return a;
    return (a >= b) ? a : b;
}

/* common.norm: ||x|| / sqrt(n), with x given as a/b elementwise. */
static inline double gagen_rms_ratio(int n, const double *a, const double *b)
{
    double s = 0.0;
    int i;
    for (i = 0; i < n; ++i) {
        double r = a[i] / b[i];
        s += r * r;
    }
    return sqrt(s) / pow((double)n, 0.5);
}

static inline void gagen_copy(int n, const double *src, double *dst)
{
    int i;
    for (i = 0; i < n; ++i) dst[i] = src[i];
}

static inline void gagen_fill_nan(double *y_out, int from, int n_eval, int n)
{
    long i;
    if (y_out == NULL) return;
    for (i = (long)from * n; i < (long)n_eval * n; ++i) y_out[i] = NAN;
}

/* The end of every integration: on failure the rows not reached become NaN. */
static inline int gagen_finish(gagen_ode_stats *out, gagen_ode_stats *st, int status,
                               double *y_out, int from, int n_eval, int n)
{
    if (status != GAGEN_OK) gagen_fill_nan(y_out, from, n_eval, n);
    st->status = status;
    if (out != NULL) *out = *st;
    return status;
}

/* Argument checks shared by the integrators.  t_eval must stay inside the interval and be
 * monotone in the integration direction, because output is produced in a single sweep. */
static inline int gagen_check_span(int n, double t0, double t1, const double *y0,
                                   const double *t_eval, int n_eval, const double *y_out)
{
    double lo = (t0 < t1) ? t0 : t1, hi = (t0 < t1) ? t1 : t0;
    double direction = (t1 >= t0) ? 1.0 : -1.0;
    int i;
    if (n < 0 || n_eval < 0) return GAGEN_ERR_BAD_ARG;
    if (!isfinite(t0) || !isfinite(t1)) return GAGEN_ERR_BAD_ARG;
    if (n > 0 && y0 == NULL) return GAGEN_ERR_BAD_ARG;
    if (n_eval > 0 && (t_eval == NULL || (n > 0 && y_out == NULL))) return GAGEN_ERR_BAD_ARG;
    for (i = 0; i < n_eval; ++i) {
        if (!(t_eval[i] >= lo && t_eval[i] <= hi)) return GAGEN_ERR_BAD_ARG;
        if (i > 0 && direction * (t_eval[i] - t_eval[i - 1]) < 0) return GAGEN_ERR_BAD_ARG;
    }
    return GAGEN_OK;
}

/* Rows of y_out for the leading t_eval points equal to t: the exact y. Returns the new ie. */
static inline int gagen_output_exact(int n, double t, const double *y, const double *t_eval,
                                     int n_eval, int ie, double *y_out)
{
    while (ie < n_eval && t_eval[ie] == t) {
        gagen_copy(n, y, y_out + (long)ie * n);
        ++ie;
    }
    return ie;
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

/* The stages K are stored row after row: K[s*n + i] is component i of stage s (7 rows). */

/* validate_tol and the tolerances' own checks; *rtol is raised to 100 eps like scipy. */
static inline int gagen_dp_check_tolerances(int n, double *rtol, const double *atol)
{
    int i;
    if (n > 0 && atol == NULL) return GAGEN_ERR_BAD_ARG;
    if (*rtol != *rtol) return GAGEN_ERR_BAD_ARG;
    for (i = 0; i < n; ++i)
        if (!(atol[i] >= 0)) return GAGEN_ERR_BAD_ARG;
    if (*rtol < 100 * DBL_EPSILON) *rtol = 100 * DBL_EPSILON;
    return GAGEN_OK;
}

/* select_initial_step, first half: the trial step h0 and the point y1 = y0 + h0 f0 at which
 * the caller evaluates f1 (scale, y1 and *d1 are kept for the second half). */
static inline double gagen_dp_initial_trial(int n, const double *y0, const double *f0,
                                            double direction, double rtol, const double *atol,
                                            double interval_length, double *scale, double *y1,
                                            double *d1)
{
    double d0, h0;
    int i;
    for (i = 0; i < n; ++i) scale[i] = atol[i] + fabs(y0[i]) * rtol;
    d0 = gagen_rms_ratio(n, y0, scale);
    *d1 = gagen_rms_ratio(n, f0, scale);
    if (d0 < 1e-5 || *d1 < 1e-5)
        h0 = 1e-6;
    else
        h0 = 0.01 * d0 / *d1;
    h0 = gagen_pymin(h0, interval_length);
    for (i = 0; i < n; ++i) y1[i] = y0[i] + h0 * direction * f0[i];
    return h0;
}

/* select_initial_step, second half, from f1 = f(t0 + h0 direction, y1); y1 is reused. */
static inline double gagen_dp_initial_step(int n, const double *f0, const double *f1,
                                           const double *scale, double h0, double d1,
                                           double interval_length, double max_step,
                                           double *y1)
{
    double d2, h1, h;
    int i;
    for (i = 0; i < n; ++i) y1[i] = f1[i] - f0[i];
    d2 = gagen_rms_ratio(n, y1, scale) / h0;
    if (d1 <= 1e-15 && d2 <= 1e-15)
        h1 = gagen_pymax(1e-6, h0 * 1e-3);
    else
        h1 = pow(0.01 / gagen_pymax(d1, d2), 1.0 / 5.0);
    h = gagen_pymin(100 * h0, h1);
    h = gagen_pymin(h, interval_length);
    return gagen_pymin(h, max_step);
}

/* Input of stage s (1..5), components lo..hi-1: y + (K[:s].T @ A[s][:s]) * h, rk_step's
 * order of operations. */
static inline void gagen_dp_stage_input(int n, int lo, int hi, int s, const double *K,
                                        const double *y, double h, double *out)
{
    int i, j;
    for (i = lo; i < hi; ++i) {
        double acc = 0.0;
        for (j = 0; j < s; ++j) acc += K[(long)j * n + i] * gagen_dp_A[s][j];
        out[i] = y[i] + acc * h;
    }
}

/* The fifth-order solution y + h * (K[:6].T @ B), components lo..hi-1. */
static inline void gagen_dp_solution(int n, int lo, int hi, const double *K, const double *y,
                                     double h, double *y_new)
{
    int i, j;
    for (i = lo; i < hi; ++i) {
        double acc = 0.0;
        for (j = 0; j < GAGEN_DP_NSTAGES; ++j) acc += K[(long)j * n + i] * gagen_dp_B[j];
        y_new[i] = y[i] + h * acc;
    }
}

/* _estimate_error_norm: RMS of (K.T @ E) h / (atol + rtol max(|y|, |y_new|)). */
static inline double gagen_dp_error_norm(int n, const double *K, const double *y,
                                         const double *y_new, double h, double rtol,
                                         const double *atol, double root_n)
{
    double ssq = 0.0;
    int i, j;
    for (i = 0; i < n; ++i) {
        double acc = 0.0, scale, r;
        for (j = 0; j <= GAGEN_DP_NSTAGES; ++j) acc += K[(long)j * n + i] * gagen_dp_E[j];
        scale = atol[i] + gagen_npmaximum(fabs(y[i]), fabs(y_new[i])) * rtol;
        r = (acc * h) / scale;
        ssq += r * r;
    }
    return sqrt(ssq) / root_n;
}

/* The factor of an accepted step's size (error_norm < 1). */
static inline double gagen_dp_accept_factor(double error_norm, int step_rejected)
{
    double factor;
    if (error_norm == 0)
        factor = GAGEN_DP_MAX_FACTOR;
    else
        factor = gagen_pymin(GAGEN_DP_MAX_FACTOR,
                             GAGEN_DP_SAFETY * pow(error_norm, GAGEN_DP_ERROR_EXPONENT));
    return step_rejected ? gagen_pymin(1, factor) : factor;
}

/* The factor of a rejected step's size. */
static inline double gagen_dp_reject_factor(double error_norm)
{
    return gagen_pymax(GAGEN_DP_MIN_FACTOR,
                       GAGEN_DP_SAFETY * pow(error_norm, GAGEN_DP_ERROR_EXPONENT));
}

/* The size of the first attempt of a step from t: h_abs within [min_step, max_step]. */
static inline double gagen_dp_clip_step(double h_abs, double min_step, double max_step)
{
    if (h_abs > max_step) return max_step;
    if (h_abs < min_step) return min_step;
    return h_abs;
}

/* A step attempt from t: GAGEN_OK and its h and t_new (the step cut to end at t1), with
 * h_abs = |h| and one more attempt counted; or the error that ends the integration. */
static inline int gagen_dp_attempt(double *h_abs, double min_step, long *nsteps,
                                   long max_steps, double t, double t1, double direction,
                                   double *h, double *t_new)
{
    if (*h_abs < min_step) return GAGEN_ERR_STEP_TOO_SMALL;
    if (max_steps > 0 && *nsteps >= max_steps) return GAGEN_ERR_MAX_STEPS;
    *h = *h_abs * direction;
    *t_new = t + *h;
    if (direction * (*t_new - t1) > 0) *t_new = t1;
    *h = *t_new - t;
    *h_abs = fabs(*h);
    ++*nsteps;
    return GAGEN_OK;
}

/* Step-size control after an attempt: 1 if it is accepted (error_norm < 1; h_abs becomes the
 * next step's), else 0 and h_abs shrinks for another attempt, counted in nrejected. */
static inline int gagen_dp_control(double error_norm, int *step_rejected, double *h_abs,
                                   long *nrejected)
{
    if (error_norm < 1) {
        *h_abs *= gagen_dp_accept_factor(error_norm, *step_rejected);
        return 1;
    }
    *h_abs *= gagen_dp_reject_factor(error_norm);
    *step_rejected = 1;
    ++*nrejected;
    return 0;
}

/* The smallest step allowed at t, 10 ulp(t) in the direction of integration. */
static inline double gagen_dp_min_step(double t, double direction)
{
    return 10 * fabs(nextafter(t, direction * INFINITY) - t);
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
static inline int gagen_dp_dense_output(int n, const double *K, const double *y,
                                        const double *y_new, double t, double h, double t_new,
                                        double direction, const double *t_eval, int n_eval,
                                        int ie, double *y_out, double *Q)
{
    int i, c;
    if (ie < n_eval && direction * (t_eval[ie] - t_new) < 0) {
        const double *q0 = Q, *q1 = Q + n, *q2 = Q + 2L * n, *q3 = Q + 3L * n;
        for (i = 0; i < n; ++i) {
            double k0 = K[i], k2 = K[2L * n + i], k3 = K[3L * n + i], k4 = K[4L * n + i];
            double k5 = K[5L * n + i], k6 = K[6L * n + i];
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
    return gagen_output_exact(n, t_new, y_new, t_eval, n_eval, ie, y_out);
}

/* ---- classical RK4 ------------------------------------------------------ */

/* The number of steps of size h that cover span: the last one is shortened to land on t1;
 * the tolerance keeps an exact multiple from producing a sliver of a final step.
 * Returns 0 for an impossible count. */
static inline long gagen_rk4_steps(double span, double h)
{
    double steps = ceil(span / h - 1e-9);
    if (steps < 1) steps = 1;
    if (steps > 9.2e18) return 0;
    return (long)steps;
}

/* The end of step k of nstep_total from t0 (grid points t0 + k h, no accumulated drift). */
static inline double gagen_rk4_step_end(double t0, double t1, double direction, double h,
                                        long k, long nstep_total)
{
    return (k + 1 == nstep_total) ? t1 : t0 + direction * (double)(k + 1) * h;
}

/* y + dt/6 (k1 + 2 k2 + 2 k3 + k4), components lo..hi-1. */
static inline void gagen_rk4_solution(int lo, int hi, const double *y, double dt,
                                      const double *k1, const double *k2, const double *k3,
                                      const double *k4, double *y_new)
{
    int i;
    for (i = lo; i < hi; ++i)
        y_new[i] = y[i] + dt / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
}

/* Rows of y_out for t_eval in (t, t_new): the cubic Hermite interpolant of y and f at both
 * ends; then the exact y_new at t_new.  Returns the new ie. */
static inline int gagen_rk4_output(int n, double t, double t_new, double direction,
                                   const double *y, const double *f, const double *y_new,
                                   const double *f_new, const double *t_eval, int n_eval,
                                   int ie, double *y_out)
{
    double dt = t_new - t;
    int i;
    while (ie < n_eval && direction * (t_eval[ie] - t_new) < 0) {
        double s = (t_eval[ie] - t) / dt, s2 = s * s, s3 = s2 * s;
        double h00 = 2 * s3 - 3 * s2 + 1, h10 = s3 - 2 * s2 + s;
        double h01 = -2 * s3 + 3 * s2, h11 = s3 - s2;
        double *yo = y_out + (long)ie * n;
        for (i = 0; i < n; ++i)
            yo[i] = h00 * y[i] + h10 * dt * f[i] + h01 * y_new[i] + h11 * dt * f_new[i];
        ++ie;
    }
    return gagen_output_exact(n, t_new, y_new, t_eval, n_eval, ie, y_out);
}

#endif /* GAGEN_ODE_H */
