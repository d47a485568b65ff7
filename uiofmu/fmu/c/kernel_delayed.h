/* uiofmu: the delayed observer kernel's ports and design data (kernel_delayed.c reads them).
 *
 * A design card of kernel "delayed" (the continuous-time delayed UIO with parameter
 * identification, seed 001) becomes one constant UiofmuDelayed (design_data.c, generated;
 * numbers only): the plant x' = A x + B u + D(y) theta, y = C x, D(y) = D0 + sum_i y_i Dy[i],
 * the gain K of the system augmented with its ndelays delayed copies (c = ndelays + 1), the
 * delays and the numbers of the schedule. Stored row-major:
 *   A  n x n,  B  n x m,  C  p x n,  D0  n x nt,  Dy  p x n x nt,  K  (n c) x (p c)
 *   delays  ndelays (increasing, > 0),  xhat0  n (the default initial estimate)
 * An empty array is written as {0.0} (length 1). Every array travels with its length as the C
 * compiler counts it (UIOFMU_LENGTH), so fmi2Instantiate checks each against the dims before it
 * reads any of it.
 */
#ifndef UIOFMU_KERNEL_DELAYED_H
#define UIOFMU_KERNEL_DELAYED_H

#include <stddef.h>

#include "fmi2_plumbing.h"

/* The ports the kernel implements (the ids of the variable table; uiofmu.runtime.ports.delayed_ports):
   xhat0[n] parameter; y[p], ydot[p], u[m] inputs; xhat[n], thetahat[nt], r[p], sigma_min[1]
   outputs (Real) and valid[1] output (Integer). Their ids, names, causalities and types are
   generated at build time from uiofmu/runtime/ports.py (KERNEL_PORTS["delayed"]). */
#include "kernel_delayed_ports.h"

typedef struct {
    int n, m, p, nt;  /* states, known inputs, outputs, unknown parameters theta */
    int ndelays;      /* delayed copies (1 .. 16) */
    int rows;         /* the most past points the delay buffer keeps (uiofmu.runtime.delayed.buffer_rows) */
    double max_substep;  /* the longest RK4 substep of the observer */
    double sigma_bound;  /* the premise's smallest rank margin sigma_min(C D_y) */
    double valid_from;   /* the premise's start (the kernel takes at least the longest delay) */
    double gamma_bound;  /* the largest ||Gamma|| of the premise points certified (has_gamma_bound) */
    int has_gamma_bound; /* 0: no bound on ||Gamma|| (an infinite gamma_bound) */
    const double *A, *B, *C, *D0, *Dy, *K, *delays, *xhat0;
    size_t A_length, B_length, C_length, D0_length, Dy_length, K_length, delays_length, xhat0_length;
} UiofmuDelayed;

UIOFMU_INTERNAL extern const UiofmuDelayed UIOFMU_DELAYED;

/* The kernel, for UIOFMU_FMU.kernel. */
UIOFMU_INTERNAL extern const UiofmuKernel UIOFMU_KERNEL_DELAYED;

#endif
