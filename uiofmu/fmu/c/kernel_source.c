/* uiofmu: the signal-source kernel, the model code of uiofmu's C signal-source FMUs.
 *
 * It plugs into the shared FMI 2.0 plumbing (fmi2_plumbing.c) through UIOFMU_KERNEL_SOURCE; its
 * sizes come from design_data.c (UIOFMU_SOURCE), its table from resources/signals.bin (layout in
 * kernel_source.h), read once at fmi2Instantiate. It has no inputs and no parameters:
 *
 *   outputs at time t:  the row k of the table with the largest time t_k <= t + 1e-12 max(1, |t|)
 *                       (row 0 before the first), as uiofmu/cosim/inputs.py holds a CSV's rows
 *   fmi2DoStep(t, h):   the time becomes t + h
 *
 * A run starts at time 0 (fmi2Instantiate and fmi2Reset). A table that is missing, short, long,
 * of other sizes than the ones compiled in, with a time that is not finite or decreases, a value
 * that is not finite or a mode that is not an fmi2Integer is refused at fmi2Instantiate with a log
 * line naming the file, the row and the column: the instance is not created.
 *
 * FMU state: after the plumbing's header (the shape words m, q, s, modes), 2 doubles: phase, time;
 * the time finite and not negative, else refused.
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2_plumbing.h"
#include "kernel_source.h"
#include "kernel_util.h"

#define MAX_DIM 1048576
#define MAX_ROWS 67108864u /* 2^26 */
#define MAX_PATH 4096
#define MAGIC "UIOSIG01"
#define HEADER_BYTES 24

static const char *const PORT_NAME[UIOFMU_SOURCE_PORTS] = UIOFMU_SOURCE_PORT_NAMES;
static const int PORT_CAUSALITY[UIOFMU_SOURCE_PORTS] = UIOFMU_SOURCE_PORT_CAUSALITIES;
static const int PORT_TYPE[UIOFMU_SOURCE_PORTS] = UIOFMU_SOURCE_PORT_TYPES;

typedef struct {
    FmuInstance *fmu;
    double *times;  /* rows */
    double *values; /* rows x columns */
    size_t rows;
    int columns;
    double t;   /* the current communication point */
    size_t row; /* the row held at t */
} Source;

static int port_size(int id) {
    const UiofmuSource *d = &UIOFMU_SOURCE;
    switch (id) {
    case UIOFMU_SOURCE_U: return d->m;
    case UIOFMU_SOURCE_D: return d->q;
    case UIOFMU_SOURCE_THETA: return d->s;
    case UIOFMU_SOURCE_MODE: return d->modes;
    default: return -1;
    }
}

/* The first column of port id in a row. */
static int port_offset(int id) {
    int offset = 0;
    for (int k = 0; k < id; k++) offset += port_size(k);
    return offset;
}

static int source_check_design(char *msg, size_t len) {
    const UiofmuSource *d = &UIOFMU_SOURCE;
    const int dims[4] = {d->m, d->q, d->s, d->modes}, low[4] = {0, 0, 0, 0};
    const char *const names[4] = {"m", "q", "s", "modes"};
    if (!uiofmu_check_dims(msg, len, "source ", 4, dims, names, low, MAX_DIM)) return 0;
    if (d->modes > 1) return uiofmu_design_error(msg, len, "source modes = %d: expected 0 or 1", d->modes);
    for (int id = 0; id < UIOFMU_SOURCE_PORTS; id++)
        if (PORT_CAUSALITY[id] != UIOFMU_OUTPUT)
            return uiofmu_design_error(msg, len, "port %s is not an output", PORT_NAME[id]);
    if (PORT_TYPE[UIOFMU_SOURCE_MODE] != UIOFMU_INTEGER)
        return uiofmu_design_error(msg, len, "port %s is not an Integer", PORT_NAME[UIOFMU_SOURCE_MODE]);
    return 1;
}

static int source_port(int id, UiofmuPort *out) {
    int size = port_size(id);
    if (size < 0) return 0;
    out->name = PORT_NAME[id];
    out->size = size;
    out->causality = PORT_CAUSALITY[id];
    out->type = PORT_TYPE[id];
    return 1;
}

/* ---------------------------------------------------------------------------------------- */
/* the table                                                                                 */

static uint64_t le64(const unsigned char *b) {
    uint64_t v = 0;
    for (int i = 7; i >= 0; i--) v = (v << 8) | b[i];
    return v;
}

