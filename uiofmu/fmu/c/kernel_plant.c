/* uiofmu: the linear plant kernel, the model code of uiofmu's C plant FMUs.
 *
 * It plugs into the shared FMI 2.0 plumbing (fmi2_plumbing.c) through UIOFMU_KERNEL_PLANT; the
 * plant's numbers come from design_data.c (UIOFMU_PLANT, generated from Plant.to_data()). The
 * step semantics are those of the reference runtime (uiofmu/runtime/plant_runtime.py):
 *
 *   outputs:          y = C x + D u + F d, x    (D, F zero unless the plant feeds an input through)
 *   initialisation:   x = the parameter x0      (before it: the design's x0)
 *   fmi2DoStep(t, h): x <- Ad x + Bd u + Ed d + wd + Wd w_noise, inputs u, d, w_noise held over the step
 *
 * The input w_noise[r] (process noise) exists where the problem declares W (n x r; r = 0 otherwise).
 * Continuous plants, any step h > 0: [Ad Bd Ed Wd wd] is the first n rows of
 * exp(h [[A, B, E, W, w], [0, 0]]), the exact zero-order-hold solution (w is 0 for the continuous
 * plants uiofmu makes; the column costs nothing). The exponential is computed by scaling and
 * squaring with a Padé approximant, Higham's algorithm of 2005 (degrees 3, 5, 7, 9 and 13 by
 * the 1-norm, its theta bounds), and kept in a cache of the last CACHE_SIZE = 16 step lengths
 * (first in, first out; the twelve design intervals of the two-room building fit), keyed by the
 * exact double h: a repeated step costs one lookup (the last hit is looked at first).
 * Discrete plants: [Ad Bd Ed wd] = [A B E w], and a step other than dt (relative tolerance
 * step_rtol, as uiofmu/runtime/tolerances.py STEP_RTOL) is refused with fmi2Discard and a log
 * line naming h and dt; nothing changes.
 *
 * Switched plants (discrete, modes N >= 1; uiofmu/runtime/switching.py, bit for bit): the step
 * from t_k is x <- A_i x + B_i u + E_i d + w_i in the mode i = alpha_k of that step, which the
 * Integer output mode shows at t_k (rules threshold and random) or the Integer input mode sets
 * (rule input; one outside 1..N refuses the step with fmi2Error and a log line naming it and
 * the range, before the step length is looked at, as the reference runtime). Rule threshold:
 * alpha_k = 1 + #{thresholds <= x_k[state]}. Rule random: alpha_k is drawn from the k-th output
 * of a SplitMix64 generator (Steele, Lea, Flood 2014) started at the 64 bits of the seed (two's
 * complement): U = (output >> 11) 2^-53, alpha_k the first i with U < cumulative[i - 1], N when
 * none; mode 0 is drawn when the generator restarts (instantiation, fmi2Reset, and
 * fmi2ExitInitializationMode with the parameter seed), the next after each step taken.
 *
 * Mismatch (uiofmu/runtime/mismatch.py, bit for bit): the Real parameter mismatch (default 0) and
 * the Integer parameter mismatch_seed (default 0) are taken at fmi2ExitInitializationMode, which
 * replaces every entry M of A, B and E (every block of a switched plant) by M (1 + mismatch g),
 * g = sqrt(3) (2 U - 1), U = (output >> 11) 2^-53 of a SplitMix64 generator started at the seed's
 * 64 bits: block by block, in each A then B then E, row by row (mismatch 0: the design's matrices,
 * no draws). A mismatch that is not a finite number >= 0, or that makes an entry overflow, is
 * refused with fmi2Error and a log line naming it. The cached exponentials are forgotten.
 *
 * Non-finite inputs are refused with fmi2Error and a log line naming the input (h <= 0 or not
 * finite is refused by the plumbing); a step whose exponential or new state is not finite is
 * refused the same way. Either way nothing changes.
 *
 * FMU state: after the plumbing's header (magic, layout, size, GUID, the shape words n, m, p, q
 * and the count of doubles), 3 + 2n + m + q + r doubles, written and read with memcpy:
 *
 *   phase, x0[n], x[n], u[m], d[q], w_noise[r], mismatch, mismatch_seed
 *
 * checked before any of it is used (check_values): phase one of 0 (instantiated), 1
 * (initialisation mode), 2 (initialised; a discarded step is saved as 2: it changed nothing),
 * 3 (terminated); x0 and x finite (fmi2ExitInitializationMode refuses a non-finite x0, so a
 * state holding one is refused whatever its phase); before initialisation ended (phase 0 and
 * 1) x is the design's x0, bit for bit (only initialisation moves it there); u, d and w_noise any value,
 * NaN and Inf included (inputs that fmi2SetReal takes and fmi2DoStep refuses); mismatch_seed an
 * fmi2Integer; mismatch any value before initialisation ended (a parameter fmi2ExitInitializationMode
 * checks), after it a finite number >= 0 whose perturbation is finite. The perturbed matrices are
 * computed again from the two (the design's before initialisation ended) and the cache forgotten: the
 * cache is not part of the state (a function of h and the matrices). A switched plant adds 5 doubles,
 * integers held exactly:
 *
 *   mode_in, seed, rng_hi, rng_lo, drawn
 *
 * mode_in and seed any fmi2Integer (an input the step checks; a parameter taken as it is), the
 * generator's state as its two 32-bit halves (integers 0 <= v < 2^32: every state is one the
 * generator can be in), drawn a mode 1..N (1 for the rules other than random).
 */
