/* uiofmu: the window observer kernel's ports and design data (kernel_window.c reads them).
 *
 * A design card of kernel "window" (a dead-beat functional observer, seed 003) becomes one
 * constant UiofmuWindow (design_data.c, generated; numbers only): the formula
 *
 *   gx_k = sum_t w_t F_t [y_{k-L+1}; ...; y_k],   w_t = prod_{l, i} theta_{k-L+1+l}^(i) ^ Fexp[t][l][i]
 *
 * stored row-major:
 *   F     terms x d x (p L)   block t is F_t, its columns the window's outputs oldest first
 *   Fexp  terms x L x s       integer powers 0 .. UIOFMU_WINDOW_MAX_POWER (0^0 = 1)
 * An empty array is written as {0} (length 1). Every array travels with its length as the C
 * compiler counts it (UIOFMU_LENGTH), so fmi2Instantiate checks terms x d x p L and
 * terms x L x s against the data actually compiled in before it reads any of it.
 */
#ifndef UIOFMU_KERNEL_WINDOW_H
#define UIOFMU_KERNEL_WINDOW_H

#include <stddef.h>

#include "fmi2_plumbing.h"

/* The ports the kernel implements (the ids of the variable table; uiofmu.runtime.ports.window_ports):
   y[p] and, when the formula uses theta, theta[s] inputs (Real); gx[d] output (Real) and
   gx_valid[1] output (Integer). Their ids, names, causalities and types are generated at build
   time from uiofmu/runtime/ports.py (KERNEL_PORTS["window"]). */
#include "kernel_window_ports.h"

#define UIOFMU_WINDOW_MAX_POWER 64 /* uiofmu/runtime/card.py MAX_POWER */

typedef struct {
    int p, d, s;       /* outputs, rows of the functional, scheduling components */
    int length, delay; /* L outputs in the window; gx is G x at the point delay steps back */
    int uses_theta;    /* 1: theta[s] is an input; 0: no theta port (every power is 0) */
    int terms;         /* number of monomials in theta */
    double dt, step_rtol; /* the period: a step within step_rtol * dt of dt, else fmi2Discard */
    const double *F;
    const int *Fexp;
    size_t F_length, Fexp_length;
} UiofmuWindow;

UIOFMU_INTERNAL extern const UiofmuWindow UIOFMU_WINDOW;

/* The kernel, for UIOFMU_FMU.kernel. */
UIOFMU_INTERNAL extern const UiofmuKernel UIOFMU_KERNEL_WINDOW;

#endif
