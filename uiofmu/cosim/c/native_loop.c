/* The co-simulation master's stepping loop in C (uiofmu.cosim.native).
 *
 * A run is a program: a list of operations executed in order at every communication point k, on
 * buffers the master allocated (one row per point, so the values of point k are at base + k * stride):
 *
 *   CALL        fmi2{Set,Get}{Real,Integer}(component, refs, count, base + k * stride)
 *   STEP        fmi2DoStep(component, times[k], steps[k], fmi2True); the steps come last, none at k = K
 *   TO_INTEGER  count doubles at source + k * source_stride into fmi2Integers at base + k * stride, each an
 *               fmi2Integer (finite, integral, in the range of an int) or the run stops
 *   TO_REAL     count fmi2Integers at source + k * source_stride into doubles at base + k * stride
 *   MEASURE     count doubles: base[k] = source[k] + noise[k], then quantum * rint(base[k] / quantum)
 *               when quantum > 0 (round half to even, as numpy's round)
 *
 * A call that returns more than fmi2Warning stops the run: uiofmu_run returns 1 with fail = {point,
 * operation, status, the FMU's count of log lines before the call}; a conversion's refusal has status -1
 * and the element's index in place of that count. The FMUs' log lines reach the master's logger as in its
 * Python loop (the FMU calls it during the call). Nothing here allocates, and no arithmetic but the
 * measurement's touches a value.
 */
#include <math.h>
#include <stddef.h>
#include <stdint.h>

#if defined(_WIN32)
#define UIOFMU_EXPORT __declspec(dllexport)
#else
#define UIOFMU_EXPORT __attribute__((visibility("default")))
#endif

typedef int (*values_function)(void *component, const unsigned int *refs, size_t count, void *values);
typedef int (*step_function)(void *component, double t, double h, int no_prior_state);

enum { CALL = 0, STEP = 1, TO_INTEGER = 2, TO_REAL = 3, MEASURE = 4 };

typedef struct {
    int64_t kind;
    void *function;
    void *component;
    const unsigned int *refs;
    int64_t count;
    char *base;
    int64_t stride;
    const char *source;
    int64_t source_stride;
    const char *noise;
    int64_t noise_stride;
    double quantum;
    const int64_t *logged;
} operation;

static int stop(int64_t *fail, int64_t k, int64_t i, int64_t status, int64_t mark)
{
    fail[0] = k;
    fail[1] = i;
    fail[2] = status;
    fail[3] = mark;
    return 1;
}

/* The flat index of the first value that is not an fmi2Integer, -1 when all are. */
static int64_t first_non_integer(const double *v, int64_t count)
{
    for (int64_t j = 0; j < count; j++) {
        double x = v[j];
        if (!isfinite(x) || x != floor(x) || x < -2147483648.0 || x > 2147483647.0)
            return j;
    }
    return -1;
}

UIOFMU_EXPORT int uiofmu_run(const operation *ops, int64_t n_ops, const double *times, const double *steps,
                             int64_t k0, int64_t count, int64_t K, int64_t *fail)
{
    for (int64_t k = k0; k < k0 + count; k++) {
        for (int64_t i = 0; i < n_ops; i++) {
            const operation *o = &ops[i];
            int64_t mark;
            int status;
            switch (o->kind) {
            case CALL:
                mark = *o->logged;
                status = ((values_function)o->function)(o->component, o->refs, (size_t)o->count,
                                                         o->base + k * o->stride);
                if (status > 1)
                    return stop(fail, k, i, status, mark);
                break;
            case STEP:
                if (k == K)
                    return 0;
                mark = *o->logged;
                status = ((step_function)o->function)(o->component, times[k], steps[k], 1);
                if (status > 1)
                    return stop(fail, k, i, status, mark);
                break;
            case TO_INTEGER: {
                const double *src = (const double *)(o->source + k * o->source_stride);
                int *dst = (int *)(o->base + k * o->stride);
                int64_t bad = first_non_integer(src, o->count);
                if (bad >= 0)
                    return stop(fail, k, i, -1, bad);
                for (int64_t j = 0; j < o->count; j++)
                    dst[j] = (int)src[j];
                break;
            }
            case TO_REAL: {
                const int *src = (const int *)(o->source + k * o->source_stride);
                double *dst = (double *)(o->base + k * o->stride);
                for (int64_t j = 0; j < o->count; j++)
                    dst[j] = (double)src[j];
                break;
            }
            case MEASURE: {
                const double *y = (const double *)(o->source + k * o->source_stride);
                const double *v = (const double *)(o->noise + k * o->noise_stride);
                double *dst = (double *)(o->base + k * o->stride);
                for (int64_t j = 0; j < o->count; j++) {
                    double noisy = y[j] + v[j];
                    dst[j] = o->quantum > 0.0 ? o->quantum * rint(noisy / o->quantum) : noisy;
                }
                break;
            }
            default:
                return stop(fail, k, i, -2, 0);
            }
        }
    }
    return 0;
}
