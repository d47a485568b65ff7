/* The observer's whole step in a C host, as a master makes it: fmi2SetReal of its inputs,
 * fmi2GetReal of its outputs, fmi2DoStep (benchmarks/fmu_step_cost.py compiles and runs it).
 *
 * usage: observer_step LIB.so GUID IN_VRS OUT_VRS PLAN_FILE REPEAT
 *   IN_VRS, OUT_VRS   comma-separated value references (one fmi2SetReal, one fmi2GetReal a step)
 *   PLAN_FILE         one line per step: h followed by one value per input reference
 *   REPEAT            passes over the plan after the first; the first pass prints every output
 *                     (%a: exact, for comparing two builds bit for bit), the others are timed
 * On stderr: "cpu_ns_per_step X" (process CPU time of the timed passes over their steps) and
 * "steps N". The timed passes run in run_passes (valgrind --toggle-collect=run_passes counts
 * their instructions alone). Exit status 0, or 2 when a call returns other than fmi2OK.
 */
#define _POSIX_C_SOURCE 200809L
#include <dlfcn.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "fmi2Functions.h"

#define MAX_REFS 256

typedef struct {
    fmi2SetRealTYPE *set;
    fmi2GetRealTYPE *get;
    fmi2DoStepTYPE *step;
    fmi2Component c;
    fmi2ValueReference in[MAX_REFS], out[MAX_REFS];
    int nin, nout;
    const double *plan;
    size_t rows;
    double t;
} Run;

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                   fmi2String message, ...) {
    va_list ap;
    (void)env;
    va_start(ap, message);
    fprintf(stderr, "[%s] %d %s: ", name, (int)status, category);
    vfprintf(stderr, message, ap);
    fputc('\n', stderr);
    va_end(ap);
}

static int parse_refs(const char *text, fmi2ValueReference *out) {
    int n = 0;
    if (strcmp(text, "-") == 0) return 0;
    char *copy = strdup(text), *save = NULL;
    for (char *tok = strtok_r(copy, ",", &save); tok && n < MAX_REFS; tok = strtok_r(NULL, ",", &save))
        out[n++] = (fmi2ValueReference)strtoul(tok, NULL, 10);
    free(copy);
    return n;
}

/* One pass over the plan; the outputs printed when `show`. 0, or 2 after a call not fmi2OK. */
static int pass(Run *r, int show) {
    double values[MAX_REFS];
    for (size_t k = 0; k < r->rows; k++) {
        const double *row = &r->plan[k * (size_t)(r->nin + 1)];
        if (r->set(r->c, r->in, (size_t)r->nin, row + 1) != fmi2OK) return 2;
        if (r->get(r->c, r->out, (size_t)r->nout, values) != fmi2OK) return 2;
        if (show)
            for (int j = 0; j < r->nout; j++) printf(j + 1 < r->nout ? "%a " : "%a\n", values[j]);
        if (r->step(r->c, r->t, row[0], fmi2True) != fmi2OK) {
            fprintf(stderr, "fmi2DoStep refused row %zu\n", k);
            return 2;
        }
        r->t += row[0];
    }
    return 0;
}

/* The timed passes (not inlined: callgrind's --toggle-collect names it). */
__attribute__((noinline)) int run_passes(Run *r, int repeat) {
    for (int p = 0; p < repeat; p++)
        if (pass(r, 0)) return 2;
    return 0;
}

#define LOAD(name) \
    name##TYPE *name = (name##TYPE *)dlsym(lib, #name); \
    if (!name) { fprintf(stderr, "missing symbol %s\n", #name); return 2; }

int main(int argc, char **argv) {
    if (argc != 7) {
        fprintf(stderr, "usage: %s LIB.so GUID IN_VRS OUT_VRS PLAN_FILE REPEAT\n", argv[0]);
        return 2;
    }
    void *lib = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
    if (!lib) { fprintf(stderr, "dlopen: %s\n", dlerror()); return 2; }
    LOAD(fmi2Instantiate) LOAD(fmi2SetupExperiment) LOAD(fmi2EnterInitializationMode)
    LOAD(fmi2ExitInitializationMode) LOAD(fmi2SetReal) LOAD(fmi2GetReal) LOAD(fmi2DoStep)
    LOAD(fmi2FreeInstance)
    static Run r;
    r.set = fmi2SetReal;
    r.get = fmi2GetReal;
    r.step = fmi2DoStep;
    r.nin = parse_refs(argv[3], r.in);
    r.nout = parse_refs(argv[4], r.out);
    int repeat = atoi(argv[6]);
    FILE *f = fopen(argv[5], "r");
    if (!f) { perror(argv[5]); return 2; }
    size_t cap = 1024, width = (size_t)r.nin + 1;
    double *plan = malloc(cap * width * sizeof(double));
    for (;;) {
        if (r.rows == cap) { cap *= 2; plan = realloc(plan, cap * width * sizeof(double)); }
        size_t got = 0;
        for (size_t j = 0; j < width; j++) got += fscanf(f, "%lf", &plan[r.rows * width + j]) == 1;
        if (got != width) break;
        r.rows++;
    }
    fclose(f);
    r.plan = plan;
    fmi2CallbackFunctions cb = {logger, calloc, free, NULL, NULL};
    r.c = fmi2Instantiate("bench", fmi2CoSimulation, argv[2], "", &cb, fmi2False, fmi2False);
    if (!r.c || fmi2SetupExperiment(r.c, fmi2False, 0.0, 0.0, fmi2False, 0.0) != fmi2OK ||
        fmi2EnterInitializationMode(r.c) != fmi2OK || fmi2ExitInitializationMode(r.c) != fmi2OK) {
        fprintf(stderr, "instantiation or initialisation failed\n");
        return 2;
    }
    int status = pass(&r, 1);
    struct timespec a, b;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &a);
    if (!status) status = run_passes(&r, repeat);
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &b);
    double steps = (double)r.rows * repeat;
    if (!status && steps > 0)
        fprintf(stderr, "cpu_ns_per_step %.2f\nsteps %.0f\n",
                ((double)(b.tv_sec - a.tv_sec) * 1e9 + (double)(b.tv_nsec - a.tv_nsec)) / steps, steps);
    fmi2FreeInstance(r.c);
    free(plan);
    dlclose(lib);
    return status;
}
