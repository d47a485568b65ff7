/* uiofmu: what the kernels share (see kernel_util.h): the checks every kernel makes the same
 * way, with the same log lines, and the pieces of a kernel's part of the FMU state.
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2_plumbing.h"
#include "kernel_util.h"

/* ---------------------------------------------------------------------------------------- */
/* The design                                                                                 */

int uiofmu_check_dims(char *msg, size_t len, const char *prefix, int count, const int dims[],
                      const char *const names[], const int low[], int max) {
    for (int i = 0; i < count; i++)
        if (dims[i] < low[i] || dims[i] > max)
            return uiofmu_design_error(msg, len, "%s%s = %d is out of range [%d, %d]", prefix, names[i], dims[i],
                                       low[i], max);
    return 1;
}

int uiofmu_check_array(char *msg, size_t len, const char *prefix, const char *name, const double *v, size_t length,
                       size_t want) {
    if (!v || length != (want ? want : 1))
        return uiofmu_design_error(msg, len, "%s%s: expected %zu numbers, its array holds %zu", prefix, name, want,
                                   v ? length : 0);
    for (size_t e = 0; e < want; e++)
        if (!isfinite(v[e]))
            return uiofmu_design_error(msg, len, "%s%s[%zu] = %g is not finite", prefix, name, e, v[e]);
    return 1;
}

int uiofmu_check_period(char *msg, size_t len, double dt, double step_rtol) {
    if (!(isfinite(dt) && dt > 0) || !(isfinite(step_rtol) && step_rtol >= 0))
        return uiofmu_design_error(msg, len, "dt = %g, step_rtol = %g: expected a finite period > 0 and step_rtol >= 0",
                                   dt, step_rtol);
    return 1;
}

int uiofmu_mul(size_t a, size_t b, size_t limit, size_t *out) {
    if (a && b > limit / a) return 0;
    *out = a * b;
    return 1;
}

/* ---------------------------------------------------------------------------------------- */
/* Instances and steps                                                                       */

void *uiofmu_alloc(FmuInstance *fmu, size_t count, size_t size) {
    void *p = calloc(count ? count : 1, size);
    if (!p) uiofmu_log(fmu, fmi2Error, "fmi2Instantiate: out of memory");
    return p;
}

int uiofmu_parameter_finite(FmuInstance *fmu, const char *name, const double *v, int len) {
    char b1[32];
    for (int i = 0; i < len; i++)
        if (!isfinite(v[i])) {
            uiofmu_log(fmu, fmi2Error, "parameter %s[%d] = %s is not finite", name, i + 1, uiofmu_num(v[i], b1));
            return 0;
        }
    return 1;
}

/* uiofmu_inputs_finite's refusal of element i, v = name[i + 1]. */
UIOFMU_COLD static int input_not_finite(FmuInstance *fmu, double t, long k, double v, int i, const char *name) {
    char bt[32], at[48] = "";
    if (k >= 0) snprintf(at, sizeof at, " at step k = %ld", k);
    uiofmu_log(fmu, fmi2Error, "t = %s: " UIOFMU_REFUSAL_INPUT_NOT_FINITE, uiofmu_num(t, bt), name, i + 1,
               isnan(v) ? "nan" : (v > 0 ? "inf" : "-inf"), at);
    return 0;
}

int uiofmu_inputs_finite(FmuInstance *fmu, double t, long k, const double *v, int len, const char *name) {
    for (int i = 0; i < len; i++)
        if (!isfinite(v[i])) return input_not_finite(fmu, t, k, v[i], i, name);
    return 1;
}

int uiofmu_off_period(FmuInstance *fmu, double t, double h, double dt, double step_rtol, int observer) {
    char bt[32], bh[32], bd[32];
    if (!(fabs(h - dt) > step_rtol * dt)) return 0;
    if (observer)
        uiofmu_log(fmu, fmi2Discard, "t = %s: " UIOFMU_REFUSAL_OBSERVER_OFF_PERIOD, uiofmu_num(t, bt),
                   uiofmu_num(dt, bd), uiofmu_num(h, bh), "error");
    else
        uiofmu_log(fmu, fmi2Discard, "t = %s: " UIOFMU_REFUSAL_PLANT_OFF_PERIOD, uiofmu_num(t, bt),
                   uiofmu_num(dt, bd), uiofmu_num(h, bh));
    return 1;
}

int uiofmu_next_state_finite(FmuInstance *fmu, double t, double h, const double *xn, int n) {
    char bt[32], bh[32];
    for (int i = 0; i < n; i++)
        if (!isfinite(xn[i])) {
            uiofmu_log(fmu, fmi2Error, "t = %s: the state x[%d] after the step h = %s s would not be finite",
                       uiofmu_num(t, bt), i + 1, uiofmu_num(h, bh));
            return 0;
        }
    return 1;
}

/* ---------------------------------------------------------------------------------------- */
/* The kernel's part of the FMU state                                                        */

double uiofmu_getd(const unsigned char *b, size_t index) {
    double v;
    memcpy(&v, b + index * sizeof v, sizeof v);
    return v;
}

unsigned char *uiofmu_put(unsigned char *o, const double *v, size_t n) {
    memcpy(o, v, n * sizeof(double));
    return o + n * sizeof(double);
}

const unsigned char *uiofmu_take(const unsigned char *o, double *v, size_t n) {
    memcpy(v, o, n * sizeof(double));
    return o + n * sizeof(double);
}

void uiofmu_shape(uint32_t shape[UIOFMU_SHAPE], const char *names[UIOFMU_SHAPE], const int dims[UIOFMU_SHAPE],
                  const char *const dim_names[UIOFMU_SHAPE]) {
    for (int i = 0; i < UIOFMU_SHAPE; i++) {
        shape[i] = (uint32_t)dims[i];
        names[i] = dim_names[i];
    }
}

int uiofmu_phase_ok(FmuInstance *fmu, const char *ctx, double phase) {
    char b1[32];
    if (phase == UIOFMU_PHASE_INSTANTIATED || phase == UIOFMU_PHASE_INITIALIZATION || phase == UIOFMU_PHASE_RUNNING ||
        phase == UIOFMU_PHASE_TERMINATED)
        return 1;
    return uiofmu_state_refused(fmu, ctx, "phase = %s is none of 0 (instantiated), 1 (initialisation mode), "
                                "2 (initialised), 3 (terminated)", uiofmu_num(phase, b1));
}

int uiofmu_plant_x_ok(FmuInstance *fmu, const char *ctx, const unsigned char *v, size_t at, int n, double phase,
                      const double *design_x0) {
    char b1[32], b2[32];
    for (int w = 0; w < 2; w++)
        for (int i = 0; i < n; i++) {
            double x = uiofmu_getd(v, at + (size_t)w * (size_t)n + (size_t)i);
            if (!isfinite(x))
                return uiofmu_state_refused(fmu, ctx, "%s[%d] = %s is not finite", w ? "x" : "x0", i + 1,
                                            uiofmu_num(x, b1));
            if (w == 1 && phase < UIOFMU_PHASE_RUNNING && x != design_x0[i])
                return uiofmu_state_refused(fmu, ctx, "x[%d] = %s in phase %d, before initialisation ended: expected "
                                            "the design's x0[%d] = %s", i + 1, uiofmu_num(x, b1), (int)phase, i + 1,
                                            uiofmu_num(design_x0[i], b2));
        }
    return 1;
}
