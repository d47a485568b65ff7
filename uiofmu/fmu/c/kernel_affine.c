/* uiofmu: the observer runtime in C, with its own FMI 2.0 Co-Simulation interface.
 *
 * One generic file for every observer family: the design (matrices and schedule) comes from
 * design_data.c, generated from the design card. The step semantics are those of the
 * reference runtime (uiofmu/runtime/observer.py):
 *
 *   outputs at t_k:  xhat_k = Xz z_k + Xy y_k   (xhat_0 = the parameter xhat0)
 *                    r_k    = y_k - C xhat_k
 *                    dhat_k = Dy (y_k - pred)   (0 at k = 0)
 *   fmi2DoStep(t_k, h_k):
 *                    z_0    = xhat0 - Xy y_0    (first step only)
 *                    pred   = Yx xhat_k + Yu u_k + Yc
 *                    z_k+1  = N z_k + L y_k + G u_k + c
 *
 * with the matrices the schedule picks for (k, h_k, h_{k-1}). Bad calls (NaN inputs, h <= 0,
 * calls out of order) return fmi2Error with a log line; a step the design does not allow
 * follows the design's step policy (fmi2Discard, or the nearest interval noted once).
 *
 * Defensive throughout, so that no call sequence makes it read or write out of bounds:
 *   - fmi2Instantiate checks the design data (dims, schedule, every matrix's count, rows and
 *     cols against the dims and against the length of its array) and refuses an inconsistent
 *     design with a log line (check_design);
 *   - fmi2SetFMUstate and fmi2DeSerializeFMUstate check every byte of a state before they use
 *     any of it, and refuse a foreign or forged one with fmi2Error and a log line saying why
 *     (see "FMU state" below); fmi2GetFMUstate reuses only a state of this FMU;
 *   - the matrix lookups (pick, prev_index) refuse an index out of range, and the FMI call
 *     then returns fmi2Error with a log line instead of reading it.
 */
#include <limits.h>
#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "uiofmu_design.h"

enum { PHASE_INSTANTIATED, PHASE_INITIALIZATION, PHASE_RUNNING, PHASE_TERMINATED, PHASE_COUNT };

/* Bounds of what a design may ask for (far above what uiofmu designs: dims <= 1000); with them
   every index product (rows x cols, N x N blocks) stays well inside int and size_t. */
#define MAX_DIM 16384
#define MAX_INTERVALS 4096
#define MAX_BLOCKS 16777216
#define MAX_GUID 255

typedef struct {
    fmi2CallbackFunctions cb;
    char name[128];
    int logging;
    int phase;
    const UiofmuDesign *d;
    /* state (what fmi2GetFMUstate saves) */
    long k;
    double h_prev, h_prev0;
    int noticed;
    int j_prev; /* index of h_prev among the design intervals, -1 until looked up */
    double *z, *pred, *xhat0, *y, *u;
    /* outputs and work space */
    int dirty;
    double *xhat, *r, *dhat, *tmp, *pt;
    double *work[M_COUNT];
    long work_k;
    double *block; /* everything above, one allocation */
    size_t nblock;
} Instance;

static const char *const MATRIX_NAME[M_COUNT] = {"N", "L", "G", "c", "Xz", "Xy", "C", "Dy", "Yx", "Yu", "Yc"};

/* ---------------------------------------------------------------------------------------- */

static void logf_(Instance *s, fmi2Status status, const char *category, const char *fmt, ...) {
    char buf[1024];
    va_list ap;
    if (!s->cb.logger || (!s->logging && status == fmi2OK)) return;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    s->cb.logger(s->cb.componentEnvironment, s->name, status, category, "%s", buf);
}

/* The shortest text that reads back as v, written as Python's repr writes it (600.0, 0.1, 1e-05). */
static const char *num(double v, char *buf) {
    int digits = 1;
    for (; digits < 17; digits++) {
        snprintf(buf, 32, "%.*g", digits, v);
        if (strtod(buf, NULL) == v) break;
    }
    double a = fabs(v);
    if (strpbrk(buf, "eE") && a >= 1e-4 && a < 1e16) {
        int decimals = digits - ((int)floor(log10(a)) + 1);
        snprintf(buf, 32, "%.*f", decimals > 0 ? decimals : 0, v);
    }
    if (isfinite(v) && !strpbrk(buf, ".eE")) strcat(buf, ".0");
    return buf;
}

static size_t msize(const UiofmuMatrix *M) { return (size_t)M->rows * (size_t)M->cols; }

/* y = A x (rows x cols), y += A x */
static void matvec(const double *A, int rows, int cols, const double *x, double *y) {
    for (int i = 0; i < rows; i++) {
        double acc = 0.0;
        for (int j = 0; j < cols; j++) acc += A[i * cols + j] * x[j];
        y[i] = acc;
    }
}

static void matvec_add(const double *A, int rows, int cols, const double *x, double *y, double *t) {
    matvec(A, rows, cols, x, t);
    for (int i = 0; i < rows; i++) y[i] += t[i];
}

/* The design interval nearest to h (the first of equals) in *best, and whether h lies within
   step_rtol of it; 0 when the design has no intervals. No side effects. */
static int nearest_interval(const UiofmuDesign *d, double h, int *best, int *exact) {
    *best = 0;
    *exact = 0;
    if (d->kind != UIOFMU_INTERVAL || d->nintervals < 1 || !d->intervals) return 0;
    for (int i = 1; i < d->nintervals; i++)
        if (fabs(h - d->intervals[i]) < fabs(h - d->intervals[*best])) *best = i;
    *exact = fabs(h - d->intervals[*best]) <= d->step_rtol * d->intervals[*best];
    return 1;
}

/* Whether the runtime can take h as a step before another one (h_prev): a positive finite
   number that is a design interval, or that the policy 'nearest' maps to one. */
static int resolves(const UiofmuDesign *d, double h) {
    int best, exact;
    if (!(isfinite(h) && h > 0) || !nearest_interval(d, h, &best, &exact)) return 0;
    return exact || d->policy == UIOFMU_POLICY_NEAREST;
}

/* Index of the design interval of step h; -1 when rejected (message in msg). */
static int interval_index(Instance *s, double h, char *msg, size_t len) {
    const UiofmuDesign *d = s->d;
    int best, exact;
    if (!nearest_interval(d, h, &best, &exact)) {
        if (msg) snprintf(msg, len, "this design has no intervals");
        return -1;
    }
    if (exact) return best;
    if (d->policy == UIOFMU_POLICY_NEAREST) {
        if (!s->noticed) {
            s->noticed = 1;
            char b1[32];
            logf_(s, fmi2Warning, "logStatusWarning",
                  "step h = %s s is not a design interval; using the nearest, %g s, without a certificate "
                  "(step_policy = 'nearest'; noted once)", num(h, b1), d->intervals[best]);
        }
        return best;
    }
    if (msg) {
        char b1[32];
        int off = snprintf(msg, len, "step h = %s s is not one of the design intervals {", num(h, b1));
        for (int i = 0; i < d->nintervals && off < (int)len; i++)
            off += snprintf(msg + off, len - off, i ? ", %g" : "%g", d->intervals[i]);
        if (off < (int)len)
            snprintf(msg + off, len - off, "} s (tolerance %g relative; step_policy = 'error')", d->step_rtol);
    }
    return -1;
}

