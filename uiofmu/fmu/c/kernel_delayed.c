/* uiofmu: the delayed observer kernel, the model code of delayed-UIO observer FMUs (seed 001).
 *
 * It plugs into the shared FMI 2.0 plumbing (fmi2_plumbing.c) through UIOFMU_KERNEL_DELAYED; the
 * design (UIOFMU_DELAYED: the plant, the gain, the delays) comes from design_data.c, generated from
 * the design card. The step semantics are those of the reference runtime
 * (uiofmu/runtime/delayed.py), operation for operation:
 *
 *   augmented system  xa = [x; x(t - tau_1); ...], Aa = I (x) A, Ba, Ca likewise, c = ndelays + 1
 *                     copies, Da = [D(y); D(y(t - tau_1)); ...], F = Ca Da, W = F'F
 *   decoupling (19)   H = -Da W^-1 F', Hdot = -Dadot W^-1 F' + Da W^-1 Wdot W^-1 F' - Da W^-1 Fdot'
 *                     (none when W's smallest eigenvalue is not above 1e-12 of its largest)
 *   observer          z' = N (z - H ya) + K ya + P Ba ua,  N = Gamma - K Ca,  P = I + H Ca,
 *                     Gamma = Hdot Ca + P Aa;  xhat = z - H ya
 *   parameters (34)   thetahat = F^+ (yadot - Ca (Aa xa + Ba ua)) (least squares)
 *   signals at s      the current and delayed y, ydot from the time-stamped buffer of past
 *                     communication points and the current one: cubic Hermite between points
 *                     (the right limit of ydot at an interval's start, the left limit, with the
 *                     jump C B du of an input change taken out, at its end), a second-order
 *                     expansion after the last, the first point before the first; u held
 *   fmi2DoStep(t, h)  while valid (from valid_from, sigma_min(F) >= sigma_bound, ||Gamma|| <=
 *                     gamma_bound): RK4 substeps of at most max_substep, (re)started from the held
 *                     estimate (z = xhat + H ya); while not valid (after the longest delay): the
 *                     model's prediction xa' = Aa xa + Ba ua + Da thetahat with RK4 substeps of at
 *                     most 1 / ||A||; the point (t, y, ydot, u) joins the buffer, which keeps the
 *                     points after the last one at or before t + h - tau
 *
 * Refusals, each with the reference runtime's message and nothing changed: a non-finite input
 * (fmi2Error); t + h that is not a time, a step needing more than MAX_SUBSTEPS substeps, a
 * buffer that would hold more than the design's rows, a step whose arithmetic overflows
 * (fmi2Discard). The runtime's notes (the rank margin lost inside a step; validity lost, once)
 * are warning lines of a step that returns fmi2OK.
 *
 * Every iteration is bounded (Jacobi sweeps, substeps, the buffer's rows): no input, however odd,
 * makes a call hang, and check_design_data and check_values check every number the kernel indexes
 * with before any of it is used.
 */
#include <float.h>
#include <limits.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2_plumbing.h"
#include "kernel_delayed.h"
#include "kernel_util.h"

/* Bounds of what a design may ask for (uiofmu/runtime/checks.py: MAX_DIM = 1000; 1 to 16 delays);
   the augmented dims n c and p c at most MAX_AUGMENTED, the buffer at most MAX_ROWS points. */
#define MAX_DIM 1000
#define MAX_DELAYS 16
#define MAX_AUGMENTED 512 /* uiofmu/fmu/c_backend.py DELAYED_MAX_AUGMENTED */
#define MAX_ROWS 262144
#define MAX_BUFFER 16777216 /* doubles of the buffer (c_backend.py DELAYED_MAX_BUFFER) */
/* Most RK4 substeps of one communication step (uiofmu/runtime/delayed.py MAX_SUBSTEPS). */
#define MAX_SUBSTEPS 10000
/* Jacobi sweeps: a few suffice for the small matrices here; the bound only stops NaN and Inf. */
#define MAX_SWEEPS 60
#define MAX_SAFE_INTEGER 9007199254740992.0 /* 2^53 */

/* The ports' names, causalities and types by id (kernel_delayed_ports.h, generated). */
static const char *const PORT_NAME[UIOFMU_DELAYED_PORTS] = UIOFMU_DELAYED_PORT_NAMES;
static const int PORT_CAUSALITY[UIOFMU_DELAYED_PORTS] = UIOFMU_DELAYED_PORT_CAUSALITIES;
static const int PORT_TYPE[UIOFMU_DELAYED_PORTS] = UIOFMU_DELAYED_PORT_TYPES;

/* What the right-hand side of the observer needs at one time: z' = N (z - Hya) + cv. */
typedef struct {
    double *N, *Hya, *cv;
} Frozen;

typedef struct {
    FmuInstance *fmu;
    const UiofmuDelayed *d;
    int n, m, p, nt, c, na, pa, ma, width, R;
    double tau, valid_from, predict_substep;
    double *CB; /* p x m */
    /* state (what fmi2GetFMUstate saves) */
    double t, k;
    int running, noted, rows;
    double *z, *xa, *thetahat, *xhat0, *y, *ydot, *u;
    double *buf; /* (R + 1) x width: t, y[p], ydot[p], u[m] of each past point, oldest first */
    /* outputs */
    int dirty, valid_out;
    double sigma_out;
    double *xhat_out, *theta_out, *r_out;
    /* work space */
    double *ya, *yad, *ua;                                    /* pa, pa, ma */
    double *Da, *Dadot, *F, *Fd, *W, *Wi, *Wd, *LU, *DW, *T1, *T2; /* na x nt, pa x nt, nt x nt */
    double *H, *Hdot;                                         /* na x pa */
    double *P, *G, *M1;                                       /* na x na */
    double *ev, *eigw;                                        /* nt, nt x nt */
    double *svdU, *svdV, *sv;                                 /* max(pa, na) x max(nt, na), its square, max */
    Frozen fr[3];
    double *zn, *xn, *th, *k1, *k2, *k3, *k4, *v1, *v2;       /* na (th: nt; v1, v2: max(na, pa)) */
    int *piv;
    void *block;
    char note[2][512]; /* the step's notes, logged when it is taken */
    int notes;
} Delayed;

/* ---------------------------------------------------------------------------------------- */
/* Small dense linear algebra (row-major)                                                    */

/* Python's max(a, b) (the first unless the second is larger: NaN stays). */
static double pymax(double a, double b) { return b > a ? b : a; }

static int all_finite(const double *v, size_t n) {
    for (size_t i = 0; i < n; i++)
        if (!isfinite(v[i])) return 0;
    return 1;
}

/* The eigenvalues of the symmetric k x k matrix a (overwritten), ascending, by cyclic Jacobi
   rotations; NaN for a matrix that is not finite. */
static void sym_eigenvalues(double *a, int k, double *ev) {
    if (!all_finite(a, (size_t)k * (size_t)k)) {
        for (int i = 0; i < k; i++) ev[i] = NAN;
        return;
    }
    for (int sweep = 0; sweep < MAX_SWEEPS; sweep++) {
        int rotated = 0;
        for (int p = 0; p < k - 1; p++)
            for (int q = p + 1; q < k; q++) {
                double apq = a[(size_t)p * k + q], app = a[(size_t)p * k + p], aqq = a[(size_t)q * k + q];
                if (apq == 0.0) continue;
                if (fabs(apq) <= DBL_EPSILON * 1e-3 * sqrt(fabs(app)) * sqrt(fabs(aqq)) || fabs(apq) < DBL_MIN) {
                    a[(size_t)p * k + q] = a[(size_t)q * k + p] = 0.0;
                    continue;
                }
                rotated = 1;
                double theta = (aqq - app) / (2.0 * apq);
                double t = fabs(theta) > 1e150 ? 0.5 / theta
                                               : (theta >= 0 ? 1.0 : -1.0) / (fabs(theta) + sqrt(theta * theta + 1.0));
                double cs = 1.0 / sqrt(t * t + 1.0), sn = t * cs;
                for (int r = 0; r < k; r++) { /* columns p, q */
                    double x = a[(size_t)r * k + p], y = a[(size_t)r * k + q];
                    a[(size_t)r * k + p] = cs * x - sn * y;
                    a[(size_t)r * k + q] = sn * x + cs * y;
                }
                for (int r = 0; r < k; r++) { /* rows p, q */
                    double x = a[(size_t)p * k + r], y = a[(size_t)q * k + r];
                    a[(size_t)p * k + r] = cs * x - sn * y;
                    a[(size_t)q * k + r] = sn * x + cs * y;
                }
                a[(size_t)p * k + q] = a[(size_t)q * k + p] = 0.0;
            }
        if (!rotated) break;
    }
    for (int i = 0; i < k; i++) ev[i] = a[(size_t)i * k + i];
    for (int i = 1; i < k; i++) /* insertion sort: k is small */
        for (int j = i; j > 0 && ev[j - 1] > ev[j]; j--) {
            double x = ev[j];
            ev[j] = ev[j - 1];
            ev[j - 1] = x;
        }
}

