/* uiofmu: the affine observer kernel, the model code of every uiofmu observer FMU today.
 *
 * It plugs into the shared FMI 2.0 plumbing (fmi2_plumbing.c) through UIOFMU_KERNEL_AFFINE:
 * the plumbing owns the instance states, the value references, the logging and the FMU state
 * image; this file owns the observer's numbers. The design (matrices and schedule) comes from
 * design_data.c, generated from the design card. The step semantics are those of the
 * reference runtime (uiofmu/runtime/observer.py), bit for bit:
 *
 *   outputs at t_k:  xhat_k = Xz z_k + Xy y_k [+ Xu u_k]   (xhat_0 = the parameter xhat0; Xu when present)
 *                    r_k    = y_k - C xhat_k
 *                    dhat_k = Dy (y_k - pred)   (0 at k = 0)
 *   fmi2DoStep(t_k, h_k):
 *                    z_0    = xhat0 - Xy y_0 [- Xu u_0]    (first step only)
 *                    z_0    = Zx (xhat0 - Xy y_0)          (instead, where the design has Zx: nz < n)
 *
 * A functional observer (nf > 0, matrix Lf) starts at z_0 = Zx xhat0; below order n (nz != n) it outputs
 * zhat_k = Xz z_k + Xy y_k (zhat_0 = Lf xhat0) in the place of xhat, and has neither r nor dhat (both read xhat);
 * at order n it outputs xhat and r as above and zhat_k = Lf xhat_k.
 *                    pred   = Yx xhat_k + Yu u_k + Yc
 *                    z_k+1  = N z_k + L y_k + G u_k + c
 *
 * with the matrices the schedule picks for (k, h_k, h_{k-1}) (constant, interval or geometric;
 * uiofmu/runtime/schedules.py), or for a mode schedule (a switched plant) for the modes
 * (alpha_k, alpha_{k-1}): the Integer input `mode` is alpha_k, the mode of the step about to be
 * taken, and the instance keeps the mode of the step before (mode_prev; the Integer parameter
 * mode_prev0 before the first step), looked up exactly as the interval of the step before.
 * NaN or infinite inputs, and a mode outside 1..N, refuse the step with fmi2Error and a log
 * line; a step the design does not allow follows the design's step policy (fmi2Discard, or the
 * nearest interval noted once); either way nothing changes.
 *
 * Defensive throughout, so that no call sequence makes it read or write out of bounds:
 *   - check_design_data checks the design data (dims, schedule, every matrix's count, rows and
 *     cols against the dims and against the length of its array) before fmi2Instantiate makes
 *     an instance, and an inconsistent design is refused with a log line;
 *   - check_values checks every number of a state before fmi2SetFMUstate or
 *     fmi2DeSerializeFMUstate takes any of it (see "FMU state" below);
 *   - the matrix lookups (pick, prev_index) refuse an index out of range, and the FMI call
 *     then returns fmi2Error with a log line instead of reading it (the instance goes into the
 *     error state: its state does not fit its design).
 */
#include <limits.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2_plumbing.h"
#include "kernel_affine.h"
#include "kernel_util.h"

/* Bounds of what a design may ask for (far above what uiofmu designs: dims <= 1000); with them
   every index product (rows x cols, N x N blocks) stays well inside int and size_t. */
#define MAX_DIM 16384
#define MAX_INTERVALS 4096
#define MAX_BLOCKS 16777216
#define MAX_MODES 4096

/* The ports' names, causalities and types by id (kernel_affine_ports.h, generated). */
static const char *const PORT_NAME[UIOFMU_AFFINE_PORTS] = UIOFMU_AFFINE_PORT_NAMES;
static const int PORT_CAUSALITY[UIOFMU_AFFINE_PORTS] = UIOFMU_AFFINE_PORT_CAUSALITIES;
static const int PORT_TYPE[UIOFMU_AFFINE_PORTS] = UIOFMU_AFFINE_PORT_TYPES;

/* Where pick() finds a matrix's block for the step indices (i, j): base + i * si + j * sj doubles,
   for i and j in 0 .. range - 1 (worked out once, at fmi2Instantiate: pick() depends on (which, i, j)
   alone, the design being constant and the geometric work arrays staying where they are). base is
   NULL where pick() finds nothing. */
typedef struct {
    const double *base;
    size_t si, sj;
} Place;

typedef struct {
    FmuInstance *fmu; /* the plumbing's instance: log lines go through it */
    const UiofmuDesign *d;
    /* state (what fmi2GetFMUstate saves) */
    long k;
    double h_prev, h_prev0;
    int noticed;
    int j_prev; /* index of h_prev among the design intervals, -1 until looked up */
    int mode, mode_prev, mode_prev0; /* mode schedules: the input, the mode of the step before, the parameter */
    double *z, *pred, *xhat0, *y, *u;
    /* outputs and work space */
    int dirty;
    int xhat_current; /* xhat is xhat_k of the state and inputs: estimate computed it since they changed */
    Place place[M_COUNT];
    int range; /* N of an interval or mode schedule, else 1 (i = j = 0) */
    int sorted; /* the design intervals increase strictly: nearest() bisects them */
    int known[UIOFMU_SLOTS]; /* by uiofmu_slot(x) of each design interval x: its index (-1: none) */
    double *xhat, *r, *dhat, *zhat, *tmp;
    double *work[M_COUNT];
    long work_k;
    double *block; /* everything above, one allocation */
    size_t nblock;
} Instance;

static const char *const MATRIX_NAME[M_COUNT] = {"N", "L", "G", "c", "Xz", "Xy", "C", "Dy", "Yx", "Yu", "Yc",
                                                           "Xu", "Zx", "Lf"};

/* ---------------------------------------------------------------------------------------- */
/* The maths                                                                                  */

static size_t msize(const UiofmuMatrix *M) { return (size_t)M->rows * (size_t)M->cols; }

/* A functional observer below order n: its estimate is zhat, no xhat. */
static inline int zhat_only(const UiofmuDesign *d) { return d->nf > 0 && d->nz != d->n; }

/* The size of the estimate: nf (zhat, a functional observer below order n) or n (xhat). */
static inline int estimate_size(const UiofmuDesign *d) { return zhat_only(d) ? d->nf : d->n; }

/* The sum of a[j] x[j] over j < n, from 0.0 in the order of j (a row of a matrix times x; 0.0 for
   n = 0). Every product below is written with it, row by row, and the sums of a row added in the
   order of the formula: the same bits as the whole products added in turn. */