/* Geometric schedule: evaluate every polynomial matrix at a = alpha^k (Horner). */
static void evaluate(Instance *s, long k) {
    if (s->work_k == k) return;
    double a = pow(s->d->alpha, (double)k);
    for (int w = 0; w < M_COUNT; w++) {
        const UiofmuMatrix *M = &s->d->mat[w];
        if (w == M_C || M->count <= 1 || !s->work[w]) continue; /* constant in a: used in place */
        size_t sz = msize(M);
        double *out = s->work[w];
        memcpy(out, M->data + (size_t)(M->count - 1) * sz, sz * sizeof(double));
        for (int c = M->count - 2; c >= 0; c--)
            for (size_t e = 0; e < sz; e++) out[e] = out[e] * a + M->data[(size_t)c * sz + e];
    }
    s->work_k = k;
}

/* The matrix `which` for step indices (i, j) (interval) or step k (geometric); NULL when the
   matrix is absent or an index is out of range (never a pointer outside its data). */
static const double *pick(const Instance *s, int which, int i, int j) {
    const UiofmuDesign *d = s->d;
    if (which < 0 || which >= M_COUNT) return NULL;
    const UiofmuMatrix *M = &d->mat[which];
    size_t sz = msize(M), block;
    if (M->count < 1 || !M->data) return NULL;
    if (which == M_C || d->kind == UIOFMU_CONSTANT) return M->data;
    if (d->kind == UIOFMU_GEOMETRIC) return M->count == 1 ? M->data : s->work[which];
    int N = d->nintervals;
    if (which == M_N || which == M_L) {
        if (i < 0 || i >= N || j < 0 || j >= N) return NULL;
        block = (size_t)i * (size_t)N + (size_t)j;
    } else if (which == M_Xz || which == M_Xy || which == M_Dy) {
        if (j < 0 || j >= N) return NULL;
        block = (size_t)j;
    } else {
        if (i < 0 || i >= N) return NULL;
        block = (size_t)i;
    }
    if (block >= (size_t)M->count) return NULL;
    return M->data + block * sz;
}

/* pick(), and a log line from `fn` when there is no such matrix. */
static const double *need(Instance *s, const char *fn, int which, int i, int j) {
    const double *M = pick(s, which, i, j);
    if (!M) {
        char b1[32];
        logf_(s, fmi2Error, "logStatusError",
              "%s: no matrix %s for the step indices (%d, %d) at step k = %ld (h_prev = %s s): "
              "the instance's state does not fit its design", fn, MATRIX_NAME[which], i, j, s->k, num(s->h_prev, b1));
    }
    return M;
}

/* Index of h_prev among the design intervals (0 for the other schedules); -1 when it is none. */
static int prev_index(Instance *s) {
    if (s->d->kind != UIOFMU_INTERVAL) return 0;
    if (s->j_prev < 0 || s->j_prev >= s->d->nintervals) s->j_prev = interval_index(s, s->h_prev, NULL, 0);
    return s->j_prev;
}

static void bad_prev(Instance *s, const char *fn) {
    char b1[32];
    logf_(s, fmi2Error, "logStatusError",
          "%s: h_prev = %s s at step k = %ld is not a design interval: the instance's state does not fit its design",
          fn, num(s->h_prev, b1), s->k);
}

/* xhat_k alone (what a step needs); 0 (with a log line) when a matrix is missing. */
static int estimate(Instance *s, const char *fn, int j) {
    const UiofmuDesign *d = s->d;
    if (d->kind == UIOFMU_GEOMETRIC) evaluate(s, s->k);
    if (s->k == 0) {
        memcpy(s->xhat, s->xhat0, d->n * sizeof(double));
        return 1;
    }
    if (j < 0) {
        bad_prev(s, fn);
        return 0;
    }
    const double *Xz = need(s, fn, M_Xz, 0, j), *Xy = Xz ? need(s, fn, M_Xy, 0, j) : NULL;
    if (!Xz || !Xy) return 0;
    matvec(Xz, d->n, d->nz, s->z, s->xhat);
    matvec_add(Xy, d->n, d->p, s->y, s->xhat, s->pt);
    return 1;
}

static int refresh(Instance *s, const char *fn) {
    const UiofmuDesign *d = s->d;
    if (!s->dirty) return 1;
    int j = prev_index(s);
    const double *C = need(s, fn, M_C, 0, 0);
    if (!C || !estimate(s, fn, j)) return 0;
    matvec(C, d->p, d->n, s->xhat, s->r);
    for (int i = 0; i < d->p; i++) s->r[i] = s->y[i] - s->r[i];
    if (d->has_dhat) {
        if (s->k > 0) {
            const double *Dy = need(s, fn, M_Dy, 0, j);
            if (!Dy) return 0;
            for (int i = 0; i < d->p; i++) s->tmp[i] = s->y[i] - s->pred[i];
            matvec(Dy, d->q, d->p, s->tmp, s->dhat);
        } else {
            for (int i = 0; i < d->q; i++) s->dhat[i] = 0.0;
        }
    }
    s->dirty = 0;
    return 1;
}

static void reset_state(Instance *s) {
    s->k = 0;
    s->h_prev = s->h_prev0;
    s->j_prev = -1;
    s->noticed = 0;
    memset(s->z, 0, s->d->nz * sizeof(double));
    memset(s->pred, 0, s->d->p * sizeof(double));
    s->work_k = -1;
    s->dirty = 1;
}

/* ---------------------------------------------------------------------------------------- */
/* The design, checked once at fmi2Instantiate: everything the runtime later indexes with.   */

static int design_error(char *msg, size_t len, const char *fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, len, fmt, ap);
    va_end(ap);
    return 0;
}

/* a * b in *out, 0 when it exceeds the doubles an allocation can hold. */
static int mul_size(size_t a, size_t b, size_t *out) {
    size_t limit = SIZE_MAX / sizeof(double);
    if (a && b > limit / a) return 0;
    *out = a * b;
    return 1;
}

static void expected_shape(const UiofmuDesign *d, int w, int *rows, int *cols, const char **text) {
    static const char *const TEXT[M_COUNT] = {"nz x nz", "nz x p", "nz x m", "nz x 1", "n x nz", "n x p",
                                              "p x n", "q x p", "p x n", "p x m", "p x 1"};
    const int R[M_COUNT] = {d->nz, d->nz, d->nz, d->nz, d->n, d->n, d->p, d->q, d->p, d->p, d->p};
    const int C[M_COUNT] = {d->nz, d->p, d->m, 1, d->nz, d->p, d->n, d->p, d->n, d->m, 1};
    *rows = R[w];
    *cols = C[w];
    *text = TEXT[w];
}

