/* uiofmu: the window observer kernel, the model code of dead-beat functional observer FMUs.
 *
 * It plugs into the shared FMI 2.0 plumbing (fmi2_plumbing.c) through UIOFMU_KERNEL_WINDOW: the
 * plumbing owns the instance states, the value references, the logging and the FMU state
 * image; this file owns the formula's numbers. The design (UIOFMU_WINDOW: F, Fexp, the window
 * length L, the period dt) comes from design_data.c, generated from the design card. The step
 * semantics are those of the reference runtime (uiofmu/runtime/window.py):
 *
 *   outputs at t_k:  gx_k     = (sum_t w_t F_t) [y_{k-L+1}; ...; y_k]     when k >= L - 1, else 0
 *                    w_t      = prod_{l, i} theta_{k-L+1+l}^(i) ^ Fexp[t][l][i]   (0^0 = 1)
 *                    gx_valid = 1 when k >= L - 1, else 0
 *   fmi2DoStep(t, h): push (y_k, theta_k) into the window, k <- k + 1
 *
 * where y_k and theta_k are the inputs at t_k and the older points are the window: a ring
 * buffer of the last L - 1 points in the instance. There is no recursion and nothing to drift:
 * every output is the formula on the data. A design that does not use theta has no theta port;
 * its window holds theta = 0 (every power is 0, every weight 1).
 *
 * NaN or infinite inputs refuse the step with fmi2Error and a log line naming the input; a step
 * other than dt (relative tolerance step_rtol) is refused with fmi2Discard and a log line, as
 * the constant schedule of the affine kernel. Either way nothing changes.
 *
 * Defensive throughout, so that no call sequence makes it read or write out of bounds:
 * check_design_data checks every number the kernel indexes with (dims, window length, the
 * lengths of F and Fexp against terms x d x p L and terms x L x s, every power) before
 * fmi2Instantiate makes an instance; check_values checks every number of a state before
 * fmi2SetFMUstate or fmi2DeSerializeFMUstate takes any of it (see "FMU state" below).
 */
#include <limits.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2_plumbing.h"
#include "kernel_util.h"
#include "kernel_window.h"

/* Bounds of what a design may ask for (uiofmu/runtime/card.py: MAX_WINDOW = 1024); with them
   every index product stays well inside int and size_t. */
#define MAX_DIM 16384
#define MAX_LENGTH 1024
#define MAX_TERMS 1048576
#define MAX_NUMBERS 67108864 /* doubles of F, ints of Fexp */

/* The ports' names, causalities and types by id (kernel_window_ports.h, generated). */
static const char *const PORT_NAME[UIOFMU_WINDOW_PORTS] = UIOFMU_WINDOW_PORT_NAMES;
static const int PORT_CAUSALITY[UIOFMU_WINDOW_PORTS] = UIOFMU_WINDOW_PORT_CAUSALITIES;
static const int PORT_TYPE[UIOFMU_WINDOW_PORTS] = UIOFMU_WINDOW_PORT_TYPES;

typedef struct {
    FmuInstance *fmu; /* the plumbing's instance: log lines go through it */
    const UiofmuWindow *d;
    int W; /* L - 1 slots of the ring */
    /* state (what fmi2GetFMUstate saves) */
    long k;
    int head;            /* slot of the oldest point (the next one overwritten) */
    double *ys, *thetas; /* W x p and W x s, slot by slot */
    double *y, *theta;   /* the inputs at the current point */
    /* outputs and work space */
    int dirty;
    double *gx, *M; /* d; d x p L: sum_t w_t F_t */
    double *block;  /* everything above, one allocation */
} Window;

/* ---------------------------------------------------------------------------------------- */
/* The maths                                                                                  */

static int valid(const Window *s) { return s->k >= (long)s->W; }

/* Point l (0 = the oldest, L - 1 = the current one) of the window: its outputs and theta. */
static const double *y_at(const Window *s, int l) {
    return l < s->W ? s->ys + (size_t)((s->head + l) % s->W) * (size_t)s->d->p : s->y;
}

static const double *theta_at(const Window *s, int l) {
    return l < s->W ? s->thetas + (size_t)((s->head + l) % s->W) * (size_t)s->d->s : s->theta;
}

/* w_t: the product of the window's theta values to the powers of term t. */
static double weight(const Window *s, int t) {
    const UiofmuWindow *d = s->d;
    double w = 1.0;
    for (int l = 0; l < d->length; l++) {
        const double *th = theta_at(s, l);
        const int *e = d->Fexp + ((size_t)t * (size_t)d->length + (size_t)l) * (size_t)d->s;
        for (int i = 0; i < d->s; i++)
            if (e[i]) w *= pow(th[i], (double)e[i]);
    }
    return w;
}

