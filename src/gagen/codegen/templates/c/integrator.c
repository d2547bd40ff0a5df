/*
 * gagen: generic ODE integrators (plain C99).  See integrator.h for the contract.
 *
 * The arithmetic lives in gagen_ode.h, shared with the model-specialised second-order
 * integrators of gagen_second_order.h: a transcription of scipy's RK45, so that the
 * step sequence (and therefore nfev and the accept/reject counts) is scipy's. The loops
 * are gagen_generic.h's, which a model's constrained simulation includes too.
 */
#include <float.h>
#include <math.h>
#include <stddef.h>

#include "integrator.h"
#include "gagen_generic.h"

/* ---- Dormand-Prince 5(4), scipy RK45 (gagen_generic.h) ------------------------ */

long gagen_dopri5_work_size(int n)
{
    /* K (7 stages), y, y_new, stage input, dense-output Q (4 columns) */
    return n > 0 ? 14L * n : 0L;
}

int gagen_dopri5(gagen_ode_fn f, void *ctx, int n, double t0, double t1, const double *y0,
                 double rtol, const double *atol, double first_step, double max_step,
                 long max_steps, const double *t_eval, int n_eval, double *y_out,
                 double *work, gagen_ode_stats *stats)
{
    return gagen_generic_dopri5(f, ctx, n, t0, t1, y0, rtol, atol, first_step, max_step,
                                max_steps, t_eval, n_eval, y_out, work, stats);
}

/* ---- classical RK4 (gagen_generic.h) ------------------------------------------ */

long gagen_rk4_work_size(int n)
{
    /* y, y_new, k1 (= f at y), k2, k3, k4, stage input, f at y_new */
    return n > 0 ? 8L * n : 0L;
}

int gagen_rk4(gagen_ode_fn f, void *ctx, int n, double t0, double t1, const double *y0,
              double h, const double *t_eval, int n_eval, double *y_out, double *work,
              gagen_ode_stats *stats)
{
    return gagen_generic_rk4(f, ctx, n, t0, t1, y0, h, t_eval, n_eval, y_out, work, stats);
}