static int check_design(const UiofmuDesign *d, char *msg, size_t len) {
    static const char *const KIND[] = {"constant", "interval", "geometric"};
    size_t g = 0;
    if (!d->guid || !d->model) return design_error(msg, len, "the design has no GUID or no model identifier");
    while (g <= MAX_GUID && d->guid[g]) g++;
    if (g == 0 || g > MAX_GUID) return design_error(msg, len, "the design's GUID is empty or longer than %d bytes", MAX_GUID);
    const int dims[5] = {d->n, d->m, d->p, d->q, d->nz};
    const char *const dim_name[5] = {"n", "m", "p", "q", "nz"};
    for (int i = 0; i < 5; i++)
        if (dims[i] < (i == 0 || i == 2 ? 1 : 0) || dims[i] > MAX_DIM)
            return design_error(msg, len, "dims.%s = %d is out of range [%d, %d]", dim_name[i], dims[i],
                                i == 0 || i == 2 ? 1 : 0, MAX_DIM);
    if (d->nz != d->n) /* z_0 = xhat0 - Xy y_0 is an n-vector */
        return design_error(msg, len, "dims.nz = %d differs from dims.n = %d (the first step sets z from xhat0)",
                            d->nz, d->n);
    if (d->has_dhat != 0 && d->has_dhat != 1) return design_error(msg, len, "has_dhat = %d is neither 0 nor 1", d->has_dhat);
    if (d->kind < UIOFMU_CONSTANT || d->kind > UIOFMU_GEOMETRIC)
        return design_error(msg, len, "schedule kind %d is unknown", d->kind);
    if (d->policy < UIOFMU_POLICY_ERROR || d->policy > UIOFMU_POLICY_COUNT ||
        (d->kind == UIOFMU_CONSTANT && d->policy != UIOFMU_POLICY_ERROR) ||
        (d->kind == UIOFMU_GEOMETRIC && d->policy == UIOFMU_POLICY_NEAREST))
        return design_error(msg, len, "step policy %d does not go with a %s schedule", d->policy, KIND[d->kind]);
    if (!isfinite(d->dt) || !isfinite(d->alpha) || !isfinite(d->h_prev0) || !isfinite(d->step_rtol) ||
        d->step_rtol < 0 || !(d->h_prev0 > 0))
        return design_error(msg, len, "dt = %g, alpha = %g, h_prev0 = %g, step_rtol = %g: expected finite numbers, "
                            "h_prev0 > 0 and step_rtol >= 0", d->dt, d->alpha, d->h_prev0, d->step_rtol);
    if (d->kind != UIOFMU_INTERVAL && !(d->dt > 0))
        return design_error(msg, len, "dt = %g: a %s schedule needs a period > 0", d->dt, KIND[d->kind]);
    if (!d->xhat0 || d->xhat0_length != (size_t)d->n)
        return design_error(msg, len, "xhat0 holds %zu numbers, expected n = %d", d->xhat0 ? d->xhat0_length : 0, d->n);
    for (int i = 0; i < d->n; i++)
        if (!isfinite(d->xhat0[i])) return design_error(msg, len, "xhat0[%d] = %g is not finite", i + 1, d->xhat0[i]);
    if (d->nintervals < 0 || d->nintervals > MAX_INTERVALS || (d->kind == UIOFMU_INTERVAL && d->nintervals < 1) ||
        !d->intervals ||
        d->intervals_length != (size_t)(d->nintervals ? d->nintervals : 1))
        return design_error(msg, len, "%d intervals in an array of %zu for a %s schedule", d->nintervals,
                            d->intervals ? d->intervals_length : 0, KIND[d->kind]);
    for (int i = 0; i < d->nintervals; i++) /* read by interval schedules only */
        if (!(isfinite(d->intervals[i]) && (d->intervals[i] > 0 || d->kind != UIOFMU_INTERVAL)))
            return design_error(msg, len, "interval %d = %g is not a positive finite step", i + 1, d->intervals[i]);
    if (d->kind == UIOFMU_INTERVAL && !resolves(d, d->h_prev0))
        return design_error(msg, len, "h_prev0 = %g is not one of the design intervals", d->h_prev0);
    for (int w = 0; w < M_COUNT; w++) {
        const UiofmuMatrix *M = &d->mat[w];
        int rows, cols, required = w <= M_C || d->has_dhat;
        const char *shape;
        size_t want, total = 0;
        expected_shape(d, w, &rows, &cols, &shape);
        if (M->count == 0 && !required) continue;
        if (w == M_C || d->kind == UIOFMU_CONSTANT) want = 1;
        else if (d->kind == UIOFMU_INTERVAL) want = (size_t)d->nintervals * (w == M_N || w == M_L ? (size_t)d->nintervals : 1);
        else want = 0; /* geometric: any number of coefficients */
        if (M->count < 1 || (want && (size_t)M->count != want) || M->count > MAX_BLOCKS)
            return design_error(msg, len, "matrix %s has %d blocks, expected %s%zu", MATRIX_NAME[w], M->count,
                                want ? "" : "at least ", want ? want : (size_t)1);
        if (M->rows != rows || M->cols != cols)
            return design_error(msg, len, "matrix %s is %d x %d, expected %s = %d x %d", MATRIX_NAME[w], M->rows,
                                M->cols, shape, rows, cols);
        if (!M->data || !mul_size((size_t)M->count, msize(M), &total) || M->length != (total ? total : 1))
            return design_error(msg, len, "matrix %s: %d blocks of %d x %d need %zu numbers, its array holds %zu",
                                MATRIX_NAME[w], M->count, rows, cols, total, M->data ? M->length : 0);
    }
    return 1;
}

/* ---------------------------------------------------------------------------------------- */
/* value references: xhat0[n], (h_prev0), y[p], u[m], xhat[n], r[p], (dhat[q])                */

typedef struct { double *ptr; int kind; } Slot; /* kind: 0 parameter, 1 input, 2 output */

static int slot(Instance *s, fmi2ValueReference vr, Slot *out) {
    const UiofmuDesign *d = s->d;
    size_t v = (size_t)vr; /* unsigned all the way: no reference wraps to a negative index */
    if (v < (size_t)d->n) { *out = (Slot){ &s->xhat0[v], 0 }; return 1; }
    v -= (size_t)d->n;
    if (d->kind == UIOFMU_INTERVAL) {
        if (v == 0) { *out = (Slot){ &s->h_prev0, 0 }; return 1; }
        v -= 1;
    }
    if (v < (size_t)d->p) { *out = (Slot){ &s->y[v], 1 }; return 1; }
    v -= (size_t)d->p;
    if (v < (size_t)d->m) { *out = (Slot){ &s->u[v], 1 }; return 1; }
    v -= (size_t)d->m;
    if (v < (size_t)d->n) { *out = (Slot){ &s->xhat[v], 2 }; return 1; }
    v -= (size_t)d->n;
    if (v < (size_t)d->p) { *out = (Slot){ &s->r[v], 2 }; return 1; }
    v -= (size_t)d->p;
    if (d->has_dhat && v < (size_t)d->q) { *out = (Slot){ &s->dhat[v], 2 }; return 1; }
    return 0;
}

/* ---------------------------------------------------------------------------------------- */

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

