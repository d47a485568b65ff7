/* uiofmu: the kernel of plants with unknown parameters (seed 001's plant), the model code of their
 * C plant FMUs.
 *
 * It plugs into the shared FMI 2.0 plumbing (fmi2_plumbing.c) through UIOFMU_KERNEL_PARAMETRIC;
 * the plant's numbers come from design_data.c (UIOFMU_PARAMETRIC). The step semantics are those of
 * the reference runtime (uiofmu/runtime/parametric_plant.py), operation for operation:
 *
 *   f(x)              A x + B u + (D0 + sum_i (C x)_i Dy[i]) theta, u held
 *   outputs           y = C x, ydot = C f(x) (with the current u), x
 *   initialisation    x = the parameter x0; theta = the parameter theta, and the substep
 *                     0.02 / max(1, rate), rate = ||A|| + sum |Dy| max |theta| ||C|| + sum |D0|
 *                     (infinite when it overflows)
 *   fmi2DoStep(t, h)  ceil(h / substep) classical RK4 substeps (at most MAX_SUBSTEPS, else
 *                     fmi2Discard with the runtime's message and the longest step taken)
 *
 * Non-finite inputs are refused with fmi2Error and a log line naming the input; so is a step whose
 * new state is not finite (the other C plants' rule); either way nothing changes.
 *
 * FMU state: after the plumbing's header (the shape words n, m, p, n_theta), 1 + 2 n + m + 2 n_theta
 * doubles, written and read with memcpy:
 *
 *   phase, x0[n], x[n], u[m], theta[nt], params[nt]
 *
 * checked before any of it is used (check_values): the phase one of 0 .. 3; x0 and x finite, and x
 * the design's x0 before initialisation ended (uiofmu_plant_x_ok); theta (the parameter) and params
 * (the theta the plant simulates since initialisation) finite, params the design's theta before
 * initialisation ended; u any value, NaN and Inf included (an input that fmi2SetReal takes and
 * fmi2DoStep refuses). The substep is a function of params, recomputed when a state is taken.
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2_plumbing.h"
#include "kernel_parametric.h"
#include "kernel_util.h"

#define MAX_DIM 1000
/* Most RK4 substeps of one communication step, and the substep as a fraction of the fastest time
   constant (uiofmu/runtime/parametric_plant.py MAX_SUBSTEPS, SUBSTEP_FRACTION). */
#define MAX_SUBSTEPS 20000
#define SUBSTEP_FRACTION 0.02

/* The ports' names, causalities and types by id (kernel_parametric_ports.h, generated). */
static const char *const PORT_NAME[UIOFMU_PARAMETRIC_PORTS] = UIOFMU_PARAMETRIC_PORT_NAMES;
static const int PORT_CAUSALITY[UIOFMU_PARAMETRIC_PORTS] = UIOFMU_PARAMETRIC_PORT_CAUSALITIES;
static const int PORT_TYPE[UIOFMU_PARAMETRIC_PORTS] = UIOFMU_PARAMETRIC_PORT_TYPES;

typedef struct {
    FmuInstance *fmu;
    const UiofmuParametric *d;
    /* state */
    double *x0, *x, *u, *theta, *params;
    double substep;
    /* outputs and work space */
    int dirty;
    double *y, *ydot, *fx, *k1, *k2, *k3, *k4, *arg, *xn, *cx;
    double *block;
} Parametric;

/* ---------------------------------------------------------------------------------------- */
/* The maths                                                                                  */

/* The substep of the parameters (apply_parameters): 0.02 / max(1, rate), Python's max. */
static double substep_of(const UiofmuParametric *d, const double *theta) {
    double big = 0.0;
    for (int i = 0; i < d->nt; i++) {
        double a = fabs(theta[i]);
        if (a > big || isnan(a)) big = a;
    }
    double value = d->norm_A + (d->sum_Dy * big * d->norm_C + d->sum_D0);
    double rate = isfinite(value) ? value : INFINITY;
    return SUBSTEP_FRACTION / (rate > 1.0 ? rate : 1.0);
}

/* out = f(x): A x + B u + (D0 + sum_l (C x)_l Dy[l]) params. */
static void rhs(Parametric *s, const double *x, double *out) {
    const UiofmuParametric *d = s->d;
    int n = d->n, m = d->m, p = d->p, nt = d->nt;
    for (int l = 0; l < p; l++) {
        double acc = 0.0;
        for (int r = 0; r < n; r++) acc += d->C[(size_t)l * n + r] * x[r];
        s->cx[l] = acc;
    }
    for (int r = 0; r < n; r++) {
        double ax = 0.0, bu = 0.0, dth = 0.0;
        for (int j = 0; j < n; j++) ax += d->A[(size_t)r * n + j] * x[j];
        for (int j = 0; j < m; j++) bu += d->B[(size_t)r * m + j] * s->u[j];
        for (int q = 0; q < nt; q++) {
            double acc = 0.0;
            for (int l = 0; l < p; l++) acc += s->cx[l] * d->Dy[((size_t)l * n + r) * nt + q];
            dth += (d->D0[(size_t)r * nt + q] + acc) * s->params[q];
        }
        out[r] = ax + bu + dth;
    }
}

