/*
 * gagen_math.h -- fast, accurate inline sin/cos for gagen's generated C kernels.
 *
 * Why: the generated equation-of-motion kernels take sin and cos of every joint
 * angle, and glibc's sincos (~10 ns a call) was about 20 % of a kernel's run
 * time.  This inline code has no call, no table and no global or static data,
 * and is about twice as fast for joint-like arguments (|x| < 10 rad): 6.0 vs
 * 11.5 ns per sin+cos pair with gcc -O3 for baseline x86-64 (4.6 ns with
 * -march=x86-64-v3), on an AMD EPYC.
 *
 * Accuracy guarantee: for finite |x| < GAGEN_TRIG_MAX = 2^20 each result is
 * within 1 ulp of the correctly rounded sin/cos (largest error measured against
 * mpmath: 0.80 ulp, on 300000 random and all the hardest-to-reduce arguments;
 * see tests/test_fast_trig.py); sin(+-0) = +-0 and cos(+-0) = 1.  For |x| >= 2^20
 * and for inf and nan, libm's sin() and cos() are called, so those results are
 * libm's (nan for inf and nan).
 *
 * gagen_sin(x) and gagen_cos(x) return bit for bit the outputs of
 * gagen_sincos(x, ...): they are the same code, whose common path is
 * straight-line, so when both are inlined on the same x the compiler computes
 * the reduction and the polynomials once (checked with GCC 12, -O2 and -O3,
 * also with other calls in between).
 * gagen_sin alone costs about as much as gagen_sincos: the branch-free quadrant
 * selection needs both polynomials.
 *
 * Method (fdlibm / FreeBSD msun, as in musl): n = rint(x * 2/pi) and
 * x - n*pi/2 = y0 + y1 by Cody-Waite reduction with pi/2 split into 33-bit
 * parts (fdlibm's __ieee754_rem_pio2 "medium" case); as |n| < 2^20 every
 * product n*pio2_k is exact.  The common path does one round (85 bits); x within
 * 2^-16 (relative) of a multiple of pi/2 takes a rarely used path with up to
 * three rounds (151 bits, enough for every double below 2^20 * pi/2).  Then the
 * fdlibm kernels __kernel_sin and (FreeBSD's branch-free) __kernel_cos on
 * [-pi/4, pi/4], in Estrin form, and a branch-free choice of quadrant.
 *
 * Requirements: IEEE-754 binary64 arithmetic evaluated in double precision
 * (FLT_EVAL_METHOD == 0, e.g. SSE2 on x86-64, or AArch64), round-to-nearest,
 * and no value-changing optimisation: -ffast-math / -Ofast (-fassociative-math)
 * would cancel the rint trick and the error-compensation terms, so where
 * __FAST_MATH__ is defined or FLT_EVAL_METHOD != 0 the functions just call
 * libm.  Contraction into fused multiply-adds (e.g. GNU C with
 * -march=x86-64-v3) is harmless.  Plain C99, also valid C++; link with -lm.
 */
/*
 * The polynomial coefficients, the split of pi/2 and the structure of the
 * reduction and kernels are fdlibm's:
 *
 * ====================================================
 * Copyright (C) 1993 by Sun Microsystems, Inc. All rights reserved.
 *
 * Developed at SunSoft, a Sun Microsystems, Inc. business.
 * Permission to use, copy, modify, and distribute this
 * software is freely granted, provided that this notice
 * is preserved.
 * ====================================================
 */
#ifndef GAGEN_MATH_H
#define GAGEN_MATH_H

#include <float.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

/* sin/cos are computed inline for |x| < GAGEN_TRIG_MAX, by libm otherwise. */
#define GAGEN_TRIG_MAX 1048576.0                       /* 2^20 */