/* A log line before there is an instance (fmi2Instantiate refusing). */
static void log_early(const fmi2CallbackFunctions *f, fmi2String name, const char *fmt, ...) {
    char buf[1024];
    va_list ap;
    if (!f->logger) return;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    f->logger(f->componentEnvironment, name ? name : "", fmi2Error, "logStatusError", "%s", buf);
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn) {
    const UiofmuDesign *d = &UIOFMU_DESIGN;
    char msg[512];
    (void)fmuResourceLocation;
    (void)visible;
    if (!functions) return NULL;
    if (!instanceName || !instanceName[0]) {
        log_early(functions, instanceName, "fmi2Instantiate: the instance name is %s (FMI 2.0 asks for a non-empty name)",
                  instanceName ? "empty" : "a null pointer");
        return NULL;
    }
    if (!check_design(d, msg, sizeof msg)) {
        log_early(functions, instanceName, "fmi2Instantiate: the design data compiled into this FMU is inconsistent: %s",
                  msg);
        return NULL;
    }
    if (fmuType != fmi2CoSimulation || !fmuGUID || strcmp(fmuGUID, d->guid) != 0) {
        log_early(functions, instanceName, "fmi2Instantiate: expected a Co-Simulation instance with GUID %s", d->guid);
        return NULL;
    }
    Instance *s = (Instance *)calloc(1, sizeof(Instance));
    if (!s) return NULL;
    s->cb = *functions;
    snprintf(s->name, sizeof s->name, "%s", instanceName);
    s->logging = loggingOn;
    s->d = d;
    size_t nwork = 0, sz;
    for (int w = 0; w < M_COUNT; w++)
        if (d->kind == UIOFMU_GEOMETRIC && w != M_C && d->mat[w].count) {
            if (!mul_size((size_t)d->mat[w].rows, (size_t)d->mat[w].cols, &sz) || nwork > SIZE_MAX / 2 - sz) {
                free(s);
                log_early(functions, instanceName, "fmi2Instantiate: the design's matrices are too large");
                return NULL;
            }
            nwork += sz;
        }
    size_t mx = (size_t)(d->nz > d->n ? d->nz : d->n);
    if ((size_t)d->p > mx) mx = (size_t)d->p;
    s->nblock = (size_t)d->nz + d->p + d->n + d->p + d->m + d->n + d->p + d->q + mx + mx + nwork;
    s->block = (double *)calloc(s->nblock ? s->nblock : 1, sizeof(double));
    if (!s->block) {
        free(s);
        log_early(functions, instanceName, "fmi2Instantiate: out of memory");
        return NULL;
    }
    double *b = s->block;
    s->z = b; b += d->nz;
    s->pred = b; b += d->p;
    s->xhat0 = b; b += d->n;
    s->y = b; b += d->p;
    s->u = b; b += d->m;
    s->xhat = b; b += d->n;
    s->r = b; b += d->p;
    s->dhat = b; b += d->q;
    s->tmp = b; b += mx;
    s->pt = b; b += mx;
    for (int w = 0; w < M_COUNT; w++)
        if (d->kind == UIOFMU_GEOMETRIC && w != M_C && d->mat[w].count) { s->work[w] = b; b += msize(&d->mat[w]); }
    memcpy(s->xhat0, d->xhat0, d->n * sizeof(double));
    s->h_prev0 = d->h_prev0;
    reset_state(s);
    s->phase = PHASE_INSTANTIATED;
    return s;
}

void fmi2FreeInstance(fmi2Component c) {
    Instance *s = (Instance *)c;
    if (!s) return;
    free(s->block);
    free(s);
}

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t n, const fmi2String cats[]) {
    (void)n;
    (void)cats;
    if (!c) return fmi2Error;
    ((Instance *)c)->logging = loggingOn;
    return fmi2OK;
}

#define CHECK_INSTANCE(c) \
    Instance *s = (Instance *)(c); \
    if (!s) return fmi2Error;

