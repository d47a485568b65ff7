/* uiofmu: the linear plant kernel, the model code of uiofmu's C plant FMUs.
 *
 * It plugs into the shared FMI 2.0 plumbing (fmi2_plumbing.c) through UIOFMU_KERNEL_PLANT; the
 * plant's numbers come from design_data.c (UIOFMU_PLANT, generated from Plant.to_data()). The
 * step semantics are those of the reference runtime (uiofmu/runtime/plant_runtime.py):
 *
 *   outputs:          y = C x, x                (no input feeds through)
 *   initialisation:   x = the parameter x0      (before it: the design's x0)
 *   fmi2DoStep(t, h): x <- Ad x + Bd u + Ed d + wd, inputs u, d held over the step
 *
 * Continuous plants, any step h > 0: [Ad Bd Ed wd] is the first n rows of
 * exp(h [[A, B, E, w], [0, 0]]), the exact zero-order-hold solution (w is 0 for the continuous
 * plants uiofmu makes; the column costs nothing). The exponential is computed by scaling and
 * squaring with a Padé approximant, Higham's algorithm of 2005 (degrees 3, 5, 7, 9 and 13 by
 * the 1-norm, its theta bounds), and kept in a cache of the last CACHE_SIZE = 16 step lengths
 * (first in, first out; the twelve design intervals of the two-room building fit), keyed by the
 * exact double h: a repeated step costs one lookup (the last hit is looked at first).
 * Discrete plants: [Ad Bd Ed wd] = [A B E w], and a step other than dt (relative tolerance
 * step_rtol, as uiofmu/runtime/tolerances.py STEP_RTOL) is refused with fmi2Discard and a log
 * line naming h and dt; nothing changes.
 *
 * Non-finite inputs are refused with fmi2Error and a log line naming the input (h <= 0 or not
 * finite is refused by the plumbing); a step whose exponential or new state is not finite is
 * refused the same way. Either way nothing changes.
 *
 * FMU state: after the plumbing's header (magic, layout, size, GUID, the shape words n, m, p, q
 * and the count of doubles), 1 + 2n + m + q doubles, written and read with memcpy:
 *
 *   phase, x0[n], x[n], u[m], d[q]
 *
 * checked before any of it is used (check_values): phase one of 0 (instantiated), 1
 * (initialisation mode), 2 (initialised; a discarded step is saved as 2: it changed nothing),
 * 3 (terminated); x0 and x finite (fmi2ExitInitializationMode refuses a non-finite x0, so a
 * state holding one is refused whatever its phase); before initialisation ended (phase 0 and
 * 1) x is the design's x0, bit for bit (only initialisation moves it there); u and d any value,
 * NaN and Inf included (inputs that fmi2SetReal takes and fmi2DoStep refuses). The cache is not
 * part of the state: it is a function of h alone.
 */
#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2_plumbing.h"
#include "kernel_plant.h"

/* Bounds of what a plant may ask for: the augmented matrix is K x K, K = n + m + q + 1. */
#define MAX_DIM 2048
#define CACHE_SIZE 16

typedef struct {
    double h;
    int valid;
    double *phi; /* n x K: [Ad Bd Ed wd] */
} CacheEntry;

typedef struct {
    FmuInstance *fmu;
    const UiofmuPlant *d;
    int K;
    double *x0, *u, *dv, *x, *y, *tmp;
    int dirty;
    double *aug, *ex, *work; /* K x K, K x K, 7 K x K */
    int *piv;
    CacheEntry cache[CACHE_SIZE];
    int next, last;
    double *block; /* every double above, one allocation */
} Plant;

/* ---------------------------------------------------------------------------------------- */
/* The matrix exponential                                                                    */

/* C = A B (k x k) */
static void matmul(const double *A, const double *B, double *C, int k) {
    for (int i = 0; i < k; i++) {
        double *c = C + (size_t)i * k;
        for (int j = 0; j < k; j++) c[j] = 0.0;
        for (int l = 0; l < k; l++) {
            double a = A[(size_t)i * k + l];
            if (a == 0.0) continue;
            const double *b = B + (size_t)l * k;
            for (int j = 0; j < k; j++) c[j] += a * b[j];
        }
    }
}