/* The singular values of the rows x cols matrix U (overwritten: its columns become sv_j u_j) by
   one-sided Jacobi rotations (Hestenes), V (cols x cols) the right singular vectors; 0 when U is
   not finite (nothing is computed). */
static int svd(double *U, int rows, int cols, double *V, double *sv) {
    if (!all_finite(U, (size_t)rows * (size_t)cols)) return 0;
    for (int i = 0; i < cols; i++)
        for (int j = 0; j < cols; j++) V[(size_t)i * cols + j] = i == j ? 1.0 : 0.0;
    for (int sweep = 0; sweep < MAX_SWEEPS; sweep++) {
        int rotated = 0;
        for (int i = 0; i < cols - 1; i++)
            for (int j = i + 1; j < cols; j++) {
                double alpha = 0.0, beta = 0.0, gamma = 0.0;
                for (int r = 0; r < rows; r++) {
                    double x = U[(size_t)r * cols + i], y = U[(size_t)r * cols + j];
                    alpha += x * x;
                    beta += y * y;
                    gamma += x * y;
                }
                if (gamma == 0.0 || fabs(gamma) <= DBL_EPSILON * sqrt(alpha) * sqrt(beta)) continue;
                rotated = 1;
                double zeta = (beta - alpha) / (2.0 * gamma);
                double t = fabs(zeta) > 1e150 ? 0.5 / zeta
                                              : (zeta >= 0 ? 1.0 : -1.0) / (fabs(zeta) + sqrt(1.0 + zeta * zeta));
                double cs = 1.0 / sqrt(1.0 + t * t), sn = cs * t;
                for (int r = 0; r < rows; r++) {
                    double x = U[(size_t)r * cols + i], y = U[(size_t)r * cols + j];
                    U[(size_t)r * cols + i] = cs * x - sn * y;
                    U[(size_t)r * cols + j] = sn * x + cs * y;
                }
                for (int r = 0; r < cols; r++) {
                    double x = V[(size_t)r * cols + i], y = V[(size_t)r * cols + j];
                    V[(size_t)r * cols + i] = cs * x - sn * y;
                    V[(size_t)r * cols + j] = sn * x + cs * y;
                }
            }
        if (!rotated) break;
    }
    for (int j = 0; j < cols; j++) {
        double acc = 0.0;
        for (int r = 0; r < rows; r++) acc += U[(size_t)r * cols + j] * U[(size_t)r * cols + j];
        sv[j] = sqrt(acc);
    }
    return 1;
}

/* The largest absolute value of the n numbers at v (0 for none). */
static double largest(const double *v, size_t n) {
    double big = 0.0;
    for (size_t i = 0; i < n; i++)
        if (fabs(v[i]) > big) big = fabs(v[i]);
    return big;
}

/* ||M||_2 of the rows x cols matrix M (numpy.linalg.norm(M, 2)); 0 when M is not finite (numpy's
   SVD does not converge). */
static int norm2(Delayed *s, const double *M, int rows, int cols, double *out) {
    size_t total = (size_t)rows * (size_t)cols;
    if (!all_finite(M, total)) return 0;
    double scale = largest(M, total);
    if (scale == 0.0) {
        *out = 0.0;
        return 1;
    }
    for (size_t e = 0; e < total; e++) s->svdU[e] = M[e] / scale;
    svd(s->svdU, rows, cols, s->svdV, s->sv);
    double big = 0.0;
    for (int j = 0; j < cols; j++) big = pymax(big, s->sv[j]);
    *out = big * scale;
    return 1;
}

/* numpy.linalg.lstsq(A, b, rcond=None)[0] of the rows x cols matrix A: the minimum-norm least-squares
   solution, singular values up to eps max(rows, cols) of the largest taken as 0; 0 when A or b is
   not finite (numpy's SVD does not converge). */
static int lstsq(Delayed *s, const double *A, int rows, int cols, const double *b, double *x) {
    size_t total = (size_t)rows * (size_t)cols;
    if (!all_finite(A, total) || !all_finite(b, (size_t)rows)) return 0;
    for (int j = 0; j < cols; j++) x[j] = 0.0;
    double scale = largest(A, total);
    if (scale == 0.0) return 1;
    for (size_t e = 0; e < total; e++) s->svdU[e] = A[e] / scale;
    svd(s->svdU, rows, cols, s->svdV, s->sv);
    double big = 0.0;
    for (int j = 0; j < cols; j++) big = pymax(big, s->sv[j]);
    double cut = DBL_EPSILON * (double)(rows > cols ? rows : cols) * big;
    for (int j = 0; j < cols; j++) {
        if (!(s->sv[j] > cut)) continue;
        double dot = 0.0;
        for (int r = 0; r < rows; r++) dot += s->svdU[(size_t)r * cols + j] * b[r];
        double w = dot / (s->sv[j] * s->sv[j]) / scale; /* (u_j . b) / sigma_j of A = U diag(sv) V' scale */
        for (int i = 0; i < cols; i++) x[i] += s->svdV[(size_t)i * cols + j] * w;
    }
    return 1;
}

/* The inverse of the k x k matrix W into Wi by LU with partial pivoting (LU, piv: work); 0 when a
   pivot is 0. */
static int inverse(const double *W, int k, double *Wi, double *LU, int *piv) {
    memcpy(LU, W, (size_t)k * (size_t)k * sizeof(double));
    for (int col = 0; col < k; col++) {
        int best = col;
        for (int i = col + 1; i < k; i++)
            if (fabs(LU[(size_t)i * k + col]) > fabs(LU[(size_t)best * k + col])) best = i;
        piv[col] = best;
        if (!(LU[(size_t)best * k + col] != 0.0)) return 0;
        if (best != col)
            for (int j = 0; j < k; j++) {
                double x = LU[(size_t)col * k + j];
                LU[(size_t)col * k + j] = LU[(size_t)best * k + j];
                LU[(size_t)best * k + j] = x;
            }
        for (int i = col + 1; i < k; i++) {
            double f = LU[(size_t)i * k + col] /= LU[(size_t)col * k + col];
            for (int j = col + 1; j < k; j++) LU[(size_t)i * k + j] -= f * LU[(size_t)col * k + j];
        }
    }
    for (int j = 0; j < k; j++) { /* column j of the inverse: solve LU x = P e_j */
        double *x = Wi; /* written column-wise through the stride */
        for (int i = 0; i < k; i++) x[(size_t)i * k + j] = i == j ? 1.0 : 0.0;
        for (int i = 0; i < k; i++) { /* the row exchanges, in order */
            int r = piv[i];
            if (r != i) {
                double tmp = x[(size_t)i * k + j];
                x[(size_t)i * k + j] = x[(size_t)r * k + j];
                x[(size_t)r * k + j] = tmp;
            }
        }
        for (int i = 0; i < k; i++) {
            double acc = x[(size_t)i * k + j];
            for (int l = 0; l < i; l++) acc -= LU[(size_t)i * k + l] * x[(size_t)l * k + j];
            x[(size_t)i * k + j] = acc;
        }
        for (int i = k - 1; i >= 0; i--) {
            double acc = x[(size_t)i * k + j];
            for (int l = i + 1; l < k; l++) acc -= LU[(size_t)i * k + l] * x[(size_t)l * k + j];
            x[(size_t)i * k + j] = acc / LU[(size_t)i * k + i];
        }
    }
    return 1;
}