static void refresh(Window *s) {
    const UiofmuWindow *d = s->d;
    if (!s->dirty) return;
    if (!valid(s)) {
        memset(s->gx, 0, (size_t)d->d * sizeof(double));
        s->dirty = 0;
        return;
    }
    size_t cols = (size_t)d->p * (size_t)d->length, sz = (size_t)d->d * cols;
    memset(s->M, 0, sz * sizeof(double));
    for (int t = 0; t < d->terms; t++) {
        double w = weight(s, t);
        const double *F = d->F + (size_t)t * sz;
        for (size_t e = 0; e < sz; e++) s->M[e] += w * F[e];
    }
    for (int r = 0; r < d->d; r++) {
        const double *row = s->M + (size_t)r * cols;
        double acc = 0.0;
        for (int l = 0; l < d->length; l++) {
            const double *y = y_at(s, l);
            for (int j = 0; j < d->p; j++) acc += row[(size_t)l * d->p + j] * y[j];
        }
        s->gx[r] = acc;
    }
    s->dirty = 0;
}

static void reset_state(Window *s) {
    const UiofmuWindow *d = s->d;
    s->k = 0;
    s->head = 0;
    memset(s->ys, 0, (size_t)s->W * (size_t)d->p * sizeof(double));
    memset(s->thetas, 0, (size_t)s->W * (size_t)d->s * sizeof(double));
    s->dirty = 1;
}

/* ---------------------------------------------------------------------------------------- */
/* The design, checked once at fmi2Instantiate: everything the runtime later indexes with.   */

/* a * b in *out, 0 when it exceeds MAX_NUMBERS. */
static int mul_count(size_t a, size_t b, size_t *out) { return uiofmu_mul(a, b, MAX_NUMBERS, out); }

static int check_design_data(const UiofmuWindow *d, char *msg, size_t len) {
    const int dims[3] = {d->p, d->d, d->s}, low[3] = {1, 1, 0};
    const char *const dim_name[3] = {"p", "d", "s"};
    size_t pl, rows, total_f, tl, total_e;
    if (!uiofmu_check_dims(msg, len, "", 3, dims, dim_name, low, MAX_DIM)) return 0;
    if (d->length < 1 || d->length > MAX_LENGTH)
        return uiofmu_design_error(msg, len, "window length L = %d is out of range [1, %d]", d->length, MAX_LENGTH);
    if (d->delay < 0 || d->delay >= d->length)
        return uiofmu_design_error(msg, len, "delay = %d is out of range [0, L - 1 = %d]", d->delay, d->length - 1);
    if (d->uses_theta != 0 && d->uses_theta != 1)
        return uiofmu_design_error(msg, len, "uses_theta = %d is neither 0 nor 1", d->uses_theta);
    if (d->terms < 1 || d->terms > MAX_TERMS)
        return uiofmu_design_error(msg, len, "terms = %d is out of range [1, %d]", d->terms, MAX_TERMS);
    if (!uiofmu_check_period(msg, len, d->dt, d->step_rtol)) return 0;
    if (!mul_count((size_t)d->p, (size_t)d->length, &pl) || !mul_count(pl, (size_t)d->d, &rows) ||
        !mul_count(rows, (size_t)d->terms, &total_f))
        return uiofmu_design_error(msg, len, "F of %d terms of %d x %d x %d is larger than %d numbers", d->terms, d->d,
                                   d->p, d->length, MAX_NUMBERS);
    if (!d->F || d->F_length != total_f)
        return uiofmu_design_error(msg, len, "F: %d terms of %d x %d (p L) need %zu numbers, its array holds %zu",
                                   d->terms, d->d, d->p * d->length, total_f, d->F ? d->F_length : 0);
    for (size_t e = 0; e < total_f; e++)
        if (!isfinite(d->F[e])) return uiofmu_design_error(msg, len, "F[%zu] = %g is not finite", e, d->F[e]);
    if (!mul_count((size_t)d->terms, (size_t)d->length, &tl) || !mul_count(tl, (size_t)d->s, &total_e))
        return uiofmu_design_error(msg, len, "Fexp of %d terms of %d x %d is larger than %d numbers", d->terms,
                                   d->length, d->s, MAX_NUMBERS);
    if (!d->Fexp || d->Fexp_length != (total_e ? total_e : 1))
        return uiofmu_design_error(msg, len, "Fexp: %d terms of %d x %d (L s) need %zu numbers, its array holds %zu",
                                   d->terms, d->length, d->s, total_e, d->Fexp ? d->Fexp_length : 0);
    for (size_t e = 0; e < total_e; e++) {
        if (d->Fexp[e] < 0 || d->Fexp[e] > UIOFMU_WINDOW_MAX_POWER)
            return uiofmu_design_error(msg, len, "Fexp[%zu] = %d is not a power from 0 to %d", e, d->Fexp[e],
                                       UIOFMU_WINDOW_MAX_POWER);
        if (d->Fexp[e] && !d->uses_theta)
            return uiofmu_design_error(msg, len, "Fexp[%zu] = %d, but the design does not use theta", e, d->Fexp[e]);
    }
    return 1;
}

