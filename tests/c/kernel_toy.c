/* kernel_toy: a second model on uiofmu's FMI 2.0 plumbing (uiofmu/fmu/c/fmi2_plumbing.c), to
 * test what the observer kernel cannot reach: Integer ports, a kernel state at odds with its
 * design (the error state), and the checks fmi2Instantiate makes of a variable table.
 *
 * An accumulator: parameter x0, Integer input mode, inputs u[2]; outputs x and the Integer
 * count of steps taken. fmi2DoStep(t, h): mode 0 holds x, mode 1 adds h (u[1] + u[2]), mode 2
 * is a step the model does not take (fmi2Discard), any other mode is refused (fmi2Error); an
 * input u[1] = 666 stands for a state that does not fit the design (UIOFMU_BROKEN).
 *
 * Its own design data and variable table are here too (design_data.c in an FMU); -DTOY_TABLE=n
 * compiles a broken table n instead (1: out of order, 2: a type the port does not have, 3: a
 * port the kernel has not, 4: an element missing, 5: a port's element past its size, 6: a broken
 * step rule, 7: a kernel that cannot set its Real parameter), or the toy's Real variables read and
 * written through real_storage instead of get_real and set_real (8: with no storage for x, 9: for
 * every one).
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2_plumbing.h"

enum { TOY_X0, TOY_MODE, TOY_U, TOY_X, TOY_COUNT, TOY_PORTS };

typedef struct {
    FmuInstance *fmu;
    double x0, x, u[2];
    int mode, count;
} Toy;

static int toy_check_design(char *msg, size_t len) { (void)msg; (void)len; return 1; }

static int toy_port(int id, UiofmuPort *out) {
    static const UiofmuPort PORTS[TOY_PORTS] = {
        {"x0", 1, UIOFMU_PARAMETER, UIOFMU_REAL}, {"mode", 1, UIOFMU_INPUT, UIOFMU_INTEGER},
        {"u", 2, UIOFMU_INPUT, UIOFMU_REAL}, {"x", 1, UIOFMU_OUTPUT, UIOFMU_REAL},
        {"count", 1, UIOFMU_OUTPUT, UIOFMU_INTEGER}};
    if (id < 0 || id >= TOY_PORTS) return 0;
    *out = PORTS[id];
    return 1;
}

static void toy_reset(void *self) {
    Toy *s = (Toy *)self;
    s->x0 = 1.0;
    s->x = s->x0;
    s->u[0] = s->u[1] = 0.0;
    s->mode = 1;
    s->count = 0;
}

static void *toy_instantiate(FmuInstance *fmu) {
    Toy *s = (Toy *)calloc(1, sizeof(Toy));
    if (!s) {
        uiofmu_log(fmu, fmi2Error, "fmi2Instantiate: out of memory");
        return NULL;
    }
    s->fmu = fmu;
    toy_reset(s);
    return s;
}

static void toy_free(void *self) { free(self); }

static UiofmuResult toy_exit_initialization(void *self) {
    Toy *s = (Toy *)self;
    if (!isfinite(s->x0)) {
        uiofmu_log(s->fmu, fmi2Error, "parameter x0 = %g is not finite", s->x0);
        return UIOFMU_REFUSED;
    }
    s->x = s->x0;
    s->count = 0;
    return UIOFMU_DONE;
}

static UiofmuResult toy_calculate(void *self, const char *fn) { (void)self; (void)fn; return UIOFMU_DONE; }

#if TOY_TABLE >= 8
static double *toy_real_storage(void *self, int port, int index) {
    Toy *s = (Toy *)self;
    if (port == TOY_X0) return &s->x0;
    if (port == TOY_U) return &s->u[index];
    return port == TOY_X && TOY_TABLE == 9 ? &s->x : NULL;
}

static void toy_changed(void *self) { (void)self; }
#else
static double toy_get_real(void *self, int port, int index) {
    Toy *s = (Toy *)self;
    return port == TOY_X0 ? s->x0 : port == TOY_U ? s->u[index] : s->x;
}

static void toy_set_real(void *self, int port, int index, double value) {
    Toy *s = (Toy *)self;
    if (port == TOY_X0) s->x0 = value;
    else if (port == TOY_U) s->u[index] = value;
}
#endif

static int toy_get_integer(void *self, int port, int index) {
    Toy *s = (Toy *)self;
    (void)index;
    return port == TOY_MODE ? s->mode : s->count;
}

static void toy_set_integer(void *self, int port, int index, int value) {
    (void)index;
    if (port == TOY_MODE) ((Toy *)self)->mode = value;
}

static UiofmuResult toy_step(void *self, double t, double h) {
    Toy *s = (Toy *)self;
    char bt[32];
    if (s->u[0] == 666.0) {
        uiofmu_log(s->fmu, fmi2Error, "t = %s: u[1] = 666: the state does not fit the design", uiofmu_num(t, bt));
        return UIOFMU_BROKEN;
    }
    if (s->mode == 2) {
        uiofmu_log(s->fmu, fmi2Discard, "t = %s: mode 2 takes no step", uiofmu_num(t, bt));
        return UIOFMU_DISCARDED;
    }
    if (s->mode != 0 && s->mode != 1) {
        uiofmu_log(s->fmu, fmi2Error, "t = %s: unknown mode %d (the modes are 0, 1 and 2)", uiofmu_num(t, bt), s->mode);
        return UIOFMU_REFUSED;
    }
    if (!isfinite(s->u[0]) || !isfinite(s->u[1])) {
        uiofmu_log(s->fmu, fmi2Error, "t = %s: an input u is not finite", uiofmu_num(t, bt));
        return UIOFMU_REFUSED;
    }
    if (s->mode == 1) s->x += h * (s->u[0] + s->u[1]);
    s->count++;
    return UIOFMU_DONE;
}

/* state: x0, x, u[1], u[2], mode, count, phase */
enum { D_X0, D_X, D_U1, D_U2, D_MODE, D_COUNT, D_PHASE, D_N };