/* C = A B, A r x q, B q x c (C may not alias A or B). */
static void matmul(const double *A, const double *B, double *C, int r, int q, int c) {
    for (int i = 0; i < r; i++) {
        double *row = C + (size_t)i * c;
        for (int j = 0; j < c; j++) row[j] = 0.0;
        for (int l = 0; l < q; l++) {
            double a = A[(size_t)i * q + l];
            const double *b = B + (size_t)l * c;
            for (int j = 0; j < c; j++) row[j] += a * b[j];
        }
    }
}

/* C = A B', A r x q, B c x q. */
static void matmul_t(const double *A, const double *B, double *C, int r, int q, int c) {
    for (int i = 0; i < r; i++)
        for (int j = 0; j < c; j++) {
            double acc = 0.0;
            for (int l = 0; l < q; l++) acc += A[(size_t)i * q + l] * B[(size_t)j * q + l];
            C[(size_t)i * c + j] = acc;
        }
}

/* out = X Ca (X r x pa, Ca = I_c (x) C: pa x na), block by block. */
static void times_ca(const Delayed *s, const double *X, int r, double *out) {
    const double *C = s->d->C;
    for (int i = 0; i < r; i++)
        for (int b = 0; b < s->c; b++)
            for (int col = 0; col < s->n; col++) {
                double acc = 0.0;
                for (int l = 0; l < s->p; l++) acc += X[(size_t)i * s->pa + (size_t)b * s->p + l] * C[(size_t)l * s->n + col];
                out[(size_t)i * s->na + (size_t)b * s->n + col] = acc;
            }
}

/* ---------------------------------------------------------------------------------------- */
/* The signals at any time: the buffer's points and the current one                          */

static int points(const Delayed *s) { return s->rows + 1; }
static double time_at(const Delayed *s, int i) { return i < s->rows ? s->buf[(size_t)i * s->width] : s->t; }
static const double *y_at(const Delayed *s, int i) {
    return i < s->rows ? s->buf + (size_t)i * s->width + 1 : s->y;
}
static const double *yd_at(const Delayed *s, int i) {
    return i < s->rows ? s->buf + (size_t)i * s->width + 1 + s->p : s->ydot;
}
static const double *u_at(const Delayed *s, int i) {
    return i < s->rows ? s->buf + (size_t)i * s->width + 1 + 2 * (size_t)s->p : s->u;
}

/* ydot's left limit at point i, element j: before the input changed there (ydot jumps by C B du). */
static double left_at(const Delayed *s, int i, int j) {
    double v = yd_at(s, i)[j];
    if (i == 0) return v;
    const double *u1 = u_at(s, i), *u0 = u_at(s, i - 1);
    double acc = 0.0;
    for (int l = 0; l < s->m; l++) acc += (u1[l] - u0[l]) * s->CB[(size_t)j * s->m + l];
    return v - acc;
}

/* How many points have a time <= at (numpy.searchsorted(times, at, side="right")). */
static int count_upto(const Delayed *s, double at) {
    int lo = 0, hi = points(s);
    while (lo < hi) {
        int mid = lo + (hi - lo) / 2;
        if (time_at(s, mid) <= at) lo = mid + 1;
        else hi = mid;
    }
    return lo;
}

/* y(at) and ydot(at) (uiofmu.runtime.delayed.hermite) into y[p], yd[p]. */
static void hermite(const Delayed *s, double at, double *y, double *yd) {
    int last = points(s) - 1, p = s->p;
    double tl = time_at(s, last);
    if (at >= tl) {
        double d = at - tl;
        const double *ys = y_at(s, last), *ds = yd_at(s, last);
        if (last == 0) {
            for (int j = 0; j < p; j++) {
                y[j] = ys[j] + ds[j] * d;
                yd[j] = ds[j];
            }
            return;
        }
        double span = tl - time_at(s, last - 1);
        const double *before = yd_at(s, last - 1);
        for (int j = 0; j < p; j++) {
            double ydd = (left_at(s, last, j) - before[j]) / span;
            y[j] = ys[j] + ds[j] * d + 0.5 * ydd * d * d;
            yd[j] = ds[j] + ydd * d;
        }
        return;
    }
    if (at <= time_at(s, 0) || last == 0) {
        memcpy(y, y_at(s, 0), (size_t)p * sizeof(double));
        memcpy(yd, yd_at(s, 0), (size_t)p * sizeof(double));
        return;
    }
    int j = count_upto(s, at) - 1;
    if (j < 0) j = 0;
    if (j > last - 1) j = last - 1;
    double h = time_at(s, j + 1) - time_at(s, j);
    double x = (at - time_at(s, j)) / h, x2 = x * x, x3 = x * x * x;
    const double *y0 = y_at(s, j), *y1 = y_at(s, j + 1), *d0 = yd_at(s, j);
    for (int e = 0; e < p; e++) {
        double ya = y0[e], yb = y1[e], da = d0[e] * h, db = left_at(s, j + 1, e) * h;
        y[e] = (2 * x3 - 3 * x2 + 1) * ya + (x3 - 2 * x2 + x) * da + (-2 * x3 + 3 * x2) * yb + (x3 - x2) * db;
        yd[e] = ((6 * x2 - 6 * x) * ya + (3 * x2 - 4 * x + 1) * da + (-6 * x2 + 6 * x) * yb + (3 * x2 - 2 * x) * db) /
                h;
    }
}

/* ya, yad, ua at time at: the current and delayed signals stacked. */
static void augmented_at(Delayed *s, double at) {
    for (int i = 0; i < s->c; i++) {
        double tau = i == 0 ? 0.0 : s->d->delays[i - 1];
        double when = at - tau;
        hermite(s, when, s->ya + (size_t)i * s->p, s->yad + (size_t)i * s->p);
        int j = count_upto(s, when) - 1;
        memcpy(s->ua + (size_t)i * s->m, u_at(s, j > 0 ? j : 0), (size_t)s->m * sizeof(double));
    }
}

/* ---------------------------------------------------------------------------------------- */
/* The decoupling at the signals ya, yad                                                      */

/* Da and Dadot of the signals (stacked(): the sum over the outputs first, then D0). */
static void stacked(Delayed *s) {
    const UiofmuDelayed *d = s->d;
    int n = s->n, nt = s->nt, p = s->p;
    for (int i = 0; i < s->c; i++)
        for (int r = 0; r < n; r++)
            for (int q = 0; q < nt; q++) {
                double acc = 0.0, accd = 0.0;
                for (int l = 0; l < p; l++) {
                    double w = d->Dy[((size_t)l * n + r) * nt + q];
                    acc += s->ya[(size_t)i * p + l] * w;
                    accd += s->yad[(size_t)i * p + l] * w;
                }
                s->Da[((size_t)i * n + r) * nt + q] = acc + d->D0[(size_t)r * nt + q];
                s->Dadot[((size_t)i * n + r) * nt + q] = accd;
            }
}

/* X = Ca Y for Y na x nt (F = Ca Da, Fdot = Ca Dadot). */
static void ca_times(const Delayed *s, const double *Y, double *X) {
    const double *C = s->d->C;
    int n = s->n, nt = s->nt, p = s->p;
    for (int i = 0; i < s->c; i++)
        for (int l = 0; l < p; l++)
            for (int q = 0; q < nt; q++) {
                double acc = 0.0;
                for (int r = 0; r < n; r++) acc += C[(size_t)l * n + r] * Y[((size_t)i * n + r) * nt + q];
                X[((size_t)i * p + l) * nt + q] = acc;
            }
}

/* decoupling(): Da, F, sigma_min(F) always; H (and Hdot, Gamma when `rates`) when W is invertible
   to working precision. Returns 1 with H, 0 without. */