#if defined(__GNUC__) || defined(__clang__)
#define GAGEN_TRIG_INLINE static inline __attribute__((always_inline))
#define GAGEN_TRIG_COLD static __attribute__((noinline, cold, unused))
#define GAGEN_TRIG_UNLIKELY(c) __builtin_expect(!!(c), 0)
#else
#define GAGEN_TRIG_INLINE static inline
#define GAGEN_TRIG_COLD static inline
#define GAGEN_TRIG_UNLIKELY(c) (c)
#endif

#if (defined(FLT_EVAL_METHOD) && FLT_EVAL_METHOD != 0) || defined(__FAST_MATH__)
#define GAGEN_TRIG_USE_LIBM 1
#else
#define GAGEN_TRIG_USE_LIBM 0
#endif

typedef struct {
    double s, c;
} gagen_trig_pair;

#if !GAGEN_TRIG_USE_LIBM

/*
 * pi/2 = pio2_1 + pio2_2 + pio2_3 + pio2_3t: the first three parts have at
 * most 33 significant bits; pio2_kt = pi/2 - (pio2_1 + ... + pio2_k).
 */
#define GAGEN_TRIG_TOINT 6755399441055744.0                 /* 0x1.8p52 */
#define GAGEN_TRIG_INVPIO2 6.36619772367581382433e-01       /* 0x3FE45F30, 0x6DC9C883 */
#define GAGEN_TRIG_PIO2_1 1.57079632673412561417e+00        /* 0x3FF921FB, 0x54400000 */
#define GAGEN_TRIG_PIO2_1T 6.07710050650619224932e-11       /* 0x3DD0B461, 0x1A626331 */
#define GAGEN_TRIG_PIO2_2 6.07710050630396597660e-11        /* 0x3DD0B461, 0x1A600000 */
#define GAGEN_TRIG_PIO2_2T 2.02226624879595063154e-21       /* 0x3BA3198A, 0x2E037073 */
#define GAGEN_TRIG_PIO2_3 2.02226624871116645580e-21        /* 0x3BA3198A, 0x2E000000 */
#define GAGEN_TRIG_PIO2_3T 8.47842766036889956997e-32       /* 0x397B839A, 0x252049C1 */

/* Biased exponent of |v| (bits 52..62). */
GAGEN_TRIG_INLINE int gagen_trig_exponent(double v)
{
    uint64_t b;
    memcpy(&b, &v, sizeof b);
    return (int)((b >> 52) & 0x7ff);
}

/*
 * sin and cos of n*pi/2 + y0 - m, |y0| <~ pi/4, |m| <~ ulp(y0)/2, q = n mod 4
 * (m = -y1 is the negated tail).  fdlibm's __kernel_sin (iy = 1) and FreeBSD's
 * __kernel_cos with their minimax coefficients (|error| <= 2^-58 on
 * [-pi/4, pi/4]), in Estrin form:
 *   sin: y0 - (v*(NS1 + NS2 z + ... + NS6 z^5) + m*(1 - z/2)), NSk = -Sk,
 *        z = y0^2, v = z*y0
 *   cos: t + (w*(C1 + C2 z + ... + C6 z^5) + (((1 - t) - z/2) + y0*m)),
 *        t = 1 - z/2, w = z^2; (1 - t) - z/2 is exactly the rounding error of t.
 * The sine ends with a subtraction (hence the negated Sk and tail) so that
 * sin(-0) = -0 (bit for bit the same results as with the usual signs otherwise).
 */