static void refresh(Parametric *s) {
    const UiofmuParametric *d = s->d;
    if (!s->dirty) return;
    rhs(s, s->x, s->fx);
    for (int l = 0; l < d->p; l++) {
        double acc = 0.0, accd = 0.0;
        for (int r = 0; r < d->n; r++) {
            acc += d->C[(size_t)l * d->n + r] * s->x[r];
            accd += d->C[(size_t)l * d->n + r] * s->fx[r];
        }
        s->y[l] = acc;
        s->ydot[l] = accd;
    }
    s->dirty = 0;
}

static void reset_state(Parametric *s) {
    memcpy(s->x, s->x0, (size_t)s->d->n * sizeof(double));
    s->dirty = 1;
}

/* ---------------------------------------------------------------------------------------- */
/* The design, checked once at fmi2Instantiate                                                */

static int check_design_data(const UiofmuParametric *d, char *msg, size_t len) {
    const int dims[4] = {d->n, d->m, d->p, d->nt}, low[4] = {1, 0, 1, 1};
    const char *const names[4] = {"n", "m", "p", "n_theta"};
    if (!uiofmu_check_dims(msg, len, "plant ", 4, dims, names, low, MAX_DIM)) return 0;
    size_t n = (size_t)d->n, m = (size_t)d->m, p = (size_t)d->p, nt = (size_t)d->nt;
    if (!uiofmu_check_array(msg, len, "plant ", "A", d->A, d->A_length, n * n) ||
        !uiofmu_check_array(msg, len, "plant ", "B", d->B, d->B_length, n * m) ||
        !uiofmu_check_array(msg, len, "plant ", "C", d->C, d->C_length, p * n) ||
        !uiofmu_check_array(msg, len, "plant ", "D0", d->D0, d->D0_length, n * nt) ||
        !uiofmu_check_array(msg, len, "plant ", "Dy", d->Dy, d->Dy_length, p * n * nt) ||
        !uiofmu_check_array(msg, len, "plant ", "x0", d->x0, d->x0_length, n) ||
        !uiofmu_check_array(msg, len, "plant ", "theta", d->theta, d->theta_length, nt))
        return 0;
    if (!(isfinite(d->norm_A) && d->norm_A >= 0 && isfinite(d->norm_C) && d->norm_C >= 0 && isfinite(d->sum_Dy) &&
          d->sum_Dy >= 0 && isfinite(d->sum_D0) && d->sum_D0 >= 0))
        return uiofmu_design_error(msg, len, "plant rate terms ||A|| = %g, ||C|| = %g, sum |Dy| = %g, sum |D0| = %g: "
                                   "expected finite numbers >= 0", d->norm_A, d->norm_C, d->sum_Dy, d->sum_D0);
    return 1;
}

/* ---------------------------------------------------------------------------------------- */
/* The kernel's operations (UiofmuKernel)                                                    */

static int parametric_check_design(char *msg, size_t len) { return check_design_data(&UIOFMU_PARAMETRIC, msg, len); }

static int parametric_port(int id, UiofmuPort *out) {
    const UiofmuParametric *d = &UIOFMU_PARAMETRIC;
    int size;
    switch (id) {
    case UIOFMU_PARAMETRIC_X0: case UIOFMU_PARAMETRIC_X: size = d->n; break;
    case UIOFMU_PARAMETRIC_THETA: size = d->nt; break;
    case UIOFMU_PARAMETRIC_U: size = d->m; break;
    case UIOFMU_PARAMETRIC_Y: case UIOFMU_PARAMETRIC_YDOT: size = d->p; break;
    default: return 0;
    }
    out->name = PORT_NAME[id];
    out->size = size;
    out->causality = PORT_CAUSALITY[id];
    out->type = PORT_TYPE[id];
    return 1;
}

static void parametric_reset(void *self) {
    Parametric *s = (Parametric *)self;
    const UiofmuParametric *d = s->d;
    memcpy(s->x0, d->x0, (size_t)d->n * sizeof(double));
    memcpy(s->theta, d->theta, (size_t)d->nt * sizeof(double));
    memcpy(s->params, d->theta, (size_t)d->nt * sizeof(double));
    memset(s->u, 0, (size_t)d->m * sizeof(double));
    s->substep = substep_of(d, s->params);
    reset_state(s);
}

