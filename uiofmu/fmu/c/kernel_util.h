/* uiofmu: what the kernels share (kernel_util.c), written once for every kernel_<name>.c.
 *
 * The checks every model makes the same way, with the same log lines: its design data (dims,
 * counts, the period), its inputs before a step (finite), a step against the period, a
 * parameter when initialisation ends, the next state of a plant; and the pieces of its part of
 * the FMU state (the doubles after the plumbing's header: read and written with memcpy, the
 * phase among them, the shape words). The plumbing never calls them; a kernel calls what it
 * needs and keeps its own numbers and words.
 */
#ifndef UIOFMU_KERNEL_UTIL_H
#define UIOFMU_KERNEL_UTIL_H

#include <stddef.h>
#include <stdint.h>

#include "fmi2_plumbing.h"
/* The refusals shared with the Python runtime (UIOFMU_REFUSAL_*: printf formats), generated at build
   time from uiofmu/runtime/refusals.py. */
#include "uiofmu_refusals.h"

/* ---------------------------------------------------------------------------------------- */
/* The design, checked once at fmi2Instantiate (check_design)                                */

/* Each of the `count` dims in [low[i], max], else 0 with "<prefix><name> = <dim> is out of
   range [low, max]" in msg (prefix "plant dims." gives "plant dims.n = 0 is out of range"). */
UIOFMU_INTERNAL int uiofmu_check_dims(char *msg, size_t len, const char *prefix, int count, const int dims[],
                                      const char *const names[], const int low[], int max);

/* The design array v of `length` numbers holds `want` finite ones (an empty array is generated with one
   placeholder: length 1 for want 0), else 0 with "<prefix><name>: expected ..." or "<prefix><name>[e] = ... is
   not finite" in msg. */
UIOFMU_INTERNAL int uiofmu_check_array(char *msg, size_t len, const char *prefix, const char *name, const double *v,
                                       size_t length, size_t want);

/* dt a finite period > 0 and step_rtol >= 0 finite, else 0 with the numbers in msg. */
UIOFMU_INTERNAL int uiofmu_check_period(char *msg, size_t len, double dt, double step_rtol);

/* a * b in *out, 0 when it exceeds limit. */
UIOFMU_INTERNAL int uiofmu_mul(size_t a, size_t b, size_t limit, size_t *out);

/* ---------------------------------------------------------------------------------------- */
/* Instances and steps                                                                       */

/* calloc(count, size) (one element at the least), NULL after the log line "fmi2Instantiate:
   out of memory". */
UIOFMU_INTERNAL void *uiofmu_alloc(FmuInstance *fmu, size_t count, size_t size);

/* Each of the parameter's len values finite, else 0 after the fmi2Error line "parameter
   name[i] = v is not finite" (fmi2ExitInitializationMode refuses it). */
UIOFMU_INTERNAL int uiofmu_parameter_finite(FmuInstance *fmu, const char *name, const double *v, int len);

/* Each of the input's len values finite, else 0 after the fmi2Error line "t = ..: input
   name[i] = nan is not finite" (with "at step k = .." before "is" when k >= 0). */
UIOFMU_INTERNAL int uiofmu_inputs_finite(FmuInstance *fmu, double t, long k, const double *v, int len,
                                         const char *name);

/* Whether h is off the period: more than step_rtol * dt from dt. Then 1 after the fmi2Discard
   line naming h and dt (of an observer, which notes step_policy 'error', or of a plant). */
UIOFMU_INTERNAL int uiofmu_off_period(FmuInstance *fmu, double t, double h, double dt, double step_rtol,
                                      int observer);

/* Each of the n values of a plant's next state finite, else 0 after the fmi2Error line naming
   the first that is not, t and h. */
UIOFMU_INTERNAL int uiofmu_next_state_finite(FmuInstance *fmu, double t, double h, const double *xn, int n);

/* real_storage from the first element of each port (first[port], NULL when the port has no
   elements here): where element `index` of port `port` lives. */
static inline double *uiofmu_element(double *const first[], int port, int index) {
    return first[port] ? first[port] + index : NULL;
}

/* ---------------------------------------------------------------------------------------- */
/* The kernel's part of the FMU state                                                        */

/* Double `index` of the doubles at b (unaligned: memcpy). */
UIOFMU_INTERNAL double uiofmu_getd(const unsigned char *b, size_t index);

/* The n doubles of v written at o (taken from o into v); the byte after them. */
UIOFMU_INTERNAL unsigned char *uiofmu_put(unsigned char *o, const double *v, size_t n);
UIOFMU_INTERNAL const unsigned char *uiofmu_take(const unsigned char *o, double *v, size_t n);

/* state_shape: the four dims and their names. */
UIOFMU_INTERNAL void uiofmu_shape(uint32_t shape[UIOFMU_SHAPE], const char *names[UIOFMU_SHAPE],
                                  const int dims[UIOFMU_SHAPE], const char *const dim_names[UIOFMU_SHAPE]);

/* Whether phase is one of UIOFMU_PHASE_*, else 0 after check_state's refusal naming it
   (uiofmu_state_refused). */
UIOFMU_INTERNAL int uiofmu_phase_ok(FmuInstance *fmu, const char *ctx, double phase);

/* A plant's x0[n] and x[n], the doubles from index `at` of v: both finite, and x the design's
   x0 (bit for bit) before initialisation ended (phase 0 and 1), else 0 after check_state's
   refusal naming the first that is not. */
UIOFMU_INTERNAL int uiofmu_plant_x_ok(FmuInstance *fmu, const char *ctx, const unsigned char *v, size_t at, int n,
                                      double phase, const double *design_x0);

#endif
