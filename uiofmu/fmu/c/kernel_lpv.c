/* uiofmu: the LPV plant kernel, the model code of uiofmu's C LPV plant FMUs.
 *
 * It plugs into the shared FMI 2.0 plumbing (fmi2_plumbing.c) through UIOFMU_KERNEL_LPV; the
 * plant's numbers come from design_data.c (UIOFMU_LPV, generated from LpvPlant.to_data()). The
 * step semantics are those of the reference runtime (uiofmu/runtime/lpv.py):
 *
 *   theta_k           = T x_k (kind state: the plant is then the nonlinear system it describes,
 *                       exactly), or the input theta (kind input)
 *   M(theta)          = M_0 + sum_i theta^(i) M_i     for M = A, E, C, D
 *   outputs:          y = C(theta_k) x_k + D(theta_k) d_k (d feeds through), x, and for kind
 *                     state theta_k
 *   initialisation:   x = the parameter x0            (before it: the design's x0)
 *   fmi2DoStep(t, h): x <- A(theta_k) x + E(theta_k) d, inputs d, theta held over the step
 *
 * A discrete plant: a step other than dt (relative tolerance step_rtol, as
 * uiofmu/runtime/tolerances.py STEP_RTOL) is refused with fmi2Discard and a log line naming h
 * and dt. Non-finite inputs d or theta are refused with fmi2Error and a log line naming the
 * input (before the step length is looked at, as the reference runtime); a step whose new state
 * is not finite (a nonlinear plant can blow up) is refused the same way. Either way nothing
 * changes.
 *
 * FMU state: after the plumbing's header (magic, layout, size, GUID, the shape words n, p, q, s
 * and the count of doubles), 1 + 2n + q + s doubles, written and read with memcpy:
 *
 *   phase, x0[n], x[n], d[q], theta[s]
 *
 * checked before any of it is used (check_state): phase one of 0 (instantiated), 1
 * (initialisation mode), 2 (initialised; a discarded step is saved as 2: it changed nothing),
 * 3 (terminated); x0 and x finite (fmi2ExitInitializationMode refuses a non-finite x0, so a
 * state holding one is refused whatever its phase); before initialisation ended (phase 0 and
 * 1) x is the design's x0, bit for bit (only initialisation moves it there); d any value, NaN
 * and Inf included (an input that fmi2SetReal takes and fmi2DoStep refuses); theta the input
 * (kind input: any value, as d) or 0 (kind state: theta is then an output, nothing sets the
 * input).
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2_plumbing.h"
#include "kernel_lpv.h"
#include "kernel_util.h"

/* Bounds of what a plant may ask for. */
#define MAX_DIM 2048
#define MAX_NUMBERS 67108864 /* doubles of one array */

/* The ports' names, causalities and types by id (kernel_lpv_ports.h, generated). */
static const char *const PORT_NAME[UIOFMU_LPV_PORTS] = UIOFMU_LPV_PORT_NAMES;
static const int PORT_CAUSALITY[UIOFMU_LPV_PORTS] = UIOFMU_LPV_PORT_CAUSALITIES;
static const int PORT_TYPE[UIOFMU_LPV_PORTS] = UIOFMU_LPV_PORT_TYPES;

typedef struct {
    FmuInstance *fmu;
    const UiofmuLpv *d;
    double *x0, *x, *dv, *theta_in; /* the state (what fmi2GetFMUstate saves) */
    double *th, *y, *xn, *t1;       /* theta_k, the outputs, the next state, work */
    double *MA, *ME, *MC, *MD;      /* A(theta_k), E(theta_k), C(theta_k), D(theta_k) */
    int dirty;
    double *block; /* every double above, one allocation */
} Lpv;

/* ---------------------------------------------------------------------------------------- */
/* The maths                                                                                  */

/* theta_k into s->th: T x (kind state) or the input. */
static void current_theta(Lpv *s) {
    const UiofmuLpv *d = s->d;
    if (d->kind == UIOFMU_THETA_INPUT) {
        memcpy(s->th, s->theta_in, (size_t)d->s * sizeof(double));
        return;
    }
    for (int i = 0; i < d->s; i++) {
        double acc = 0.0;
        for (int j = 0; j < d->n; j++) acc += d->T[(size_t)i * d->n + j] * s->x[j];
        s->th[i] = acc;
    }
}

/* out = M_0 + sum_i theta^(i) M_i of a matrix of `size` numbers stored as 1 + s blocks. */
static void scheduled(const double *parts, size_t size, const double *theta, int ns, double *out) {
    for (size_t e = 0; e < size; e++) {
        double acc = 0.0;
        for (int i = 0; i < ns; i++) acc += theta[i] * parts[(size_t)(i + 1) * size + e];
        out[e] = parts[e] + acc;
    }
}