static double norm1(const double *A, int k) {
    double best = 0.0;
    for (int j = 0; j < k; j++) {
        double s = 0.0;
        for (int i = 0; i < k; i++) s += fabs(A[(size_t)i * k + j]);
        if (s > best || isnan(s)) best = s;
    }
    return best;
}

/* Solve P X = R in place (R becomes X), P k x k overwritten by its LU factors (partial pivoting).
   0 when P is singular. */
static int solve(double *P, double *R, int k, int *piv) {
    for (int c = 0; c < k; c++) {
        int p = c;
        double big = fabs(P[(size_t)c * k + c]);
        for (int i = c + 1; i < k; i++)
            if (fabs(P[(size_t)i * k + c]) > big) { big = fabs(P[(size_t)i * k + c]); p = i; }
        if (!(big > 0.0)) return 0;
        piv[c] = p;
        if (p != c) {
            for (int j = 0; j < k; j++) {
                double t = P[(size_t)c * k + j]; P[(size_t)c * k + j] = P[(size_t)p * k + j]; P[(size_t)p * k + j] = t;
                t = R[(size_t)c * k + j]; R[(size_t)c * k + j] = R[(size_t)p * k + j]; R[(size_t)p * k + j] = t;
            }
        }
        double pivot = P[(size_t)c * k + c];
        for (int i = c + 1; i < k; i++) {
            double f = P[(size_t)i * k + c] / pivot;
            if (f == 0.0) continue;
            P[(size_t)i * k + c] = f;
            for (int j = c + 1; j < k; j++) P[(size_t)i * k + j] -= f * P[(size_t)c * k + j];
            for (int j = 0; j < k; j++) R[(size_t)i * k + j] -= f * R[(size_t)c * k + j];
        }
    }
    for (int c = k - 1; c >= 0; c--) {
        double pivot = P[(size_t)c * k + c];
        for (int j = 0; j < k; j++) {
            double acc = R[(size_t)c * k + j];
            for (int l = c + 1; l < k; l++) acc -= P[(size_t)c * k + l] * R[(size_t)l * k + j];
            R[(size_t)c * k + j] = acc / pivot;
        }
    }
    return 1;
}

/* Higham (2005), "The scaling and squaring method for the matrix exponential revisited",
   Table 2.3 (theta_m) and the Padé coefficients b_j of degree m. */
static const double THETA[5] = {1.495585217958292e-2, 2.539398330063230e-1, 9.504178996162932e-1,
                                2.097847961257068e0, 5.371920351148152e0};
static const int DEGREE[5] = {3, 5, 7, 9, 13};
static const double B3[4] = {120.0, 60.0, 12.0, 1.0};
static const double B5[6] = {30240.0, 15120.0, 3360.0, 420.0, 30.0, 1.0};
static const double B7[8] = {17297280.0, 8648640.0, 1995840.0, 277200.0, 25200.0, 1512.0, 56.0, 1.0};
static const double B9[10] = {17643225600.0, 8821612800.0, 2075673600.0, 302702400.0, 30270240.0,
                              2162160.0, 110880.0, 3960.0, 90.0, 1.0};
static const double B13[14] = {64764752532480000.0, 32382376266240000.0, 7771770303897600.0,
                               1187353796428800.0, 129060195264000.0, 10559470521600.0, 670442572800.0,
                               33522128640.0, 1323241920.0, 40840800.0, 960960.0, 16380.0, 182.0, 1.0};