static size_t toy_state_count(void) { return D_N; }

static void toy_state_shape(uint32_t shape[UIOFMU_SHAPE], const char *names[UIOFMU_SHAPE]) {
    static const char *const NAMES[UIOFMU_SHAPE] = {"u", "modes", "spare", "spare"};
    const uint32_t SHAPE[UIOFMU_SHAPE] = {2, 3, 0, 0};
    for (int i = 0; i < UIOFMU_SHAPE; i++) {
        shape[i] = SHAPE[i];
        names[i] = NAMES[i];
    }
}

static void toy_save_state(void *self, int phase, unsigned char *doubles) {
    Toy *s = (Toy *)self;
    double v[D_N] = {s->x0, s->x, s->u[0], s->u[1], (double)s->mode, (double)s->count, (double)phase};
    memcpy(doubles, v, sizeof v);
}

static int toy_check_state(void *self, const char *ctx, const unsigned char *doubles, int *phase) {
    Toy *s = (Toy *)self;
    double v[D_N];
    memcpy(v, doubles, sizeof v);
    if (!isfinite(v[D_X0]) || !isfinite(v[D_X]) || !(v[D_COUNT] >= 0 && v[D_COUNT] < 1e9 && v[D_COUNT] == floor(v[D_COUNT])) ||
        !(fabs(v[D_MODE]) < 1e9 && v[D_MODE] == floor(v[D_MODE])) ||
        !(v[D_PHASE] == 0 || v[D_PHASE] == 1 || v[D_PHASE] == 2 || v[D_PHASE] == 3)) {
        uiofmu_log(s->fmu, fmi2Error, "%s: not a state of the toy", ctx);
        return 0;
    }
    *phase = (int)v[D_PHASE];
    return 1;
}