static double le_double(const unsigned char *b) {
    uint64_t bits = le64(b);
    double v;
    memcpy(&v, &bits, sizeof v);
    return v;
}

/* Read and check the table of path into s (times, values, rows); 0 after a log line. */
static int read_table(Source *s, const char *path) {
    FmuInstance *fmu = s->fmu;
    unsigned char head[HEADER_BYTES], cell[8];
    char b1[32];
    int ok = 0;
    FILE *f = fopen(path, "rb");
    if (!f) {
        uiofmu_log(fmu, fmi2Error, "fmi2Instantiate: cannot open the signal table %.600s", path);
        return 0;
    }
    if (fread(head, 1, HEADER_BYTES, f) != HEADER_BYTES || memcmp(head, MAGIC, 8) != 0) {
        uiofmu_log(fmu, fmi2Error, "fmi2Instantiate: %.600s is not a signal table (no %s header)", path, MAGIC);
        goto done;
    }
    uint64_t rows = le64(head + 8), columns = le64(head + 16);
    if (rows < 1 || rows > MAX_ROWS) {
        uiofmu_log(fmu, fmi2Error, "fmi2Instantiate: %.600s has %llu rows, expected 1 to %u", path,
                   (unsigned long long)rows, MAX_ROWS);
        goto done;
    }
    if (columns != (uint64_t)s->columns) {
        uiofmu_log(fmu, fmi2Error, "fmi2Instantiate: %.600s has %llu value columns, this source plays %d (u %d, d %d, "
                   "theta %d, mode %d)", path, (unsigned long long)columns, s->columns, UIOFMU_SOURCE.m,
                   UIOFMU_SOURCE.q, UIOFMU_SOURCE.s, UIOFMU_SOURCE.modes);
        goto done;
    }
    s->rows = (size_t)rows;
    s->times = (double *)uiofmu_alloc(fmu, s->rows, sizeof(double));
    s->values = (double *)uiofmu_alloc(fmu, s->rows * (size_t)(s->columns ? s->columns : 1), sizeof(double));
    if (!s->times || !s->values) goto done;
    for (size_t r = 0; r < s->rows; r++) {
        for (int c = -1; c < s->columns; c++) {
            if (fread(cell, 1, 8, f) != 8) {
                uiofmu_log(fmu, fmi2Error, "fmi2Instantiate: %.600s ends in row %zu of %zu", path, r + 1, s->rows);
                goto done;
            }
            double v = le_double(cell);
            if (!isfinite(v)) {
                uiofmu_log(fmu, fmi2Error, "fmi2Instantiate: %.600s row %zu, column %d: %s is not finite", path, r + 1,
                           c + 1, uiofmu_num(v, b1));
                goto done;
            }
            if (c < 0) {
                if (r > 0 && v < s->times[r - 1]) {
                    uiofmu_log(fmu, fmi2Error, "fmi2Instantiate: %.600s row %zu: time %s is before the row above's",
                               path, r + 1, uiofmu_num(v, b1));
                    goto done;
                }
                s->times[r] = v;
            } else {
                if (UIOFMU_SOURCE.modes && c == s->columns - 1 &&
                    (v != floor(v) || v < -2147483648.0 || v > 2147483647.0)) {
                    uiofmu_log(fmu, fmi2Error, "fmi2Instantiate: %.600s row %zu: mode %s is not an fmi2Integer", path,
                               r + 1, uiofmu_num(v, b1));
                    goto done;
                }
                s->values[r * (size_t)s->columns + (size_t)c] = v;
            }
        }
    }
    if (fread(cell, 1, 1, f) != 0) {
        uiofmu_log(fmu, fmi2Error, "fmi2Instantiate: %.600s is longer than its %zu rows", path, s->rows);
        goto done;
    }
    ok = 1;
done:
    fclose(f);
    return ok;
}

/* The row held at time t: the last whose time is at most t + 1e-12 max(1, |t|), 0 before the first. */
static size_t row_at(const Source *s, double t) {
    double limit = t + 1e-12 * fmax(1.0, fabs(t));
    size_t lo = 0, hi = s->rows; /* the answer is the count of times <= limit, minus one */
    while (lo < hi) {
        size_t mid = lo + (hi - lo) / 2;
        if (s->times[mid] <= limit) lo = mid + 1;
        else hi = mid;
    }
    return lo ? lo - 1 : 0;
}