int uiofmu_expm(const double *M, int k, double *out, double *work, int *piv) {
    size_t kk = (size_t)k * (size_t)k;
    double *As = work, *A2 = work + kk, *A4 = work + 2 * kk, *A6 = work + 3 * kk, *T = work + 4 * kk,
           *U = work + 5 * kk, *V = work + 6 * kk;
    for (size_t e = 0; e < kk; e++)
        if (!isfinite(M[e])) return 0;
    double nrm = norm1(M, k);
    int m = 13, s = 0;
    for (int i = 0; i < 4; i++)
        if (nrm <= THETA[i]) { m = DEGREE[i]; break; }
    if (m == 13 && nrm > THETA[4]) s = (int)ceil(log2(nrm / THETA[4]));
    if (s < 0) s = 0;
    if (s > 2000) return 0;
    for (size_t e = 0; e < kk; e++) As[e] = ldexp(M[e], -s);
    matmul(As, As, A2, k);
    if (m == 13) {
        const double *b = B13;
        matmul(A2, A2, A4, k);
        matmul(A4, A2, A6, k);
        /* U = A [A6 (b13 A6 + b11 A4 + b9 A2) + b7 A6 + b5 A4 + b3 A2 + b1 I] */
        for (size_t e = 0; e < kk; e++) T[e] = b[13] * A6[e] + b[11] * A4[e] + b[9] * A2[e];
        matmul(A6, T, V, k);
        for (size_t e = 0; e < kk; e++) V[e] += b[7] * A6[e] + b[5] * A4[e] + b[3] * A2[e];
        for (int i = 0; i < k; i++) V[(size_t)i * k + i] += b[1];
        matmul(As, V, U, k);
        /* V = A6 (b12 A6 + b10 A4 + b8 A2) + b6 A6 + b4 A4 + b2 A2 + b0 I */
        for (size_t e = 0; e < kk; e++) T[e] = b[12] * A6[e] + b[10] * A4[e] + b[8] * A2[e];
        matmul(A6, T, V, k);
        for (size_t e = 0; e < kk; e++) V[e] += b[6] * A6[e] + b[4] * A4[e] + b[2] * A2[e];
        for (int i = 0; i < k; i++) V[(size_t)i * k + i] += b[0];
    } else {
        const double *b = m == 3 ? B3 : m == 5 ? B5 : m == 7 ? B7 : B9;
        /* powers A^2j in A2, A4, A6 and (m = 9) A^8 in T; odd part into out, even part into V */
        const double *pw[5] = {NULL, A2, A4, A6, T};
        if (m >= 5) matmul(A2, A2, A4, k);
        if (m >= 7) matmul(A4, A2, A6, k);
        if (m >= 9) matmul(A6, A2, T, k);
        for (size_t e = 0; e < kk; e++) { out[e] = 0.0; V[e] = 0.0; }
        for (int i = 0; i < k; i++) { out[(size_t)i * k + i] = b[1]; V[(size_t)i * k + i] = b[0]; }
        for (int j = 1; 2 * j <= m; j++) {
            const double *P = pw[j];
            double odd = b[2 * j + 1], even = b[2 * j];
            for (size_t e = 0; e < kk; e++) { out[e] += odd * P[e]; V[e] += even * P[e]; }
        }
        matmul(As, out, U, k);
    }
    /* (V - U) X = V + U */
    for (size_t e = 0; e < kk; e++) {
        out[e] = V[e] + U[e];
        V[e] -= U[e];
    }
    if (!solve(V, out, k, piv)) return 0;
    for (int i = 0; i < s; i++) {
        matmul(out, out, T, k);
        memcpy(out, T, kk * sizeof(double));
    }
    for (size_t e = 0; e < kk; e++)
        if (!isfinite(out[e])) return 0;
    return 1;
}

/* ---------------------------------------------------------------------------------------- */
/* The design, checked once at fmi2Instantiate                                               */

static int design_error(char *msg, size_t len, const char *fmt, ...) UIOFMU_PRINTF(3, 4);
static int design_error(char *msg, size_t len, const char *fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, len, fmt, ap);
    va_end(ap);
    return 0;
}