static void toy_load_state(void *self, const unsigned char *doubles) {
    Toy *s = (Toy *)self;
    double v[D_N];
    memcpy(v, doubles, sizeof v);
    s->x0 = v[D_X0];
    s->x = v[D_X];
    s->u[0] = v[D_U1];
    s->u[1] = v[D_U2];
    s->mode = (int)v[D_MODE];
    s->count = (int)v[D_COUNT];
}

static const UiofmuKernel TOY_KERNEL = {
    .name = "toy",
    .check_design = toy_check_design,
    .ports = TOY_PORTS,
    .port = toy_port,
    .instantiate = toy_instantiate,
    .free_instance = toy_free,
    .reset = toy_reset,
    .exit_initialization = toy_exit_initialization,
    .calculate = toy_calculate,
#if TOY_TABLE >= 8
    .real_storage = toy_real_storage,
    .changed = toy_changed,
#else
    .get_real = toy_get_real,
    .set_real = TOY_TABLE == 7 ? NULL : toy_set_real,
#endif
    .get_integer = toy_get_integer,
    .set_integer = toy_set_integer,
    .step = toy_step,
    .state_count = toy_state_count,
    .state_shape = toy_state_shape,
    .save_state = toy_save_state,
    .check_state = toy_check_state,
    .load_state = toy_load_state,
};

/* value references: x0 0, mode 1, u 2 3, x 4, count 5 */
#ifndef TOY_TABLE
#define TOY_TABLE 0
#endif
static const UiofmuVariable variables[] = {
    {TOY_X0, 0, UIOFMU_PARAMETER, UIOFMU_REAL},
#if TOY_TABLE == 2
    {TOY_MODE, 0, UIOFMU_INPUT, UIOFMU_REAL},
#else
    {TOY_MODE, 0, UIOFMU_INPUT, UIOFMU_INTEGER},
#endif
#if TOY_TABLE == 1
    {TOY_U, 1, UIOFMU_INPUT, UIOFMU_REAL},
    {TOY_U, 0, UIOFMU_INPUT, UIOFMU_REAL},
#elif TOY_TABLE == 4
    {TOY_U, 0, UIOFMU_INPUT, UIOFMU_REAL},
#elif TOY_TABLE == 5
    {TOY_U, 0, UIOFMU_INPUT, UIOFMU_REAL},
    {TOY_U, 1, UIOFMU_INPUT, UIOFMU_REAL},
    {TOY_U, 2, UIOFMU_INPUT, UIOFMU_REAL},
#else
    {TOY_U, 0, UIOFMU_INPUT, UIOFMU_REAL},
    {TOY_U, 1, UIOFMU_INPUT, UIOFMU_REAL},
#endif
    {TOY_X, 0, UIOFMU_OUTPUT, UIOFMU_REAL},
#if TOY_TABLE == 3
    {TOY_PORTS + 3, 0, UIOFMU_OUTPUT, UIOFMU_INTEGER},
#else
    {TOY_COUNT, 0, UIOFMU_OUTPUT, UIOFMU_INTEGER},
#endif
};

/* the plumbing's step rule: steps of 0.25, 0.5 and 1 (the toy itself takes any step); TOY_TABLE 6 breaks it */
#if TOY_TABLE == 6
static const double toy_steps[] = {0.25, 1e-12, 1.0};
#else
static const double toy_steps[] = {0.25, 0.5, 1.0};
#endif
const UiofmuSteps UIOFMU_STEPS = {
    .tiny = 0.25e-9, .ulps = 4.0, .ulps_limit = 1e-3, .nsteps = 3,
    .steps = toy_steps, .steps_length = UIOFMU_LENGTH(toy_steps),
};

const UiofmuFmu UIOFMU_FMU = {
    .guid = "{00000000-0000-0000-0000-00000000707f}",
    .model = "toy",
    .kernel = &TOY_KERNEL,
    .nvariables = (int)UIOFMU_LENGTH(variables), .variables = variables, .variables_length = UIOFMU_LENGTH(variables),
    .steps = &UIOFMU_STEPS,
};