static void *parametric_instantiate(FmuInstance *fmu) {
    const UiofmuParametric *d = &UIOFMU_PARAMETRIC;
    Parametric *s = (Parametric *)uiofmu_alloc(fmu, 1, sizeof(Parametric));
    if (!s) return NULL;
    s->fmu = fmu;
    s->d = d;
    size_t n = (size_t)d->n, m = (size_t)d->m, p = (size_t)d->p, nt = (size_t)d->nt;
    s->block = (double *)uiofmu_alloc(fmu, 10 * n + m + 2 * nt + 3 * p, sizeof(double));
    if (!s->block) {
        free(s);
        return NULL;
    }
    double *b = s->block;
    double **slots[] = {&s->x0, &s->x, &s->fx, &s->k1, &s->k2, &s->k3, &s->k4, &s->arg, &s->xn};
    for (size_t i = 0; i < UIOFMU_LENGTH(slots); i++) {
        *slots[i] = b;
        b += n;
    }
    s->u = b; b += m;
    s->theta = b; b += nt;
    s->params = b; b += nt;
    s->y = b; b += p;
    s->ydot = b; b += p;
    s->cx = b;
    parametric_reset(s);
    return s;
}

static void parametric_free(void *self) {
    Parametric *s = (Parametric *)self;
    if (!s) return;
    free(s->block);
    free(s);
}

static UiofmuResult parametric_exit_initialization(void *self) {
    Parametric *s = (Parametric *)self;
    const UiofmuParametric *d = s->d;
    if (!uiofmu_parameter_finite(s->fmu, PORT_NAME[UIOFMU_PARAMETRIC_X0], s->x0, d->n) ||
        !uiofmu_parameter_finite(s->fmu, PORT_NAME[UIOFMU_PARAMETRIC_THETA], s->theta, d->nt))
        return UIOFMU_REFUSED;
    memcpy(s->params, s->theta, (size_t)d->nt * sizeof(double));
    s->substep = substep_of(d, s->params);
    reset_state(s);
    return UIOFMU_DONE;
}

static UiofmuResult parametric_calculate(void *self, const char *fn) {
    (void)fn;
    refresh((Parametric *)self);
    return UIOFMU_DONE;
}

/* The storage of element `index` of port `port` (the plumbing checked both against the table). */
static double *parametric_real_storage(void *self, int port, int index) {
    Parametric *s = (Parametric *)self;
    double *const first[UIOFMU_PARAMETRIC_PORTS] = {[UIOFMU_PARAMETRIC_X0] = s->x0,
                                                    [UIOFMU_PARAMETRIC_THETA] = s->theta, [UIOFMU_PARAMETRIC_U] = s->u,
                                                    [UIOFMU_PARAMETRIC_Y] = s->y, [UIOFMU_PARAMETRIC_YDOT] = s->ydot,
                                                    [UIOFMU_PARAMETRIC_X] = s->x};
    return uiofmu_element(first, port, index);
}

/* The plumbing stored new values: the outputs are computed again before they are read. */
static void parametric_changed(void *self) { ((Parametric *)self)->dirty = 1; }

static UiofmuResult parametric_step(void *self, double t, double h) {
    Parametric *s = (Parametric *)self;
    const UiofmuParametric *d = s->d;
    char bt[32];
    int n = d->n;
    if (!uiofmu_inputs_finite(s->fmu, t, -1, s->u, d->m, PORT_NAME[UIOFMU_PARAMETRIC_U])) return UIOFMU_REFUSED;
    double count = h / s->substep - 1e-9;
    if (!(count <= MAX_SUBSTEPS)) {
        uiofmu_log(s->fmu, fmi2Discard, "t = %s: communication step h = %.6g s needs %.3g RK4 substeps of the plant "
                   "(at most %.3g s each), more than the %d a step may take: take steps of at most %.6g s",
                   uiofmu_num(t, bt), h, count + 1e-9, s->substep, MAX_SUBSTEPS, MAX_SUBSTEPS * s->substep);
        return UIOFMU_DISCARDED;
    }
    int steps = (int)ceil(count);
    if (steps < 1) steps = 1;
    double dt = h / steps;
    memcpy(s->xn, s->x, (size_t)n * sizeof(double));
    for (int i = 0; i < steps; i++) {
        rhs(s, s->xn, s->k1);
        for (int e = 0; e < n; e++) s->arg[e] = s->xn[e] + dt / 2 * s->k1[e];
        rhs(s, s->arg, s->k2);
        for (int e = 0; e < n; e++) s->arg[e] = s->xn[e] + dt / 2 * s->k2[e];
        rhs(s, s->arg, s->k3);
        for (int e = 0; e < n; e++) s->arg[e] = s->xn[e] + dt * s->k3[e];
        rhs(s, s->arg, s->k4);
        for (int e = 0; e < n; e++) s->xn[e] = s->xn[e] + dt / 6 * (s->k1[e] + 2 * s->k2[e] + 2 * s->k3[e] + s->k4[e]);
    }
    if (!uiofmu_next_state_finite(s->fmu, t, h, s->xn, n)) return UIOFMU_REFUSED;
    memcpy(s->x, s->xn, (size_t)n * sizeof(double));
    s->dirty = 1;
    return UIOFMU_DONE;
}