static fmi2Status refuse(Instance *s, const char *fn, const char *why) {
    logf_(s, fmi2Error, "logStatusError", "%s: %s", fn, why);
    return fmi2Error;
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean tolDefined, fmi2Real tol, fmi2Real start,
                               fmi2Boolean stopDefined, fmi2Real stop) {
    CHECK_INSTANCE(c)
    (void)tolDefined; (void)tol; (void)start; (void)stopDefined; (void)stop;
    if (s->phase != PHASE_INSTANTIATED) return refuse(s, "fmi2SetupExperiment", "only after fmi2Instantiate");
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    CHECK_INSTANCE(c)
    if (s->phase != PHASE_INSTANTIATED) return refuse(s, "fmi2EnterInitializationMode", "only after fmi2Instantiate");
    s->phase = PHASE_INITIALIZATION;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    CHECK_INSTANCE(c)
    char msg[512], b1[32];
    if (s->phase != PHASE_INITIALIZATION)
        return refuse(s, "fmi2ExitInitializationMode", "only in initialisation mode");
    for (int i = 0; i < s->d->n; i++)
        if (!isfinite(s->xhat0[i])) {
            logf_(s, fmi2Error, "logStatusError", "parameter xhat0[%d] = %g is not finite", i + 1, s->xhat0[i]);
            return fmi2Error;
        }
    if (s->d->kind == UIOFMU_INTERVAL) {
        /* step_policy 'nearest' maps any number to an interval; a step must still be one */
        if (s->d->policy == UIOFMU_POLICY_NEAREST && !(isfinite(s->h_prev0) && s->h_prev0 > 0)) {
            logf_(s, fmi2Error, "logStatusError", "parameter h_prev0 = %s s: expected a step > 0", num(s->h_prev0, b1));
            return fmi2Error;
        }
        if (interval_index(s, s->h_prev0, msg, sizeof msg) < 0) {
            logf_(s, fmi2Error, "logStatusError", "parameter h_prev0: %s", msg);
            return fmi2Error;
        }
    }
    reset_state(s);
    s->phase = PHASE_RUNNING;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c) {
    CHECK_INSTANCE(c)
    if (s->phase != PHASE_RUNNING) return refuse(s, "fmi2Terminate", "only after initialisation");
    s->phase = PHASE_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c) {
    CHECK_INSTANCE(c)
    memcpy(s->xhat0, s->d->xhat0, s->d->n * sizeof(double));
    s->h_prev0 = s->d->h_prev0;
    memset(s->y, 0, s->d->p * sizeof(double));
    memset(s->u, 0, s->d->m * sizeof(double));
    reset_state(s);
    s->phase = PHASE_INSTANTIATED;
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]) {
    CHECK_INSTANCE(c)
    Slot sl;
    if (nvr && (!vr || !value)) return refuse(s, "fmi2GetReal", "null argument");
    if (!refresh(s, "fmi2GetReal")) return fmi2Error;
    for (size_t i = 0; i < nvr; i++) {
        if (!slot(s, vr[i], &sl)) {
            logf_(s, fmi2Error, "logStatusError", "fmi2GetReal: unknown value reference %u", vr[i]);
            return fmi2Error;
        }
        value[i] = *sl.ptr;
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[]) {
    CHECK_INSTANCE(c)
    Slot sl;
    if (nvr && (!vr || !value)) return refuse(s, "fmi2SetReal", "null argument");
    for (size_t i = 0; i < nvr; i++) {
        if (!slot(s, vr[i], &sl)) {
            logf_(s, fmi2Error, "logStatusError", "fmi2SetReal: unknown value reference %u", vr[i]);
            return fmi2Error;
        }
        if (sl.kind == 2) {
            logf_(s, fmi2Error, "logStatusError", "fmi2SetReal: value reference %u is an output", vr[i]);
            return fmi2Error;
        }
        if (sl.kind == 0 && s->phase != PHASE_INSTANTIATED && s->phase != PHASE_INITIALIZATION) {
            logf_(s, fmi2Error, "logStatusError",
                  "fmi2SetReal: value reference %u is a fixed parameter, settable only before initialisation ends",
                  vr[i]);
            return fmi2Error;
        }
        if (s->phase == PHASE_TERMINATED) return refuse(s, "fmi2SetReal", "the instance is terminated");
        *sl.ptr = value[i];
        s->dirty = 1;
    }
    return fmi2OK;
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noSetPrior) {
    CHECK_INSTANCE(c)
#ifdef UIOFMU_CALL_FLOOR
    (void)t; (void)h; (void)noSetPrior;
    return fmi2OK; /* benchmark build only: the cost of the FMI call itself */
#endif
    static const char fn[] = "fmi2DoStep";
    const UiofmuDesign *d = s->d;
    char msg[512];
    (void)noSetPrior;
    if (s->phase != PHASE_RUNNING)
        return refuse(s, fn, "called before fmi2ExitInitializationMode or after fmi2Terminate");
    char bt[32], bh[32], bd[32];
    if (!(isfinite(h) && h > 0)) {
        logf_(s, fmi2Error, "logStatusError", "t = %s: communication step h = %g at step k = %ld: expected h > 0",
              num(t, bt), h, s->k);
        return fmi2Error;
    }
    for (int i = 0; i < d->p; i++)
        if (!isfinite(s->y[i])) {
            logf_(s, fmi2Error, "logStatusError", "t = %s: input y[%d] = %s at step k = %ld is not finite",
                  num(t, bt), i + 1, isnan(s->y[i]) ? "nan" : (s->y[i] > 0 ? "inf" : "-inf"), s->k);
            return fmi2Error;
        }
    for (int i = 0; i < d->m; i++)
        if (!isfinite(s->u[i])) {
            logf_(s, fmi2Error, "logStatusError", "t = %s: input u[%d] = %s at step k = %ld is not finite",
                  num(t, bt), i + 1, isnan(s->u[i]) ? "nan" : (s->u[i] > 0 ? "inf" : "-inf"), s->k);
            return fmi2Error;
        }
    int i = 0, j = 0;
    if (d->kind == UIOFMU_INTERVAL) {
        i = interval_index(s, h, msg, sizeof msg);
        if (i < 0) {
            logf_(s, fmi2Discard, "logStatusDiscard", "t = %s: %s", num(t, bt), msg);
            return fmi2Discard;
        }
        j = prev_index(s);
        if (j < 0) {
            bad_prev(s, fn);
            return fmi2Error;
        }
    } else if (d->policy == UIOFMU_POLICY_ERROR && fabs(h - d->dt) > d->step_rtol * d->dt) {
        logf_(s, fmi2Discard, "logStatusDiscard",
              "t = %s: this observer was designed for steps of dt = %s s and received h = %s s "
              "(step_policy = 'error')", num(t, bt), num(d->dt, bd), num(h, bh));
        return fmi2Discard;
    }
    /* every matrix of the step before anything changes: a missing one refuses the step whole */
    const double *Xy = need(s, fn, M_Xy, i, j), *N = need(s, fn, M_N, i, j), *L = need(s, fn, M_L, i, j),
                 *G = need(s, fn, M_G, i, j), *cc = need(s, fn, M_c, i, j);
    const double *Yx = NULL, *Yu = NULL, *Yc = NULL;
    if (!Xy || !N || !L || !G || !cc) return fmi2Error;
    if (d->has_dhat) {
        Yx = need(s, fn, M_Yx, i, j);
        Yu = need(s, fn, M_Yu, i, j);
        Yc = need(s, fn, M_Yc, i, j);
        if (!Yx || !Yu || !Yc) return fmi2Error;
    }
    if (!estimate(s, fn, j)) return fmi2Error; /* xhat_k (and the geometric matrices of step k) */
    if (s->k == 0) {
        matvec(Xy, d->n, d->p, s->y, s->tmp);
        for (int e = 0; e < d->nz; e++) s->z[e] = s->xhat0[e] - s->tmp[e];
    }
    if (d->has_dhat) {
        matvec(Yx, d->p, d->n, s->xhat, s->pred);
        matvec_add(Yu, d->p, d->m, s->u, s->pred, s->pt);
        for (int e = 0; e < d->p; e++) s->pred[e] += Yc[e];
    }
    matvec(N, d->nz, d->nz, s->z, s->tmp);
    matvec_add(L, d->nz, d->p, s->y, s->tmp, s->pt);
    matvec_add(G, d->nz, d->m, s->u, s->tmp, s->pt);
    for (int e = 0; e < d->nz; e++) s->z[e] = s->tmp[e] + cc[e];
    s->h_prev = h;
    s->j_prev = i;
    s->k += 1;
    s->dirty = 1;
    return fmi2OK;
}

fmi2Status fmi2CancelStep(fmi2Component c) {
    CHECK_INSTANCE(c)
    return refuse(s, "fmi2CancelStep", "not supported (steps complete synchronously)");
}

/* ---------------------------------------------------------------------------------------- */
/* FMU state
 *
 * One byte image, the same in memory (what fmi2GetFMUstate returns: a malloc'ed block of
 * exactly `size` bytes) and serialised. Every field is read and written with memcpy (no
 * alignment assumed, serialised bytes may sit anywhere), in the platform's byte order:
 *
 *   offset   bytes  field
 *        0       4  magic        0x75696f66 ("uiof")
 *        4       4  layout       STATE_LAYOUT = 2 (layout 1 had magic, count, doubles, GUID)
 *        8       8  size         bytes of the whole image
 *       16       4  guid_length  G
 *       20      16  n, m, p, nz  the dims of the FMU that made it
 *       36       4  count        D = 5 + nz + p + n + p + m, the doubles below
 *       40       G  the GUID of the FMU that made it, then zero bytes up to a multiple of 8
 *   40 + G'    8 D  k, h_prev, h_prev0, noticed, phase, z[nz], pred[p], xhat0[n], y[p], u[m]
 *
 * fmi2SetFMUstate and fmi2DeSerializeFMUstate refuse a state (fmi2Error and a log line with
 * the numbers) unless every header field is this FMU's (magic, layout, size, GUID, dims,
 * count, zero padding; and serialised bytes fill the buffer exactly) and every value is one
 * this FMU can be in (check_values), all checked before any of it is used:
 *   k        an integer 0 <= k < 2^53 (and within long); 0 before initialisation ends
 *   phase    0 instantiated, 1 initialisation mode, 2 initialised, 3 terminated
 *   noticed  0 or 1, and 1 only for an interval schedule with step_policy 'nearest'
 *   h_prev0  finite, > 0. Constant and geometric schedules: the design's (not a variable of
 *            those FMUs). Interval schedules in phase 2 and 3: a design interval (it was
 *            checked when initialisation ended, reset_state copied it to h_prev, and it
 *            cannot change after); in phase 0 and 1 a parameter value not yet taken, which
 *            fmi2ExitInitializationMode checks before it becomes h_prev
 *   h_prev   finite, > 0, and equal to h_prev0 at k = 0 (in phase 2 and 3; in every phase
 *            for the schedules without an h_prev0 variable). Interval schedules: a design
 *            interval in every phase (the runtime indexes its matrices with it at every step
 *            and every output); constant and geometric ones with step_policy 'error', k > 0:
 *            within step_rtol of dt (the only step such an FMU takes)
 *   z, pred  finite, and all zero at k = 0 (reset_state zeroes them; the first step sets them)
 *   xhat0    finite (the first output and z_0; fmi2ExitInitializationMode refuses a
 *            non-finite one, so a state holding one is refused as well, whatever its phase)
 *   y, u     any value, NaN and Inf included: they are inputs, which fmi2SetReal takes
 *            whatever their value (as the reference runtime does) and fmi2DoStep checks
 *            before any use, refusing a non-finite one; the outputs they feed are plain
 *            arithmetic, never an index. An instance holds such an input legitimately (a
 *            master set it, the step was refused), and refusing its state would break the
 *            get/set round trip.
 * A state is this FMU's when its GUID is, whatever its dims: two FMUs with equal dims and
 * other matrices (or only another xhat0) have other GUIDs. fmi2GetFMUstate and
 * fmi2DeSerializeFMUstate reuse a non-NULL *FMUstate only when its header is this FMU's
 * (same size), fmi2FreeFMUstate frees only such a state.
 */

#define STATE_MAGIC 0x75696f66u
#define STATE_LAYOUT 2u
#define STATE_HEADER 40
#define MAX_SAFE_INTEGER 9007199254740992.0 /* 2^53 */

enum { SV_K, SV_H_PREV, SV_H_PREV0, SV_NOTICED, SV_PHASE, SV_SCALARS };

typedef unsigned char Byte;

static size_t state_count(const UiofmuDesign *d) {
    return SV_SCALARS + (size_t)d->nz + (size_t)d->p + (size_t)d->n + (size_t)d->p + (size_t)d->m;
}
static size_t state_data(const UiofmuDesign *d) { return STATE_HEADER + (strlen(d->guid) + 7) / 8 * 8; }
static size_t state_size(const UiofmuDesign *d) { return state_data(d) + sizeof(double) * state_count(d); }

static uint32_t get32(const Byte *b, size_t off) { uint32_t v; memcpy(&v, b + off, sizeof v); return v; }
static uint64_t get64(const Byte *b, size_t off) { uint64_t v; memcpy(&v, b + off, sizeof v); return v; }
static double getd(const Byte *b, size_t index) { double v; memcpy(&v, b + index * sizeof v, sizeof v); return v; }
static void put32(Byte *b, size_t off, uint32_t v) { memcpy(b + off, &v, sizeof v); }
static void put64(Byte *b, size_t off, uint64_t v) { memcpy(b + off, &v, sizeof v); }

static int state_refused(Instance *s, const char *ctx, const char *fmt, ...) {
    char buf[768];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    logf_(s, fmi2Error, "logStatusError", "%s: %s", ctx, buf);
    return 0;
}

static void write_state(Instance *s, Byte *b) {
    const UiofmuDesign *d = s->d;
    size_t g = strlen(d->guid), off = state_data(d);
    double scalars[SV_SCALARS] = {(double)s->k, s->h_prev, s->h_prev0, (double)s->noticed, (double)s->phase};
    memset(b, 0, off);
    put32(b, 0, STATE_MAGIC);
    put32(b, 4, STATE_LAYOUT);
    put64(b, 8, (uint64_t)state_size(d));
    put32(b, 16, (uint32_t)g);
    put32(b, 20, (uint32_t)d->n);
    put32(b, 24, (uint32_t)d->m);
    put32(b, 28, (uint32_t)d->p);
    put32(b, 32, (uint32_t)d->nz);
    put32(b, 36, (uint32_t)state_count(d));
    memcpy(b + STATE_HEADER, d->guid, g);
    Byte *o = b + off;
    memcpy(o, scalars, sizeof scalars); o += sizeof scalars;
    memcpy(o, s->z, d->nz * sizeof(double)); o += d->nz * sizeof(double);
    memcpy(o, s->pred, d->p * sizeof(double)); o += d->p * sizeof(double);
    memcpy(o, s->xhat0, d->n * sizeof(double)); o += d->n * sizeof(double);
    memcpy(o, s->y, d->p * sizeof(double)); o += d->p * sizeof(double);
    memcpy(o, s->u, d->m * sizeof(double));
}

/* Whether the image at b is a state of this FMU, header only (a log line from ctx saying why
   not). Serialised bytes (in_memory 0) are avail bytes long, and nothing past them is read; a
   state in memory is as long as its own size field says. */
static int check_header(Instance *s, const char *ctx, const Byte *b, size_t avail, int in_memory) {
    const UiofmuDesign *d = s->d;
    size_t want = state_size(d), g = strlen(d->guid), data = state_data(d);
    if (!in_memory && avail < STATE_HEADER)
        return state_refused(s, ctx, "%zu bytes are too few for a state of this FMU (%zu bytes)", avail, want);
    uint32_t magic = get32(b, 0), layout = get32(b, 4), glen;
    uint64_t size = get64(b, 8);
    if (magic != STATE_MAGIC)
        return state_refused(s, ctx, "not a uiofmu observer state (magic 0x%08lx, expected 0x%08lx)",
                             (unsigned long)magic, (unsigned long)STATE_MAGIC);
    if (layout != STATE_LAYOUT)
        return state_refused(s, ctx, "state layout version %lu, this FMU reads version %lu", (unsigned long)layout,
                             (unsigned long)STATE_LAYOUT);
    if (!in_memory && size != (uint64_t)avail)
        return state_refused(s, ctx, "the buffer holds %zu bytes, the state in it says %llu bytes (truncated or extended; "
                             "this FMU's states are %zu bytes)", avail, (unsigned long long)size, want);
    if (size < STATE_HEADER)
        return state_refused(s, ctx, "the state says it is %llu bytes, less than its %d-byte header",
                             (unsigned long long)size, STATE_HEADER);
    glen = get32(b, 16);
    if ((uint64_t)glen > size - STATE_HEADER)
        return state_refused(s, ctx, "its GUID length %lu does not fit in a %llu-byte state", (unsigned long)glen,
                             (unsigned long long)size);
    if ((size_t)glen != g || memcmp(b + STATE_HEADER, d->guid, g) != 0) {
        char other[80];
        size_t i, shown = glen < sizeof other - 4 ? glen : sizeof other - 4;
        for (i = 0; i < shown; i++) {
            Byte ch = b[STATE_HEADER + i];
            other[i] = ch >= 0x20 && ch < 0x7f ? (char)ch : '?';
        }
        strcpy(other + i, shown < glen ? "..." : "");
        return state_refused(s, ctx, "the state belongs to the FMU with GUID %s, not to this FMU (GUID %s)", other,
                             d->guid);
    }
    uint32_t n = get32(b, 20), m = get32(b, 24), p = get32(b, 28), nz = get32(b, 32), count = get32(b, 36);
    if (n != (uint32_t)d->n || m != (uint32_t)d->m || p != (uint32_t)d->p || nz != (uint32_t)d->nz ||
        count != (uint32_t)state_count(d))
        return state_refused(s, ctx, "the state has n = %lu, m = %lu, p = %lu, nz = %lu and %lu numbers; this FMU has "
                             "n = %d, m = %d, p = %d, nz = %d and %zu", (unsigned long)n, (unsigned long)m,
                             (unsigned long)p, (unsigned long)nz, (unsigned long)count, d->n, d->m, d->p, d->nz,
                             state_count(d));
    if (size != (uint64_t)want)
        return state_refused(s, ctx, "the state is %llu bytes, this FMU's states are %zu bytes",
                             (unsigned long long)size, want);
    for (size_t i = STATE_HEADER + g; i < data; i++)
        if (b[i])
            return state_refused(s, ctx, "byte %zu (padding after the GUID) is %u, expected 0", i, (unsigned)b[i]);
    return 1;
}

/* " (nearest interval 600 s, tolerance 1e-06 relative; step_policy 'error')" */
static const char *interval_note(const UiofmuDesign *d, double h, char *buf, size_t len) {
    int best, exact;
    if (nearest_interval(d, h, &best, &exact))
        snprintf(buf, len, "nearest interval %g s, tolerance %g relative; step_policy 'error'", d->intervals[best],
                 d->step_rtol);
    else
        snprintf(buf, len, "no intervals");
    return buf;
}

/* Whether the doubles at v (k, h_prev, ...; see above) are a state this FMU can be in. */
static int check_values(Instance *s, const char *ctx, const Byte *v) {
    static const char *const VECTOR[3] = {"z", "pred", "xhat0"};
    const UiofmuDesign *d = s->d;
    char b1[32], b2[32], note[160];
    double k = getd(v, SV_K), hp = getd(v, SV_H_PREV), hp0 = getd(v, SV_H_PREV0), noticed = getd(v, SV_NOTICED),
           phase = getd(v, SV_PHASE);
    int interval = d->kind == UIOFMU_INTERVAL;
    if (!(isfinite(k) && k >= 0 && k == floor(k) && k < MAX_SAFE_INTEGER && k <= (double)LONG_MAX))
        return state_refused(s, ctx, "k = %s is not a step count (an integer, 0 <= k < 2^53)", num(k, b1));
    if (!(phase == PHASE_INSTANTIATED || phase == PHASE_INITIALIZATION || phase == PHASE_RUNNING ||
          phase == PHASE_TERMINATED))
        return state_refused(s, ctx, "phase = %s is none of 0 (instantiated), 1 (initialisation mode), "
                             "2 (initialised), 3 (terminated)", num(phase, b1));
    int running = phase >= PHASE_RUNNING;
    if (!(noticed == 0 || noticed == 1)) return state_refused(s, ctx, "noticed = %s is neither 0 nor 1", num(noticed, b1));
    if (noticed == 1 && !(interval && d->policy == UIOFMU_POLICY_NEAREST))
        return state_refused(s, ctx, "noticed = 1, but only an interval schedule with step_policy 'nearest' notes a step");
    if (!running && k != 0)
        return state_refused(s, ctx, "k = %s in phase %d, before initialisation ended: expected 0", num(k, b1), (int)phase);
    if (!(isfinite(hp0) && hp0 > 0)) return state_refused(s, ctx, "h_prev0 = %s is not a step (finite, > 0)", num(hp0, b1));
    if (!interval && hp0 != d->h_prev0)
        return state_refused(s, ctx, "h_prev0 = %s differs from this design's %s (not a variable of this FMU)",
                             num(hp0, b1), num(d->h_prev0, b2));
    if (interval && running && !resolves(d, hp0))
        return state_refused(s, ctx, "h_prev0 = %s s is not a design interval (%s), but initialisation ended",
                             num(hp0, b1), interval_note(d, hp0, note, sizeof note));
    if (!(isfinite(hp) && hp > 0)) return state_refused(s, ctx, "h_prev = %s is not a step (finite, > 0)", num(hp, b1));
    if (interval && !resolves(d, hp))
        return state_refused(s, ctx, "h_prev = %s s is not a design interval (%s)", num(hp, b1),
                             interval_note(d, hp, note, sizeof note));
    if (k == 0 && (running || !interval) && hp != hp0)
        return state_refused(s, ctx, "h_prev = %s s at k = 0 differs from h_prev0 = %s s", num(hp, b1), num(hp0, b2));
    if (!interval && d->policy == UIOFMU_POLICY_ERROR && k > 0 && fabs(hp - d->dt) > d->step_rtol * d->dt)
        return state_refused(s, ctx, "h_prev = %s s is not the design step dt = %s s (step_policy 'error')",
                             num(hp, b1), num(d->dt, b2));
    const int length[3] = {d->nz, d->p, d->n};
    size_t at = SV_SCALARS;
    for (int w = 0; w < 3; w++) {
        for (int i = 0; i < length[w]; i++) {
            double x = getd(v, at + (size_t)i);
            if (!isfinite(x)) return state_refused(s, ctx, "%s[%d] = %s is not finite", VECTOR[w], i + 1, num(x, b1));
            if (w < 2 && k == 0 && x != 0)
                return state_refused(s, ctx, "%s[%d] = %s at k = 0: expected 0 (the first step sets it)", VECTOR[w],
                                     i + 1, num(x, b1));
        }
        at += (size_t)length[w];
    }
    /* y[p], u[m]: taken as they are (see above) */
    return 1;
}

static void apply_state(Instance *s, const Byte *v) {
    const UiofmuDesign *d = s->d;
    s->k = (long)getd(v, SV_K);
    s->h_prev = getd(v, SV_H_PREV);
    s->h_prev0 = getd(v, SV_H_PREV0);
    s->noticed = (int)getd(v, SV_NOTICED);
    s->phase = (int)getd(v, SV_PHASE);
    const Byte *o = v + SV_SCALARS * sizeof(double);
    memcpy(s->z, o, d->nz * sizeof(double)); o += d->nz * sizeof(double);
    memcpy(s->pred, o, d->p * sizeof(double)); o += d->p * sizeof(double);
    memcpy(s->xhat0, o, d->n * sizeof(double)); o += d->n * sizeof(double);
    memcpy(s->y, o, d->p * sizeof(double)); o += d->p * sizeof(double);
    memcpy(s->u, o, d->m * sizeof(double));
    s->work_k = -1;
    s->j_prev = -1;
    s->dirty = 1;
}

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *state) {
    CHECK_INSTANCE(c)
    if (!state) return refuse(s, "fmi2GetFMUstate", "null argument");
    Byte *b = (Byte *)*state;
    if (b && !check_header(s, "fmi2GetFMUstate: cannot reuse *FMUstate, which is not a state of this FMU "
                           "(pass NULL for a new one)", b, 0, 1))
        return fmi2Error;
    if (!b) {
        b = (Byte *)malloc(state_size(s->d));
        if (!b) return refuse(s, "fmi2GetFMUstate", "out of memory");
    }
    write_state(s, b);
    *state = b;
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate state) {
    CHECK_INSTANCE(c)
    static const char ctx[] = "fmi2SetFMUstate: state refused";
    const Byte *b = (const Byte *)state;
    if (!b) return refuse(s, "fmi2SetFMUstate", "null state");
    if (!check_header(s, ctx, b, 0, 1) || !check_values(s, ctx, b + state_data(s->d))) return fmi2Error;
    apply_state(s, b + state_data(s->d));
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *state) {
    CHECK_INSTANCE(c)
    if (!state || !*state) return fmi2OK;
    Byte *b = (Byte *)*state;
    if (!check_header(s, "fmi2FreeFMUstate: not freed, not a state of this FMU", b, 0, 1)) return fmi2Error;
    put32(b, 0, 0); /* whatever still points here no longer points at a state */
    free(b);
    *state = NULL;
    return fmi2OK;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate state, size_t *size) {
    CHECK_INSTANCE(c)
    if (!size || !state) return refuse(s, "fmi2SerializedFMUstateSize", "null argument");
    if (!check_header(s, "fmi2SerializedFMUstateSize: not a state of this FMU", (const Byte *)state, 0, 1))
        return fmi2Error;
    *size = state_size(s->d);
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate state, fmi2Byte bytes[], size_t size) {
    CHECK_INSTANCE(c)
    size_t need = state_size(s->d);
    if (!state || !bytes) return refuse(s, "fmi2SerializeFMUstate", "null argument");
    if (!check_header(s, "fmi2SerializeFMUstate: not a state of this FMU", (const Byte *)state, 0, 1)) return fmi2Error;
    if (size < need) {
        logf_(s, fmi2Error, "logStatusError", "fmi2SerializeFMUstate: the buffer holds %zu bytes, the state needs %zu "
              "(fmi2SerializedFMUstateSize)", size, need);
        return fmi2Error;
    }
    memcpy(bytes, state, need);
    return fmi2OK;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte bytes[], size_t size, fmi2FMUstate *state) {
    CHECK_INSTANCE(c)
    static const char ctx[] = "fmi2DeSerializeFMUstate: bytes refused";
    const Byte *in = (const Byte *)bytes;
    size_t need = state_size(s->d);
    if (!in || !state) return refuse(s, "fmi2DeSerializeFMUstate", "null argument");
    if (!check_header(s, ctx, in, size, 0) || !check_values(s, ctx, in + state_data(s->d))) return fmi2Error;
    Byte *b = (Byte *)*state;
    if (b && !check_header(s, "fmi2DeSerializeFMUstate: cannot reuse *FMUstate, which is not a state of this FMU "
                           "(pass NULL for a new one)", b, 0, 1))
        return fmi2Error;
    if (!b) {
        b = (Byte *)malloc(need);
        if (!b) return refuse(s, "fmi2DeSerializeFMUstate", "out of memory");
    }
    memcpy(b, in, need);
    *state = b;
    return fmi2OK;
}