/* out = A x + B v (A rows x na, B rows x nb), t work of rows doubles. */
static void affine_map(const double *A, const double *x, int na, const double *B, const double *v, int nb, int rows,
                       double *out, double *t) {
    for (int i = 0; i < rows; i++) {
        double ax = 0.0, bv = 0.0;
        for (int j = 0; j < na; j++) ax += A[(size_t)i * na + j] * x[j];
        for (int j = 0; j < nb; j++) bv += B[(size_t)i * nb + j] * v[j];
        out[i] = ax;
        t[i] = bv;
    }
    for (int i = 0; i < rows; i++) out[i] += t[i];
}

/* ---------------------------------------------------------------------------------------- */
/* The design, checked once at fmi2Instantiate                                               */

/* a * b * c in *out, 0 when it exceeds MAX_NUMBERS. */
static int count3(size_t a, size_t b, size_t c, size_t *out) {
    size_t ab;
    return uiofmu_mul(a, b, MAX_NUMBERS, &ab) && uiofmu_mul(ab, c, MAX_NUMBERS, out);
}

static int lpv_check_design(char *msg, size_t len) {
    const UiofmuLpv *d = &UIOFMU_LPV;
    const int dims[4] = {d->n, d->p, d->q, d->s}, low[4] = {1, 1, 0, 0};
    const char *const dim_name[4] = {"n", "p", "q", "s"};
    if (!uiofmu_check_dims(msg, len, "plant ", 4, dims, dim_name, low, MAX_DIM)) return 0;
    if (d->kind != UIOFMU_THETA_STATE && d->kind != UIOFMU_THETA_INPUT)
        return uiofmu_design_error(msg, len, "theta kind %d is neither state (0) nor input (1)", d->kind);
    if ((PORT_CAUSALITY[UIOFMU_LPV_THETA] == UIOFMU_INPUT) != (d->kind == UIOFMU_THETA_INPUT))
        return uiofmu_design_error(msg, len, "port %s is declared with causality %d, theta kind %d needs %s",
                                   PORT_NAME[UIOFMU_LPV_THETA], PORT_CAUSALITY[UIOFMU_LPV_THETA], d->kind,
                                   d->kind == UIOFMU_THETA_INPUT ? "an input" : "an output");
    if (!uiofmu_check_period(msg, len, d->dt, d->step_rtol)) return 0;
    size_t blocks = 1 + (size_t)d->s;
    const char *const name[6] = {"A", "E", "C", "D", "T", "x0"};
    const double *data[6] = {d->A, d->E, d->C, d->D, d->T, d->x0};
    const size_t length[6] = {d->A_length, d->E_length, d->C_length, d->D_length, d->T_length, d->x0_length};
    const size_t a[6] = {blocks, blocks, blocks, blocks, 1, 1};
    const size_t rows[6] = {(size_t)d->n, (size_t)d->n, (size_t)d->p, (size_t)d->p, (size_t)d->s, 1};
    const size_t cols[6] = {(size_t)d->n, (size_t)d->q, (size_t)d->n, (size_t)d->q, (size_t)d->n, (size_t)d->n};
    for (int w = 0; w < 6; w++) {
        size_t want;
        if (!count3(a[w], rows[w], cols[w], &want))
            return uiofmu_design_error(msg, len, "plant %s: %zu blocks of %zu x %zu are more than %d numbers", name[w],
                                       a[w], rows[w], cols[w], MAX_NUMBERS);
        if (!data[w] || length[w] != (want ? want : 1))
            return uiofmu_design_error(msg, len, "plant %s: %zu blocks of %zu x %zu need %zu numbers, its array "
                                       "holds %zu", name[w], a[w], rows[w], cols[w], want, data[w] ? length[w] : 0);
        for (size_t e = 0; e < want; e++)
            if (!isfinite(data[w][e]))
                return uiofmu_design_error(msg, len, "plant %s[%zu] = %g is not finite", name[w], e, data[w][e]);
    }
    if (d->kind == UIOFMU_THETA_INPUT)
        for (size_t e = 0; e < (size_t)d->s * (size_t)d->n; e++)
            if (d->T[e] != 0)
                return uiofmu_design_error(msg, len, "plant T[%zu] = %g, but theta is an input", e, d->T[e]);
    return 1;
}

/* ---------------------------------------------------------------------------------------- */
/* The kernel's operations (UiofmuKernel)                                                    */

