/* uiofmu: the kernel of plants with unknown parameters: its ports and design data
 * (kernel_parametric.c reads them).
 *
 * A plant x' = A x + B u + D(y) theta, y = C x, D(y) = D0 + sum_i y_i Dy[i]
 * (uiofmu.parametric_plant.ParametricPlant.to_data()) becomes one constant UiofmuParametric
 * (design_data.c, generated; numbers only), stored row-major:
 *   A  n x n,  B  n x m,  C  p x n,  D0  n x nt,  Dy  p x n x nt,  x0  n,  theta  nt (the default)
 * with the numbers of its rate that do not depend on theta, as numpy computes them
 * (uiofmu.runtime.parametric_plant.rate): ||A||_2, ||C||_2, sum |Dy|, sum |D0|. An empty array
 * is written as {0.0} (length 1); every array travels with its length as the C compiler counts
 * it (UIOFMU_LENGTH), so fmi2Instantiate checks each against the dims before it reads any of it.
 */
#ifndef UIOFMU_KERNEL_PARAMETRIC_H
#define UIOFMU_KERNEL_PARAMETRIC_H

#include <stddef.h>

#include "fmi2_plumbing.h"

/* The ports the kernel implements (uiofmu.runtime.ports.parametric_plant_ports): x0[n] and
   theta[nt] parameters, u[m] input, y[p], ydot[p] and x[n] outputs, all Real. Their ids, names,
   causalities and types are generated at build time from uiofmu/runtime/ports.py
   (KERNEL_PORTS["parametric"]). */
#include "kernel_parametric_ports.h"

typedef struct {
    int n, m, p, nt;
    double norm_A, norm_C, sum_Dy, sum_D0; /* the rate's constant parts (numpy's) */
    const double *A, *B, *C, *D0, *Dy, *x0, *theta;
    size_t A_length, B_length, C_length, D0_length, Dy_length, x0_length, theta_length;
} UiofmuParametric;

UIOFMU_INTERNAL extern const UiofmuParametric UIOFMU_PARAMETRIC;

/* The kernel, for UIOFMU_FMU.kernel. */
UIOFMU_INTERNAL extern const UiofmuKernel UIOFMU_KERNEL_PARAMETRIC;

#endif
