/* uiofmu: the affine observer kernel's ports and design data (kernel_affine.c reads them).
 *
 * A design card becomes one constant UiofmuDesign (design_data.c, generated). Every matrix
 * is stored row-major with its schedule axis first: `count` blocks of rows x cols.
 *   constant : count = 1
 *   interval : N, L: count = N*N, block [i*N + j]; G, c, Yx, Yu, Yc: block [i]; Xz, Xy, Dy: block [j]
 *              (i: index of h_k, j: index of h_{k-1})
 *   mode     : as interval, with i = alpha_k - 1 (the input mode, the mode of the step taken) and
 *              j = alpha_{k-1} - 1 (the mode of the step before; mode_prev0 before the first step)
 *   geometric: count = number of polynomial coefficients in a = alpha^k
 * C is never scheduled. count = 0 marks an absent matrix (no dhat; no Xu, the direct term of u in xhat,
 * which only a constant schedule may have).
 *
 * Every array travels with its length as the C compiler counts it (UIOFMU_LENGTH), so
 * fmi2Instantiate can check count x rows x cols against the data actually there before it
 * reads any of it (an empty array is written as {0.0}: length 1).
 */
#ifndef UIOFMU_KERNEL_AFFINE_H
#define UIOFMU_KERNEL_AFFINE_H

#include <stddef.h>

#include "fmi2_plumbing.h"

/* The ports the kernel implements (the ids of the variable table; uiofmu.runtime.ports.observer_ports):
   xhat0[n] parameter, h_prev0[1] parameter (interval schedules), y[p] and u[m] inputs,
   xhat[n], r[p] and dhat[q] (with Dy) outputs, all Real (a functional observer: zhat[nf] instead); mode schedules add the Integer
   parameter mode_prev0[1] and the Integer input mode[1]. Their ids (UIOFMU_AFFINE_XHAT0 ...
   UIOFMU_AFFINE_PORTS), names, causalities and types are generated at build time from
   uiofmu/runtime/ports.py (KERNEL_PORTS["affine"]); the variable table lists them in the order of
   the card's ports. */
#include "kernel_affine_ports.h"

typedef struct {
    int count;
    int rows, cols;
    const double *data;
    size_t length; /* number of doubles in data */
} UiofmuMatrix;

enum { UIOFMU_CONSTANT = 0, UIOFMU_INTERVAL = 1, UIOFMU_GEOMETRIC = 2, UIOFMU_MODE = 3 };
enum { UIOFMU_POLICY_ERROR = 0, UIOFMU_POLICY_NEAREST = 1, UIOFMU_POLICY_COUNT = 2 };
enum { M_N, M_L, M_G, M_c, M_Xz, M_Xy, M_C, M_Dy, M_Yx, M_Yu, M_Yc, M_Xu, M_Zx, M_Lf, M_COUNT };

/* nf > 0: a functional observer of the functionals Lf x (Lf nf x n), z_0 = Zx xhat0, no dhat. Below order n
   (nz != n) its estimate is zhat[nf] = Xz z + Xy y (Xz nf x nz, Xy nf x p), zhat_0 = Lf xhat0, and it has no r; at
   order n (nz = n) it estimates the state as xhat = Xz z + Xy y, with r, and zhat = Lf xhat.
   nf = 0: the state observer (xhat[n]). */
typedef struct {
    int n, m, p, q, nz, has_dhat;
    int nf;
    int kind, policy;
    double dt, alpha, h_prev0, step_rtol;
    int nintervals;
    const double *intervals;
    int modes, mode_prev0; /* mode schedules: N >= 1 and the mode assumed before the first step (1..N) */
    const double *xhat0;
    UiofmuMatrix mat[M_COUNT];
    size_t intervals_length; /* number of doubles in intervals (1 when there are none) */
    size_t xhat0_length;     /* number of doubles in xhat0 */
} UiofmuDesign;

UIOFMU_INTERNAL extern const UiofmuDesign UIOFMU_DESIGN;

/* The kernel, for UIOFMU_FMU.kernel. */
UIOFMU_INTERNAL extern const UiofmuKernel UIOFMU_KERNEL_AFFINE;

#endif