GAGEN_TRIG_INLINE gagen_trig_pair gagen_trig_kernel(double y0, double m, unsigned q)
{
    /* NSk = -Sk, with Sk fdlibm's sine coefficients (hex: IEEE-754 words of Sk) */
    const double NS1 = 1.66666666666666324348e-01;      /* S1: 0xBFC55555, 0x55555549 */
    const double NS2 = -8.33333333332248946124e-03;     /* S2: 0x3F811111, 0x1110F8A6 */
    const double NS3 = 1.98412698298579493134e-04;      /* S3: 0xBF2A01A0, 0x19C161D5 */
    const double NS4 = -2.75573137070700676789e-06;     /* S4: 0x3EC71DE3, 0x57B1FE7D */
    const double NS5 = 2.50507602534068634195e-08;      /* S5: 0xBE5AE5E6, 0x8A2B9CEB */
    const double NS6 = -1.58969099521155010221e-10;     /* S6: 0x3DE5D93A, 0x5ACFD57C */
    const double C1 = 4.16666666666666019037e-02;       /* 0x3FA55555, 0x5555554C */
    const double C2 = -1.38888888888741095749e-03;      /* 0xBF56C16C, 0x16C15177 */
    const double C3 = 2.48015872894767294178e-05;       /* 0x3EFA01A0, 0x19CB1590 */
    const double C4 = -2.75573143513906633035e-07;      /* 0xBE927E4F, 0x809C52AD */
    const double C5 = 2.08757232129817482790e-09;       /* 0x3E21EE9E, 0xBDB4B1C4 */
    const double C6 = -1.13596475577881948265e-11;      /* 0xBDA8FAE9, 0xBE8838D4 */
    double z = y0 * y0;
    double w = z * z;
    double z4 = w * w;
    double v = z * y0;
    double hz = 0.5 * z;
    double t = 1.0 - hz;
    double ps = ((NS1 + z * NS2) + w * (NS3 + z * NS4)) + z4 * (NS5 + z * NS6);
    double pc = ((C1 + z * C2) + w * (C3 + z * C4)) + z4 * (C5 + z * C6);
    double ks = y0 - (v * ps + m * t);
    double kc = t + (w * pc + (((1.0 - t) - hz) + y0 * m));
    uint64_t bs, bc, d;
    gagen_trig_pair out;

    /* Quadrant without branches (q is random for joint angles):
     * (sin, cos) = (ks, kc), (kc, -ks), (-ks, -kc), (-kc, ks) for q = 0, 1, 2, 3. */
    memcpy(&bs, &ks, sizeof bs);
    memcpy(&bc, &kc, sizeof bc);
    d = (bs ^ bc) & ((uint64_t)0 - (uint64_t)(q & 1u));   /* swap if q is odd */
    bs ^= d ^ ((uint64_t)(q & 2u) << 62);                  /* sign flips */
    bc ^= d ^ ((uint64_t)((q + 1u) & 2u) << 62);
    memcpy(&out.s, &bs, sizeof bs);
    memcpy(&out.c, &bc, sizeof bc);
    return out;
}

/* Rare cases: |x| >= 2^20, inf or nan (libm), or x so close to a multiple of
 * pi/2 that the reduction needs a second or third round (fdlibm rem_pio2). */
GAGEN_TRIG_COLD gagen_trig_pair gagen_trig_slow(double x)
{
    double t, fn, r, w, y0;
    int ex;
    uint64_t bt;
    gagen_trig_pair p;

    if (!(fabs(x) < GAGEN_TRIG_MAX)) {
        p.s = sin(x);
        p.c = cos(x);
        return p;
    }
    ex = gagen_trig_exponent(x);
    t = x * GAGEN_TRIG_INVPIO2 + GAGEN_TRIG_TOINT;
    memcpy(&bt, &t, sizeof bt);
    fn = t - GAGEN_TRIG_TOINT;
    r = x - fn * GAGEN_TRIG_PIO2_1;
    w = fn * GAGEN_TRIG_PIO2_1T;                         /* 1st round, 85 bits */
    y0 = r - w;
    if (ex - gagen_trig_exponent(y0) > 16) {
        t = r;                                           /* 2nd round, 118 bits */
        w = fn * GAGEN_TRIG_PIO2_2;
        r = t - w;
        w = fn * GAGEN_TRIG_PIO2_2T - ((t - r) - w);
        y0 = r - w;
        if (ex - gagen_trig_exponent(y0) > 49) {
            t = r;                                       /* 3rd round, 151 bits */
            w = fn * GAGEN_TRIG_PIO2_3;
            r = t - w;
            w = fn * GAGEN_TRIG_PIO2_3T - ((t - r) - w);
            y0 = r - w;
        }
    }
    return gagen_trig_kernel(y0, w - (r - y0), (unsigned)bt);
}

