/*
 * gagen: generic ODE integrators, and the types of gagen's robot simulations (plain C99).
 *
 * gagen_dopri5 and gagen_rk4 integrate any ODE dy/dt = f(t, y) given as a function
 * pointer.  A generated model's own simulation (<model>_simulate in <model>.h, from
 * simulation.c) runs the same methods, step for step, specialised for the robot's
 * [q, qd] state and its controllers (gagen_control below).
 *
 * Everything here is reentrant: no globals, no static mutable state, no
 * malloc.  The caller provides all scratch memory, so the same code can run
 * inside Python (through Cython) and inside an embedded control loop.
 *
 * Error codes: the integrators return 0 on success.  Their own failures are
 * the negative GAGEN_ERR_* codes below; a nonzero code returned by the
 * right-hand side (or by the model's fd/id) is passed through unchanged, so
 * model code should use positive codes to stay distinguishable.
 */
#ifndef GAGEN_INTEGRATOR_H
#define GAGEN_INTEGRATOR_H

#ifdef __cplusplus
extern "C" {
#endif

#define GAGEN_OK 0
#define GAGEN_ERR_STEP_TOO_SMALL (-101) /* step size fell below 10 ulp(t) */
#define GAGEN_ERR_MAX_STEPS (-102)      /* max_steps step attempts used up */
#define GAGEN_ERR_BAD_ARG (-103)        /* invalid argument (NULL, unsorted t_eval, ...) */
#define GAGEN_ERR_INTERRUPTED (-104)    /* the poll function of a gagen_control said stop */
#define GAGEN_ERR_NONFINITE (-105)      /* the state became NaN or inf */

/* A simulation calls its poll function (if any) every GAGEN_POLL_STEPS steps: often enough
 * to stop within milliseconds, rarely enough to cost nothing measurable. */
#define GAGEN_POLL_STEPS 256
typedef int (*gagen_poll_fn)(void *ctx);

/* Right-hand side dy/dt = f(t, y).  Returns 0 on success, or a nonzero error
 * code that aborts the integration and becomes the integrator's status. */
typedef int (*gagen_ode_fn)(void *ctx, double t, const double *y, double *dydt);

typedef struct {
    long nfev;      /* right-hand side evaluations (same count as scipy's nfev) */
    long nsteps;    /* step attempts = naccepted + nrejected */
    long naccepted; /* accepted steps (scipy: len(sol.t) - 1 without t_eval) */
    long nrejected; /* rejected step attempts */
    int status;     /* same value as the function's return value */
} gagen_ode_stats;

/*
 * Dormand-Prince 5(4) with exactly the step-size control of
 * scipy.integrate.solve_ivp(method="RK45"): same tableau, RMS error norm with
 * scale atol_i + rtol*max(|y_i|, |y_new_i|), SAFETY=0.9, MIN_FACTOR=0.2,
 * MAX_FACTOR=10, error exponent -1/5, growth capped at 1 after a rejection,
 * scipy's select_initial_step when first_step <= 0, FSAL, rtol raised to
 * 100*DBL_EPSILON like scipy.  max_step <= 0 or inf means unbounded.
 * max_steps <= 0 means unlimited step attempts.
 *
 * t1 < t0 integrates backwards.  t_eval must be monotone in the direction of
 * integration and lie within [t0, t1]; values are produced with scipy's RK45
 * dense output (quartic interpolant, scipy's P matrix), except that points
 * coinciding with a step end (including t0 and t1) get the exact step value.
 * y_out is n_eval*n, row-major.  On failure, rows not reached are set to NaN.
 * stats may be NULL.
 */
int gagen_dopri5(gagen_ode_fn f, void *ctx, int n, double t0, double t1, const double *y0,
                 double rtol, const double *atol, double first_step, double max_step,
                 long max_steps, const double *t_eval, int n_eval, double *y_out,
                 double *work, gagen_ode_stats *stats);
long gagen_dopri5_work_size(int n); /* in doubles */

/*
 * Classical fixed-step RK4 with step h > 0 (direction taken from t1 - t0);
 * the last step is shortened to land exactly on t1.  Values at t_eval are
 * cubic Hermite interpolants over the containing step (y and f at both ends),
 * which keeps the output fourth-order accurate.
 */
int gagen_rk4(gagen_ode_fn f, void *ctx, int n, double t0, double t1, const double *y0,
              double h, const double *t_eval, int n_eval, double *y_out, double *work,
              gagen_ode_stats *stats);
long gagen_rk4_work_size(int n); /* in doubles */

/* ---- robot controllers ------------------------------------------------ */

#define GAGEN_CTRL_NONE 0
#define GAGEN_CTRL_PD 1
#define GAGEN_CTRL_COMPUTED_TORQUE 2

/* The integration methods of <model>_simulate. */
#define GAGEN_METHOD_DOPRI5 0
#define GAGEN_METHOD_RK4 1

/*
 * A feedback law tau(t, q, qd) of a robot with n coordinates:
 *   GAGEN_CTRL_NONE:  tau = 0
 *   GAGEN_CTRL_PD:    tau = -kp*(q - target) - kd*qd [+ g(q), the gravity torques]
 *   GAGEN_CTRL_COMPUTED_TORQUE:
 *                     tau = id(q, qd, qdd_r + kd*(qd_r - qd) + kp*(q_r - q)), with
 *                     (q_r, qd_r, qdd_r) the eq. 11 motion from traj_q0 to traj_qf in traj_Tp
 * The arrays have n entries; a NULL gain or target means zero.
 */
typedef struct {
    int kind;                 /* GAGEN_CTRL_* */
    const double *kp, *kd;    /* per-joint gains */
    const double *target;     /* PD target q */
    int gravity_compensation; /* PD: add g(q) when nonzero */
    const double *traj_q0, *traj_qf;
    double traj_Tp;
    /* Optional (NULL: never): called every GAGEN_POLL_STEPS steps of a simulation; a
     * nonzero return stops it with GAGEN_ERR_INTERRUPTED (Python's Ctrl-C uses this). */
    gagen_poll_fn poll;
    void *poll_ctx;
    /* Optional (NULL: zeros): PD's constant feed-forward torques, added to its output */
    const double *feedforward;
    /* Optional (0: none): constant wrenches on frames, (force, torque) in world axes at the
     * frames' origins, wrenches[6 k .. 6 k + 5] on frame frames[k]; their generalised force
     * J^T w acts with the controller's torques (and is not part of them) */
    int nframes;
    const int *frames;
    const double *wrenches;
} gagen_control;

#ifdef __cplusplus
}
#endif

#endif /* GAGEN_INTEGRATOR_H */