/* ---------------------------------------------------------------------------------------- */
/* The kernel's operations (UiofmuKernel)                                                    */

static int window_check_design(char *msg, size_t len) { return check_design_data(&UIOFMU_WINDOW, msg, len); }

static int window_port(int id, UiofmuPort *out) {
    const UiofmuWindow *d = &UIOFMU_WINDOW;
    int size;
    switch (id) {
    case UIOFMU_WINDOW_Y: size = d->p; break;
    case UIOFMU_WINDOW_THETA: size = d->uses_theta ? d->s : 0; break;
    case UIOFMU_WINDOW_GX: size = d->d; break;
    case UIOFMU_WINDOW_GX_VALID: size = 1; break;
    default: return 0;
    }
    out->name = PORT_NAME[id];
    out->size = size;
    out->causality = PORT_CAUSALITY[id];
    out->type = PORT_TYPE[id];
    return 1;
}

static void *window_instantiate(FmuInstance *fmu) {
    const UiofmuWindow *d = &UIOFMU_WINDOW;
    Window *s = (Window *)uiofmu_alloc(fmu, 1, sizeof(Window));
    if (!s) return NULL;
    s->fmu = fmu;
    s->d = d;
    s->W = d->length - 1;
    /* every count below is bounded by the checked design (W p <= p L, d p L <= the length of F) */
    size_t W = (size_t)s->W, p = (size_t)d->p, th = (size_t)d->s, rows = (size_t)d->d;
    size_t total = W * p + W * th + p + th + rows + rows * p * (size_t)d->length;
    s->block = (double *)uiofmu_alloc(fmu, total, sizeof(double));
    if (!s->block) {
        free(s);
        return NULL;
    }
    double *b = s->block;
    s->ys = b; b += W * p;
    s->thetas = b; b += W * th;
    s->y = b; b += p;
    s->theta = b; b += th;
    s->gx = b; b += rows;
    s->M = b;
    reset_state(s);
    return s;
}

static void window_free(void *self) {
    Window *s = (Window *)self;
    if (!s) return;
    free(s->block);
    free(s);
}

static void window_reset(void *self) {
    Window *s = (Window *)self;
    memset(s->y, 0, (size_t)s->d->p * sizeof(double));
    memset(s->theta, 0, (size_t)s->d->s * sizeof(double));
    reset_state(s);
}

static UiofmuResult window_exit_initialization(void *self) {
    reset_state((Window *)self); /* no parameters: an empty window at step 0 */
    return UIOFMU_DONE;
}

static UiofmuResult window_calculate(void *self, const char *fn) {
    (void)fn;
    refresh((Window *)self);
    return UIOFMU_DONE;
}

/* The storage of element `index` of port `port` (the plumbing checked both against the table). */
static double *window_real_storage(void *self, int port, int index) {
    Window *s = (Window *)self;
    double *const first[UIOFMU_WINDOW_PORTS] = {[UIOFMU_WINDOW_Y] = s->y, [UIOFMU_WINDOW_THETA] = s->theta,
                                                [UIOFMU_WINDOW_GX] = s->gx};
    return uiofmu_element(first, port, index);
}

/* The plumbing stored new values: the outputs are computed again before they are read. */
static void window_changed(void *self) { ((Window *)self)->dirty = 1; }

/* The Integer port: gx_valid (an output). */
static int window_get_integer(void *self, int port, int index) {
    (void)index;
    return port == UIOFMU_WINDOW_GX_VALID ? valid((const Window *)self) : 0;
}