/*
 * Common path: one round of reduction (85 bits), enough unless x is within
 * 2^-16 (relative) of a multiple of pi/2.  It is straight-line code, computed
 * even when the slow path then replaces the result, so that the compiler can
 * share it between gagen_sin(x) and gagen_cos(x).  Huge or non-finite x is
 * replaced by 0 first, so that this discarded work raises no spurious
 * floating-point exception (the compiler turns that into a branch).
 */
GAGEN_TRIG_INLINE gagen_trig_pair gagen_trig_sincos(double x)
{
    double xr, t, fn, r, w, y0;
    uint64_t bx, ex, by, bt;
    int slow;
    gagen_trig_pair p;

    memcpy(&bx, &x, sizeof bx);
    ex = bx & 0x7ff0000000000000ULL;                     /* biased exponent << 52 */
    slow = ex >= 0x4130000000000000ULL;                  /* |x| >= 2^20, inf, nan */
    bx = slow ? 0 : bx;
    memcpy(&xr, &bx, sizeof xr);
    t = xr * GAGEN_TRIG_INVPIO2 + GAGEN_TRIG_TOINT;      /* 1.5*2^52 + rint(x*2/pi) */
    memcpy(&bt, &t, sizeof bt);                          /* low bits: n mod 4 */
    fn = t - GAGEN_TRIG_TOINT;
    r = xr - fn * GAGEN_TRIG_PIO2_1;                     /* exact as |fn| < 2^20 */
    w = fn * GAGEN_TRIG_PIO2_1T;
    y0 = r - w;
    memcpy(&by, &y0, sizeof by);
    by &= 0x7fffffffffffffffULL;
    slow |= (int64_t)by < (int64_t)ex - ((int64_t)16 << 52);   /* lost > 16 bits */
    p = gagen_trig_kernel(y0, w - (r - y0), (unsigned)bt);
    if (GAGEN_TRIG_UNLIKELY(slow)) {
        p = gagen_trig_slow(x);
    }
    return p;
}

/*
 * Two at a time: the same operations on both lanes of a 128-bit vector (GCC's and Clang's
 * vector extensions, SSE2 on any x86-64), so each result is bit for bit gagen_sincos's, for
 * about the price of one.  The scalar code's integer tests on the exponent become the
 * equivalent floating-point comparisons, which SSE2 has for 64-bit lanes.
 */
#if (defined(__GNUC__) || defined(__clang__)) && !defined(GAGEN_TRIG_NO_VECTOR)
#define GAGEN_TRIG_VECTOR 1
typedef double gagen_v2d __attribute__((vector_size(16)));
typedef uint64_t gagen_v2u __attribute__((vector_size(16)));
typedef int64_t gagen_v2i __attribute__((vector_size(16)));

GAGEN_TRIG_INLINE gagen_v2d gagen_v2d_splat(double a)
{
    gagen_v2d v = {a, a};
    return v;
}

GAGEN_TRIG_INLINE gagen_v2u gagen_v2u_splat(uint64_t a)
{
    gagen_v2u v = {a, a};
    return v;
}