static int plant_check_design(char *msg, size_t len) {
    const UiofmuPlant *d = &UIOFMU_PLANT;
    const int dims[4] = {d->n, d->m, d->p, d->q};
    const char *const dim_name[4] = {"n", "m", "p", "q"};
    for (int i = 0; i < 4; i++) {
        int low = i == 0 || i == 2 ? 1 : 0;
        if (dims[i] < low || dims[i] > MAX_DIM)
            return design_error(msg, len, "plant dims.%s = %d is out of range [%d, %d]", dim_name[i], dims[i], low, MAX_DIM);
    }
    if (d->time != UIOFMU_DISCRETE && d->time != UIOFMU_CONTINUOUS)
        return design_error(msg, len, "plant time = %d is neither discrete (0) nor continuous (1)", d->time);
    if (d->time == UIOFMU_DISCRETE && !(isfinite(d->dt) && d->dt > 0))
        return design_error(msg, len, "plant dt = %g: a discrete plant needs a period > 0", d->dt);
    if (!(isfinite(d->step_rtol) && d->step_rtol >= 0 && d->step_rtol < 1))
        return design_error(msg, len, "plant step_rtol = %g is out of range [0, 1)", d->step_rtol);
    struct { const char *name; const double *data; size_t length, want; } M[6] = {
        {"A", d->A, d->A_length, (size_t)d->n * d->n}, {"B", d->B, d->B_length, (size_t)d->n * d->m},
        {"E", d->E, d->E_length, (size_t)d->n * d->q}, {"C", d->C, d->C_length, (size_t)d->p * d->n},
        {"w", d->w, d->w_length, (size_t)d->n}, {"x0", d->x0, d->x0_length, (size_t)d->n}};
    for (int i = 0; i < 6; i++) {
        size_t want = M[i].want ? M[i].want : 1; /* an empty array is written as {0.0} */
        if (!M[i].data || M[i].length != want)
            return design_error(msg, len, "plant %s: %zu numbers compiled in, expected %zu", M[i].name, M[i].length, want);
        for (size_t e = 0; e < M[i].want; e++)
            if (!isfinite(M[i].data[e]))
                return design_error(msg, len, "plant %s: entry %zu is not finite", M[i].name, e + 1);
    }
    return 1;
}

static int plant_port(int id, UiofmuPort *out) {
    static const char *const NAME[UIOFMU_PLANT_PORTS] = {"x0", "u", "d", "y", "x"};
    const UiofmuPlant *d = &UIOFMU_PLANT;
    int size;
    switch (id) {
    case UIOFMU_PLANT_X0: case UIOFMU_PLANT_X: size = d->n; break;
    case UIOFMU_PLANT_U: size = d->m; break;
    case UIOFMU_PLANT_D: size = d->q; break;
    case UIOFMU_PLANT_Y: size = d->p; break;
    default: return 0;
    }
    out->name = NAME[id];
    out->size = size;
    out->causality = id == UIOFMU_PLANT_X0 ? UIOFMU_PARAMETER : id <= UIOFMU_PLANT_D ? UIOFMU_INPUT : UIOFMU_OUTPUT;
    out->type = UIOFMU_REAL;
    return 1;
}

/* ---------------------------------------------------------------------------------------- */
/* Instances                                                                                 */

static void plant_reset(void *self) {
    Plant *s = (Plant *)self;
    const UiofmuPlant *d = s->d;
    memcpy(s->x0, d->x0, (size_t)d->n * sizeof(double));
    memcpy(s->x, d->x0, (size_t)d->n * sizeof(double));
    memset(s->u, 0, (size_t)d->m * sizeof(double));
    memset(s->dv, 0, (size_t)d->q * sizeof(double));
    s->dirty = 1;
}

static void *plant_instantiate(FmuInstance *fmu) {
    const UiofmuPlant *d = &UIOFMU_PLANT;
    Plant *s = (Plant *)calloc(1, sizeof(Plant));
    if (!s) {
        uiofmu_log(fmu, fmi2Error, "fmi2Instantiate: out of memory");
        return NULL;
    }
    s->fmu = fmu;
    s->d = d;
    s->K = d->n + d->m + d->q + 1;
    size_t n = (size_t)d->n, K = (size_t)s->K, kk = K * K;
    int continuous = d->time == UIOFMU_CONTINUOUS;
    size_t total = 4 * n + (size_t)d->m + (size_t)d->q + (size_t)d->p +
                   (continuous ? 9 * kk + CACHE_SIZE * n * K : 0);
    s->block = (double *)calloc(total, sizeof(double));
    s->piv = continuous ? (int *)calloc(K, sizeof(int)) : NULL;
    if (!s->block || (continuous && !s->piv)) {
        free(s->block);
        free(s->piv);
        free(s);
        uiofmu_log(fmu, fmi2Error, "fmi2Instantiate: out of memory");
        return NULL;
    }
    double *b = s->block;
    s->x0 = b; b += n;
    s->x = b; b += n;
    s->tmp = b; b += 2 * n;
    s->u = b; b += d->m;
    s->dv = b; b += d->q;
    s->y = b; b += d->p;
    if (continuous) {
        s->aug = b; b += kk;
        s->ex = b; b += kk;
        s->work = b; b += 7 * kk;
        for (int i = 0; i < CACHE_SIZE; i++) { s->cache[i].phi = b; b += n * K; }
    }
    s->last = 0;
    plant_reset(s);
    return s;
}