#include <limits.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2_plumbing.h"
#include "kernel_plant.h"
#include "kernel_util.h"

/* Bounds of what a plant may ask for: the augmented matrix is K x K, K = n + m + q + r + 1. */
#define MAX_DIM 2048
#define CACHE_SIZE 16
#define MAX_MODES 4096

/* The ports' names, causalities and types by id (kernel_plant_ports.h, generated). */
static const char *const PORT_NAME[UIOFMU_PLANT_PORTS] = UIOFMU_PLANT_PORT_NAMES;
static const int PORT_CAUSALITY[UIOFMU_PLANT_PORTS] = UIOFMU_PLANT_PORT_CAUSALITIES;
static const int PORT_TYPE[UIOFMU_PLANT_PORTS] = UIOFMU_PLANT_PORT_TYPES;

typedef struct {
    double h;
    int valid;
    double *phi; /* n x K: [Ad Bd Ed Wd wd] */
} CacheEntry;

typedef struct {
    FmuInstance *fmu;
    const UiofmuPlant *d;
    int K;
    double *x0, *u, *dv, *wn, *x, *y, *tmp;
    int dirty;
    double *aug, *ex, *work; /* K x K, K x K, 7 K x K */
    int *piv;
    CacheEntry cache[CACHE_SIZE];
    int next, last;
    /* switched plants: the input mode, the seed, the generator and the mode it drew */
    int mode_in, seed, drawn;
    uint64_t rng;
    /* the parameters mismatch and mismatch_seed, and the matrices the steps use: the design's
       A, B, E perturbed by them at fmi2ExitInitializationMode (every block; the design's before) */
    double mismatch;
    int mismatch_seed;
    double *A, *B, *E;
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
    if (!isfinite(nrm)) return 0; /* finite entries whose sums overflow */
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

/* The switching rule's numbers (thresholds, cumulative probabilities, state index, mode0). */
static int switching_ok(const UiofmuPlant *d, char *msg, size_t len) {
    int want_th = d->rule == UIOFMU_RULE_THRESHOLD ? d->modes - 1 : 0;
    if (d->nthresholds != want_th || !d->thresholds || d->thresholds_length != (size_t)(want_th ? want_th : 1))
        return uiofmu_design_error(msg, len, "plant thresholds: %d in an array of %zu, expected %d", d->nthresholds,
                                   d->thresholds ? d->thresholds_length : 0, want_th);
    for (int i = 0; i < want_th; i++)
        if (!isfinite(d->thresholds[i]) || (i && !(d->thresholds[i] > d->thresholds[i - 1])))
            return uiofmu_design_error(msg, len, "plant thresholds: entry %d = %g is not finite and above the one "
                                       "before", i + 1, d->thresholds[i]);
    if (d->rule == UIOFMU_RULE_THRESHOLD && !(d->state >= 0 && d->state < d->n))
        return uiofmu_design_error(msg, len, "plant switching state = %d is not a state index (0 to %d)", d->state,
                                   d->n - 1);
    size_t want_c = d->rule == UIOFMU_RULE_RANDOM ? (size_t)d->modes : 1;
    if (!d->cumulative || d->cumulative_length != want_c)
        return uiofmu_design_error(msg, len, "plant cumulative probabilities: %zu numbers, expected %zu",
                                   d->cumulative ? d->cumulative_length : 0, want_c);
    for (size_t i = 0; i < want_c; i++)
        if (!isfinite(d->cumulative[i]))
            return uiofmu_design_error(msg, len, "plant cumulative probabilities: entry %zu is not finite", i + 1);
    if (d->rule == UIOFMU_RULE_INPUT && !(d->mode0 >= 1 && d->mode0 <= d->modes))
        return uiofmu_design_error(msg, len, "plant mode0 = %d is not a mode (1 to %d)", d->mode0, d->modes);
    return 1;
}

static int plant_check_design(char *msg, size_t len) {
    const UiofmuPlant *d = &UIOFMU_PLANT;
    const int dims[5] = {d->n, d->m, d->p, d->q, d->r}, low[5] = {1, 0, 1, 0, 0};
    const char *const dim_name[5] = {"n", "m", "p", "q", "r"};
    if (!uiofmu_check_dims(msg, len, "plant dims.", 5, dims, dim_name, low, MAX_DIM)) return 0;
    if (d->r && d->modes)
        return uiofmu_design_error(msg, len, "plant r = %d: a switched plant takes no process noise", d->r);
    if (d->time != UIOFMU_DISCRETE && d->time != UIOFMU_CONTINUOUS)
        return uiofmu_design_error(msg, len, "plant time = %d is neither discrete (0) nor continuous (1)", d->time);
    if (d->time == UIOFMU_DISCRETE && !(isfinite(d->dt) && d->dt > 0))
        return uiofmu_design_error(msg, len, "plant dt = %g: a discrete plant needs a period > 0", d->dt);
    if (!(isfinite(d->step_rtol) && d->step_rtol >= 0 && d->step_rtol < 1))
        return uiofmu_design_error(msg, len, "plant step_rtol = %g is out of range [0, 1)", d->step_rtol);
    if (!(d->modes >= 0 && d->modes <= MAX_MODES))
        return uiofmu_design_error(msg, len, "plant modes = %d is out of range [0, %d]", d->modes, MAX_MODES);
    if ((d->modes == 0) != (d->rule == UIOFMU_RULE_NONE) || d->rule < UIOFMU_RULE_NONE || d->rule > UIOFMU_RULE_RANDOM)
        return uiofmu_design_error(msg, len, "plant rule = %d does not go with %d modes", d->rule, d->modes);
    if (d->modes && d->time != UIOFMU_DISCRETE)
        return uiofmu_design_error(msg, len, "a switched plant is discrete, found time = %d", d->time);
    if (d->modes && (PORT_CAUSALITY[UIOFMU_PLANT_MODE] == UIOFMU_INPUT) != (d->rule == UIOFMU_RULE_INPUT))
        return uiofmu_design_error(msg, len, "port %s is declared with causality %d, rule %d needs %s",
                                   PORT_NAME[UIOFMU_PLANT_MODE], PORT_CAUSALITY[UIOFMU_PLANT_MODE], d->rule,
                                   d->rule == UIOFMU_RULE_INPUT ? "an input" : "an output");
    if (!switching_ok(d, msg, len)) return 0;
    size_t blocks = d->modes ? (size_t)d->modes : 1;
    struct { const char *name; const double *data; size_t length, want; } M[9] = {
        {"A", d->A, d->A_length, blocks * d->n * d->n}, {"B", d->B, d->B_length, blocks * d->n * d->m},
        {"E", d->E, d->E_length, blocks * d->n * d->q}, {"C", d->C, d->C_length, (size_t)d->p * d->n},
        {"w", d->w, d->w_length, blocks * d->n}, {"x0", d->x0, d->x0_length, (size_t)d->n},
        {"W", d->W, d->W_length, (size_t)d->n * d->r},
        {"D", d->D, d->D_length, (size_t)d->p * d->m}, {"F", d->F, d->F_length, (size_t)d->p * d->q}};
    for (int i = 0; i < 9; i++) {
        size_t want = M[i].want ? M[i].want : 1; /* an empty array is written as {0.0} */
        if (!M[i].data || M[i].length != want)
            return uiofmu_design_error(msg, len, "plant %s: %zu numbers compiled in, expected %zu", M[i].name,
                                       M[i].length, want);
        for (size_t e = 0; e < M[i].want; e++)
            if (!isfinite(M[i].data[e]))
                return uiofmu_design_error(msg, len, "plant %s: entry %zu is not finite", M[i].name, e + 1);
    }
    return 1;
}

static int plant_port(int id, UiofmuPort *out) {
    const UiofmuPlant *d = &UIOFMU_PLANT;
    int size;
    switch (id) {
    case UIOFMU_PLANT_X0: case UIOFMU_PLANT_X: size = d->n; break;
    case UIOFMU_PLANT_U: size = d->m; break;
    case UIOFMU_PLANT_D: size = d->q; break;
    case UIOFMU_PLANT_W_NOISE: size = d->r; break;
    case UIOFMU_PLANT_Y: size = d->p; break;
    case UIOFMU_PLANT_SEED: size = d->rule == UIOFMU_RULE_RANDOM ? 1 : 0; break;
    case UIOFMU_PLANT_MODE: size = d->modes ? 1 : 0; break;
    case UIOFMU_PLANT_MISMATCH: case UIOFMU_PLANT_MISMATCH_SEED: size = 1; break;
    default: return 0;
    }
    out->name = PORT_NAME[id];
    out->size = size;
    out->causality = PORT_CAUSALITY[id];
    out->type = PORT_TYPE[id];
    return 1;
}

/* ---------------------------------------------------------------------------------------- */
/* Instances                                                                                 */

/* ---------------------------------------------------------------------------------------- */
/* Switching                                                                                 */

/* One step of SplitMix64: the new state in *state, the 64-bit output returned. */
static uint64_t splitmix64(uint64_t *state) {
    uint64_t z = (*state += UINT64_C(0x9E3779B97F4A7C15));
    z = (z ^ (z >> 30)) * UINT64_C(0xBF58476D1CE4E5B9);
    z = (z ^ (z >> 27)) * UINT64_C(0x94D049BB133111EB);
    return z ^ (z >> 31);
}

/* Rule random: the mode of the next step from the generator (nothing for the other rules). */
static void draw(Plant *s) {
    const UiofmuPlant *d = s->d;
    if (d->rule != UIOFMU_RULE_RANDOM) return;
    double u = (double)(splitmix64(&s->rng) >> 11) * (1.0 / 9007199254740992.0);
    int mode = d->modes;
    for (int i = 0; i < d->modes - 1; i++)
        if (u < d->cumulative[i]) { mode = i + 1; break; }
    s->drawn = mode;
}

/* The generator at the seed (its 64 bits, two's complement), and the mode of step 0. */
static void restart(Plant *s) {
    s->rng = (uint64_t)(int64_t)s->seed;
    s->drawn = 1;
    draw(s);
}

/* alpha_k, the mode of the step from the current point (1 for a linear plant; for rule input
   the input as it is, which the step checks). */
static int current_mode(const Plant *s) {
    const UiofmuPlant *d = s->d;
    if (d->rule == UIOFMU_RULE_THRESHOLD) {
        int mode = 1;
        for (int i = 0; i < d->nthresholds; i++)
            if (d->thresholds[i] <= s->x[d->state]) mode++;
        return mode;
    }
    if (d->rule == UIOFMU_RULE_RANDOM) return s->drawn;
    if (d->rule == UIOFMU_RULE_INPUT) return s->mode_in;
    return 1;
}

/* ---------------------------------------------------------------------------------------- */
/* Mismatch (uiofmu/runtime/mismatch.py, bit for bit)                                        */

/* The design's A, B, E with every entry M replaced by M (1 + mismatch g), g = sqrt(3) (2 U - 1) from
   the next output of a SplitMix64 generator started at the seed's 64 bits: block by block, in each
   A then B then E, row by row. store = 1 writes them into s->A, s->B, s->E and forgets the cached
   exponentials (the caller checked them first); store = 0 only checks: 0 when an entry is not finite. */
static int perturb(Plant *s, double mismatch, int seed, int store) {
    const UiofmuPlant *d = s->d;
    size_t blocks = d->modes ? (size_t)d->modes : 1, n = (size_t)d->n;
    const size_t size[3] = {n * n, n * (size_t)d->m, n * (size_t)d->q};
    const double *design[3] = {d->A, d->B, d->E};
    double *out[3] = {s->A, s->B, s->E};
    const double root3 = sqrt(3.0);
    uint64_t rng = (uint64_t)(int64_t)seed;
    for (size_t b = 0; b < blocks; b++)
        for (int k = 0; k < 3; k++)
            for (size_t e = 0; e < size[k]; e++) {
                double v = design[k][b * size[k] + e];
                if (mismatch != 0.0) {
                    double u = (double)(splitmix64(&rng) >> 11) * (1.0 / 9007199254740992.0);
                    double g = root3 * (2.0 * u - 1.0);
                    double f = 1.0 + mismatch * g;
                    v = v * f;
                }
                if (!store && !isfinite(v)) return 0;
                if (store) out[k][b * size[k] + e] = v;
            }
    if (store)
        for (int i = 0; i < CACHE_SIZE; i++) s->cache[i].valid = 0;
    return 1;
}

static void plant_reset(void *self) {
    Plant *s = (Plant *)self;
    const UiofmuPlant *d = s->d;
    memcpy(s->x0, d->x0, (size_t)d->n * sizeof(double));
    memcpy(s->x, d->x0, (size_t)d->n * sizeof(double));
    memset(s->u, 0, (size_t)d->m * sizeof(double));
    memset(s->dv, 0, (size_t)d->q * sizeof(double));
    memset(s->wn, 0, (size_t)d->r * sizeof(double));
    s->mode_in = d->mode0;
    s->seed = d->seed;
    restart(s);
    s->mismatch = 0.0;
    s->mismatch_seed = 0;
    perturb(s, 0.0, 0, 1);
    s->dirty = 1;
}

static void *plant_instantiate(FmuInstance *fmu) {
    const UiofmuPlant *d = &UIOFMU_PLANT;
    Plant *s = (Plant *)uiofmu_alloc(fmu, 1, sizeof(Plant));
    if (!s) return NULL;
    s->fmu = fmu;
    s->d = d;
    s->K = d->n + d->m + d->q + d->r + 1;
    size_t n = (size_t)d->n, K = (size_t)s->K, kk = K * K;
    int continuous = d->time == UIOFMU_CONTINUOUS;
    size_t blocks = d->modes ? (size_t)d->modes : 1;
    size_t total = 4 * n + (size_t)d->m + (size_t)d->q + (size_t)d->r + (size_t)d->p +
                   blocks * n * (n + (size_t)d->m + (size_t)d->q) +
                   (continuous ? 9 * kk + CACHE_SIZE * n * K : 0);
    s->block = (double *)uiofmu_alloc(fmu, total, sizeof(double));
    s->piv = continuous && s->block ? (int *)uiofmu_alloc(fmu, K, sizeof(int)) : NULL;
    if (!s->block || (continuous && !s->piv)) { /* one log line said why */
        free(s->block);
        free(s->piv);
        free(s);
        return NULL;
    }
    double *b = s->block;
    s->x0 = b; b += n;
    s->x = b; b += n;
    s->tmp = b; b += 2 * n;
    s->u = b; b += d->m;
    s->dv = b; b += d->q;
    s->wn = b; b += d->r;
    s->y = b; b += d->p;
    s->A = b; b += blocks * n * n;
    s->B = b; b += blocks * n * (size_t)d->m;
    s->E = b; b += blocks * n * (size_t)d->q;
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
    if (!uiofmu_parameter_finite(s->fmu, PORT_NAME[UIOFMU_PLANT_X0], s->x0, s->d->n)) return UIOFMU_REFUSED;
    if (!(isfinite(s->mismatch) && s->mismatch >= 0)) {
        uiofmu_log(s->fmu, fmi2Error, "parameter %s = %s is not a finite number >= 0", PORT_NAME[UIOFMU_PLANT_MISMATCH],
                   uiofmu_num(s->mismatch, b1));
        return UIOFMU_REFUSED;
    }
    if (!perturb(s, s->mismatch, s->mismatch_seed, 0)) {
        uiofmu_log(s->fmu, fmi2Error, "parameter %s = %s: a perturbed entry of A, B or E is not finite",
                   PORT_NAME[UIOFMU_PLANT_MISMATCH], uiofmu_num(s->mismatch, b1));
        return UIOFMU_REFUSED;
    }
    perturb(s, s->mismatch, s->mismatch_seed, 1);
    memcpy(s->x, s->x0, (size_t)s->d->n * sizeof(double));
    restart(s);
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
        for (int j = 0; j < d->m; j++) /* zero entries skipped: without feedthrough y is C x bit for bit */
            if (d->D[(size_t)i * d->m + j] != 0.0) acc += d->D[(size_t)i * d->m + j] * s->u[j];
        for (int j = 0; j < d->q; j++)
            if (d->F[(size_t)i * d->q + j] != 0.0) acc += d->F[(size_t)i * d->q + j] * s->dv[j];
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
    case UIOFMU_PLANT_W_NOISE: return &s->wn[index];
    case UIOFMU_PLANT_Y: return &s->y[index];
    case UIOFMU_PLANT_X: return &s->x[index];
    case UIOFMU_PLANT_MISMATCH: return &s->mismatch;
    default: return NULL;
    }
}