/* gagen_trig_kernel on both lanes. */
GAGEN_TRIG_INLINE void gagen_trig_kernel2(gagen_v2d y0, gagen_v2d m, gagen_v2u q,
                                          gagen_v2d *s, gagen_v2d *c)
{
    const double NS1 = 1.66666666666666324348e-01, NS2 = -8.33333333332248946124e-03;
    const double NS3 = 1.98412698298579493134e-04, NS4 = -2.75573137070700676789e-06;
    const double NS5 = 2.50507602534068634195e-08, NS6 = -1.58969099521155010221e-10;
    const double C1 = 4.16666666666666019037e-02, C2 = -1.38888888888741095749e-03;
    const double C3 = 2.48015872894767294178e-05, C4 = -2.75573143513906633035e-07;
    const double C5 = 2.08757232129817482790e-09, C6 = -1.13596475577881948265e-11;
    const gagen_v2u one = gagen_v2u_splat(1), two = gagen_v2u_splat(2);
    gagen_v2d z = y0 * y0;
    gagen_v2d w = z * z;
    gagen_v2d z4 = w * w;
    gagen_v2d v = z * y0;
    gagen_v2d hz = 0.5 * z;
    gagen_v2d t = 1.0 - hz;
    gagen_v2d ps = ((NS1 + z * NS2) + w * (NS3 + z * NS4)) + z4 * (NS5 + z * NS6);
    gagen_v2d pc = ((C1 + z * C2) + w * (C3 + z * C4)) + z4 * (C5 + z * C6);
    gagen_v2d ks = y0 - (v * ps + m * t);
    gagen_v2d kc = t + (w * pc + (((1.0 - t) - hz) + y0 * m));
    gagen_v2u bs = (gagen_v2u)ks, bc = (gagen_v2u)kc;
    gagen_v2u d = (bs ^ bc) & (gagen_v2u_splat(0) - (q & one));
    bs ^= d ^ ((q & two) << 62);
    bc ^= d ^ (((q + one) & two) << 62);
    *s = (gagen_v2d)bs;
    *c = (gagen_v2d)bc;
}

/* gagen_trig_sincos on both lanes. */
GAGEN_TRIG_INLINE void gagen_trig_sincos2(gagen_v2d x, gagen_v2d *s, gagen_v2d *c)
{
    const gagen_v2u abs_mask = gagen_v2u_splat(0x7fffffffffffffffULL);
    gagen_v2u bx = (gagen_v2u)x;
    gagen_v2u ex = bx & gagen_v2u_splat(0x7ff0000000000000ULL);
    /* |x| >= 2^20, inf, nan: not (|x| < 2^20) */
    gagen_v2i slow = ~((gagen_v2d)(bx & abs_mask) < gagen_v2d_splat(GAGEN_TRIG_MAX));
    gagen_v2d xr = (gagen_v2d)(bx & ~(gagen_v2u)slow);
    gagen_v2d t = xr * GAGEN_TRIG_INVPIO2 + GAGEN_TRIG_TOINT;
    gagen_v2d fn = t - GAGEN_TRIG_TOINT;
    gagen_v2d r = xr - fn * GAGEN_TRIG_PIO2_1;
    gagen_v2d w = fn * GAGEN_TRIG_PIO2_1T;
    gagen_v2d y0 = r - w;
    /* lost > 16 bits: |y0| < 2^(exponent of x - 16), a negative bound never holding */
    slow |= (gagen_v2d)((gagen_v2u)y0 & abs_mask) <
            (gagen_v2d)(ex - gagen_v2u_splat((uint64_t)16 << 52));
    gagen_trig_kernel2(y0, w - (r - y0), (gagen_v2u)t, s, c);
    if (GAGEN_TRIG_UNLIKELY(slow[0] | slow[1])) {
        int lane;
        for (lane = 0; lane < 2; ++lane) {
            if (slow[lane]) {
                gagen_trig_pair p = gagen_trig_slow(x[lane]);
                (*s)[lane] = p.s;
                (*c)[lane] = p.c;
            }
        }
    }
}
#endif

#endif /* !GAGEN_TRIG_USE_LIBM */

/* *s = sin(x), *c = cos(x); within 1 ulp for |x| < GAGEN_TRIG_MAX, else libm. */
GAGEN_TRIG_INLINE void gagen_sincos(double x, double *s, double *c)
{
#if GAGEN_TRIG_USE_LIBM
    *s = sin(x);
    *c = cos(x);
#else
    gagen_trig_pair p = gagen_trig_sincos(x);
    *s = p.s;
    *c = p.c;
#endif
}