static void plant_free(void *self) {
    Plant *s = (Plant *)self;
    if (!s) return;
    free(s->block);
    free(s->piv);
    free(s);
}

static UiofmuResult plant_exit_initialization(void *self) {
    Plant *s = (Plant *)self;
    char b1[32];
    for (int i = 0; i < s->d->n; i++)
        if (!isfinite(s->x0[i])) {
            uiofmu_log(s->fmu, fmi2Error, "parameter x0[%d] = %s is not finite", i + 1, uiofmu_num(s->x0[i], b1));
            return UIOFMU_REFUSED;
        }
    memcpy(s->x, s->x0, (size_t)s->d->n * sizeof(double));
    s->dirty = 1;
    return UIOFMU_DONE;
}

static UiofmuResult plant_calculate(void *self, const char *fn) {
    Plant *s = (Plant *)self;
    const UiofmuPlant *d = s->d;
    (void)fn;
    if (!s->dirty) return UIOFMU_DONE;
    for (int i = 0; i < d->p; i++) {
        double acc = 0.0;
        for (int j = 0; j < d->n; j++) acc += d->C[(size_t)i * d->n + j] * s->x[j];
        s->y[i] = acc;
    }
    s->dirty = 0;
    return UIOFMU_DONE;
}

static double *element(Plant *s, int port, int index) {
    switch (port) {
    case UIOFMU_PLANT_X0: return &s->x0[index];
    case UIOFMU_PLANT_U: return &s->u[index];
    case UIOFMU_PLANT_D: return &s->dv[index];
    case UIOFMU_PLANT_Y: return &s->y[index];
    case UIOFMU_PLANT_X: return &s->x[index];
    default: return NULL;
    }
}

static double plant_get_real(void *self, int port, int index) {
    const double *v = element((Plant *)self, port, index);
    return v ? *v : 0.0;
}

static void plant_set_real(void *self, int port, int index, double value) {
    double *v = port <= UIOFMU_PLANT_D ? element((Plant *)self, port, index) : NULL; /* parameters and inputs */
    if (v) *v = value;
}

/* [Ad Bd Ed wd] (n x K) of a continuous plant for step h: from the cache, or computed into it.
   NULL (with a log line) when the exponential is not finite. */
static const double *discretisation(Plant *s, double t, double h) {
    const UiofmuPlant *d = s->d;
    if (s->cache[s->last].valid && s->cache[s->last].h == h) return s->cache[s->last].phi;
    for (int i = 0; i < CACHE_SIZE; i++)
        if (s->cache[i].valid && s->cache[i].h == h) {
            s->last = i;
            return s->cache[i].phi;
        }
    int n = d->n, m = d->m, q = d->q, K = s->K;
    double *M = s->aug;
    memset(M, 0, (size_t)K * K * sizeof(double));
    for (int i = 0; i < n; i++) {
        double *row = M + (size_t)i * K;
        for (int j = 0; j < n; j++) row[j] = d->A[(size_t)i * n + j] * h;
        for (int j = 0; j < m; j++) row[n + j] = d->B[(size_t)i * m + j] * h;
        for (int j = 0; j < q; j++) row[n + m + j] = d->E[(size_t)i * q + j] * h;
        row[K - 1] = d->w[i] * h;
    }
    if (!uiofmu_expm(M, K, s->ex, s->work, s->piv)) {
        char bt[32], bh[32];
        uiofmu_log(s->fmu, fmi2Error, "t = %s: the exponential of the plant over h = %s s is not finite",
                   uiofmu_num(t, bt), uiofmu_num(h, bh));
        return NULL;
    }
    CacheEntry *e = &s->cache[s->next];
    memcpy(e->phi, s->ex, (size_t)n * K * sizeof(double));
    e->h = h;
    e->valid = 1;
    s->last = s->next;
    s->next = (s->next + 1) % CACHE_SIZE;
    return e->phi;
}

