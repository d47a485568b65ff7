/* uiofmu: the observer runtime in C, with its own FMI 2.0 Co-Simulation interface.
 *
 * One generic file for every observer family: the design (matrices and schedule) comes from
 * design_data.c, generated from the design card. The step semantics are those of the
 * reference runtime (uiofmu/runtime.py):
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
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "uiofmu_design.h"

enum { PHASE_INSTANTIATED, PHASE_INITIALIZATION, PHASE_RUNNING, PHASE_TERMINATED };

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

/* Index of the design interval of step h; -1 when rejected (message in msg). */
static int interval_index(Instance *s, double h, char *msg, size_t len) {
    const UiofmuDesign *d = s->d;
    int best = 0;
    for (int i = 1; i < d->nintervals; i++)
        if (fabs(h - d->intervals[i]) < fabs(h - d->intervals[best])) best = i;
    if (fabs(h - d->intervals[best]) <= d->step_rtol * d->intervals[best]) return best;
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
        if (w == M_C || M->count <= 1) continue; /* constant in a: used in place */
        size_t sz = msize(M);
        double *out = s->work[w];
        memcpy(out, M->data + (size_t)(M->count - 1) * sz, sz * sizeof(double));
        for (int c = M->count - 2; c >= 0; c--)
            for (size_t e = 0; e < sz; e++) out[e] = out[e] * a + M->data[(size_t)c * sz + e];
    }
    s->work_k = k;
}

/* The matrix `which` for step indices (i, j) (interval) or step k (geometric). */
static const double *pick(Instance *s, int which, int i, int j) {
    const UiofmuMatrix *M = &s->d->mat[which];
    size_t sz = msize(M);
    if (which == M_C || s->d->kind == UIOFMU_CONSTANT) return M->data;
    if (s->d->kind == UIOFMU_GEOMETRIC) return M->count == 1 ? M->data : s->work[which];
    if (which == M_N || which == M_L) return M->data + ((size_t)i * s->d->nintervals + j) * sz;
    if (which == M_Xz || which == M_Xy || which == M_Dy) return M->data + (size_t)j * sz;
    return M->data + (size_t)i * sz;
}

static int prev_index(Instance *s) {
    if (s->d->kind != UIOFMU_INTERVAL) return 0;
    if (s->j_prev < 0) s->j_prev = interval_index(s, s->h_prev, NULL, 0);
    return s->j_prev;
}

/* xhat_k alone (what a step needs). */
static void estimate(Instance *s, int j) {
    const UiofmuDesign *d = s->d;
    if (d->kind == UIOFMU_GEOMETRIC) evaluate(s, s->k);
    if (s->k == 0) {
        memcpy(s->xhat, s->xhat0, d->n * sizeof(double));
    } else {
        matvec(pick(s, M_Xz, 0, j), d->n, d->nz, s->z, s->xhat);
        matvec_add(pick(s, M_Xy, 0, j), d->n, d->p, s->y, s->xhat, s->pt);
    }
}