/* *s0 = sin(x0), *c0 = cos(x0), *s1 = sin(x1), *c1 = cos(x1): gagen_sincos twice, bit for bit,
 * for about the price of once. */
GAGEN_TRIG_INLINE void gagen_sincos2(double x0, double x1, double *s0, double *c0, double *s1,
                                     double *c1)
{
#if !GAGEN_TRIG_USE_LIBM && defined(GAGEN_TRIG_VECTOR)
    gagen_v2d x = {x0, x1}, s, c;
    gagen_trig_sincos2(x, &s, &c);
    *s0 = s[0];
    *c0 = c[0];
    *s1 = s[1];
    *c1 = c[1];
#else
    gagen_sincos(x0, s0, c0);
    gagen_sincos(x1, s1, c1);
#endif
}

/* sin(x), bit for bit the sine of gagen_sincos(x, ...). */
GAGEN_TRIG_INLINE double gagen_sin(double x)
{
#if GAGEN_TRIG_USE_LIBM
    return sin(x);
#else
    return gagen_trig_sincos(x).s;
#endif
}

/* cos(x), bit for bit the cosine of gagen_sincos(x, ...). */
GAGEN_TRIG_INLINE double gagen_cos(double x)
{
#if GAGEN_TRIG_USE_LIBM
    return cos(x);
#else
    return gagen_trig_sincos(x).c;
#endif
}

/* sign(x): -1, 0 or 1 (0 at +-0; NaN stays NaN, as NumPy's sign), for Coulomb friction. */
static inline double gagen_sign(double x)
{
    return x > 0.0 ? 1.0 : (x < 0.0 ? -1.0 : x);
}

/* The smooth sign that simulations use for Coulomb friction: tanh(x / w) for a width
 * w > 0 (within 4e-9 of sign(x) for |x| > 10 w), sign(x) for w <= 0. From |x| = 19.1 w on,
 * tanh is +-1 to the last bit, returned without calling libm: a joint in motion (the
 * common case) costs a division and a comparison, not a tanh. */
static inline double gagen_smooth_sign(double x, double w)
{
    if (!(w > 0.0))
        return gagen_sign(x);
    const double y = x / w;
    if (fabs(y) >= 19.1)
        return y > 0.0 ? 1.0 : -1.0;
    return tanh(y);
}

/* f * gagen_smooth_sign(x, w), and no tanh when the friction f is 0. */
static inline double gagen_coulomb(double f, double x, double w)
{
    return f == 0.0 ? 0.0 : f * gagen_smooth_sign(x, w);
}

/*
 * GAGEN_KERNEL marks the kernels that run in loops (forward and inverse dynamics,
 * gravity).  Where GCC can pick a function's version when the library loads (x86-64
 * Linux with glibc's ifunc), each is built twice: for any x86-64 and for CPUs with fused
 * multiply-add, about 10 % faster; the price is their compile time, doubled.  Define
 * GAGEN_KERNEL as empty to build one version only: gagen does, with -mfma, when the
 * building machine has FMA (building/cache.py, compile_flags), and for portable builds.
 */
#ifndef GAGEN_KERNEL
#if defined(__GNUC__) && !defined(__clang__) && __GNUC__ >= 8 && defined(__x86_64__) && \
    defined(__linux__) && defined(__GLIBC__) && !defined(__FAST_MATH__)
#define GAGEN_KERNEL __attribute__((target_clones("fma", "default")))
#else
#define GAGEN_KERNEL
#endif
#endif

/*
 * GAGEN_HIDDEN marks the segment functions of split kernels (codegen/segments.py): they
 * link between the model's own files but are not exported from its module.  GAGEN_SEGMENT
 * is their other attributes (none by default).
 */
#if defined(__GNUC__) || defined(__clang__)
#define GAGEN_HIDDEN __attribute__((visibility("hidden")))
#else
#define GAGEN_HIDDEN
#endif
#ifndef GAGEN_SEGMENT
#define GAGEN_SEGMENT
#endif

#endif /* GAGEN_MATH_H */