static int inputs_finite(Plant *s, double t, const double *v, int len, const char *name) {
    char bt[32];
    for (int i = 0; i < len; i++)
        if (!isfinite(v[i])) {
            uiofmu_log(s->fmu, fmi2Error, "t = %s: input %s[%d] = %s is not finite", uiofmu_num(t, bt), name, i + 1,
                       isnan(v[i]) ? "nan" : (v[i] > 0 ? "inf" : "-inf"));
            return 0;
        }
    return 1;
}

static UiofmuResult plant_step(void *self, double t, double h) {
    Plant *s = (Plant *)self;
    const UiofmuPlant *d = s->d;
    int n = d->n, m = d->m, q = d->q;
    char bt[32], bh[32], bd[32];
    if (!inputs_finite(s, t, s->u, m, "u") || !inputs_finite(s, t, s->dv, q, "d")) return UIOFMU_REFUSED;
    double *xn = s->tmp;
    if (d->time == UIOFMU_DISCRETE) {
        if (fabs(h - d->dt) > d->step_rtol * d->dt) {
            uiofmu_log(s->fmu, fmi2Discard, "t = %s: this discrete plant steps at dt = %s s and received h = %s s",
                       uiofmu_num(t, bt), uiofmu_num(d->dt, bd), uiofmu_num(h, bh));
            return UIOFMU_DISCARDED;
        }
        for (int i = 0; i < n; i++) {
            double ax = 0.0, bu = 0.0, ed = 0.0;
            for (int j = 0; j < n; j++) ax += d->A[(size_t)i * n + j] * s->x[j];
            for (int j = 0; j < m; j++) bu += d->B[(size_t)i * m + j] * s->u[j];
            for (int j = 0; j < q; j++) ed += d->E[(size_t)i * q + j] * s->dv[j];
            xn[i] = ax + bu + ed + d->w[i];
        }
    } else {
        const double *phi = discretisation(s, t, h);
        if (!phi) return UIOFMU_REFUSED;
        int K = s->K;
        for (int i = 0; i < n; i++) {
            const double *row = phi + (size_t)i * K;
            double ax = 0.0, bu = 0.0, ed = 0.0;
            for (int j = 0; j < n; j++) ax += row[j] * s->x[j];
            for (int j = 0; j < m; j++) bu += row[n + j] * s->u[j];
            for (int j = 0; j < q; j++) ed += row[n + m + j] * s->dv[j];
            xn[i] = ax + bu + ed + row[K - 1];
        }
    }
    for (int i = 0; i < n; i++)
        if (!isfinite(xn[i])) {
            uiofmu_log(s->fmu, fmi2Error, "t = %s: the state x[%d] after the step h = %s s would not be finite",
                       uiofmu_num(t, bt), i + 1, uiofmu_num(h, bh));
            return UIOFMU_REFUSED;
        }
    memcpy(s->x, xn, (size_t)n * sizeof(double));
    s->dirty = 1;
    return UIOFMU_DONE;
}

/* ---------------------------------------------------------------------------------------- */
/* FMU state (layout in the header comment)                                                  */

typedef unsigned char Byte;

static double getd(const Byte *b, size_t index) { double v; memcpy(&v, b + index * sizeof v, sizeof v); return v; }

static size_t plant_state_count(void) {
    const UiofmuPlant *d = &UIOFMU_PLANT;
    return 1 + 2 * (size_t)d->n + (size_t)d->m + (size_t)d->q;
}

static void plant_state_shape(uint32_t shape[UIOFMU_SHAPE], const char *names[UIOFMU_SHAPE]) {
    const UiofmuPlant *d = &UIOFMU_PLANT;
    static const char *const NAMES[UIOFMU_SHAPE] = {"n", "m", "p", "q"};
    shape[0] = (uint32_t)d->n;
    shape[1] = (uint32_t)d->m;
    shape[2] = (uint32_t)d->p;
    shape[3] = (uint32_t)d->q;
    for (int i = 0; i < UIOFMU_SHAPE; i++) names[i] = NAMES[i];
}