/* ---------------------------------------------------------------------------------------- */
/* FMU state (see the top of this file)                                                      */

enum { SV_PHASE, SV_SCALARS };

typedef unsigned char Byte;

static size_t parametric_state_count(void) {
    const UiofmuParametric *d = &UIOFMU_PARAMETRIC;
    return SV_SCALARS + 2 * (size_t)d->n + (size_t)d->m + 2 * (size_t)d->nt;
}

static void parametric_state_shape(uint32_t shape[UIOFMU_SHAPE], const char *names[UIOFMU_SHAPE]) {
    const UiofmuParametric *d = &UIOFMU_PARAMETRIC;
    static const char *const NAMES[UIOFMU_SHAPE] = {"n", "m", "p", "n_theta"};
    const int dims[UIOFMU_SHAPE] = {d->n, d->m, d->p, d->nt};
    uiofmu_shape(shape, names, dims, NAMES);
}

static void parametric_save_state(void *self, int phase, Byte *o) {
    Parametric *s = (Parametric *)self;
    const UiofmuParametric *d = s->d;
    double scalars[SV_SCALARS] = {(double)phase};
    o = uiofmu_put(o, scalars, SV_SCALARS);
    o = uiofmu_put(o, s->x0, (size_t)d->n);
    o = uiofmu_put(o, s->x, (size_t)d->n);
    o = uiofmu_put(o, s->u, (size_t)d->m);
    o = uiofmu_put(o, s->theta, (size_t)d->nt);
    uiofmu_put(o, s->params, (size_t)d->nt);
}

static int parametric_check_state(void *self, const char *ctx, const Byte *v, int *phase) {
    Parametric *s = (Parametric *)self;
    const UiofmuParametric *d = s->d;
    char b1[32], b2[32];
    double ph = uiofmu_getd(v, SV_PHASE);
    if (!uiofmu_phase_ok(s->fmu, ctx, ph)) return 0;
    if (!uiofmu_plant_x_ok(s->fmu, ctx, v, SV_SCALARS, d->n, ph, d->x0)) return 0;
    size_t at = SV_SCALARS + 2 * (size_t)d->n + (size_t)d->m;
    for (int w = 0; w < 2; w++)
        for (int i = 0; i < d->nt; i++) {
            double x = uiofmu_getd(v, at + (size_t)w * (size_t)d->nt + (size_t)i);
            if (!isfinite(x))
                return uiofmu_state_refused(s->fmu, ctx, "%s[%d] = %s is not finite", w ? "params" : "theta", i + 1,
                                            uiofmu_num(x, b1));
            if (w == 1 && ph < UIOFMU_PHASE_RUNNING && x != d->theta[i])
                return uiofmu_state_refused(s->fmu, ctx, "params[%d] = %s in phase %d, before initialisation ended: "
                                            "expected the design's theta[%d] = %s", i + 1, uiofmu_num(x, b1), (int)ph,
                                            i + 1, uiofmu_num(d->theta[i], b2));
        }
    *phase = (int)ph;
    return 1;
}

static void parametric_load_state(void *self, const Byte *v) {
    Parametric *s = (Parametric *)self;
    const UiofmuParametric *d = s->d;
    const Byte *o = v + SV_SCALARS * sizeof(double);
    o = uiofmu_take(o, s->x0, (size_t)d->n);
    o = uiofmu_take(o, s->x, (size_t)d->n);
    o = uiofmu_take(o, s->u, (size_t)d->m);
    o = uiofmu_take(o, s->theta, (size_t)d->nt);
    uiofmu_take(o, s->params, (size_t)d->nt);
    s->substep = substep_of(d, s->params);
    s->dirty = 1;
}

const UiofmuKernel UIOFMU_KERNEL_PARAMETRIC = {
    .name = "parametric",
    .check_design = parametric_check_design,
    .ports = UIOFMU_PARAMETRIC_PORTS,
    .port = parametric_port,
    .instantiate = parametric_instantiate,
    .free_instance = parametric_free,
    .reset = parametric_reset,
    .exit_initialization = parametric_exit_initialization,
    .calculate = parametric_calculate,
    .real_storage = parametric_real_storage,
    .changed = parametric_changed,
    .get_integer = NULL,
    .set_integer = NULL,
    .step = parametric_step,
    .state_count = parametric_state_count,
    .state_shape = parametric_state_shape,
    .save_state = parametric_save_state,
    .check_state = parametric_check_state,
    .load_state = parametric_load_state,
};