static int decoupling(Delayed *s, int rates, double *sigma) {
    int nt = s->nt, na = s->na, pa = s->pa;
    stacked(s);
    ca_times(s, s->Da, s->F);
    for (int a = 0; a < nt; a++) /* W = F'F */
        for (int b = 0; b < nt; b++) {
            double acc = 0.0;
            for (int r = 0; r < pa; r++) acc += s->F[(size_t)r * nt + a] * s->F[(size_t)r * nt + b];
            s->W[(size_t)a * nt + b] = acc;
        }
    double e0 = 0.0, elast = 0.0;
    if (pa >= nt) {
        memcpy(s->eigw, s->W, (size_t)nt * (size_t)nt * sizeof(double));
        sym_eigenvalues(s->eigw, nt, s->ev);
        e0 = s->ev[0];
        elast = s->ev[nt - 1];
    }
    *sigma = sqrt(pymax(e0, 0.0));
    if (!(e0 > 1e-12 * pymax(elast, 1e-300))) return 0;
    if (!inverse(s->W, nt, s->Wi, s->LU, s->piv)) return 0;
    matmul(s->Da, s->Wi, s->DW, na, nt, nt);
    matmul_t(s->DW, s->F, s->H, na, nt, pa);
    for (size_t e = 0; e < (size_t)na * pa; e++) s->H[e] = -s->H[e];
    if (!rates) return 1;
    ca_times(s, s->Dadot, s->Fd);
    for (int a = 0; a < nt; a++) /* Wd = Fd'F + F'Fd */
        for (int b = 0; b < nt; b++) {
            double x = 0.0, y = 0.0;
            for (int r = 0; r < pa; r++) {
                x += s->Fd[(size_t)r * nt + a] * s->F[(size_t)r * nt + b];
                y += s->F[(size_t)r * nt + a] * s->Fd[(size_t)r * nt + b];
            }
            s->Wd[(size_t)a * nt + b] = x + y;
        }
    /* Hdot = -Dadot Wi F' + ((Da Wi) Wd) Wi F' - (Da Wi) Fd' */
    matmul(s->Dadot, s->Wi, s->T1, na, nt, nt);
    matmul_t(s->T1, s->F, s->Hdot, na, nt, pa);
    matmul(s->DW, s->Wd, s->T1, na, nt, nt);
    matmul(s->T1, s->Wi, s->T2, na, nt, nt);
    matmul_t(s->T2, s->F, s->M1, na, nt, pa);
    for (size_t e = 0; e < (size_t)na * pa; e++) s->Hdot[e] = -s->Hdot[e] + s->M1[e];
    matmul_t(s->DW, s->Fd, s->M1, na, nt, pa);
    for (size_t e = 0; e < (size_t)na * pa; e++) s->Hdot[e] -= s->M1[e];
    /* Gamma = Hdot Ca + P Aa, P = I + H Ca */
    times_ca(s, s->H, na, s->P);
    for (int i = 0; i < na; i++) s->P[(size_t)i * na + i] += 1.0;
    times_ca(s, s->Hdot, na, s->G);
    const double *A = s->d->A;
    int n = s->n;
    for (int i = 0; i < na; i++)
        for (int b = 0; b < s->c; b++)
            for (int col = 0; col < n; col++) {
                double acc = 0.0;
                for (int l = 0; l < n; l++) acc += s->P[(size_t)i * na + (size_t)b * n + l] * A[(size_t)l * n + col];
                s->G[(size_t)i * na + (size_t)b * n + col] += acc;
            }
    return 1;
}

/* v = Aa x (block by block). */
static void aa_times(const Delayed *s, const double *x, double *v) {
    const double *A = s->d->A;
    int n = s->n;
    for (int b = 0; b < s->c; b++)
        for (int r = 0; r < n; r++) {
            double acc = 0.0;
            for (int l = 0; l < n; l++) acc += A[(size_t)r * n + l] * x[(size_t)b * n + l];
            v[(size_t)b * n + r] = acc;
        }
}

/* v = Ba ua. */
static void ba_ua(const Delayed *s, double *v) {
    const double *B = s->d->B;
    int n = s->n, m = s->m;
    for (int b = 0; b < s->c; b++)
        for (int r = 0; r < n; r++) {
            double acc = 0.0;
            for (int l = 0; l < m; l++) acc += B[(size_t)r * m + l] * s->ua[(size_t)b * m + l];
            v[(size_t)b * n + r] = acc;
        }
}

/* ---------------------------------------------------------------------------------------- */
/* Validity and outputs at the current point                                                  */

/* sigma_min(Ca Da) and ||Gamma||_2 now (0 and inf before every delayed signal exists, or without
   H); 0 when ||Gamma|| cannot be computed (numpy's SVD would not converge). */
static int signals(Delayed *s, double *sigma, double *size) {
    if (s->t < s->tau) {
        *sigma = 0.0;
        *size = INFINITY;
        return 1;
    }
    augmented_at(s, s->t);
    if (!decoupling(s, 1, sigma)) {
        *size = INFINITY;
        return 1;
    }
    return norm2(s, s->G, s->na, s->na, size);
}

/* Whether the estimates are valid now (-1: ||Gamma|| cannot be computed). */
static int valid_now(Delayed *s) {
    double sigma, size;
    if (s->t < s->valid_from) return 0;
    if (!signals(s, &sigma, &size)) return -1;
    return sigma >= s->d->sigma_bound && size <= (s->d->has_gamma_bound ? s->d->gamma_bound : INFINITY);
}

/* The augmented estimate now into out (held while not running). */
static void xhat_augmented(Delayed *s, double *out) {
    double sigma;
    if (s->running) {
        augmented_at(s, s->t);
        if (decoupling(s, 0, &sigma)) {
            for (int i = 0; i < s->na; i++) {
                double acc = 0.0;
                for (int j = 0; j < s->pa; j++) acc += s->H[(size_t)i * s->pa + j] * s->ya[j];
                out[i] = s->z[i] - acc;
            }
            return;
        }
    }
    memcpy(out, s->xa, (size_t)s->na * sizeof(double));
}

/* thetahat now into out ((34) while running and valid, the held one otherwise); 0 when the least
   squares cannot be computed. valid: valid_now(). */
static int theta_now(Delayed *s, int valid, double *out) {
    double sigma;
    if (!(s->running && valid)) {
        memcpy(out, s->thetahat, (size_t)s->nt * sizeof(double));
        return 1;
    }
    xhat_augmented(s, s->xn);
    augmented_at(s, s->t);
    decoupling(s, 0, &sigma); /* F */
    aa_times(s, s->xn, s->v1);
    ba_ua(s, s->v2);
    for (int i = 0; i < s->na; i++) s->v1[i] += s->v2[i];
    for (int b = 0; b < s->c; b++) /* rhs = yad - Ca (Aa xa + Ba ua), into v2 */
        for (int l = 0; l < s->p; l++) {
            double acc = 0.0;
            for (int r = 0; r < s->n; r++) acc += s->d->C[(size_t)l * s->n + r] * s->v1[(size_t)b * s->n + r];
            s->v2[(size_t)b * s->p + l] = s->yad[(size_t)b * s->p + l] - acc;
        }
    return lstsq(s, s->F, s->pa, s->nt, s->v2, out);
}

static void refresh(Delayed *s) {
    if (!s->dirty) return;
    double sigma, size;
    int valid = valid_now(s);
    xhat_augmented(s, s->xn);
    memcpy(s->xhat_out, s->xn, (size_t)s->n * sizeof(double));
    if (valid < 0 || !theta_now(s, valid, s->theta_out))
        for (int i = 0; i < s->nt; i++) s->theta_out[i] = NAN;
    for (int l = 0; l < s->p; l++) {
        double acc = 0.0;
        for (int r = 0; r < s->n; r++) acc += s->d->C[(size_t)l * s->n + r] * s->xhat_out[r];
        s->r_out[l] = s->y[l] - acc;
    }
    if (!signals(s, &sigma, &size)) sigma = NAN;
    s->sigma_out = sigma;
    s->valid_out = valid > 0;
    s->dirty = 0;
}

/* ---------------------------------------------------------------------------------------- */
/* The step                                                                                   */

/* frozen(): what the observer's right-hand side needs at time at; 0 when the rank is lost. */
static int frozen(Delayed *s, double at, Frozen *f) {
    double sigma;
    int na = s->na, pa = s->pa;
    augmented_at(s, at);
    if (!decoupling(s, 1, &sigma)) return 0;
    times_ca(s, s->d->K, na, s->M1); /* K Ca */
    for (size_t e = 0; e < (size_t)na * na; e++) f->N[e] = s->G[e] - s->M1[e];
    ba_ua(s, s->v1);
    for (int i = 0; i < na; i++) {
        double hy = 0.0, ky = 0.0, pb = 0.0;
        for (int j = 0; j < pa; j++) {
            hy += s->H[(size_t)i * pa + j] * s->ya[j];
            ky += s->d->K[(size_t)i * pa + j] * s->ya[j];
        }
        for (int j = 0; j < na; j++) pb += s->P[(size_t)i * na + j] * s->v1[j];
        f->Hya[i] = hy;
        f->cv[i] = ky + pb;
    }
    return 1;
}