static void source_reset(void *self) {
    Source *s = (Source *)self;
    s->t = 0.0;
    s->row = row_at(s, 0.0);
}

static void source_free(void *self) {
    Source *s = (Source *)self;
    if (!s) return;
    free(s->times);
    free(s->values);
    free(s);
}

static void *source_instantiate(FmuInstance *fmu) {
    char path[MAX_PATH];
    Source *s = (Source *)uiofmu_alloc(fmu, 1, sizeof(Source));
    if (!s) return NULL;
    s->fmu = fmu;
    s->columns = UIOFMU_SOURCE.m + UIOFMU_SOURCE.q + UIOFMU_SOURCE.s + UIOFMU_SOURCE.modes;
    if (!uiofmu_resource_path(fmu, UIOFMU_SOURCE_TABLE_FILE, path, sizeof path) || !read_table(s, path)) {
        source_free(s);
        return NULL;
    }
    source_reset(s);
    return s;
}

static UiofmuResult source_exit_initialization(void *self) {
    (void)self;
    return UIOFMU_DONE;
}

static UiofmuResult source_calculate(void *self, const char *fn) {
    (void)self;
    (void)fn;
    return UIOFMU_DONE;
}

static double value(const Source *s, int port, int index) {
    return s->values[s->row * (size_t)s->columns + (size_t)(port_offset(port) + index)];
}

static double source_get_real(void *self, int port, int index) {
    return value((const Source *)self, port, index);
}

static int source_get_integer(void *self, int port, int index) {
    return (int)value((const Source *)self, port, index);
}

static UiofmuResult source_step(void *self, double t, double h) {
    Source *s = (Source *)self;
    double next = t + h;
    char b1[32];
    if (!isfinite(next)) {
        uiofmu_log(s->fmu, fmi2Error, "fmi2DoStep: t + h = %s is not finite", uiofmu_num(next, b1));
        return UIOFMU_REFUSED;
    }
    s->t = next;
    s->row = row_at(s, next);
    return UIOFMU_DONE;
}

/* ---------------------------------------------------------------------------------------- */
/* FMU state: phase, time                                                                    */

static size_t source_state_count(void) {
    return 2;
}

static void source_state_shape(uint32_t shape[UIOFMU_SHAPE], const char *names[UIOFMU_SHAPE]) {
    const UiofmuSource *d = &UIOFMU_SOURCE;
    static const char *const NAMES[UIOFMU_SHAPE] = {"m", "q", "s", "modes"};
    const int dims[UIOFMU_SHAPE] = {d->m, d->q, d->s, d->modes};
    uiofmu_shape(shape, names, dims, NAMES);
}

static void source_save_state(void *self, int phase, unsigned char *o) {
    Source *s = (Source *)self;
    double ph = (double)phase;
    o = uiofmu_put(o, &ph, 1);
    uiofmu_put(o, &s->t, 1);
}

static int source_check_state(void *self, const char *ctx, const unsigned char *v, int *phase) {
    Source *s = (Source *)self;
    char b1[32];
    double ph = uiofmu_getd(v, 0), t = uiofmu_getd(v, 1);
    if (!uiofmu_phase_ok(s->fmu, ctx, ph)) return 0;
    if (!isfinite(t) || t < 0)
        return uiofmu_state_refused(s->fmu, ctx, "time %s: expected a finite time >= 0", uiofmu_num(t, b1));
    *phase = (int)ph;
    return 1;
}

static void source_load_state(void *self, const unsigned char *v) {
    Source *s = (Source *)self;
    s->t = uiofmu_getd(v, 1);
    s->row = row_at(s, s->t);
}

const UiofmuKernel UIOFMU_KERNEL_SOURCE = {
    .name = "signal source",
    .check_design = source_check_design,
    .ports = UIOFMU_SOURCE_PORTS,
    .port = source_port,
    .instantiate = source_instantiate,
    .free_instance = source_free,
    .reset = source_reset,
    .exit_initialization = source_exit_initialization,
    .calculate = source_calculate,
    .get_real = source_get_real,
    .set_real = NULL, /* no input, no parameter */
    .get_integer = source_get_integer,
    .set_integer = NULL,
    .step = source_step,
    .state_count = source_state_count,
    .state_shape = source_state_shape,
    .save_state = source_save_state,
    .check_state = source_check_state,
    .load_state = source_load_state,
};