static void plant_save_state(void *self, int phase, Byte *o) {
    Plant *s = (Plant *)self;
    const UiofmuPlant *d = s->d;
    double ph = (double)phase;
    memcpy(o, &ph, sizeof ph); o += sizeof ph;
    memcpy(o, s->x0, (size_t)d->n * sizeof(double)); o += (size_t)d->n * sizeof(double);
    memcpy(o, s->x, (size_t)d->n * sizeof(double)); o += (size_t)d->n * sizeof(double);
    memcpy(o, s->u, (size_t)d->m * sizeof(double)); o += (size_t)d->m * sizeof(double);
    memcpy(o, s->dv, (size_t)d->q * sizeof(double));
}

static int plant_check_state(void *self, const char *ctx, const Byte *v, int *phase) {
    Plant *s = (Plant *)self;
    const UiofmuPlant *d = s->d;
    char b1[32], b2[32];
    double ph = getd(v, 0);
    if (!(ph == UIOFMU_PHASE_INSTANTIATED || ph == UIOFMU_PHASE_INITIALIZATION || ph == UIOFMU_PHASE_RUNNING ||
          ph == UIOFMU_PHASE_TERMINATED)) {
        uiofmu_log(s->fmu, fmi2Error, "%s: phase = %s is none of 0 (instantiated), 1 (initialisation mode), "
                   "2 (initialised), 3 (terminated)", ctx, uiofmu_num(ph, b1));
        return 0;
    }
    for (int w = 0; w < 2; w++)
        for (int i = 0; i < d->n; i++) {
            double x = getd(v, 1 + (size_t)w * d->n + (size_t)i);
            if (!isfinite(x)) {
                uiofmu_log(s->fmu, fmi2Error, "%s: %s[%d] = %s is not finite", ctx, w ? "x" : "x0", i + 1, uiofmu_num(x, b1));
                return 0;
            }
            if (w == 1 && ph < UIOFMU_PHASE_RUNNING && x != d->x0[i]) {
                uiofmu_log(s->fmu, fmi2Error, "%s: x[%d] = %s in phase %d, before initialisation ended: expected the "
                           "design's x0[%d] = %s", ctx, i + 1, uiofmu_num(x, b1), (int)ph, i + 1, uiofmu_num(d->x0[i], b2));
                return 0;
            }
        }
    /* u[m], d[q]: taken as they are (see the header comment) */
    *phase = (int)ph;
    return 1;
}

static void plant_load_state(void *self, const Byte *v) {
    Plant *s = (Plant *)self;
    const UiofmuPlant *d = s->d;
    const Byte *o = v + sizeof(double);
    memcpy(s->x0, o, (size_t)d->n * sizeof(double)); o += (size_t)d->n * sizeof(double);
    memcpy(s->x, o, (size_t)d->n * sizeof(double)); o += (size_t)d->n * sizeof(double);
    memcpy(s->u, o, (size_t)d->m * sizeof(double)); o += (size_t)d->m * sizeof(double);
    memcpy(s->dv, o, (size_t)d->q * sizeof(double));
    s->dirty = 1;
}

const UiofmuKernel UIOFMU_KERNEL_PLANT = {
    .name = "linear plant",
    .check_design = plant_check_design,
    .ports = UIOFMU_PLANT_PORTS,
    .port = plant_port,
    .instantiate = plant_instantiate,
    .free_instance = plant_free,
    .reset = plant_reset,
    .exit_initialization = plant_exit_initialization,
    .calculate = plant_calculate,
    .get_real = plant_get_real,
    .set_real = plant_set_real,
    .get_integer = NULL, /* no Integer ports */
    .set_integer = NULL,
    .step = plant_step,
    .state_count = plant_state_count,
    .state_shape = plant_state_shape,
    .save_state = plant_save_state,
    .check_state = plant_check_state,
    .load_state = plant_load_state,
};