/* out = N (z - Hya) + cv. */
static void rhs(const Delayed *s, const Frozen *f, const double *z, double *tmp, double *out) {
    int na = s->na;
    for (int i = 0; i < na; i++) tmp[i] = z[i] - f->Hya[i];
    for (int i = 0; i < na; i++) {
        double acc = 0.0;
        for (int j = 0; j < na; j++) acc += f->N[(size_t)i * na + j] * tmp[j];
        out[i] = acc + f->cv[i];
    }
}

/* The model's right-hand side Aa x + Ba ua + Da theta at time at. */
static void model_rhs(Delayed *s, double at, const double *x, const double *theta, double *out) {
    augmented_at(s, at);
    stacked(s);
    aa_times(s, x, out);
    ba_ua(s, s->v1);
    for (int i = 0; i < s->na; i++) {
        double acc = 0.0;
        for (int q = 0; q < s->nt; q++) acc += s->Da[(size_t)i * s->nt + q] * theta[q];
        out[i] = out[i] + s->v1[i] + acc;
    }
}

/* The substeps of at most `longest` that cover h (uiofmu.runtime.stepping.substeps), or 0 after the
   fmi2Discard line. */
static int substeps(Delayed *s, double tm, double h, double longest, const char *what) {
    char bt[32];
    double count = h / longest - 1e-9;
    if (!(count <= MAX_SUBSTEPS)) {
        uiofmu_log(s->fmu, fmi2Discard, "t = %s: communication step h = %.6g s needs %.3g %s (at most %.3g s each), "
                   "more than the %d a step may take: take steps of at most %.6g s", uiofmu_num(tm, bt), h,
                   count + 1e-9, what, longest, MAX_SUBSTEPS, MAX_SUBSTEPS * longest);
        return 0;
    }
    int steps = (int)ceil(count);
    return steps > 1 ? steps : 1;
}

/* The fmi2Discard line of a step whose arithmetic overflows (the runtime's _overflow). */
static UiofmuResult overflow(Delayed *s, double tm, const char *what) {
    char bt[32];
    uiofmu_log(s->fmu, fmi2Discard, "t = %s: step %.0f at t = %.6g s: the observer's arithmetic overflows on these "
               "inputs and its buffer of past outputs (%s); nothing changed", uiofmu_num(tm, bt), s->k, s->t, what);
    return UIOFMU_DISCARDED;
}

static const char SVD_FAILED[] = "LinAlgError: SVD did not converge";
static const char LSTSQ_FAILED[] = "LinAlgError: SVD did not converge in Linear Least Squares";

static UiofmuResult delayed_step(void *self, double tm, double h) {
    Delayed *s = (Delayed *)self;
    const UiofmuDelayed *d = s->d;
    char bt[32], bh[32];
    int na = s->na;
    long k = s->k <= (double)LONG_MAX ? (long)s->k : LONG_MAX;
    if (!uiofmu_inputs_finite(s->fmu, tm, k, s->y, s->p, PORT_NAME[UIOFMU_DELAYED_Y]) ||
        !uiofmu_inputs_finite(s->fmu, tm, k, s->ydot, s->p, PORT_NAME[UIOFMU_DELAYED_YDOT]) ||
        !uiofmu_inputs_finite(s->fmu, tm, k, s->u, s->m, PORT_NAME[UIOFMU_DELAYED_U]))
        return UIOFMU_REFUSED;
    double t0 = s->t, end = t0 + h;
    if (!isfinite(end)) {
        uiofmu_log(s->fmu, fmi2Discard, "t = %s: t + h = %s is not a time", uiofmu_num(tm, bt), uiofmu_num(end, bh));
        return UIOFMU_DISCARDED;
    }
    /* the points the buffer keeps after the step: from the last one at or before end - tau */
    int from = count_upto(s, end - s->tau) - 1;
    int kept = points(s) - (from > 0 ? from : 0);
    if (kept > s->R) {
        uiofmu_log(s->fmu, fmi2Discard, "t = %s: step %.0f at t = %.6g s: the delay buffer would hold %d points, more "
                   "than the %d it keeps (steps must average at least %.3g s over the longest delay, %.6g s); nothing "
                   "changed", uiofmu_num(tm, bt), s->k, t0, kept, s->R, s->tau / s->R, s->tau);
        return UIOFMU_DISCARDED;
    }
    int valid = valid_now(s);
    if (valid < 0) return overflow(s, tm, SVD_FAILED);
    xhat_augmented(s, s->xn);
    if (!theta_now(s, valid, s->th)) return overflow(s, tm, LSTSQ_FAILED);
    memcpy(s->zn, s->z, (size_t)na * sizeof(double));
    s->notes = 0;
    int steps = 0;
    if (valid) {
        steps = substeps(s, tm, h, d->max_substep, "RK4 substeps of the observer");
        if (!steps) return UIOFMU_DISCARDED;
    }
    int running = steps > 0, vanished = 0;
    if (steps && !s->running) { /* start, or restart from the predicted estimate */
        double sigma;
        augmented_at(s, t0);
        if (decoupling(s, 0, &sigma))
            for (int i = 0; i < na; i++) {
                double acc = 0.0;
                for (int j = 0; j < s->pa; j++) acc += s->H[(size_t)i * s->pa + j] * s->ya[j];
                s->zn[i] = s->xn[i] + acc;
            }
        else
            vanished = 1;
    }
    if (!steps && t0 >= s->tau) { /* the model's prediction */
        int count = substeps(s, tm, h, s->predict_substep, "RK4 substeps of the model's prediction");
        if (!count) return UIOFMU_DISCARDED;
        double dt = h / count;
        double *x = s->xn, *tmp = s->v2;
        for (int i = 0; i < count; i++) {
            double at = t0 + i * dt;
            model_rhs(s, at, x, s->th, s->k1);
            for (int e = 0; e < na; e++) tmp[e] = x[e] + dt / 2 * s->k1[e];
            model_rhs(s, at + dt / 2, tmp, s->th, s->k2);
            for (int e = 0; e < na; e++) tmp[e] = x[e] + dt / 2 * s->k2[e];
            model_rhs(s, at + dt / 2, tmp, s->th, s->k3);
            for (int e = 0; e < na; e++) tmp[e] = x[e] + dt * s->k3[e];
            model_rhs(s, at + dt, tmp, s->th, s->k4);
            for (int e = 0; e < na; e++) x[e] = x[e] + dt / 6 * (s->k1[e] + 2 * s->k2[e] + 2 * s->k3[e] + s->k4[e]);
        }
    }
    if (steps && !vanished) {
        double dt = h / steps, *z = s->zn, *tmp = s->v2, *arg = s->k4;
        Frozen *start = &s->fr[0], *mid = &s->fr[1], *last = &s->fr[2];
        if (!frozen(s, t0, start)) vanished = 1;
        for (int i = 0; i < steps && !vanished; i++) {
            double at = t0 + i * dt;
            if (!frozen(s, at + dt / 2, mid) || !frozen(s, at + dt, last)) {
                vanished = 1;
                break;
            }
            rhs(s, start, z, tmp, s->k1);
            for (int e = 0; e < na; e++) arg[e] = z[e] + dt / 2 * s->k1[e];
            rhs(s, mid, arg, tmp, s->k2);
            for (int e = 0; e < na; e++) arg[e] = z[e] + dt / 2 * s->k2[e];
            rhs(s, mid, arg, tmp, s->k3);
            for (int e = 0; e < na; e++) arg[e] = z[e] + dt * s->k3[e];
            rhs(s, last, arg, tmp, s->v1);
            for (int e = 0; e < na; e++) z[e] = z[e] + dt / 6 * (s->k1[e] + 2 * s->k2[e] + 2 * s->k3[e] + s->v1[e]);
            Frozen swap = *start; /* start = end */
            *start = *last;
            *last = swap;
        }
    }
    if (vanished) {
        memcpy(s->zn, s->z, (size_t)na * sizeof(double));
        running = 0;
        snprintf(s->note[s->notes++], sizeof s->note[0], "t = %.6g s: the rank margin vanished inside the step; the "
                 "estimates are held from here", t0);
    }
    if (!all_finite(s->xn, (size_t)na) || !all_finite(s->th, (size_t)s->nt) || !all_finite(s->zn, (size_t)na))
        return overflow(s, tm, "the new estimate is not finite");
    if (!valid && !s->noted && t0 >= s->valid_from) {
        double sigma, size;
        if (!signals(s, &sigma, &size)) return overflow(s, tm, SVD_FAILED);
        s->noted = 1;
        char why[256];
        if (sigma < d->sigma_bound)
            snprintf(why, sizeof why, "rank margin sigma_min(C D_y) = %.3g below the premise bound %.3g", sigma,
                     d->sigma_bound);
        else
            snprintf(why, sizeof why, "||Gamma|| = %.3g above the largest of the premise points certified, %.3g", size,
                     d->has_gamma_bound ? d->gamma_bound : INFINITY);
        snprintf(s->note[s->notes++], sizeof s->note[0], "t = %.6g s: %s: the estimates are not certified while it "
                 "is, thetahat is held (noted once)", t0, why);
    }
    /* the point joins the buffer, which drops the points before the last one at or before end - tau */
    double *row = s->buf + (size_t)s->rows * s->width;
    row[0] = t0;
    memcpy(row + 1, s->y, (size_t)s->p * sizeof(double));
    memcpy(row + 1 + s->p, s->ydot, (size_t)s->p * sizeof(double));
    memcpy(row + 1 + 2 * (size_t)s->p, s->u, (size_t)s->m * sizeof(double));
    int total = s->rows + 1, first = 0;
    for (int i = 0; i < total; i++)
        if (s->buf[(size_t)i * s->width] <= end - s->tau) first = i;
    if (first > 0) memmove(s->buf, s->buf + (size_t)first * s->width, (size_t)(total - first) * s->width * sizeof(double));
    s->rows = total - first;
    memset(s->buf + (size_t)s->rows * s->width, 0, (size_t)(s->R + 1 - s->rows) * s->width * sizeof(double));
    memcpy(s->xa, s->xn, (size_t)na * sizeof(double));
    memcpy(s->thetahat, s->th, (size_t)s->nt * sizeof(double));
    memcpy(s->z, s->zn, (size_t)na * sizeof(double));
    s->running = running;
    s->t = end;
    s->k += 1;
    s->dirty = 1;
    for (int i = 0; i < s->notes; i++) uiofmu_log(s->fmu, fmi2Warning, "t = %s: %s", uiofmu_num(tm, bt), s->note[i]);
    return UIOFMU_DONE;
}

