/* uiofmu: the LPV plant kernel's ports and design data (kernel_lpv.c reads them).
 *
 * An LPV plant (uiofmu.lpv_plant.LpvPlant.to_data(); discrete)
 *
 *   x+ = A(theta) x + E(theta) d,   y = C(theta) x + D(theta) d,   M(theta) = M_0 + sum_i theta^(i) M_i
 *
 * becomes one constant UiofmuLpv (design_data.c, generated; numbers only). Every matrix is
 * stored row-major as 1 + s blocks, block 0 the constant part M_0 and block i the part of
 * theta^(i) (M_i):
 *   A (1 + s) x n x n, E (1 + s) x n x q, C (1 + s) x p x n, D (1 + s) x p x q
 * and T s x n (theta = T x, kind state; zeros for kind input), x0 n.
 * An empty array (q = 0, or s = 0 for T) is written as {0.0}: length 1. Every array travels
 * with its length as the C compiler counts it (UIOFMU_LENGTH), so fmi2Instantiate checks the
 * data actually compiled in against the dims before it reads any of it.
 */
#ifndef UIOFMU_KERNEL_LPV_H
#define UIOFMU_KERNEL_LPV_H

#include <stddef.h>

#include "fmi2_plumbing.h"

/* The ports the kernel implements (the ids of the variable table; uiofmu.runtime.ports.lpv_plant_ports):
   x0[n] parameter, u[0] and d[q] inputs (held over the step), theta[s] (an input for kind input,
   an output T x for kind state), y[p] and x[n] outputs; all Real. Their ids, names, causalities
   (the one of theta as the FMU declares it) and types are generated at build time from
   uiofmu/runtime/ports.py (KERNEL_PORTS["lpv"]). */
#include "kernel_lpv_ports.h"

enum { UIOFMU_THETA_STATE = 0, UIOFMU_THETA_INPUT = 1 };

typedef struct {
    int n, p, q, s;
    int kind;          /* UIOFMU_THETA_STATE (theta = T x) or UIOFMU_THETA_INPUT */
    double dt;         /* the period */
    double step_rtol;  /* a step within step_rtol * dt of dt is dt, any other is refused */
    const double *A, *E, *C, *D, *T, *x0;
    size_t A_length, E_length, C_length, D_length, T_length, x0_length;
} UiofmuLpv;

UIOFMU_INTERNAL extern const UiofmuLpv UIOFMU_LPV;

/* The kernel, for UIOFMU_FMU.kernel. */
UIOFMU_INTERNAL extern const UiofmuKernel UIOFMU_KERNEL_LPV;

#endif
