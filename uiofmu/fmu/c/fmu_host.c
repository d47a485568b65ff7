/* uiofmu's minimal FMI 2.0 Co-Simulation host: dlopen, no Python in the process.
 *
 * usage: fmu_host LIB.so GUID RESOURCE_URI IN_VRS OUT_VRS STEPS_FILE [REPEAT]
 *   IN_VRS, OUT_VRS   comma-separated value references ("2,3" or "-" for none)
 *   STEPS_FILE        one line per step: h followed by one value per input reference
 *   REPEAT            run the whole file this many times (timing); outputs are printed for the
 *                     first pass only, then the mean time per step in ns on stderr (the passes
 *                     after the first are timed as a whole: fmi2SetReal of the inputs and fmi2DoStep)
 * For each line: set the inputs, get the outputs (printed with %.17g), then fmi2DoStep(t, h).
 * Exit status: 0, or 2 when a call returns something other than fmi2OK.
 */
#define _POSIX_C_SOURCE 200809L
#include <dlfcn.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "fmi2Functions.h"

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

static int parse_refs(const char *text, fmi2ValueReference *out, int max) {
    int n = 0;
    if (strcmp(text, "-") == 0) return 0;
    char *copy = strdup(text), *save = NULL;
    for (char *tok = strtok_r(copy, ",", &save); tok && n < max; tok = strtok_r(NULL, ",", &save))
        out[n++] = (fmi2ValueReference)strtoul(tok, NULL, 10);
    free(copy);
    return n;
}

/* Unload the FMU's library. pythonfmu 0.7.0 binaries release their interpreter state from a
   library destructor after their static has already freed it; releasing it first, while the
   library is loaded, leaves nothing behind for the destructor (see uiofmu/cosim/fmi.py). */
static int unload(void *lib, int status) {
    void (*release)(void) = (void (*)(void))dlsym(lib, "finalizePythonInterpreter");
    if (release) release();
    dlclose(lib);
    return status;
}

#define LOAD(name) \
    name##TYPE *name = (name##TYPE *)dlsym(lib, #name); \
    if (!name) { fprintf(stderr, "missing symbol %s\n", #name); return 2; }

int main(int argc, char **argv) {
    if (argc < 7) {
        fprintf(stderr, "usage: %s LIB.so GUID RESOURCE_URI IN_VRS OUT_VRS STEPS_FILE [REPEAT]\n", argv[0]);
        return 2;
    }
    void *lib = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
    if (!lib) { fprintf(stderr, "dlopen: %s\n", dlerror()); return 2; }
    LOAD(fmi2Instantiate) LOAD(fmi2SetupExperiment) LOAD(fmi2EnterInitializationMode)
    LOAD(fmi2ExitInitializationMode) LOAD(fmi2SetReal) LOAD(fmi2GetReal) LOAD(fmi2DoStep)
    LOAD(fmi2Terminate) LOAD(fmi2FreeInstance)
    fmi2ValueReference in[256], out[256];
    int nin = parse_refs(argv[4], in, 256), nout = parse_refs(argv[5], out, 256);
    int repeat = argc > 7 ? atoi(argv[7]) : 1;
    FILE *f = fopen(argv[6], "r");
    if (!f) { perror(argv[6]); return 2; }
    size_t cap = 1024, rows = 0;
    double *data = malloc(cap * (nin + 1) * sizeof(double));
    for (;;) {
        if (rows == cap) { cap *= 2; data = realloc(data, cap * (nin + 1) * sizeof(double)); }
        int got = 0;
        for (int j = 0; j <= nin; j++) got += fscanf(f, "%lf", &data[rows * (nin + 1) + j]) == 1;
        if (got != nin + 1) break;
        rows++;
    }
    fclose(f);
    fmi2CallbackFunctions cb = {logger, calloc, free, NULL, NULL};
    fmi2Component c = fmi2Instantiate("host", fmi2CoSimulation, argv[2], argv[3], &cb, fmi2False, fmi2False);
    if (!c) {
        fprintf(stderr, "fmi2Instantiate failed\n");
        free(data);
        return unload(lib, 2);
    }
    if (fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0) != fmi2OK ||
        fmi2EnterInitializationMode(c) != fmi2OK || fmi2ExitInitializationMode(c) != fmi2OK) {
        fprintf(stderr, "initialisation failed\n");
        fmi2FreeInstance(c);
        free(data);
        return unload(lib, 2);
    }
    double values[256];
    double t = 0.0, elapsed = 0.0;
    long steps = 0;
    int status = 0;
    for (int pass = 0; pass < repeat && !status; pass++) {
        struct timespec a, b;
        clock_gettime(CLOCK_MONOTONIC, &a);
        for (size_t r = 0; r < rows; r++) {
            const double *row = &data[r * (nin + 1)];
            if (nin && fmi2SetReal(c, in, nin, row + 1) != fmi2OK) { status = 2; break; }
            if (pass == 0) {
                if (nout && fmi2GetReal(c, out, nout, values) != fmi2OK) { status = 2; break; }
                for (int j = 0; j < nout; j++) printf(j ? " %.17g" : "%.17g", values[j]);
                printf("\n");
            }
            fmi2Status st = fmi2DoStep(c, t, row[0], fmi2True);
            if (st != fmi2OK) {
                fprintf(stderr, "fmi2DoStep returned %d at row %zu\n", (int)st, r);
                status = 2;
                break;
            }
            t += row[0];
        }
        clock_gettime(CLOCK_MONOTONIC, &b);
        if (pass > 0) {
            elapsed += (b.tv_sec - a.tv_sec) * 1e9 + (b.tv_nsec - a.tv_nsec);
            steps += (long)rows;
        }
    }
    if (repeat > 1 && steps) fprintf(stderr, "ns_per_step %.1f\n", elapsed / steps);
    if (!status) fmi2Terminate(c);
    fmi2FreeInstance(c);
    free(data);
    return unload(lib, status);
}