/* ---------------------------------------------------------------------------------------- */
/* The design, checked once at fmi2Instantiate: everything the runtime later indexes with.   */

static int check_design_data(const UiofmuDelayed *d, char *msg, size_t len) {
    const int dims[4] = {d->n, d->m, d->p, d->nt}, low[4] = {1, 0, 1, 1};
    const char *const dim_name[4] = {"n", "m", "p", "n_theta"};
    if (!uiofmu_check_dims(msg, len, "dims.", 4, dims, dim_name, low, MAX_DIM)) return 0;
    if (d->ndelays < 1 || d->ndelays > MAX_DELAYS)
        return uiofmu_design_error(msg, len, "%d delays: expected 1 to %d", d->ndelays, MAX_DELAYS);
    size_t c = (size_t)d->ndelays + 1, n = (size_t)d->n, m = (size_t)d->m, p = (size_t)d->p, nt = (size_t)d->nt;
    if (n * c > MAX_AUGMENTED || p * c > MAX_AUGMENTED || m * c > MAX_AUGMENTED)
        return uiofmu_design_error(msg, len, "the augmented system (n, m, p) (len(delays) + 1) = (%zu, %zu, %zu) is "
                                   "larger than %d", n * c, m * c, p * c, MAX_AUGMENTED);
    if (d->rows < 2 || d->rows > MAX_ROWS || (size_t)(d->rows + 1) * (1 + 2 * p + m) > MAX_BUFFER)
        return uiofmu_design_error(msg, len, "a buffer of %d points of %zu numbers: expected 2 to %d points and at most "
                                   "%d numbers", d->rows, 1 + 2 * p + m, MAX_ROWS, MAX_BUFFER);
    if (!(isfinite(d->max_substep) && d->max_substep > 0) || !(isfinite(d->sigma_bound) && d->sigma_bound >= 0) ||
        !(isfinite(d->valid_from) && d->valid_from >= 0) || (d->has_gamma_bound != 0 && d->has_gamma_bound != 1) ||
        (d->has_gamma_bound && !(isfinite(d->gamma_bound) && d->gamma_bound > 0)))
        return uiofmu_design_error(msg, len, "max_substep = %g, sigma_bound = %g, valid_from = %g, gamma_bound = %g "
                                   "(%d): expected max_substep > 0, sigma_bound >= 0, valid_from >= 0 and, when given, "
                                   "gamma_bound > 0, all finite", d->max_substep, d->sigma_bound, d->valid_from,
                                   d->gamma_bound, d->has_gamma_bound);
    if (!uiofmu_check_array(msg, len, "", "A", d->A, d->A_length, n * n) ||
        !uiofmu_check_array(msg, len, "", "B", d->B, d->B_length, n * m) ||
        !uiofmu_check_array(msg, len, "", "C", d->C, d->C_length, p * n) ||
        !uiofmu_check_array(msg, len, "", "D0", d->D0, d->D0_length, n * nt) ||
        !uiofmu_check_array(msg, len, "", "Dy", d->Dy, d->Dy_length, p * n * nt) ||
        !uiofmu_check_array(msg, len, "", "K", d->K, d->K_length, n * c * p * c) ||
        !uiofmu_check_array(msg, len, "", "delays", d->delays, d->delays_length, c - 1) ||
        !uiofmu_check_array(msg, len, "", "xhat0", d->xhat0, d->xhat0_length, n))
        return 0;
    for (int i = 0; i < d->ndelays; i++)
        if (!(d->delays[i] > 0) || (i && !(d->delays[i] > d->delays[i - 1])))
            return uiofmu_design_error(msg, len, "delays[%d] = %g: expected increasing delays > 0", i + 1, d->delays[i]);
    return 1;
}

/* ---------------------------------------------------------------------------------------- */
/* The kernel's operations (UiofmuKernel)                                                    */

static int delayed_check_design(char *msg, size_t len) { return check_design_data(&UIOFMU_DELAYED, msg, len); }

static int delayed_port(int id, UiofmuPort *out) {
    const UiofmuDelayed *d = &UIOFMU_DELAYED;
    int size;
    switch (id) {
    case UIOFMU_DELAYED_XHAT0: case UIOFMU_DELAYED_XHAT: size = d->n; break;
    case UIOFMU_DELAYED_Y: case UIOFMU_DELAYED_YDOT: case UIOFMU_DELAYED_R: size = d->p; break;
    case UIOFMU_DELAYED_U: size = d->m; break;
    case UIOFMU_DELAYED_THETAHAT: size = d->nt; break;
    case UIOFMU_DELAYED_SIGMA_MIN: case UIOFMU_DELAYED_VALID: size = 1; break;
    default: return 0;
    }
    out->name = PORT_NAME[id];
    out->size = size;
    out->causality = PORT_CAUSALITY[id];
    out->type = PORT_TYPE[id];
    return 1;
}

/* Back to t = 0: the estimate xhat0 (and its delayed copies), an empty buffer, not running. */
static void reset_state(Delayed *s) {
    s->t = 0.0;
    s->k = 0.0;
    s->running = s->noted = 0;
    s->rows = 0;
    for (int b = 0; b < s->c; b++) memcpy(s->xa + (size_t)b * s->n, s->xhat0, (size_t)s->n * sizeof(double));
    memset(s->z, 0, (size_t)s->na * sizeof(double));
    memset(s->thetahat, 0, (size_t)s->nt * sizeof(double));
    memset(s->buf, 0, (size_t)(s->R + 1) * s->width * sizeof(double));
    s->dirty = 1;
}