static void refresh(Instance *s) {
    const UiofmuDesign *d = s->d;
    if (!s->dirty) return;
    int j = prev_index(s);
    estimate(s, j);
    matvec(d->mat[M_C].data, d->p, d->n, s->xhat, s->r);
    for (int i = 0; i < d->p; i++) s->r[i] = s->y[i] - s->r[i];
    if (d->has_dhat) {
        if (s->k > 0) {
            for (int i = 0; i < d->p; i++) s->tmp[i] = s->y[i] - s->pred[i];
            matvec(pick(s, M_Dy, 0, j), d->q, d->p, s->tmp, s->dhat);
        } else {
            for (int i = 0; i < d->q; i++) s->dhat[i] = 0.0;
        }
    }
    s->dirty = 0;
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
/* value references: xhat0[n], (h_prev0), y[p], u[m], xhat[n], r[p], (dhat[q])                */

typedef struct { double *ptr; int kind; } Slot; /* kind: 0 parameter, 1 input, 2 output */

static int slot(Instance *s, fmi2ValueReference vr, Slot *out) {
    const UiofmuDesign *d = s->d;
    long v = (long)vr;
    if (v < d->n) { *out = (Slot){ &s->xhat0[v], 0 }; return 1; }
    v -= d->n;
    if (d->kind == UIOFMU_INTERVAL) {
        if (v == 0) { *out = (Slot){ &s->h_prev0, 0 }; return 1; }
        v -= 1;
    }
    if (v < d->p) { *out = (Slot){ &s->y[v], 1 }; return 1; }
    v -= d->p;
    if (v < d->m) { *out = (Slot){ &s->u[v], 1 }; return 1; }
    v -= d->m;
    if (v < d->n) { *out = (Slot){ &s->xhat[v], 2 }; return 1; }
    v -= d->n;
    if (v < d->p) { *out = (Slot){ &s->r[v], 2 }; return 1; }
    v -= d->p;
    if (d->has_dhat && v < d->q) { *out = (Slot){ &s->dhat[v], 2 }; return 1; }
    return 0;
}

/* ---------------------------------------------------------------------------------------- */

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn) {
    const UiofmuDesign *d = &UIOFMU_DESIGN;
    (void)fmuResourceLocation;
    (void)visible;
    if (!functions) return NULL;
    if (fmuType != fmi2CoSimulation || !fmuGUID || strcmp(fmuGUID, d->guid) != 0) {
        if (functions->logger)
            functions->logger(functions->componentEnvironment, instanceName ? instanceName : "", fmi2Error,
                              "logStatusError", "fmi2Instantiate: expected a Co-Simulation instance with GUID %s",
                              d->guid);
        return NULL;
    }
    Instance *s = (Instance *)calloc(1, sizeof(Instance));
    if (!s) return NULL;
    s->cb = *functions;
    snprintf(s->name, sizeof s->name, "%s", instanceName ? instanceName : "");
    s->logging = loggingOn;
    s->d = d;
    size_t nwork = 0;
    for (int w = 0; w < M_COUNT; w++)
        if (d->kind == UIOFMU_GEOMETRIC && w != M_C && d->mat[w].count) nwork += msize(&d->mat[w]);
    size_t mx = (size_t)(d->nz > d->n ? d->nz : d->n);
    if ((size_t)d->p > mx) mx = (size_t)d->p;
    s->nblock = (size_t)d->nz + d->p + d->n + d->p + d->m + d->n + d->p + d->q + mx + mx + nwork;
    s->block = (double *)calloc(s->nblock ? s->nblock : 1, sizeof(double));
    if (!s->block) { free(s); return NULL; }
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
    char msg[512];
    if (s->phase != PHASE_INITIALIZATION)
        return refuse(s, "fmi2ExitInitializationMode", "only in initialisation mode");
    for (int i = 0; i < s->d->n; i++)
        if (!isfinite(s->xhat0[i])) {
            logf_(s, fmi2Error, "logStatusError", "parameter xhat0[%d] = %g is not finite", i + 1, s->xhat0[i]);
            return fmi2Error;
        }
    if (s->d->kind == UIOFMU_INTERVAL && interval_index(s, s->h_prev0, msg, sizeof msg) < 0) {
        logf_(s, fmi2Error, "logStatusError", "parameter h_prev0: %s", msg);
        return fmi2Error;
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
    refresh(s);
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
    const UiofmuDesign *d = s->d;
    char msg[512];
    (void)noSetPrior;
    if (s->phase != PHASE_RUNNING)
        return refuse(s, "fmi2DoStep", "called before fmi2ExitInitializationMode or after fmi2Terminate");
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
    } else if (d->policy == UIOFMU_POLICY_ERROR && fabs(h - d->dt) > d->step_rtol * d->dt) {
        logf_(s, fmi2Discard, "logStatusDiscard",
              "t = %s: this observer was designed for steps of dt = %s s and received h = %s s "
              "(step_policy = 'error')", num(t, bt), num(d->dt, bd), num(h, bh));
        return fmi2Discard;
    }
    estimate(s, j); /* xhat_k (and the geometric matrices of step k) */
    if (s->k == 0) {
        matvec(pick(s, M_Xy, i, j), d->n, d->p, s->y, s->tmp);
        for (int e = 0; e < d->nz; e++) s->z[e] = s->xhat0[e] - s->tmp[e];
    }
    if (d->has_dhat) {
        matvec(pick(s, M_Yx, i, j), d->p, d->n, s->xhat, s->pred);
        matvec_add(pick(s, M_Yu, i, j), d->p, d->m, s->u, s->pred, s->pt);
        const double *Yc = pick(s, M_Yc, i, j);
        for (int e = 0; e < d->p; e++) s->pred[e] += Yc[e];
    }
    matvec(pick(s, M_N, i, j), d->nz, d->nz, s->z, s->tmp);
    matvec_add(pick(s, M_L, i, j), d->nz, d->p, s->y, s->tmp, s->pt);
    matvec_add(pick(s, M_G, i, j), d->nz, d->m, s->u, s->tmp, s->pt);
    const double *cc = pick(s, M_c, i, j);
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
/* FMU state: k, h_prev, h_prev0, noticed, phase, then z, pred, xhat0, y, u                  */

#define STATE_MAGIC 0x75696f66 /* "uiof" */

static size_t state_doubles(const UiofmuDesign *d) { return 5 + (size_t)d->nz + d->p + d->n + d->p + d->m; }

static void pack(Instance *s, double *out) {
    const UiofmuDesign *d = s->d;
    out[0] = (double)s->k; out[1] = s->h_prev; out[2] = s->h_prev0; out[3] = s->noticed; out[4] = s->phase;
    double *o = out + 5;
    memcpy(o, s->z, d->nz * sizeof(double)); o += d->nz;
    memcpy(o, s->pred, d->p * sizeof(double)); o += d->p;
    memcpy(o, s->xhat0, d->n * sizeof(double)); o += d->n;
    memcpy(o, s->y, d->p * sizeof(double)); o += d->p;
    memcpy(o, s->u, d->m * sizeof(double));
}

static void unpack(Instance *s, const double *in) {
    const UiofmuDesign *d = s->d;
    s->k = (long)in[0]; s->h_prev = in[1]; s->h_prev0 = in[2]; s->noticed = (int)in[3]; s->phase = (int)in[4];
    const double *o = in + 5;
    memcpy(s->z, o, d->nz * sizeof(double)); o += d->nz;
    memcpy(s->pred, o, d->p * sizeof(double)); o += d->p;
    memcpy(s->xhat0, o, d->n * sizeof(double)); o += d->n;
    memcpy(s->y, o, d->p * sizeof(double)); o += d->p;
    memcpy(s->u, o, d->m * sizeof(double));
    s->work_k = -1;
    s->j_prev = -1;
    s->dirty = 1;
}

typedef struct { unsigned magic; size_t count; double data[]; } Saved;

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *state) {
    CHECK_INSTANCE(c)
    if (!state) return refuse(s, "fmi2GetFMUstate", "null argument");
    size_t n = state_doubles(s->d);
    Saved *st = (Saved *)*state;
    if (!st) {
        st = (Saved *)malloc(sizeof(Saved) + n * sizeof(double));
        if (!st) return refuse(s, "fmi2GetFMUstate", "out of memory");
    }
    st->magic = STATE_MAGIC;
    st->count = n;
    pack(s, st->data);
    *state = st;
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate state) {
    CHECK_INSTANCE(c)
    Saved *st = (Saved *)state;
    if (!st || st->magic != STATE_MAGIC || st->count != state_doubles(s->d))
        return refuse(s, "fmi2SetFMUstate", "not a state of this FMU");
    unpack(s, st->data);
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *state) {
    CHECK_INSTANCE(c)
    if (state && *state) {
        free(*state);
        *state = NULL;
    }
    return fmi2OK;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate state, size_t *size) {
    CHECK_INSTANCE(c)
    (void)state;
    if (!size) return refuse(s, "fmi2SerializedFMUstateSize", "null argument");
    *size = sizeof(unsigned) + sizeof(size_t) + state_doubles(s->d) * sizeof(double) + strlen(s->d->guid);
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate state, fmi2Byte bytes[], size_t size) {
    CHECK_INSTANCE(c)
    Saved *st = (Saved *)state;
    size_t need = sizeof(unsigned) + sizeof(size_t) + state_doubles(s->d) * sizeof(double) + strlen(s->d->guid);
    if (!st || st->magic != STATE_MAGIC || !bytes || size < need)
        return refuse(s, "fmi2SerializeFMUstate", "not a state of this FMU, or the buffer is too small");
    char *p = bytes;
    memcpy(p, &st->magic, sizeof(unsigned)); p += sizeof(unsigned);
    memcpy(p, &st->count, sizeof(size_t)); p += sizeof(size_t);
    memcpy(p, st->data, st->count * sizeof(double)); p += st->count * sizeof(double);
    memcpy(p, s->d->guid, strlen(s->d->guid));
    return fmi2OK;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte bytes[], size_t size, fmi2FMUstate *state) {
    CHECK_INSTANCE(c)
    size_t n = state_doubles(s->d);
    size_t need = sizeof(unsigned) + sizeof(size_t) + n * sizeof(double) + strlen(s->d->guid);
    unsigned magic;
    size_t count;
    if (!bytes || !state || size != need) return refuse(s, "fmi2DeSerializeFMUstate", "wrong size for this FMU");
    memcpy(&magic, bytes, sizeof(unsigned));
    memcpy(&count, bytes + sizeof(unsigned), sizeof(size_t));
    if (magic != STATE_MAGIC || count != n ||
        memcmp(bytes + need - strlen(s->d->guid), s->d->guid, strlen(s->d->guid)) != 0)
        return refuse(s, "fmi2DeSerializeFMUstate", "the bytes are not a serialized state of this FMU");
    Saved *st = (Saved *)*state;
    if (!st) st = (Saved *)malloc(sizeof(Saved) + n * sizeof(double));
    if (!st) return refuse(s, "fmi2DeSerializeFMUstate", "out of memory");
    st->magic = magic;
    st->count = n;
    memcpy(st->data, bytes + sizeof(unsigned) + sizeof(size_t), n * sizeof(double));
    *state = st;
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