static UiofmuResult window_step(void *self, double t, double h) {
    Window *s = (Window *)self;
    const UiofmuWindow *d = s->d;
    /* the inputs first, as the reference runtime: a bad one is an input error, not a step rejected */
    if (!uiofmu_inputs_finite(s->fmu, t, s->k, s->y, d->p, PORT_NAME[UIOFMU_WINDOW_Y]) ||
        !uiofmu_inputs_finite(s->fmu, t, s->k, s->theta, d->s, PORT_NAME[UIOFMU_WINDOW_THETA]))
        return UIOFMU_REFUSED;
    if (uiofmu_off_period(s->fmu, t, h, d->dt, d->step_rtol, 1)) return UIOFMU_DISCARDED;
    if (s->W > 0) { /* the current point replaces the oldest */
        memcpy(s->ys + (size_t)s->head * (size_t)d->p, s->y, (size_t)d->p * sizeof(double));
        memcpy(s->thetas + (size_t)s->head * (size_t)d->s, s->theta, (size_t)d->s * sizeof(double));
        s->head = (s->head + 1) % s->W;
    }
    if (s->k < LONG_MAX) s->k += 1;
    s->dirty = 1;
    return UIOFMU_DONE;
}

/* ---------------------------------------------------------------------------------------- */
/* FMU state: the kernel's doubles
 *
 * The plumbing writes the image's header (magic, layout, size, GUID, the shape words p, d, s,
 * L and the count D of doubles; fmi2_plumbing.c) and checks it; then come
 * D = 2 + (L - 1) (p + s) + p + s doubles, written and read with memcpy (no alignment
 * assumed), in the platform's byte order:
 *
 *   k, phase, ys[(L - 1) p], thetas[(L - 1) s], y[p], theta[s]
 *
 * the window oldest point first (the ring unrolled: equal windows, equal bytes), as the
 * reference runtime's get_state. fmi2SetFMUstate and fmi2DeSerializeFMUstate refuse a state
 * (fmi2Error and a log line with the numbers) unless every value is one this FMU can be in
 * (check_values), all checked before any of it is used:
 *   k        an integer 0 <= k <= 2^53 (and within long); 0 before initialisation ends
 *   phase    0 instantiated, 1 initialisation mode, 2 initialised, 3 terminated (the
 *            plumbing's instance state; a discarded step is saved as 2: it changed nothing)
 *   ys, thetas finite (fmi2DoStep pushes only inputs it checked), and 0 in the points not yet
 *            filled (the oldest L - 1 - k while k < L - 1: reset_state zeroes them); thetas all
 *            0 when the design has no theta port
 *   y, theta any value, NaN and Inf included: inputs that fmi2SetReal takes whatever their
 *            value and fmi2DoStep checks before any use (an instance holds such an input
 *            legitimately: a master set it, the step was refused); theta 0 when the design has
 *            no theta port (nothing sets it)
 */

#define MAX_SAFE_INTEGER 9007199254740992.0 /* 2^53 */

enum { SV_K, SV_PHASE, SV_SCALARS };

typedef unsigned char Byte;

static size_t window_state_count(void) {
    const UiofmuWindow *d = &UIOFMU_WINDOW;
    size_t W = (size_t)(d->length - 1);
    return SV_SCALARS + W * ((size_t)d->p + (size_t)d->s) + (size_t)d->p + (size_t)d->s;
}

static void window_state_shape(uint32_t shape[UIOFMU_SHAPE], const char *names[UIOFMU_SHAPE]) {
    const UiofmuWindow *d = &UIOFMU_WINDOW;
    static const char *const NAMES[UIOFMU_SHAPE] = {"p", "d", "s", "L"};
    const int dims[UIOFMU_SHAPE] = {d->p, d->d, d->s, d->length};
    uiofmu_shape(shape, names, dims, NAMES);
}

static void window_save_state(void *self, int phase, Byte *o) {
    Window *s = (Window *)self;
    const UiofmuWindow *d = s->d;
    size_t py = (size_t)d->p, pt = (size_t)d->s;
    double scalars[SV_SCALARS] = {(double)s->k, (double)phase};
    o = uiofmu_put(o, scalars, SV_SCALARS);
    for (int l = 0; l < s->W; l++) o = uiofmu_put(o, y_at(s, l), py);
    for (int l = 0; l < s->W; l++) o = uiofmu_put(o, theta_at(s, l), pt);
    o = uiofmu_put(o, s->y, py);
    uiofmu_put(o, s->theta, pt);
}