static void *delayed_instantiate(FmuInstance *fmu) {
    const UiofmuDelayed *d = &UIOFMU_DELAYED;
    Delayed *s = (Delayed *)uiofmu_alloc(fmu, 1, sizeof(Delayed));
    if (!s) return NULL;
    s->fmu = fmu;
    s->d = d;
    s->n = d->n;
    s->m = d->m;
    s->p = d->p;
    s->nt = d->nt;
    s->c = d->ndelays + 1;
    s->na = s->n * s->c;
    s->pa = s->p * s->c;
    s->ma = s->m * s->c;
    s->width = 1 + 2 * s->p + s->m;
    s->R = d->rows;
    s->tau = d->delays[d->ndelays - 1];
    s->valid_from = pymax(d->valid_from, s->tau);
    /* every count below is bounded by the checked design (augmented dims <= MAX_AUGMENTED) */
    size_t n = (size_t)s->n, m = (size_t)s->m, p = (size_t)s->p, nt = (size_t)s->nt, na = (size_t)s->na,
           pa = (size_t)s->pa, ma = (size_t)s->ma, big = pa > na ? pa : na, wide = nt > na ? nt : na;
    size_t sizes[] = {p * m,                                                  /* CB */
                      na, na, nt, n, p, p, m,                                 /* z, xa, thetahat, xhat0, y, ydot, u */
                      (size_t)(s->R + 1) * (size_t)s->width,                  /* buf */
                      n, nt, p,                                               /* outputs */
                      pa, pa, ma,                                             /* ya, yad, ua */
                      na * nt, na * nt, pa * nt, pa * nt, nt * nt, nt * nt, nt * nt, nt * nt, na * nt, na * nt, na * nt,
                      na * pa, na * pa, na * na, na * na, na * pa > na * na ? na * pa : na * na, /* H .. M1 */
                      nt, nt * nt,                                            /* ev, eigw */
                      big * wide, wide * wide, wide,                          /* svd */
                      na * na, na, na, na * na, na, na, na * na, na, na,      /* three Frozen */
                      na, na, nt, na, na, na, na, big, big};                  /* zn .. v2 */
    size_t total = 0;
    for (size_t i = 0; i < UIOFMU_LENGTH(sizes); i++) total += sizes[i] ? sizes[i] : 1;
    double *b = (double *)uiofmu_alloc(fmu, total, sizeof(double));
    s->piv = (int *)uiofmu_alloc(fmu, nt, sizeof(int));
    if (!b || !s->piv) {
        free(b);
        free(s->piv);
        free(s);
        return NULL;
    }
    s->block = b;
    double **slots[] = {&s->CB, &s->z, &s->xa, &s->thetahat, &s->xhat0, &s->y, &s->ydot, &s->u, &s->buf,
                        &s->xhat_out, &s->theta_out, &s->r_out, &s->ya, &s->yad, &s->ua,
                        &s->Da, &s->Dadot, &s->F, &s->Fd, &s->W, &s->Wi, &s->Wd, &s->LU, &s->DW, &s->T1, &s->T2,
                        &s->H, &s->Hdot, &s->P, &s->G, &s->M1, &s->ev, &s->eigw, &s->svdU, &s->svdV, &s->sv,
                        &s->fr[0].N, &s->fr[0].Hya, &s->fr[0].cv, &s->fr[1].N, &s->fr[1].Hya, &s->fr[1].cv,
                        &s->fr[2].N, &s->fr[2].Hya, &s->fr[2].cv,
                        &s->zn, &s->xn, &s->th, &s->k1, &s->k2, &s->k3, &s->k4, &s->v1, &s->v2};
    for (size_t i = 0; i < UIOFMU_LENGTH(slots); i++) {
        *slots[i] = b;
        b += sizes[i] ? sizes[i] : 1;
    }
    matmul(d->C, d->B, s->CB, s->p, s->n, s->m);
    double normA;
    norm2(s, d->A, s->n, s->n, &normA); /* ||Aa||_2 = ||A||_2 (block diagonal); A is finite */
    s->predict_substep = 1.0 / pymax(normA, 1e-300);
    memcpy(s->xhat0, d->xhat0, n * sizeof(double));
    reset_state(s);
    return s;
}

static void delayed_free(void *self) {
    Delayed *s = (Delayed *)self;
    if (!s) return;
    free(s->block);
    free(s->piv);
    free(s);
}

static void delayed_reset(void *self) {
    Delayed *s = (Delayed *)self;
    memcpy(s->xhat0, s->d->xhat0, (size_t)s->n * sizeof(double));
    memset(s->y, 0, (size_t)s->p * sizeof(double));
    memset(s->ydot, 0, (size_t)s->p * sizeof(double));
    memset(s->u, 0, (size_t)s->m * sizeof(double));
    reset_state(s);
}

static UiofmuResult delayed_exit_initialization(void *self) {
    Delayed *s = (Delayed *)self;
    if (!uiofmu_parameter_finite(s->fmu, PORT_NAME[UIOFMU_DELAYED_XHAT0], s->xhat0, s->n)) return UIOFMU_REFUSED;
    reset_state(s);
    return UIOFMU_DONE;
}

static UiofmuResult delayed_calculate(void *self, const char *fn) {
    (void)fn;
    refresh((Delayed *)self);
    return UIOFMU_DONE;
}

/* The storage of element `index` of port `port` (the plumbing checked both against the table). */
static double *delayed_real_storage(void *self, int port, int index) {
    Delayed *s = (Delayed *)self;
    double *const first[UIOFMU_DELAYED_PORTS] = {[UIOFMU_DELAYED_XHAT0] = s->xhat0, [UIOFMU_DELAYED_Y] = s->y,
                                                 [UIOFMU_DELAYED_YDOT] = s->ydot, [UIOFMU_DELAYED_U] = s->u,
                                                 [UIOFMU_DELAYED_XHAT] = s->xhat_out,
                                                 [UIOFMU_DELAYED_THETAHAT] = s->theta_out,
                                                 [UIOFMU_DELAYED_R] = s->r_out,
                                                 [UIOFMU_DELAYED_SIGMA_MIN] = &s->sigma_out};
    return uiofmu_element(first, port, index);
}

/* The plumbing stored new values: the outputs are computed again before they are read. */
static void delayed_changed(void *self) { ((Delayed *)self)->dirty = 1; }

/* The Integer port: valid (an output). */
static int delayed_get_integer(void *self, int port, int index) {
    (void)index;
    return port == UIOFMU_DELAYED_VALID ? ((Delayed *)self)->valid_out : 0;
}

/* ---------------------------------------------------------------------------------------- */
/* FMU state: the kernel's doubles
 *
 * The plumbing writes the image's header (magic, layout, size, GUID, the shape words n, p,
 * n_theta, rows and the count D of doubles; fmi2_plumbing.c) and checks it; then come
 * D = 6 + 2 n c + n_theta + n + 2 p + m + rows (1 + 2 p + m) doubles, written and read with
 * memcpy (no alignment assumed), in the platform's byte order:
 *
 *   t, k, phase, running, noted, used, z[n c], xa[n c], thetahat[n_theta], xhat0[n], y[p],
 *   ydot[p], u[m], buffer[rows][1 + 2 p + m]
 *
 * the buffer's points oldest first (t, y, ydot, u each), the first `used` of its `rows`, the
 * others 0. fmi2SetFMUstate and fmi2DeSerializeFMUstate refuse a state (fmi2Error and a log line
 * with the numbers) unless every value is one this FMU can be in (check_values), all checked
 * before any of it is used:
 *   t        finite, >= 0; 0 before initialisation ended
 *   k        an integer 0 <= k <= 2^53; 0 before initialisation ended
 *   phase    0 instantiated, 1 initialisation mode, 2 initialised, 3 terminated
 *   running, noted  0 or 1; 0 before initialisation ended
 *   used     an integer 0 <= used <= rows; 0 before initialisation ended
 *   z, xa, thetahat, xhat0  finite (xhat0: the parameter; fmi2ExitInitializationMode refuses
 *            a non-finite one)
 *   y, ydot, u  any value, NaN and Inf included (inputs that fmi2SetReal takes and fmi2DoStep
 *            refuses)
 *   buffer   the used points finite, their times increasing and none after t; the rest 0
 */