/* ---------------------------------------------------------------------------------------- */
/* The rest of the FMI 2.0 CS interface: no such variables, or not supported.              */

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Integer v[]) {
    CHECK_INSTANCE(c)
    (void)vr; (void)v;
    return nvr ? refuse(s, "fmi2GetInteger", "this FMU has no Integer variables") : fmi2OK;
}
fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean v[]) {
    CHECK_INSTANCE(c)
    (void)vr; (void)v;
    return nvr ? refuse(s, "fmi2GetBoolean", "this FMU has no Boolean variables") : fmi2OK;
}
fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2String v[]) {
    CHECK_INSTANCE(c)
    (void)vr; (void)v;
    return nvr ? refuse(s, "fmi2GetString", "this FMU has no String variables") : fmi2OK;
}
fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Integer v[]) {
    CHECK_INSTANCE(c)
    (void)vr; (void)v;
    return nvr ? refuse(s, "fmi2SetInteger", "this FMU has no Integer variables") : fmi2OK;
}
fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Boolean v[]) {
    CHECK_INSTANCE(c)
    (void)vr; (void)v;
    return nvr ? refuse(s, "fmi2SetBoolean", "this FMU has no Boolean variables") : fmi2OK;
}
fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2String v[]) {
    CHECK_INSTANCE(c)
    (void)vr; (void)v;
    return nvr ? refuse(s, "fmi2SetString", "this FMU has no String variables") : fmi2OK;
}
fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference u[], size_t nu,
                                        const fmi2ValueReference z[], size_t nz, const fmi2Real dv[],
                                        fmi2Real dz[]) {
    CHECK_INSTANCE(c)
    (void)u; (void)nu; (void)z; (void)nz; (void)dv; (void)dz;
    return refuse(s, "fmi2GetDirectionalDerivative", "not supported");
}
fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    CHECK_INSTANCE(c)
    (void)vr; (void)nvr; (void)order; (void)value;
    return refuse(s, "fmi2SetRealInputDerivatives", "not supported (canInterpolateInputs = false)");
}
fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    CHECK_INSTANCE(c)
    (void)vr; (void)nvr; (void)order; (void)value;
    return refuse(s, "fmi2GetRealOutputDerivatives", "not supported (MaxOutputDerivativeOrder = 0)");
}
fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind k, fmi2Status *v) {
    CHECK_INSTANCE(c)
    (void)k; (void)v;
    return refuse(s, "fmi2GetStatus", "not supported (steps complete synchronously)");
}
fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind k, fmi2Real *v) {
    CHECK_INSTANCE(c)
    if (k == fmi2LastSuccessfulTime && v) {
        *v = 0.0;
        return refuse(s, "fmi2GetRealStatus", "fmi2LastSuccessfulTime is not tracked");
    }
    return refuse(s, "fmi2GetRealStatus", "not supported");
}
fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind k, fmi2Integer *v) {
    CHECK_INSTANCE(c)
    (void)k; (void)v;
    return refuse(s, "fmi2GetIntegerStatus", "not supported");
}
fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind k, fmi2Boolean *v) {
    CHECK_INSTANCE(c)
    (void)k; (void)v;
    return refuse(s, "fmi2GetBooleanStatus", "not supported");
}
fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind k, fmi2String *v) {
    CHECK_INSTANCE(c)
    (void)k; (void)v;
    return refuse(s, "fmi2GetStringStatus", "not supported");
}