static int lpv_port(int id, UiofmuPort *out) {
    const UiofmuLpv *d = &UIOFMU_LPV;
    int size;
    switch (id) {
    case UIOFMU_LPV_X0: case UIOFMU_LPV_X: size = d->n; break;
    case UIOFMU_LPV_U: size = 0; break;
    case UIOFMU_LPV_D: size = d->q; break;
    case UIOFMU_LPV_THETA: size = d->s; break;
    case UIOFMU_LPV_Y: size = d->p; break;
    default: return 0;
    }
    out->name = PORT_NAME[id];
    out->size = size;
    out->causality = PORT_CAUSALITY[id];
    out->type = PORT_TYPE[id];
    return 1;
}

static void lpv_reset(void *self) {
    Lpv *s = (Lpv *)self;
    const UiofmuLpv *d = s->d;
    memcpy(s->x0, d->x0, (size_t)d->n * sizeof(double));
    memcpy(s->x, d->x0, (size_t)d->n * sizeof(double));
    memset(s->dv, 0, (size_t)d->q * sizeof(double));
    memset(s->theta_in, 0, (size_t)d->s * sizeof(double));
    s->dirty = 1;
}

static void *lpv_instantiate(FmuInstance *fmu) {
    const UiofmuLpv *d = &UIOFMU_LPV;
    Lpv *s = (Lpv *)uiofmu_alloc(fmu, 1, sizeof(Lpv));
    if (!s) return NULL;
    s->fmu = fmu;
    s->d = d;
    /* bounded by the checked design: each matrix is one block of its array */
    size_t n = (size_t)d->n, p = (size_t)d->p, q = (size_t)d->q, ns = (size_t)d->s;
    size_t big = n > p ? n : p;
    size_t total = 3 * n + q + 2 * ns + p + big + n * n + n * q + p * n + p * q;
    s->block = (double *)uiofmu_alloc(fmu, total, sizeof(double));
    if (!s->block) {
        free(s);
        return NULL;
    }
    double *b = s->block;
    s->x0 = b; b += n;
    s->x = b; b += n;
    s->xn = b; b += n;
    s->dv = b; b += q;
    s->theta_in = b; b += ns;
    s->th = b; b += ns;
    s->y = b; b += p;
    s->t1 = b; b += big;
    s->MA = b; b += n * n;
    s->ME = b; b += n * q;
    s->MC = b; b += p * n;
    s->MD = b;
    lpv_reset(s);
    return s;
}

static void lpv_free(void *self) {
    Lpv *s = (Lpv *)self;
    if (!s) return;
    free(s->block);
    free(s);
}

static UiofmuResult lpv_exit_initialization(void *self) {
    Lpv *s = (Lpv *)self;
    if (!uiofmu_parameter_finite(s->fmu, PORT_NAME[UIOFMU_LPV_X0], s->x0, s->d->n)) return UIOFMU_REFUSED;
    memcpy(s->x, s->x0, (size_t)s->d->n * sizeof(double));
    s->dirty = 1;
    return UIOFMU_DONE;
}

static UiofmuResult lpv_calculate(void *self, const char *fn) {
    Lpv *s = (Lpv *)self;
    const UiofmuLpv *d = s->d;
    (void)fn;
    if (!s->dirty) return UIOFMU_DONE;
    current_theta(s);
    scheduled(d->C, (size_t)d->p * d->n, s->th, d->s, s->MC);
    scheduled(d->D, (size_t)d->p * d->q, s->th, d->s, s->MD);
    affine_map(s->MC, s->x, d->n, s->MD, s->dv, d->q, d->p, s->y, s->t1);
    s->dirty = 0;
    return UIOFMU_DONE;
}

/* The storage of element `index` of port `port` (the plumbing checked both against the table). */
static double *lpv_real_storage(void *self, int port, int index) {
    Lpv *s = (Lpv *)self;
    double *theta = s->d->kind == UIOFMU_THETA_INPUT ? s->theta_in : s->th; /* an input, or theta_k */
    double *const first[UIOFMU_LPV_PORTS] = {[UIOFMU_LPV_X0] = s->x0, [UIOFMU_LPV_D] = s->dv, [UIOFMU_LPV_THETA] = theta,
                                             [UIOFMU_LPV_Y] = s->y, [UIOFMU_LPV_X] = s->x}; /* u has no elements */
    return uiofmu_element(first, port, index);
}

/* The plumbing stored new values: the outputs are computed again before they are read. */
static void lpv_changed(void *self) { ((Lpv *)self)->dirty = 1; }