enum { SV_T, SV_K, SV_PHASE, SV_RUNNING, SV_NOTED, SV_USED, SV_SCALARS };

typedef unsigned char Byte;

static size_t delayed_state_count(void) {
    const UiofmuDelayed *d = &UIOFMU_DELAYED;
    size_t c = (size_t)d->ndelays + 1, n = (size_t)d->n, p = (size_t)d->p, m = (size_t)d->m, nt = (size_t)d->nt;
    return SV_SCALARS + 2 * n * c + nt + n + 2 * p + m + (size_t)d->rows * (1 + 2 * p + m);
}

static void delayed_state_shape(uint32_t shape[UIOFMU_SHAPE], const char *names[UIOFMU_SHAPE]) {
    const UiofmuDelayed *d = &UIOFMU_DELAYED;
    static const char *const NAMES[UIOFMU_SHAPE] = {"n", "p", "n_theta", "rows"};
    const int dims[UIOFMU_SHAPE] = {d->n, d->p, d->nt, d->rows};
    uiofmu_shape(shape, names, dims, NAMES);
}

static void delayed_save_state(void *self, int phase, Byte *o) {
    Delayed *s = (Delayed *)self;
    double scalars[SV_SCALARS] = {s->t, s->k, (double)phase, (double)s->running, (double)s->noted, (double)s->rows};
    o = uiofmu_put(o, scalars, SV_SCALARS);
    o = uiofmu_put(o, s->z, (size_t)s->na);
    o = uiofmu_put(o, s->xa, (size_t)s->na);
    o = uiofmu_put(o, s->thetahat, (size_t)s->nt);
    o = uiofmu_put(o, s->xhat0, (size_t)s->n);
    o = uiofmu_put(o, s->y, (size_t)s->p);
    o = uiofmu_put(o, s->ydot, (size_t)s->p);
    o = uiofmu_put(o, s->u, (size_t)s->m);
    uiofmu_put(o, s->buf, (size_t)s->R * (size_t)s->width); /* the rows beyond `used` are 0 */
}

/* Whether the doubles at v (see above) are a state this FMU can be in. */
static int check_values(Delayed *s, const char *ctx, const Byte *v) {
    static const char *const VECTOR[4] = {"z", "xa", "thetahat", "xhat0"};
    char b1[32], b2[32];
    double t = uiofmu_getd(v, SV_T), k = uiofmu_getd(v, SV_K), phase = uiofmu_getd(v, SV_PHASE);
    double used = uiofmu_getd(v, SV_USED);
    if (!(isfinite(t) && t >= 0)) return uiofmu_state_refused(s->fmu, ctx, "t = %s: expected a finite time >= 0",
                                                             uiofmu_num(t, b1));
    if (!(isfinite(k) && k >= 0 && k == floor(k) && k <= MAX_SAFE_INTEGER))
        return uiofmu_state_refused(s->fmu, ctx, "k = %s is not a step count (an integer, 0 <= k <= 2^53)",
                                    uiofmu_num(k, b1));
    if (!uiofmu_phase_ok(s->fmu, ctx, phase)) return 0;
    for (int w = SV_RUNNING; w <= SV_NOTED; w++) {
        double x = uiofmu_getd(v, (size_t)w);
        if (x != 0.0 && x != 1.0)
            return uiofmu_state_refused(s->fmu, ctx, "%s = %s: expected 0 or 1", w == SV_RUNNING ? "running" : "noted",
                                        uiofmu_num(x, b1));
    }
    if (!(used >= 0 && used <= (double)s->R && used == floor(used)))
        return uiofmu_state_refused(s->fmu, ctx, "the buffer's used points = %s: expected an integer from 0 to %d",
                                    uiofmu_num(used, b1), s->R);
    if (phase < UIOFMU_PHASE_RUNNING &&
        (t != 0 || k != 0 || used != 0 || uiofmu_getd(v, SV_RUNNING) != 0 || uiofmu_getd(v, SV_NOTED) != 0))
        return uiofmu_state_refused(s->fmu, ctx, "t = %s, k = %s in phase %d, before initialisation ended: expected "
                                    "t = 0, k = 0, an empty buffer, not running", uiofmu_num(t, b1), uiofmu_num(k, b2),
                                    (int)phase);
    size_t at = SV_SCALARS;
    const size_t lengths[4] = {(size_t)s->na, (size_t)s->na, (size_t)s->nt, (size_t)s->n};
    for (int w = 0; w < 4; w++) {
        for (size_t i = 0; i < lengths[w]; i++) {
            double x = uiofmu_getd(v, at + i);
            if (!isfinite(x))
                return uiofmu_state_refused(s->fmu, ctx, "%s[%zu] = %s is not finite", VECTOR[w], i + 1,
                                            uiofmu_num(x, b1));
        }
        at += lengths[w];
    }
    at += 2 * (size_t)s->p + (size_t)s->m; /* y, ydot, u: taken as they are (see above) */
    int rows = (int)used;
    double before = -INFINITY;
    for (int r = 0; r < s->R; r++)
        for (int e = 0; e < s->width; e++) {
            double x = uiofmu_getd(v, at + (size_t)r * s->width + (size_t)e);
            if (r >= rows) {
                if (x != 0)
                    return uiofmu_state_refused(s->fmu, ctx, "buffer[%d][%d] = %s: expected 0 (past the %d points "
                                                "used)", r + 1, e + 1, uiofmu_num(x, b1), rows);
                continue;
            }
            if (!isfinite(x))
                return uiofmu_state_refused(s->fmu, ctx, "buffer[%d][%d] = %s is not finite", r + 1, e + 1,
                                            uiofmu_num(x, b1));
            if (e == 0) {
                if (!(x > before) || x > t)
                    return uiofmu_state_refused(s->fmu, ctx, "buffer[%d] at t = %s: the buffer's times must increase "
                                                "and not pass t = %s", r + 1, uiofmu_num(x, b1), uiofmu_num(t, b2));
                before = x;
            }
        }
    return 1;
}

static int delayed_check_state(void *self, const char *ctx, const Byte *v, int *phase) {
    if (!check_values((Delayed *)self, ctx, v)) return 0;
    *phase = (int)uiofmu_getd(v, SV_PHASE);
    return 1;
}

static void delayed_load_state(void *self, const Byte *v) {
    Delayed *s = (Delayed *)self;
    s->t = uiofmu_getd(v, SV_T);
    s->k = uiofmu_getd(v, SV_K);
    s->running = uiofmu_getd(v, SV_RUNNING) != 0;
    s->noted = uiofmu_getd(v, SV_NOTED) != 0;
    s->rows = (int)uiofmu_getd(v, SV_USED);
    const Byte *o = v + SV_SCALARS * sizeof(double);
    o = uiofmu_take(o, s->z, (size_t)s->na);
    o = uiofmu_take(o, s->xa, (size_t)s->na);
    o = uiofmu_take(o, s->thetahat, (size_t)s->nt);
    o = uiofmu_take(o, s->xhat0, (size_t)s->n);
    o = uiofmu_take(o, s->y, (size_t)s->p);
    o = uiofmu_take(o, s->ydot, (size_t)s->p);
    o = uiofmu_take(o, s->u, (size_t)s->m);
    uiofmu_take(o, s->buf, (size_t)s->R * (size_t)s->width);
    memset(s->buf + (size_t)s->R * s->width, 0, (size_t)s->width * sizeof(double));
    s->dirty = 1;
}

const UiofmuKernel UIOFMU_KERNEL_DELAYED = {
    .name = "delayed",
    .check_design = delayed_check_design,
    .ports = UIOFMU_DELAYED_PORTS,
    .port = delayed_port,
    .instantiate = delayed_instantiate,
    .free_instance = delayed_free,
    .reset = delayed_reset,
    .exit_initialization = delayed_exit_initialization,
    .calculate = delayed_calculate,
    .real_storage = delayed_real_storage,
    .changed = delayed_changed,
    .get_integer = delayed_get_integer, /* valid */
    .set_integer = NULL, /* no Integer input */
    .step = delayed_step,
    .state_count = delayed_state_count,
    .state_shape = delayed_state_shape,
    .save_state = delayed_save_state,
    .check_state = delayed_check_state,
    .load_state = delayed_load_state,
};
