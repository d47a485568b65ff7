/* uiofmu: the linear plant kernel's ports and design data (kernel_plant.c reads them).
 *
 * A linear plant (uiofmu.plant.Plant.to_data()) becomes one constant UiofmuPlant
 * (design_data.c, generated; numbers only). Matrices are row-major:
 *   A n x n, B n x m, E n x q, C p x n, w n, x0 n, W n x r (process noise; r = 0 but for a linear plant
 *   whose problem declares it), D p x m, F p x q (y = C x + D u + F d; zeros: no feedthrough, the FMU then
 *   declares none)
 * A switched plant (uiofmu.switched_plant.SwitchedPlant.to_data(), modes = N >= 1; discrete) has
 * N blocks of each of A, B, E and w, mode i (1..N) the block i - 1, and its switching rule:
 *   threshold: mode 1 + #{thresholds[t] <= x[state]} (N - 1 increasing thresholds)
 *   input:     the Integer input mode (mode0 before a master sets it)
 *   random:    i.i.d. draws from SplitMix64 seeded with the Integer parameter seed, by the
 *              cumulative probabilities (N running sums)
 * (uiofmu/runtime/switching.py). A linear plant has modes = 0 and rule UIOFMU_RULE_NONE.
 * An empty matrix (m = 0 or q = 0) is written as {0.0}: length 1. Every array travels with
 * its length as the C compiler counts it (UIOFMU_LENGTH), so fmi2Instantiate checks the data
 * actually compiled in against the dims before it reads any of it.
 */
#ifndef UIOFMU_KERNEL_PLANT_H
#define UIOFMU_KERNEL_PLANT_H

#include <stddef.h>

#include "fmi2_plumbing.h"

/* The ports the kernel implements (the ids of the variable table; uiofmu.runtime.ports.plant_ports):
   x0[n] parameter, u[m] and d[q] inputs (held over the step), y[p] = C x + D u + F d and x[n] outputs; all
   Real.
   A switched plant adds the Integer mode[1]: an input (rule input) or an output (rules threshold
   and random), and rule random the Integer parameter seed[1]. Every plant ends with the Real
   parameter mismatch[1] and the Integer parameter mismatch_seed[1], the perturbation of its A, B, E
   (kernel_plant.c, uiofmu/runtime/mismatch.py). Their ids, names, causalities
   (the one of mode as the FMU declares it) and types are generated at build time from
   uiofmu/runtime/ports.py (KERNEL_PORTS["plant"]). */
#include "kernel_plant_ports.h"

enum { UIOFMU_DISCRETE = 0, UIOFMU_CONTINUOUS = 1 };
enum { UIOFMU_RULE_NONE = 0, UIOFMU_RULE_THRESHOLD = 1, UIOFMU_RULE_INPUT = 2, UIOFMU_RULE_RANDOM = 3 };

typedef struct {
    int n, m, p, q;
    int r;             /* process-noise inputs w_noise: the columns of W (0: none declared) */
    int time;          /* UIOFMU_DISCRETE or UIOFMU_CONTINUOUS */
    double dt;         /* discrete plants: the period (0 for continuous ones) */
    double step_rtol;  /* discrete plants: a step within step_rtol * dt of dt is dt */
    const double *A, *B, *E, *C, *w, *x0, *W, *D, *F;
    size_t A_length, B_length, E_length, C_length, w_length, x0_length, W_length, D_length, F_length;
    /* switched plants (modes = 0 for a linear one) */
    int modes, rule;
    int state;          /* rule threshold: the 0-based index of the state compared */
    int nthresholds;    /* rule threshold: N - 1 */
    int mode0, seed;    /* rule input: the input's start value; rule random: the seed's */
    const double *thresholds, *cumulative; /* N - 1 increasing values; N running sums of the probabilities */
    size_t thresholds_length, cumulative_length;
} UiofmuPlant;

UIOFMU_INTERNAL extern const UiofmuPlant UIOFMU_PLANT;

/* The kernel, for UIOFMU_FMU.kernel. */
UIOFMU_INTERNAL extern const UiofmuKernel UIOFMU_KERNEL_PLANT;

/* exp(M) of a k x k row-major matrix into out (k x k) by scaling and squaring with a Padé
   approximant (Higham 2005, degrees 3, 5, 7, 9, 13); work holds 7 k x k doubles and piv k ints.
   0 when M has a non-finite entry or the result is not finite. */
UIOFMU_INTERNAL int uiofmu_expm(const double *M, int k, double *out, double *work, int *piv);

#endif