/* Whether the doubles at v (k, phase, ...; see above) are a state this FMU can be in. */
static int check_values(Window *s, const char *ctx, const Byte *v) {
    static const char *const VECTOR[2] = {"ys", "thetas"};
    const UiofmuWindow *d = s->d;
    char b1[32], b2[32];
    double k = uiofmu_getd(v, SV_K), phase = uiofmu_getd(v, SV_PHASE);
    if (!(isfinite(k) && k >= 0 && k == floor(k) && k <= MAX_SAFE_INTEGER && k <= (double)LONG_MAX))
        return uiofmu_state_refused(s->fmu, ctx, "k = %s is not a step count (an integer, 0 <= k <= 2^53)",
                                    uiofmu_num(k, b1));
    if (!uiofmu_phase_ok(s->fmu, ctx, phase)) return 0;
    if (phase < UIOFMU_PHASE_RUNNING && k != 0)
        return uiofmu_state_refused(s->fmu, ctx, "k = %s in phase %d, before initialisation ended: expected 0",
                                    uiofmu_num(k, b1), (int)phase);
    /* the points not yet filled: the oldest W - k while k < W */
    int empty = k < (double)s->W ? s->W - (int)k : 0;
    const int width[2] = {d->p, d->s};
    size_t at = SV_SCALARS;
    for (int w = 0; w < 2; w++) {
        for (int l = 0; l < s->W; l++)
            for (int i = 0; i < width[w]; i++) {
                double x = uiofmu_getd(v, at + (size_t)l * (size_t)width[w] + (size_t)i);
                if (!isfinite(x))
                    return uiofmu_state_refused(s->fmu, ctx, "%s[%d][%d] = %s is not finite", VECTOR[w], l + 1, i + 1,
                                                uiofmu_num(x, b1));
                if (x != 0 && l < empty)
                    return uiofmu_state_refused(s->fmu, ctx, "%s[%d][%d] = %s at k = %s: expected 0 (a point not yet "
                                                "filled)", VECTOR[w], l + 1, i + 1, uiofmu_num(x, b1),
                                                uiofmu_num(k, b2));
                if (x != 0 && w == 1 && !d->uses_theta)
                    return uiofmu_state_refused(s->fmu, ctx, "thetas[%d][%d] = %s: expected 0 (this design has no "
                                                "theta input)", l + 1, i + 1, uiofmu_num(x, b1));
            }
        at += (size_t)s->W * (size_t)width[w];
    }
    at += (size_t)d->p; /* y[p]: taken as it is (see above) */
    if (!d->uses_theta)
        for (int i = 0; i < d->s; i++) {
            double x = uiofmu_getd(v, at + (size_t)i);
            if (x != 0)
                return uiofmu_state_refused(s->fmu, ctx, "theta[%d] = %s: expected 0 (this design has no theta "
                                            "input)", i + 1, uiofmu_num(x, b1));
        }
    return 1;
}

static int window_check_state(void *self, const char *ctx, const Byte *v, int *phase) {
    if (!check_values((Window *)self, ctx, v)) return 0;
    *phase = (int)uiofmu_getd(v, SV_PHASE);
    return 1;
}

static void window_load_state(void *self, const Byte *v) {
    Window *s = (Window *)self;
    const UiofmuWindow *d = s->d;
    size_t W = (size_t)s->W, p = (size_t)d->p, th = (size_t)d->s;
    s->k = (long)uiofmu_getd(v, SV_K);
    s->head = 0; /* saved oldest first */
    const Byte *o = v + SV_SCALARS * sizeof(double);
    o = uiofmu_take(o, s->ys, W * p);
    o = uiofmu_take(o, s->thetas, W * th);
    o = uiofmu_take(o, s->y, p);
    uiofmu_take(o, s->theta, th);
    s->dirty = 1;
}

const UiofmuKernel UIOFMU_KERNEL_WINDOW = {
    .name = "window",
    .check_design = window_check_design,
    .ports = UIOFMU_WINDOW_PORTS,
    .port = window_port,
    .instantiate = window_instantiate,
    .free_instance = window_free,
    .reset = window_reset,
    .exit_initialization = window_exit_initialization,
    .calculate = window_calculate,
    .real_storage = window_real_storage,
    .changed = window_changed,
    .get_integer = window_get_integer, /* gx_valid */
    .set_integer = NULL, /* no Integer input */
    .step = window_step,
    .state_count = window_state_count,
    .state_shape = window_state_shape,
    .save_state = window_save_state,
    .check_state = window_check_state,
    .load_state = window_load_state,
};