static double plant_get_real(void *self, int port, int index) {
    const double *v = element((Plant *)self, port, index);
    return v ? *v : 0.0;
}

static void plant_set_real(void *self, int port, int index, double value) {
    double *v = PORT_CAUSALITY[port] != UIOFMU_OUTPUT ? element((Plant *)self, port, index) : NULL; /* parameters
                                                                                                        and inputs */
    if (v) *v = value;
    if (port == UIOFMU_PLANT_U || port == UIOFMU_PLANT_D) ((Plant *)self)->dirty = 1; /* y feeds them through */
}

/* The Integer ports of a switched plant: seed (parameter) and mode (input or output). */
static int plant_get_integer(void *self, int port, int index) {
    const Plant *s = (const Plant *)self;
    (void)index;
    return port == UIOFMU_PLANT_SEED ? s->seed : port == UIOFMU_PLANT_MODE ? current_mode(s)
           : port == UIOFMU_PLANT_MISMATCH_SEED ? s->mismatch_seed : 0;
}

static void plant_set_integer(void *self, int port, int index, int value) {
    Plant *s = (Plant *)self;
    (void)index;
    if (port == UIOFMU_PLANT_SEED) s->seed = value; /* taken at fmi2ExitInitializationMode */
    else if (port == UIOFMU_PLANT_MISMATCH_SEED) s->mismatch_seed = value; /* the same */
    else if (port == UIOFMU_PLANT_MODE && s->d->rule == UIOFMU_RULE_INPUT) s->mode_in = value;
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
    int n = d->n, m = d->m, q = d->q, r = d->r, K = s->K;
    double *M = s->aug;
    memset(M, 0, (size_t)K * K * sizeof(double));
    for (int i = 0; i < n; i++) {
        double *row = M + (size_t)i * K;
        for (int j = 0; j < n; j++) row[j] = s->A[(size_t)i * n + j] * h;
        for (int j = 0; j < m; j++) row[n + j] = s->B[(size_t)i * m + j] * h;
        for (int j = 0; j < q; j++) row[n + m + j] = s->E[(size_t)i * q + j] * h;
        for (int j = 0; j < r; j++) row[n + m + q + j] = d->W[(size_t)i * r + j] * h;
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

static UiofmuResult plant_step(void *self, double t, double h) {
    Plant *s = (Plant *)self;
    const UiofmuPlant *d = s->d;
    int n = d->n, m = d->m, q = d->q, r = d->r;
    char bt[32];
    if (!uiofmu_inputs_finite(s->fmu, t, -1, s->u, m, PORT_NAME[UIOFMU_PLANT_U]) ||
        !uiofmu_inputs_finite(s->fmu, t, -1, s->dv, q, PORT_NAME[UIOFMU_PLANT_D]) ||
        !uiofmu_inputs_finite(s->fmu, t, -1, s->wn, r, PORT_NAME[UIOFMU_PLANT_W_NOISE]))
        return UIOFMU_REFUSED;
    int mode = current_mode(s);
    if (!(mode >= 1 && mode <= (d->modes ? d->modes : 1))) { /* only an input can be out of range */
        uiofmu_log(s->fmu, fmi2Error, "t = %s: input %s = %d is not a mode of this plant (expected an integer from 1 "
                   "to %d)", uiofmu_num(t, bt), PORT_NAME[UIOFMU_PLANT_MODE], mode, d->modes);
        return UIOFMU_REFUSED;
    }
    double *xn = s->tmp;
    if (d->time == UIOFMU_DISCRETE) {
        if (uiofmu_off_period(s->fmu, t, h, d->dt, d->step_rtol, 0)) return UIOFMU_DISCARDED;
        size_t b = (size_t)(mode - 1); /* the mode's block of A, B, E, w */
        const double *A = s->A + b * n * n, *B = s->B + b * n * m, *E = s->E + b * n * q, *w = d->w + b * n;
        for (int i = 0; i < n; i++) {
            double ax = 0.0, bu = 0.0, ed = 0.0;
            for (int j = 0; j < n; j++) ax += A[(size_t)i * n + j] * s->x[j];
            for (int j = 0; j < m; j++) bu += B[(size_t)i * m + j] * s->u[j];
            for (int j = 0; j < q; j++) ed += E[(size_t)i * q + j] * s->dv[j];
            xn[i] = ax + bu + ed + w[i];
            if (r) {
                double wv = 0.0;
                for (int j = 0; j < r; j++) wv += d->W[(size_t)i * r + j] * s->wn[j];
                xn[i] += wv;
            }
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
            if (r) {
                double wv = 0.0;
                for (int j = 0; j < r; j++) wv += row[n + m + q + j] * s->wn[j];
                xn[i] += wv;
            }
        }
    }
    if (!uiofmu_next_state_finite(s->fmu, t, h, xn, n)) return UIOFMU_REFUSED;
    memcpy(s->x, xn, (size_t)n * sizeof(double));
    draw(s); /* rule random: the mode of the next step */
    s->dirty = 1;
    return UIOFMU_DONE;
}

/* ---------------------------------------------------------------------------------------- */
/* FMU state (layout in the header comment)                                                  */

typedef unsigned char Byte;

enum { SV_MISMATCH, SV_MISMATCH_SEED, SV_PLANT }; /* after d[q] */
enum { SV_MODE_IN, SV_SEED, SV_RNG_HI, SV_RNG_LO, SV_DRAWN, SV_SWITCHED }; /* after those, switched plants only */

static size_t mismatch_at(const UiofmuPlant *d) {
    return 1 + 2 * (size_t)d->n + (size_t)d->m + (size_t)d->q + (size_t)d->r;
}

static size_t switched_at(const UiofmuPlant *d) { return mismatch_at(d) + SV_PLANT; }

static size_t plant_state_count(void) {
    const UiofmuPlant *d = &UIOFMU_PLANT;
    return switched_at(d) + (d->modes ? SV_SWITCHED : 0);
}

static void plant_state_shape(uint32_t shape[UIOFMU_SHAPE], const char *names[UIOFMU_SHAPE]) {
    const UiofmuPlant *d = &UIOFMU_PLANT;
    static const char *const NAMES[UIOFMU_SHAPE] = {"n", "m", "p", "q"};
    const int dims[UIOFMU_SHAPE] = {d->n, d->m, d->p, d->q};
    uiofmu_shape(shape, names, dims, NAMES);
}

static void plant_save_state(void *self, int phase, Byte *o) {
    Plant *s = (Plant *)self;
    const UiofmuPlant *d = s->d;
    double ph = (double)phase;
    o = uiofmu_put(o, &ph, 1);
    o = uiofmu_put(o, s->x0, (size_t)d->n);
    o = uiofmu_put(o, s->x, (size_t)d->n);
    o = uiofmu_put(o, s->u, (size_t)d->m);
    o = uiofmu_put(o, s->dv, (size_t)d->q);
    o = uiofmu_put(o, s->wn, (size_t)d->r);
    double mm[SV_PLANT] = {s->mismatch, (double)s->mismatch_seed};
    o = uiofmu_put(o, mm, SV_PLANT);
    if (d->modes) {
        double sw[SV_SWITCHED] = {(double)s->mode_in, (double)s->seed, (double)(uint32_t)(s->rng >> 32),
                                  (double)(uint32_t)(s->rng & UINT64_C(0xFFFFFFFF)), (double)s->drawn};
        uiofmu_put(o, sw, SV_SWITCHED);
    }
}

static int plant_check_state(void *self, const char *ctx, const Byte *v, int *phase) {
    Plant *s = (Plant *)self;
    const UiofmuPlant *d = s->d;
    char b1[32], b2[32], b3[32];
    double ph = uiofmu_getd(v, 0);
    if (!uiofmu_phase_ok(s->fmu, ctx, ph) || !uiofmu_plant_x_ok(s->fmu, ctx, v, 1, d->n, ph, d->x0)) return 0;
    /* u[m], d[q], w_noise[r]: taken as they are (see the header comment) */
    double mismatch = uiofmu_getd(v, mismatch_at(d) + SV_MISMATCH);
    double mseed = uiofmu_getd(v, mismatch_at(d) + SV_MISMATCH_SEED);
    if (!(mseed == floor(mseed) && mseed >= INT_MIN && mseed <= INT_MAX))
        return uiofmu_state_refused(s->fmu, ctx, "mismatch_seed = %s is not an integer from %d to %d",
                                    uiofmu_num(mseed, b1), INT_MIN, INT_MAX);
    if (ph >= UIOFMU_PHASE_RUNNING && !(isfinite(mismatch) && mismatch >= 0))
        return uiofmu_state_refused(s->fmu, ctx, "mismatch = %s is not a finite number >= 0",
                                    uiofmu_num(mismatch, b1));
    if (ph >= UIOFMU_PHASE_RUNNING && !perturb(s, mismatch, (int)mseed, 0))
        return uiofmu_state_refused(s->fmu, ctx, "mismatch = %s makes an entry of A, B or E overflow",
                                    uiofmu_num(mismatch, b1));
    if (d->modes) {
        static const char *const NAME[SV_SWITCHED] = {"mode_in", "seed", "rng_hi", "rng_lo", "drawn"};
        const double low[SV_SWITCHED] = {INT_MIN, INT_MIN, 0, 0, 1};
        const double high[SV_SWITCHED] = {INT_MAX, INT_MAX, 4294967295.0, 4294967295.0, d->modes};
        for (int i = 0; i < SV_SWITCHED; i++) {
            double x = uiofmu_getd(v, switched_at(d) + (size_t)i);
            if (!(x == floor(x) && x >= low[i] && x <= high[i]))
                return uiofmu_state_refused(s->fmu, ctx, "%s = %s is not an integer from %s to %s", NAME[i],
                                            uiofmu_num(x, b1), uiofmu_num(low[i], b2), uiofmu_num(high[i], b3));
        }
        double drawn = uiofmu_getd(v, switched_at(d) + SV_DRAWN);
        if (d->rule != UIOFMU_RULE_RANDOM && drawn != 1)
            return uiofmu_state_refused(s->fmu, ctx, "drawn = %s, but only rule random draws modes (expected 1)",
                                        uiofmu_num(drawn, b1));
    }
    *phase = (int)ph;
    return 1;
}

static void plant_load_state(void *self, const Byte *v) {
    Plant *s = (Plant *)self;
    const UiofmuPlant *d = s->d;
    const Byte *o = v + sizeof(double);
    o = uiofmu_take(o, s->x0, (size_t)d->n);
    o = uiofmu_take(o, s->x, (size_t)d->n);
    o = uiofmu_take(o, s->u, (size_t)d->m);
    o = uiofmu_take(o, s->dv, (size_t)d->q);
    uiofmu_take(o, s->wn, (size_t)d->r);
    s->mismatch = uiofmu_getd(v, mismatch_at(d) + SV_MISMATCH);
    s->mismatch_seed = (int)uiofmu_getd(v, mismatch_at(d) + SV_MISMATCH_SEED);
    /* the matrices the steps use: perturbed once initialisation ended, the design's before */
    int running = uiofmu_getd(v, 0) >= UIOFMU_PHASE_RUNNING;
    perturb(s, running ? s->mismatch : 0.0, s->mismatch_seed, 1);
    if (d->modes) {
        size_t at = switched_at(d);
        s->mode_in = (int)uiofmu_getd(v, at + SV_MODE_IN);
        s->seed = (int)uiofmu_getd(v, at + SV_SEED);
        s->rng = ((uint64_t)uiofmu_getd(v, at + SV_RNG_HI) << 32) | (uint64_t)uiofmu_getd(v, at + SV_RNG_LO);
        s->drawn = (int)uiofmu_getd(v, at + SV_DRAWN);
    }
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
    .get_integer = plant_get_integer, /* switched plants: seed and mode */
    .set_integer = plant_set_integer,
    .step = plant_step,
    .state_count = plant_state_count,
    .state_shape = plant_state_shape,
    .save_state = plant_save_state,
    .check_state = plant_check_state,
    .load_state = plant_load_state,
};
