/*
 * gagen_api.h -- how a model's compiled module hands its kernels to gagen's runtime.
 *
 * A model's extension module (module.c, generated) holds the model's C functions and one
 * table of them, exported as the capsule API ("gagen.model_api" or, for its derivative
 * module, "gagen.derivatives_api"). gagen's runtime (gagen.runtime._native, compiled once
 * when gagen is installed) reads the sizes and calls the kernels through that table: a
 * model's build then compiles the model's own C only, with no Cython and no NumPy.
 *
 * version changes with any change of these structures; the runtime refuses another.
 */
#ifndef GAGEN_API_H
#define GAGEN_API_H

#include "integrator.h"

#define GAGEN_API_VERSION 3

typedef struct {
    int version;                     /* GAGEN_API_VERSION */
    const char *ident;               /* the model's C identifier */
    int nq, nv, nb, nf, np, nreg;    /* sizes: q, qd, bodies, frames, p, regressor columns */
    int err_nonfinite;               /* forward_dynamics's status for a NaN or inf state */
    const double *parameter_defaults;  /* np values */
    void (*mass_matrix)(const double *q, const double *p, double *M);
    void (*forcing)(const double *q, const double *qd, const double *tau, const double *p,
                    double *F);
    int (*forward_dynamics)(const double *q, const double *qd, const double *tau,
                            const double *p, double *qdd);
    void (*inverse_dynamics)(const double *q, const double *qd, const double *qdd,
                             const double *p, double *tau);
    void (*energy)(const double *q, const double *qd, const double *p, double *TV);
    void (*gravity)(const double *q, const double *p, double *G);
    void (*placements)(const double *q, const double *p, double *X);
    void (*frame_offsets)(const double *p, double *F);
    int (*frame_placement)(const double *q, const double *p, int frame, double *R,
                           double *pos);
    int (*frame_jacobian)(const double *q, const double *p, int frame, int reference,
                          double *J);
    int (*frame_velocity)(const double *q, const double *qd, const double *p, int frame,
                          int reference, double *v);
    void (*regressor)(const double *q, const double *qd, const double *qdd, const double *p,
                      double *Y);
    void (*regressor_parameters)(const double *p, double *pi);
    int (*simulate)(int method, const gagen_control *c, const double *p, double t0,
                    double t1, const double *y0, double rtol, const double *atol,
                    double first_step, double max_step, long max_steps, double h,
                    const double *t_eval, int n_eval, double *y_out, gagen_ode_stats *stats);
    int (*control_torques)(const gagen_control *c, const double *p, long m, const double *t,
                           const double *y, double *tau);
    /* centre of mass and centroidal dynamics (centroidal.c) */
    void (*center_of_mass)(const double *q, const double *p, double *com);
    void (*com_velocity)(const double *q, const double *qd, const double *p, double *vcom);
    void (*com_jacobian)(const double *q, const double *p, double *J);
    void (*centroidal_map)(const double *q, const double *p, double *Ag);
    void (*centroidal_momentum)(const double *q, const double *qd, const double *p,
                                double *hg);
    void (*centroidal_map_time_variation)(const double *q, const double *qd, const double *p,
                                          double *dAg);
    void (*centroidal_bias)(const double *q, const double *qd, const double *p, double *b);
    /* task space (frames.c) */
    int (*frame_jacobians)(const double *q, const double *p, int count, const int *frames,
                           int reference, double *J);
    int (*frame_acceleration)(const double *q, const double *qd, const double *qdd,
                              const double *p, int frame, int reference, int kind, double *a);
    int (*frame_jacobian_time_variation)(const double *q, const double *qd, const double *p,
                                         int frame, int reference, double *dJ);
    int (*delassus)(const double *q, const double *p, int count, const int *frames, int dims,
                    double *work, double *G);
    int (*operational_space_inertia)(const double *q, const double *p, int count,
                                     const int *frames, int dims, double *work,
                                     double *Lambda);
} gagen_model_api;

typedef struct {
    int version;                     /* GAGEN_API_VERSION */
    const char *ident;
    int nq, nv, np;
    int err_nonfinite;
    const double *parameter_defaults;
    void (*inverse_dynamics_derivatives)(const double *q, const double *qd, const double *qdd,
                                         const double *p, double *dtau_dq, double *dtau_dqd);
    void (*coriolis_matrix)(const double *q, const double *qd, const double *p, double *C);
    int (*forward_dynamics_derivatives)(const double *q, const double *qd, const double *tau,
                                        const double *p, double *dqdd_dq, double *dqdd_dqd,
                                        double *Minv);
    int (*linearize)(const double *q, const double *qd, const double *tau, const double *p,
                     double *A, double *B);
} gagen_derivatives_api;

#endif /* GAGEN_API_H */