static inline double dot(const double *a, const double *x, int n) {
    double acc = 0.0;
    for (int j = 0; j < n; j++) acc += a[j] * x[j];
    return acc;
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

/* nearest_interval() for an instance: a step that is a design interval (the usual case) found in
   Instance.known, any other by bisection when the intervals increase strictly. Then the
   distance |h - x|, rounded, does not decrease away from h on either side, so the nearest is the
   last interval <= h or the one after it, and of equal distances nearest_interval() takes the
   first: the start of the run of equals that ends at the last interval <= h. */
static int nearest(const Instance *s, double h, int *best, int *exact) {
    const UiofmuDesign *d = s->d;
    if (!s->sorted) return nearest_interval(d, h, best, exact);
    const double *x = d->intervals;
    int i = s->known[uiofmu_slot(h)];
    if (i >= 0 && x[i] == h) { /* distinct intervals: the only one at distance 0 */
        *best = i;
        *exact = fabs(h - x[i]) <= d->step_rtol * x[i];
        return 1;
    }
    int lo = 0, hi = d->nintervals; /* lo becomes the number of intervals <= h (none for a NaN) */
    while (lo < hi) {
        int mid = lo + (hi - lo) / 2;
        if (x[mid] <= h) lo = mid + 1;
        else hi = mid;
    }
    int b = lo == 0 ? 0 : lo == d->nintervals || !(fabs(h - x[lo]) < fabs(h - x[lo - 1])) ? lo - 1 : lo;
    if (b < lo)
        while (b > 0 && fabs(h - x[b - 1]) == fabs(h - x[b])) b--;
    *best = b;
    *exact = fabs(h - x[b]) <= d->step_rtol * x[b];
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
    if (!nearest(s, h, &best, &exact)) {
        if (msg) snprintf(msg, len, "this design has no intervals");
        return -1;
    }
    if (exact) return best;
    if (d->policy == UIOFMU_POLICY_NEAREST) {
        if (!s->noticed) {
            s->noticed = 1;
            char b1[32];
            uiofmu_log(s->fmu, fmi2Warning, "step h = %s s is not a design interval; using the nearest, %g s, without a certificate "
                  "(step_policy = 'nearest'; noted once)", uiofmu_num(h, b1), d->intervals[best]);
        }
        return best;
    }
    if (msg) {
        char b1[32], listed[512];
        int off = 0;
        listed[0] = '\0';
        for (int i = 0; i < d->nintervals && off < (int)sizeof listed; i++)
            off += snprintf(listed + off, sizeof listed - off, i ? ", %g" : "%g", d->intervals[i]);
        snprintf(msg, len, UIOFMU_REFUSAL_NOT_A_DESIGN_INTERVAL, uiofmu_num(h, b1), listed, d->step_rtol);
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
    int N = d->kind == UIOFMU_MODE ? d->modes : d->nintervals;
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
UIOFMU_COLD static const double *need(Instance *s, const char *fn, int which, int i, int j) {
    const double *M = pick(s, which, i, j);
    if (!M) {
        char b1[32];
        uiofmu_log(s->fmu, fmi2Error, "%s: no matrix %s for the step indices (%d, %d) at step k = %ld (h_prev = %s s): "
              "the instance's state does not fit its design", fn, MATRIX_NAME[which], i, j, s->k, uiofmu_num(s->h_prev, b1));
    }
    return M;
}

/* s->place: pick()'s blocks as offsets (see Place). */
static void find_places(Instance *s) {
    const UiofmuDesign *d = s->d;
    int scheduled = d->kind == UIOFMU_INTERVAL || d->kind == UIOFMU_MODE;
    s->range = d->kind == UIOFMU_MODE ? d->modes : d->kind == UIOFMU_INTERVAL ? d->nintervals : 1;
    s->sorted = d->kind == UIOFMU_INTERVAL && d->nintervals >= 1;
    for (int i = 1; i < d->nintervals && s->sorted; i++) s->sorted = d->intervals[i - 1] < d->intervals[i];
    for (int k = 0; k < UIOFMU_SLOTS; k++) s->known[k] = -1;
    for (int i = 0; i < d->nintervals && s->sorted; i++) s->known[uiofmu_slot(d->intervals[i])] = i;
    for (int w = 0; w < M_COUNT; w++) {
        size_t sz = msize(&d->mat[w]), N = (size_t)s->range;
        Place *p = &s->place[w];
        p->base = pick(s, w, 0, 0);
        p->si = p->sj = 0;
        if (!scheduled || w == M_C) continue;
        if (w == M_N || w == M_L) {
            p->si = N * sz;
            p->sj = sz;
        } else if (w == M_Xz || w == M_Xy || w == M_Dy) {
            p->sj = sz;
        } else {
            p->si = sz;
        }
    }
}

/* pick() (and need()'s line where it finds nothing) for the step indices (i, j), by its offsets. */
static const double *matrix(Instance *s, const char *fn, int which, int i, int j) {
    const Place *p = &s->place[which];
    if (p->base && (unsigned)i < (unsigned)s->range && (unsigned)j < (unsigned)s->range)
        return p->base + (size_t)i * p->si + (size_t)j * p->sj;
    return need(s, fn, which, i, j);
}

/* Every change of the state, an input or a parameter: the outputs, xhat among them, are out of date. */
static void touched(Instance *s) {
    s->dirty = 1;
    s->xhat_current = 0;
}

/* Index of h_prev among the design intervals (mode schedules: of mode_prev among the modes; 0 for
   the other schedules); -1 when it is none. */
static inline int prev_index(Instance *s) {
    if (s->d->kind == UIOFMU_MODE) return s->mode_prev >= 1 && s->mode_prev <= s->d->modes ? s->mode_prev - 1 : -1;
    if (s->d->kind != UIOFMU_INTERVAL) return 0;
    if (s->j_prev < 0 || s->j_prev >= s->d->nintervals) s->j_prev = interval_index(s, s->h_prev, NULL, 0);
    return s->j_prev;
}

UIOFMU_COLD static void bad_prev(Instance *s, const char *fn) {
    char b1[32];
    if (s->d->kind == UIOFMU_MODE) {
        uiofmu_log(s->fmu, fmi2Error, "%s: mode_prev = %d at step k = %ld is not a mode (1 to %d): the instance's state "
                   "does not fit its design", fn, s->mode_prev, s->k, s->d->modes);
        return;
    }
    uiofmu_log(s->fmu, fmi2Error, "%s: h_prev = %s s at step k = %ld is not a design interval: the instance's state does not fit its design",
          fn, uiofmu_num(s->h_prev, b1), s->k);
}

/* xhat_k alone (what a step needs), computed once until the state or an input changes (j is
   prev_index(), a function of the state); 0 (with a log line) when a matrix is missing. */
static int estimate(Instance *s, const char *fn, int j) {
    const UiofmuDesign *d = s->d;
    if (d->kind == UIOFMU_GEOMETRIC) evaluate(s, s->k);
    if (s->xhat_current) return 1;
    if (s->k == 0 && zhat_only(d)) { /* zhat_0 = Lf xhat0 */
        const double *Lf = s->place[M_Lf].base;
        if (!Lf) return 0;
        for (int i = 0; i < d->nf; i++) s->xhat[i] = dot(Lf + (size_t)i * d->n, s->xhat0, d->n);
        s->xhat_current = 1;
        return 1;
    }
    if (s->k == 0) {
        memcpy(s->xhat, s->xhat0, d->n * sizeof(double));
        s->xhat_current = 1;
        return 1;
    }
    if (j < 0) {
        bad_prev(s, fn);
        return 0;
    }
    const double *Xz = matrix(s, fn, M_Xz, 0, j), *Xy = Xz ? matrix(s, fn, M_Xy, 0, j) : NULL;
    if (!Xz || !Xy) return 0;
    int ne = estimate_size(d);
    for (int i = 0; i < ne; i++)
        s->xhat[i] = dot(Xz + (size_t)i * d->nz, s->z, d->nz) + dot(Xy + (size_t)i * d->p, s->y, d->p);
    /* absent: no direct term of u; only a constant schedule has one, pick()'s for every (i, j) */
    const double *Xu = s->place[M_Xu].base;
    if (Xu)
        for (int i = 0; i < ne; i++) s->xhat[i] += dot(Xu + (size_t)i * d->m, s->u, d->m);
    s->xhat_current = 1;
    return 1;
}

static int refresh(Instance *s, const char *fn) {
    const UiofmuDesign *d = s->d;
    if (!s->dirty) return 1;
    int j = prev_index(s);
    const double *C = matrix(s, fn, M_C, 0, 0);
    if (!C || !estimate(s, fn, j)) return 0;
    if (!zhat_only(d)) /* a functional observer below order n has no residual */
        for (int i = 0; i < d->p; i++) s->r[i] = s->y[i] - dot(C + (size_t)i * d->n, s->xhat, d->n);
    if (d->nf > 0 && !zhat_only(d)) { /* order n: zhat = Lf xhat */
        const double *Lf = s->place[M_Lf].base;
        if (!Lf) return 0;
        for (int i = 0; i < d->nf; i++) s->zhat[i] = dot(Lf + (size_t)i * d->n, s->xhat, d->n);
    }
    if (d->has_dhat) {
        if (s->k > 0) {
            const double *Dy = matrix(s, fn, M_Dy, 0, j);
            if (!Dy) return 0;
            for (int i = 0; i < d->p; i++) s->tmp[i] = s->y[i] - s->pred[i];
            for (int i = 0; i < d->q; i++) s->dhat[i] = dot(Dy + (size_t)i * d->p, s->tmp, d->p);
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
    s->mode_prev = s->mode_prev0;
    s->j_prev = -1;
    s->noticed = 0;
    memset(s->z, 0, s->d->nz * sizeof(double));
    memset(s->pred, 0, s->d->p * sizeof(double));
    s->work_k = -1;
    touched(s);
}

/* ---------------------------------------------------------------------------------------- */
/* The design, checked once at fmi2Instantiate: everything the runtime later indexes with.   */

/* a * b in *out, 0 when it exceeds the doubles an allocation can hold. */
static int mul_size(size_t a, size_t b, size_t *out) { return uiofmu_mul(a, b, SIZE_MAX / sizeof(double), out); }

static void expected_shape(const UiofmuDesign *d, int w, int *rows, int *cols, const char **text) {
    static const char *const TEXT[M_COUNT] = {"nz x nz", "nz x p", "nz x m", "nz x 1", "n x nz", "n x p",
                                              "p x n", "q x p", "p x n", "p x m", "p x 1", "n x m", "nz x n",
                                              "nf x n"};
    const int ne = estimate_size(d); /* n, or nf for a functional observer */
    const int R[M_COUNT] = {d->nz, d->nz, d->nz, d->nz, ne, ne, d->p, d->q, d->p, d->p, d->p, ne, d->nz, d->nf};
    const int C[M_COUNT] = {d->nz, d->p, d->m, 1, d->nz, d->p, d->n, d->p, d->n, d->m, 1, d->m, d->n, d->n};
    *rows = R[w];
    *cols = C[w];
    *text = TEXT[w];
    if (zhat_only(d) && (w == M_Xz || w == M_Xy || w == M_Xu)) /* zhat's rows */
        *text = w == M_Xz ? "nf x nz" : w == M_Xy ? "nf x p" : "nf x m";
}

static int check_design_data(const UiofmuDesign *d, char *msg, size_t len) {
    static const char *const KIND[] = {"constant", "interval", "geometric", "mode"};
    const int dims[5] = {d->n, d->m, d->p, d->q, d->nz}, low[5] = {1, 0, 1, 0, 0};
    const char *const dim_name[5] = {"n", "m", "p", "q", "nz"};
    if (!uiofmu_check_dims(msg, len, "dims.", 5, dims, dim_name, low, MAX_DIM)) return 0;
    if (d->nz != d->n && d->mat[M_Zx].count == 0) /* z_0 = xhat0 - Xy y_0 is an n-vector; Zx maps it to nz */
        return uiofmu_design_error(msg, len, "dims.nz = %d differs from dims.n = %d and the design has no matrix Zx "
                                   "(the first step sets z from xhat0)", d->nz, d->n);
    if (d->has_dhat != 0 && d->has_dhat != 1)
        return uiofmu_design_error(msg, len, "has_dhat = %d is neither 0 nor 1", d->has_dhat);
    if (d->nf < 0 || d->nf > MAX_DIM)
        return uiofmu_design_error(msg, len, "dims.nf = %d is out of range [0, %d]", d->nf, MAX_DIM);
    if ((d->nf > 0) != (d->mat[M_Lf].count > 0))
        return uiofmu_design_error(msg, len, "dims.nf = %d and matrix Lf (%d blocks): a functional observer has "
                                   "both, a state observer neither", d->nf, d->mat[M_Lf].count);
    if (d->nf > 0 && (d->mat[M_Zx].count == 0 || d->kind != UIOFMU_CONSTANT || d->has_dhat ||
                      d->mat[M_Xu].count != 0))
        return uiofmu_design_error(msg, len, "a functional observer (dims.nf = %d) needs the matrix Zx and a constant "
                                   "schedule, and has no dhat and no Xu", d->nf);
    if (d->kind < UIOFMU_CONSTANT || d->kind > UIOFMU_MODE)
        return uiofmu_design_error(msg, len, "schedule kind %d is unknown", d->kind);
    if (d->policy < UIOFMU_POLICY_ERROR || d->policy > UIOFMU_POLICY_COUNT ||
        ((d->kind == UIOFMU_CONSTANT || d->kind == UIOFMU_MODE) && d->policy != UIOFMU_POLICY_ERROR) ||
        (d->kind == UIOFMU_GEOMETRIC && d->policy == UIOFMU_POLICY_NEAREST))
        return uiofmu_design_error(msg, len, "step policy %d does not go with a %s schedule", d->policy, KIND[d->kind]);
    if (!isfinite(d->dt) || !isfinite(d->alpha) || !isfinite(d->h_prev0) || !isfinite(d->step_rtol) ||
        d->step_rtol < 0 || !(d->h_prev0 > 0))
        return uiofmu_design_error(msg, len, "dt = %g, alpha = %g, h_prev0 = %g, step_rtol = %g: expected finite "
                                   "numbers, h_prev0 > 0 and step_rtol >= 0", d->dt, d->alpha, d->h_prev0, d->step_rtol);
    if (d->kind != UIOFMU_INTERVAL && !(d->dt > 0))
        return uiofmu_design_error(msg, len, "dt = %g: a %s schedule needs a period > 0", d->dt, KIND[d->kind]);
    if (!d->xhat0 || d->xhat0_length != (size_t)d->n)
        return uiofmu_design_error(msg, len, "xhat0 holds %zu numbers, expected n = %d",
                                   d->xhat0 ? d->xhat0_length : 0, d->n);
    for (int i = 0; i < d->n; i++)
        if (!isfinite(d->xhat0[i]))
            return uiofmu_design_error(msg, len, "xhat0[%d] = %g is not finite", i + 1, d->xhat0[i]);
    if (d->nintervals < 0 || d->nintervals > MAX_INTERVALS || (d->kind == UIOFMU_INTERVAL && d->nintervals < 1) ||
        !d->intervals ||
        d->intervals_length != (size_t)(d->nintervals ? d->nintervals : 1))
        return uiofmu_design_error(msg, len, "%d intervals in an array of %zu for a %s schedule", d->nintervals,
                                   d->intervals ? d->intervals_length : 0, KIND[d->kind]);
    for (int i = 0; i < d->nintervals; i++) /* read by interval schedules only */
        if (!(isfinite(d->intervals[i]) && (d->intervals[i] > 0 || d->kind != UIOFMU_INTERVAL)))
            return uiofmu_design_error(msg, len, "interval %d = %g is not a positive finite step", i + 1,
                                       d->intervals[i]);
    if (d->kind == UIOFMU_INTERVAL && !resolves(d, d->h_prev0))
        return uiofmu_design_error(msg, len, "h_prev0 = %g is not one of the design intervals", d->h_prev0);
    if (d->kind == UIOFMU_MODE && !(d->modes >= 1 && d->modes <= MAX_MODES))
        return uiofmu_design_error(msg, len, "modes = %d is out of range [1, %d] for a mode schedule", d->modes,
                                   MAX_MODES);
    if (d->kind == UIOFMU_MODE && !(d->mode_prev0 >= 1 && d->mode_prev0 <= d->modes))
        return uiofmu_design_error(msg, len, "mode_prev0 = %d is not a mode (1 to %d)", d->mode_prev0, d->modes);
    for (int w = 0; w < M_COUNT; w++) {
        const UiofmuMatrix *M = &d->mat[w];
        int rows, cols, required = w <= M_C || (d->has_dhat && w <= M_Yc);
        const char *shape;
        size_t want, total = 0;
        expected_shape(d, w, &rows, &cols, &shape);
        if (M->count == 0 && !required) continue;
        if (w == M_Xu && d->kind != UIOFMU_CONSTANT)
            return uiofmu_design_error(msg, len, "matrix Xu (the direct term of u in xhat) needs a constant schedule, "
                                       "found a %s one", KIND[d->kind]);
        if ((w == M_Zx || w == M_Lf) && d->kind != UIOFMU_CONSTANT)
            return uiofmu_design_error(msg, len, "matrix %s (%s) needs a constant schedule, found a %s one",
                                       MATRIX_NAME[w], w == M_Zx ? "the first step's z_0 = Zx (xhat0 - Xy y_0)"
                                                                 : "the functionals zhat estimates", KIND[d->kind]);
        if (w == M_C || d->kind == UIOFMU_CONSTANT) want = 1;
        else if (d->kind == UIOFMU_INTERVAL) want = (size_t)d->nintervals * (w == M_N || w == M_L ? (size_t)d->nintervals : 1);
        else if (d->kind == UIOFMU_MODE) want = (size_t)d->modes * (w == M_N || w == M_L ? (size_t)d->modes : 1);
        else want = 0; /* geometric: any number of coefficients */
        if (M->count < 1 || (want && (size_t)M->count != want) || M->count > MAX_BLOCKS)
            return uiofmu_design_error(msg, len, "matrix %s has %d blocks, expected %s%zu", MATRIX_NAME[w], M->count,
                                       want ? "" : "at least ", want ? want : (size_t)1);
        if (M->rows != rows || M->cols != cols)
            return uiofmu_design_error(msg, len, "matrix %s is %d x %d, expected %s = %d x %d", MATRIX_NAME[w], M->rows,
                                       M->cols, shape, rows, cols);
        if (!M->data || !mul_size((size_t)M->count, msize(M), &total) || M->length != (total ? total : 1))
            return uiofmu_design_error(msg, len, "matrix %s: %d blocks of %d x %d need %zu numbers, its array holds "
                                       "%zu", MATRIX_NAME[w], M->count, rows, cols, total, M->data ? M->length : 0);
    }
    return 1;
}

/* ---------------------------------------------------------------------------------------- */
/* The kernel's operations (UiofmuKernel)                                                    */

static int affine_check_design(char *msg, size_t len) { return check_design_data(&UIOFMU_DESIGN, msg, len); }

static int affine_port(int id, UiofmuPort *out) {
    const UiofmuDesign *d = &UIOFMU_DESIGN;
    int size;
    switch (id) {
    case UIOFMU_AFFINE_XHAT0: size = d->n; break;
    case UIOFMU_AFFINE_H_PREV0: size = d->kind == UIOFMU_INTERVAL ? 1 : 0; break;
    case UIOFMU_AFFINE_Y: size = d->p; break;
    case UIOFMU_AFFINE_R: size = zhat_only(d) ? 0 : d->p; break;
    case UIOFMU_AFFINE_U: size = d->m; break;
    case UIOFMU_AFFINE_XHAT: size = zhat_only(d) ? 0 : d->n; break;
    case UIOFMU_AFFINE_ZHAT: size = d->nf; break;
    case UIOFMU_AFFINE_DHAT: size = d->has_dhat ? d->q : 0; break;
    case UIOFMU_AFFINE_MODE_PREV0: case UIOFMU_AFFINE_MODE: size = d->kind == UIOFMU_MODE ? 1 : 0; break;
    default: return 0;
    }
    out->name = PORT_NAME[id];
    out->size = size;
    out->causality = PORT_CAUSALITY[id];
    out->type = PORT_TYPE[id];
    return 1;
}

static void *affine_instantiate(FmuInstance *fmu) {
    const UiofmuDesign *d = &UIOFMU_DESIGN;
    Instance *s = (Instance *)uiofmu_alloc(fmu, 1, sizeof(Instance));
    if (!s) return NULL;
    s->fmu = fmu;
    s->d = d;
    size_t nwork = 0, sz;
    for (int w = 0; w < M_COUNT; w++)
        if (d->kind == UIOFMU_GEOMETRIC && w != M_C && d->mat[w].count) {
            if (!mul_size((size_t)d->mat[w].rows, (size_t)d->mat[w].cols, &sz) || nwork > SIZE_MAX / 2 - sz) {
                free(s);
                uiofmu_log(fmu, fmi2Error, "fmi2Instantiate: the design's matrices are too large");
                return NULL;
            }
            nwork += sz;
        }
    size_t mx = (size_t)(d->nz > d->n ? d->nz : d->n);
    if ((size_t)d->p > mx) mx = (size_t)d->p;
    size_t ne = (size_t)estimate_size(d), nzhat = zhat_only(d) ? 0 : (size_t)d->nf; /* order n: zhat of its own */
    s->nblock = (size_t)d->nz + d->p + d->n + d->p + d->m + ne + d->p + d->q + nzhat + mx + nwork;
    s->block = (double *)uiofmu_alloc(fmu, s->nblock, sizeof(double));
    if (!s->block) {
        free(s);
        return NULL;
    }
    double *b = s->block;
    s->z = b; b += d->nz;
    s->pred = b; b += d->p;
    s->xhat0 = b; b += d->n;
    s->y = b; b += d->p;
    s->u = b; b += d->m;
    s->xhat = b; b += ne; /* xhat[n], or zhat[nf] */
    s->r = b; b += d->p;
    s->dhat = b; b += d->q;
    s->zhat = zhat_only(d) ? s->xhat : b; /* below order n zhat is the estimate itself */
    b += nzhat;
    s->tmp = b; b += mx;
    for (int w = 0; w < M_COUNT; w++)
        if (d->kind == UIOFMU_GEOMETRIC && w != M_C && d->mat[w].count) { s->work[w] = b; b += msize(&d->mat[w]); }
    memcpy(s->xhat0, d->xhat0, d->n * sizeof(double));
    s->h_prev0 = d->h_prev0;
    s->mode_prev0 = s->mode = d->mode_prev0;
    find_places(s);
    reset_state(s);
    return s;
}

static void affine_free(void *self) {
    Instance *s = (Instance *)self;
    if (!s) return;
    free(s->block);
    free(s);
}

static void affine_reset(void *self) {
    Instance *s = (Instance *)self;
    memcpy(s->xhat0, s->d->xhat0, s->d->n * sizeof(double));
    s->h_prev0 = s->d->h_prev0;
    s->mode_prev0 = s->mode = s->d->mode_prev0;
    memset(s->y, 0, s->d->p * sizeof(double));
    memset(s->u, 0, s->d->m * sizeof(double));
    reset_state(s);
}

static UiofmuResult affine_exit_initialization(void *self) {
    Instance *s = (Instance *)self;
    char msg[512], b1[32];
    if (!uiofmu_parameter_finite(s->fmu, PORT_NAME[UIOFMU_AFFINE_XHAT0], s->xhat0, s->d->n)) return UIOFMU_REFUSED;
    if (s->d->kind == UIOFMU_INTERVAL) {
        /* step_policy 'nearest' maps any number to an interval; a step must still be one */
        if (s->d->policy == UIOFMU_POLICY_NEAREST && !(isfinite(s->h_prev0) && s->h_prev0 > 0)) {
            uiofmu_log(s->fmu, fmi2Error, "parameter %s = %s s: expected a step > 0", PORT_NAME[UIOFMU_AFFINE_H_PREV0],
                       uiofmu_num(s->h_prev0, b1));
            return UIOFMU_REFUSED;
        }
        if (interval_index(s, s->h_prev0, msg, sizeof msg) < 0) {
            uiofmu_log(s->fmu, fmi2Error, "parameter %s: %s", PORT_NAME[UIOFMU_AFFINE_H_PREV0], msg);
            return UIOFMU_REFUSED;
        }
    }
    if (s->d->kind == UIOFMU_MODE && !(s->mode_prev0 >= 1 && s->mode_prev0 <= s->d->modes)) {
        uiofmu_log(s->fmu, fmi2Error, "parameter %s = %d is not a mode of this observer's plant (expected an integer "
                   "from 1 to %d)", PORT_NAME[UIOFMU_AFFINE_MODE_PREV0], s->mode_prev0, s->d->modes);
        return UIOFMU_REFUSED;
    }
    reset_state(s);
    return UIOFMU_DONE;
}

static UiofmuResult affine_calculate(void *self, const char *fn) {
    return refresh((Instance *)self, fn) ? UIOFMU_DONE : UIOFMU_BROKEN;
}

/* The storage of element `index` of port `port` (the plumbing checked both against the table). */
static double *affine_real_storage(void *self, int port, int index) {
    Instance *s = (Instance *)self;
    double *const first[UIOFMU_AFFINE_PORTS] = {[UIOFMU_AFFINE_XHAT0] = s->xhat0, [UIOFMU_AFFINE_H_PREV0] = &s->h_prev0,
                                                [UIOFMU_AFFINE_Y] = s->y, [UIOFMU_AFFINE_U] = s->u,
                                                [UIOFMU_AFFINE_XHAT] = s->xhat, [UIOFMU_AFFINE_R] = s->r,
                                                [UIOFMU_AFFINE_DHAT] = s->dhat, [UIOFMU_AFFINE_ZHAT] = s->zhat};
    return uiofmu_element(first, port, index);
}

/* The plumbing stored new values: the outputs are computed again before they are read. */
static void affine_changed(void *self) { touched((Instance *)self); }

/* The Integer ports (mode schedules): mode_prev0 (parameter) and mode (input). */
static int affine_get_integer(void *self, int port, int index) {
    const Instance *s = (const Instance *)self;
    (void)index;
    return port == UIOFMU_AFFINE_MODE_PREV0 ? s->mode_prev0 : port == UIOFMU_AFFINE_MODE ? s->mode : 0;
}

static void affine_set_integer(void *self, int port, int index, int value) {
    Instance *s = (Instance *)self;
    (void)index;
    if (port == UIOFMU_AFFINE_MODE_PREV0) s->mode_prev0 = value;
    else if (port == UIOFMU_AFFINE_MODE) s->mode = value;
    else return;
    touched(s);
}

static UiofmuResult affine_step(void *self, double t, double h) {
    static const char fn[] = "fmi2DoStep";
    Instance *s = (Instance *)self;
    const UiofmuDesign *d = s->d;
    char msg[512], bt[32];
    if (!uiofmu_inputs_finite(s->fmu, t, s->k, s->y, d->p, PORT_NAME[UIOFMU_AFFINE_Y]) ||
        !uiofmu_inputs_finite(s->fmu, t, s->k, s->u, d->m, PORT_NAME[UIOFMU_AFFINE_U]))
        return UIOFMU_REFUSED;
    int i = 0, j = 0;
    if (d->kind == UIOFMU_MODE) {
        /* the mode first, as the reference runtime: a bad one is an input error, not a step rejected */
        if (!(s->mode >= 1 && s->mode <= d->modes)) {
            uiofmu_log(s->fmu, fmi2Error, "t = %s: input %s = %d is not a mode of this observer's plant (expected an "
                       "integer from 1 to %d) at step k = %ld", uiofmu_num(t, bt), PORT_NAME[UIOFMU_AFFINE_MODE], s->mode,
                       d->modes, s->k);
            return UIOFMU_REFUSED;
        }
        i = s->mode - 1;
        j = prev_index(s);
        if (j < 0) {
            bad_prev(s, fn);
            return UIOFMU_BROKEN;
        }
    }
    if (d->kind == UIOFMU_INTERVAL) {
        i = interval_index(s, h, msg, sizeof msg);
        if (i < 0) {
            uiofmu_log(s->fmu, fmi2Discard, "t = %s: %s", uiofmu_num(t, bt), msg);
            return UIOFMU_DISCARDED;
        }
        j = prev_index(s);
        if (j < 0) {
            bad_prev(s, fn);
            return UIOFMU_BROKEN;
        }
    } else if (d->policy == UIOFMU_POLICY_ERROR && uiofmu_off_period(s->fmu, t, h, d->dt, d->step_rtol, 1)) {
        return UIOFMU_DISCARDED;
    }
    /* every matrix of the step before anything changes: a missing one refuses the step whole */
    const double *Xy = matrix(s, fn, M_Xy, i, j), *N = matrix(s, fn, M_N, i, j), *L = matrix(s, fn, M_L, i, j),
                 *G = matrix(s, fn, M_G, i, j), *cc = matrix(s, fn, M_c, i, j);
    const double *Yx = NULL, *Yu = NULL, *Yc = NULL;
    if (!Xy || !N || !L || !G || !cc) return UIOFMU_BROKEN;
    if (d->has_dhat) {
        Yx = matrix(s, fn, M_Yx, i, j);
        Yu = matrix(s, fn, M_Yu, i, j);
        Yc = matrix(s, fn, M_Yc, i, j);
        if (!Yx || !Yu || !Yc) return UIOFMU_BROKEN;
    }
    if (!estimate(s, fn, j)) return UIOFMU_BROKEN; /* xhat_k (and the geometric matrices of step k) */
    if (s->k == 0 && d->nf > 0) { /* z_0 = Zx xhat0 (check_design_data: a functional observer has Zx) */
        const double *Zx = s->place[M_Zx].base;
        for (int e = 0; e < d->nz; e++) s->z[e] = dot(Zx + (size_t)e * d->n, s->xhat0, d->n);
    } else if (s->k == 0) {
        const double *Zx = s->place[M_Zx].base;
        double *v = Zx ? s->tmp : s->z; /* with Zx (nz < n), xhat0 - Xy y_0 goes through tmp (n doubles) */
        for (int e = 0; e < d->n; e++) v[e] = s->xhat0[e] - dot(Xy + (size_t)e * d->p, s->y, d->p);
        const double *Xu = s->place[M_Xu].base; /* as in estimate() */
        if (Xu)
            for (int e = 0; e < d->n; e++) v[e] -= dot(Xu + (size_t)e * d->m, s->u, d->m);
        if (Zx)
            for (int e = 0; e < d->nz; e++) s->z[e] = dot(Zx + (size_t)e * d->n, v, d->n);
    }
    if (d->has_dhat) {
        for (int e = 0; e < d->p; e++)
            s->pred[e] = dot(Yx + (size_t)e * d->n, s->xhat, d->n) + dot(Yu + (size_t)e * d->m, s->u, d->m) + Yc[e];
    }
    for (int e = 0; e < d->nz; e++)
        s->tmp[e] = dot(N + (size_t)e * d->nz, s->z, d->nz) + dot(L + (size_t)e * d->p, s->y, d->p) +
                    dot(G + (size_t)e * d->m, s->u, d->m) + cc[e];
    for (int e = 0; e < d->nz; e++) s->z[e] = s->tmp[e];
    s->h_prev = h;
    s->j_prev = i;
    if (d->kind == UIOFMU_MODE) s->mode_prev = s->mode;
    s->k += 1;
    touched(s);
    return UIOFMU_DONE;
}

/* ---------------------------------------------------------------------------------------- */
/* FMU state: the kernel's doubles
 *
 * The plumbing writes the image's header (magic, layout, size, GUID, the shape words n, m, p,
 * nz and the count D of doubles; fmi2_plumbing.c) and checks it; then come D = 5 + nz + p + n +
 * p + m doubles, written and read with memcpy (no alignment assumed), in the platform's byte
 * order:
 *
 *   k, h_prev, h_prev0, noticed, phase, z[nz], pred[p], xhat0[n], y[p], u[m]
 *
 * and for a mode schedule three more (D = 8 + nz + p + n + p + m), integers held exactly:
 *
 *   mode, mode_prev, mode_prev0
 *
 * fmi2SetFMUstate and fmi2DeSerializeFMUstate refuse a state (fmi2Error and a log line with
 * the numbers) unless every value is one this FMU can be in (check_values), all checked
 * before any of it is used:
 *   k        an integer 0 <= k < 2^53 (and within long); 0 before initialisation ends
 *   phase    0 instantiated, 1 initialisation mode, 2 initialised, 3 terminated (the
 *            plumbing's instance state; a step discarded is saved as 2, since the refused step
 *            changed nothing)
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
 *   mode     an integer in the range of fmi2Integer (an input: fmi2DoStep refuses one outside 1..N)
 *   mode_prev a mode, 1..N (every step and output indexes the matrices with it), equal to
 *            mode_prev0 at k = 0 in phase 2 and 3
 *   mode_prev0 a mode in phase 2 and 3 (fmi2ExitInitializationMode checked it); in phase 0 and
 *            1 any fmi2Integer, a parameter value not yet taken
 */

#define MAX_SAFE_INTEGER 9007199254740992.0 /* 2^53 */

enum { SV_K, SV_H_PREV, SV_H_PREV0, SV_NOTICED, SV_PHASE, SV_SCALARS };

typedef unsigned char Byte;

enum { SV_MODE, SV_MODE_PREV, SV_MODE_PREV0, SV_MODES }; /* after u[m], mode schedules only */

/* Index of the first mode double (mode schedules). */
static size_t mode_at(const UiofmuDesign *d) {
    return SV_SCALARS + (size_t)d->nz + (size_t)d->p + (size_t)d->n + (size_t)d->p + (size_t)d->m;
}

static size_t affine_state_count(void) {
    const UiofmuDesign *d = &UIOFMU_DESIGN;
    return mode_at(d) + (d->kind == UIOFMU_MODE ? SV_MODES : 0);
}

static void affine_state_shape(uint32_t shape[UIOFMU_SHAPE], const char *names[UIOFMU_SHAPE]) {
    const UiofmuDesign *d = &UIOFMU_DESIGN;
    static const char *const NAMES[UIOFMU_SHAPE] = {"n", "m", "p", "nz"};
    const int dims[UIOFMU_SHAPE] = {d->n, d->m, d->p, d->nz};
    uiofmu_shape(shape, names, dims, NAMES);
}

static void affine_save_state(void *self, int phase, Byte *o) {
    Instance *s = (Instance *)self;
    const UiofmuDesign *d = s->d;
    double scalars[SV_SCALARS] = {(double)s->k, s->h_prev, s->h_prev0, (double)s->noticed, (double)phase};
    o = uiofmu_put(o, scalars, SV_SCALARS);
    o = uiofmu_put(o, s->z, (size_t)d->nz);
    o = uiofmu_put(o, s->pred, (size_t)d->p);
    o = uiofmu_put(o, s->xhat0, (size_t)d->n);
    o = uiofmu_put(o, s->y, (size_t)d->p);
    o = uiofmu_put(o, s->u, (size_t)d->m);
    if (d->kind == UIOFMU_MODE) {
        double modes[SV_MODES] = {(double)s->mode, (double)s->mode_prev, (double)s->mode_prev0};
        uiofmu_put(o, modes, SV_MODES);
    }
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
    FmuInstance *fmu = s->fmu;
    char b1[32], b2[32], note[160];
    double k = uiofmu_getd(v, SV_K), hp = uiofmu_getd(v, SV_H_PREV), hp0 = uiofmu_getd(v, SV_H_PREV0),
           noticed = uiofmu_getd(v, SV_NOTICED), phase = uiofmu_getd(v, SV_PHASE);
    int interval = d->kind == UIOFMU_INTERVAL;
    if (!(isfinite(k) && k >= 0 && k == floor(k) && k < MAX_SAFE_INTEGER && k <= (double)LONG_MAX))
        return uiofmu_state_refused(fmu, ctx, "k = %s is not a step count (an integer, 0 <= k < 2^53)",
                                    uiofmu_num(k, b1));
    if (!uiofmu_phase_ok(fmu, ctx, phase)) return 0;
    int running = phase >= UIOFMU_PHASE_RUNNING;
    if (!(noticed == 0 || noticed == 1))
        return uiofmu_state_refused(fmu, ctx, "noticed = %s is neither 0 nor 1", uiofmu_num(noticed, b1));
    if (noticed == 1 && !(interval && d->policy == UIOFMU_POLICY_NEAREST))
        return uiofmu_state_refused(fmu, ctx, "noticed = 1, but only an interval schedule with step_policy 'nearest' "
                                    "notes a step");
    if (!running && k != 0)
        return uiofmu_state_refused(fmu, ctx, "k = %s in phase %d, before initialisation ended: expected 0",
                                    uiofmu_num(k, b1), (int)phase);
    if (!(isfinite(hp0) && hp0 > 0))
        return uiofmu_state_refused(fmu, ctx, "h_prev0 = %s is not a step (finite, > 0)", uiofmu_num(hp0, b1));
    if (!interval && hp0 != d->h_prev0)
        return uiofmu_state_refused(fmu, ctx, "h_prev0 = %s differs from this design's %s (not a variable of this FMU)",
                                    uiofmu_num(hp0, b1), uiofmu_num(d->h_prev0, b2));
    if (interval && running && !resolves(d, hp0))
        return uiofmu_state_refused(fmu, ctx, "h_prev0 = %s s is not a design interval (%s), but initialisation ended",
                                    uiofmu_num(hp0, b1), interval_note(d, hp0, note, sizeof note));
    if (!(isfinite(hp) && hp > 0))
        return uiofmu_state_refused(fmu, ctx, "h_prev = %s is not a step (finite, > 0)", uiofmu_num(hp, b1));
    if (interval && !resolves(d, hp))
        return uiofmu_state_refused(fmu, ctx, "h_prev = %s s is not a design interval (%s)", uiofmu_num(hp, b1),
                                    interval_note(d, hp, note, sizeof note));
    if (k == 0 && (running || !interval) && hp != hp0)
        return uiofmu_state_refused(fmu, ctx, "h_prev = %s s at k = 0 differs from h_prev0 = %s s", uiofmu_num(hp, b1),
                                    uiofmu_num(hp0, b2));
    if (!interval && d->policy == UIOFMU_POLICY_ERROR && k > 0 && fabs(hp - d->dt) > d->step_rtol * d->dt)
        return uiofmu_state_refused(fmu, ctx, "h_prev = %s s is not the design step dt = %s s (step_policy 'error')",
                                    uiofmu_num(hp, b1), uiofmu_num(d->dt, b2));
    const int length[3] = {d->nz, d->p, d->n};
    size_t at = SV_SCALARS;
    for (int w = 0; w < 3; w++) {
        for (int i = 0; i < length[w]; i++) {
            double x = uiofmu_getd(v, at + (size_t)i);
            if (!isfinite(x))
                return uiofmu_state_refused(fmu, ctx, "%s[%d] = %s is not finite", VECTOR[w], i + 1, uiofmu_num(x, b1));
            if (w < 2 && k == 0 && x != 0)
                return uiofmu_state_refused(fmu, ctx, "%s[%d] = %s at k = 0: expected 0 (the first step sets it)",
                                            VECTOR[w], i + 1, uiofmu_num(x, b1));
        }
        at += (size_t)length[w];
    }
    /* y[p], u[m]: taken as they are (see above) */
    if (d->kind == UIOFMU_MODE) {
        size_t m0 = mode_at(d);
        double mode = uiofmu_getd(v, m0 + SV_MODE), mp = uiofmu_getd(v, m0 + SV_MODE_PREV),
               mp0 = uiofmu_getd(v, m0 + SV_MODE_PREV0);
        if (!(mode == floor(mode) && mode >= INT_MIN && mode <= INT_MAX))
            return uiofmu_state_refused(fmu, ctx, "mode = %s is not an fmi2Integer", uiofmu_num(mode, b1));
        if (!(mp == floor(mp) && mp >= 1 && mp <= d->modes))
            return uiofmu_state_refused(fmu, ctx, "mode_prev = %s is not a mode (an integer from 1 to %d)",
                                        uiofmu_num(mp, b1), d->modes);
        if (!(mp0 == floor(mp0) && mp0 >= INT_MIN && mp0 <= INT_MAX))
            return uiofmu_state_refused(fmu, ctx, "mode_prev0 = %s is not an fmi2Integer", uiofmu_num(mp0, b1));
        if (running && !(mp0 >= 1 && mp0 <= d->modes))
            return uiofmu_state_refused(fmu, ctx, "mode_prev0 = %s is not a mode (an integer from 1 to %d), but "
                                        "initialisation ended", uiofmu_num(mp0, b1), d->modes);
        if (running && k == 0 && mp != mp0)
            return uiofmu_state_refused(fmu, ctx, "mode_prev = %s at k = 0 differs from mode_prev0 = %s",
                                        uiofmu_num(mp, b1), uiofmu_num(mp0, b2));
    }
    return 1;
}

static void apply_state(Instance *s, const Byte *v) {
    const UiofmuDesign *d = s->d;
    s->k = (long)uiofmu_getd(v, SV_K);
    s->h_prev = uiofmu_getd(v, SV_H_PREV);
    s->h_prev0 = uiofmu_getd(v, SV_H_PREV0);
    s->noticed = (int)uiofmu_getd(v, SV_NOTICED);
    const Byte *o = v + SV_SCALARS * sizeof(double);
    o = uiofmu_take(o, s->z, (size_t)d->nz);
    o = uiofmu_take(o, s->pred, (size_t)d->p);
    o = uiofmu_take(o, s->xhat0, (size_t)d->n);
    o = uiofmu_take(o, s->y, (size_t)d->p);
    uiofmu_take(o, s->u, (size_t)d->m);
    if (d->kind == UIOFMU_MODE) {
        size_t m0 = mode_at(d);
        s->mode = (int)uiofmu_getd(v, m0 + SV_MODE);
        s->mode_prev = (int)uiofmu_getd(v, m0 + SV_MODE_PREV);
        s->mode_prev0 = (int)uiofmu_getd(v, m0 + SV_MODE_PREV0);
    }
    s->work_k = -1;
    s->j_prev = -1;
    touched(s);
}
static int affine_check_state(void *self, const char *ctx, const Byte *v, int *phase) {
    if (!check_values((Instance *)self, ctx, v)) return 0;
    *phase = (int)uiofmu_getd(v, SV_PHASE);
    return 1;
}

static void affine_load_state(void *self, const Byte *v) { apply_state((Instance *)self, v); }

const UiofmuKernel UIOFMU_KERNEL_AFFINE = {
    .name = "affine",
    .check_design = affine_check_design,
    .ports = UIOFMU_AFFINE_PORTS,
    .port = affine_port,
    .instantiate = affine_instantiate,
    .free_instance = affine_free,
    .reset = affine_reset,
    .exit_initialization = affine_exit_initialization,
    .calculate = affine_calculate,
    .real_storage = affine_real_storage,
    .changed = affine_changed,
    .get_integer = affine_get_integer, /* mode schedules: mode_prev0 and mode */
    .set_integer = affine_set_integer,
    .step = affine_step,
    .state_count = affine_state_count,
    .state_shape = affine_state_shape,
    .save_state = affine_save_state,
    .check_state = affine_check_state,
    .load_state = affine_load_state,
};