static UiofmuResult lpv_step(void *self, double t, double h) {
    Lpv *s = (Lpv *)self;
    const UiofmuLpv *d = s->d;
    int n = d->n, q = d->q;
    if (!uiofmu_inputs_finite(s->fmu, t, -1, s->dv, q, PORT_NAME[UIOFMU_LPV_D]) ||
        !uiofmu_inputs_finite(s->fmu, t, -1, s->theta_in, d->s, PORT_NAME[UIOFMU_LPV_THETA]))
        return UIOFMU_REFUSED;
    if (uiofmu_off_period(s->fmu, t, h, d->dt, d->step_rtol, 0)) return UIOFMU_DISCARDED;
    current_theta(s);
    scheduled(d->A, (size_t)n * n, s->th, d->s, s->MA);
    scheduled(d->E, (size_t)n * q, s->th, d->s, s->ME);
    affine_map(s->MA, s->x, n, s->ME, s->dv, q, n, s->xn, s->t1);
    if (!uiofmu_next_state_finite(s->fmu, t, h, s->xn, n))
        return UIOFMU_REFUSED; /* th is theta_k of the unchanged state: nothing changed */
    memcpy(s->x, s->xn, (size_t)n * sizeof(double));
    s->dirty = 1;
    return UIOFMU_DONE;
}

/* ---------------------------------------------------------------------------------------- */
/* FMU state (layout in the header comment)                                                  */

typedef unsigned char Byte;

static size_t lpv_state_count(void) {
    const UiofmuLpv *d = &UIOFMU_LPV;
    return 1 + 2 * (size_t)d->n + (size_t)d->q + (size_t)d->s;
}

static void lpv_state_shape(uint32_t shape[UIOFMU_SHAPE], const char *names[UIOFMU_SHAPE]) {
    const UiofmuLpv *d = &UIOFMU_LPV;
    static const char *const NAMES[UIOFMU_SHAPE] = {"n", "p", "q", "s"};
    const int dims[UIOFMU_SHAPE] = {d->n, d->p, d->q, d->s};
    uiofmu_shape(shape, names, dims, NAMES);
}

static void lpv_save_state(void *self, int phase, Byte *o) {
    Lpv *s = (Lpv *)self;
    const UiofmuLpv *d = s->d;
    double ph = (double)phase;
    o = uiofmu_put(o, &ph, 1);
    o = uiofmu_put(o, s->x0, (size_t)d->n);
    o = uiofmu_put(o, s->x, (size_t)d->n);
    o = uiofmu_put(o, s->dv, (size_t)d->q);
    uiofmu_put(o, s->theta_in, (size_t)d->s);
}

static int lpv_check_state(void *self, const char *ctx, const Byte *v, int *phase) {
    Lpv *s = (Lpv *)self;
    const UiofmuLpv *d = s->d;
    char b1[32];
    double ph = uiofmu_getd(v, 0);
    if (!uiofmu_phase_ok(s->fmu, ctx, ph) || !uiofmu_plant_x_ok(s->fmu, ctx, v, 1, d->n, ph, d->x0)) return 0;
    /* d[q]: taken as it is (see the header comment); theta[s] as well for kind input */
    if (d->kind == UIOFMU_THETA_STATE)
        for (int i = 0; i < d->s; i++) {
            double x = uiofmu_getd(v, 1 + 2 * (size_t)d->n + (size_t)d->q + (size_t)i);
            if (x != 0)
                return uiofmu_state_refused(s->fmu, ctx, "theta[%d] = %s: expected 0 (theta = T x is an output of "
                                            "this plant, not an input)", i + 1, uiofmu_num(x, b1));
        }
    *phase = (int)ph;
    return 1;
}

static void lpv_load_state(void *self, const Byte *v) {
    Lpv *s = (Lpv *)self;
    const UiofmuLpv *d = s->d;
    const Byte *o = v + sizeof(double);
    o = uiofmu_take(o, s->x0, (size_t)d->n);
    o = uiofmu_take(o, s->x, (size_t)d->n);
    o = uiofmu_take(o, s->dv, (size_t)d->q);
    uiofmu_take(o, s->theta_in, (size_t)d->s);
    s->dirty = 1;
}

const UiofmuKernel UIOFMU_KERNEL_LPV = {
    .name = "LPV plant",
    .check_design = lpv_check_design,
    .ports = UIOFMU_LPV_PORTS,
    .port = lpv_port,
    .instantiate = lpv_instantiate,
    .free_instance = lpv_free,
    .reset = lpv_reset,
    .exit_initialization = lpv_exit_initialization,
    .calculate = lpv_calculate,
    .real_storage = lpv_real_storage,
    .changed = lpv_changed,
    .get_integer = NULL, /* no Integer port */
    .set_integer = NULL,
    .step = lpv_step,
    .state_count = lpv_state_count,
    .state_shape = lpv_state_shape,
    .save_state = lpv_save_state,
    .check_state = lpv_check_state,
    .load_state = lpv_load_state,
};
