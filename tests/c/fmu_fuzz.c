/* fmu_fuzz: seeded random FMI 2.0 call sequences against one uiofmu C observer FMU.
 *
 * Built as one executable with the FMU's own C files (sources/fmi2_plumbing.c,
 * sources/kernel_affine.c, sources/design_data.c; and the headers of the same sources/), under
 * -fsanitize=address,undefined -fno-sanitize-recover=all, by tests/cfuzz.py (with
 * -DUIOFMU_LEGACY_RUNTIME for the one-file runtime of older revisions, sources/observer.c). It drives the FMI functions directly, keeps a
 * model of what each call must return (the phase of each instance, which steps are
 * admissible, which states are valid) and reports every disagreement:
 *
 *   fmu_fuzz random    [--seed S] [--iterations N] [--seconds T] [--verbose]
 *   fmu_fuzz scenarios [--scenario NAME] [--verbose]
 *   fmu_fuzz list
 *
 * random     N sequences (or T seconds, whichever ends first) of 20..400 calls each: instances
 *            made well and badly, setupExperiment and initialisation in and out of order,
 *            get/set of Real variables (references in and out of range, NaN, Inf, huge values),
 *            steps (admissible, random, 0, negative, NaN, Inf), FMU states got, set, freed,
 *            reused (also states of the wrong size and forged ones), serialised into exact,
 *            short, long and random buffers, deserialised from honest and mutated bytes (bit
 *            flips; every double overwritten with NaN, Inf, -1, 123, 1e300, ...; GUID, layout
 *            and size fields changed), states moved between two instances, Integer, Boolean
 *            and String access, the status queries, the log categories, reset, terminate, free.
 * scenarios  the known attacks one by one, each with the status it must get (a forged state
 *            that is accepted is a failure); every fmi2 function in every state an instance can
 *            be brought to (the state masks of fmi2_plumbing.c, written out again here from
 *            FMI 2.0 and the documented differences); the status queries after a discarded
 *            step and a master going on with a valid step; the log categories.
 *
 * Oracles: the status the model expects; a log line for every status other than fmi2OK whose
 * category is on, and none under a category that is off; a state that is refused leaves the instance exactly as it was (its serialised state is
 * byte-identical before and after); a state that is set gives back, bit for bit, the outputs
 * read when it was taken; replaying the same inputs from a state gives the same outputs bit
 * for bit (in the same instance, and in another one through serialised bytes). The sanitizers
 * watch every memory access, and LeakSanitizer every allocation, at exit.
 *
 * Output on stdout: the counts (calls per function, statuses returned) and "failures=F".
 * Exit status 0 when nothing was wrong, 1 when a check failed (messages on stderr, "FAIL ...").
 *
 * The serialised layout is read in two versions: layout 2 (magic "uiof", layout, size, GUID
 * length, dims, count, GUID, doubles) and, to measure the runtime before it was hardened,
 * layout 1 (magic, count, doubles, GUID). The valid-state model below is written from the
 * rules documented in kernel_affine.c, independently of its code.
 */
#define _POSIX_C_SOURCE 200809L
#include <float.h>
#include <math.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "fmi2Functions.h"
#ifdef UIOFMU_LEGACY_RUNTIME
#include "uiofmu_design.h"
#define FMU_GUID (UIOFMU_DESIGN.guid)
#define FMU_MODEL (UIOFMU_DESIGN.model)
#else
#include "kernel_affine.h"
#define FMU_GUID (UIOFMU_FMU.guid)
#define FMU_MODEL (UIOFMU_FMU.model)
#endif

#if defined(__SANITIZE_ADDRESS__)
#include <sanitizer/common_interface_defs.h>
#define HAVE_DEATH_CALLBACK 1
#endif

static const UiofmuDesign *D = &UIOFMU_DESIGN;

/* ---------------------------------------------------------------------------------------- */
/* the design as the fuzzer sees it                                                          */

static int NV;                   /* number of Real variables */
static int VR_XHAT0, VR_HPREV0;  /* VR_HPREV0 = -1 without it */
static int VR_Y, VR_U, VR_OUT;   /* first references */
static int NOUT;                 /* xhat, r, dhat */
static size_t ND;                /* doubles in a state */
static int INTERVAL;

enum { FK, FHPREV, FHPREV0, FNOTICED, FPHASE, NSCALAR };
static size_t F_Z, F_PRED, F_XHAT0, F_Y, F_U; /* indices of the vectors among the doubles */

enum { PH_INSTANTIATED, PH_INIT, PH_RUNNING, PH_TERMINATED, PH_NONE };

static void design_facts(void) {
    INTERVAL = D->kind == UIOFMU_INTERVAL;
    VR_XHAT0 = 0;
    VR_HPREV0 = INTERVAL ? D->n : -1;
    VR_Y = D->n + (INTERVAL ? 1 : 0);
    VR_U = VR_Y + D->p;
    VR_OUT = VR_U + D->m;
    NOUT = D->n + D->p + (D->has_dhat ? D->q : 0);
    NV = VR_OUT + NOUT;
    F_Z = NSCALAR;
    F_PRED = F_Z + (size_t)D->nz;
    F_XHAT0 = F_PRED + (size_t)D->p;
    F_Y = F_XHAT0 + (size_t)D->n;
    F_U = F_Y + (size_t)D->p;
    ND = F_U + (size_t)D->m;
}

/* ---------------------------------------------------------------------------------------- */
/* random numbers (splitmix64)                                                               */

static uint64_t rng;
static uint64_t next64(void) {
    uint64_t z = (rng += 0x9e3779b97f4a7c15ull);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return z ^ (z >> 31);
}
static double unif(void) { return (double)(next64() >> 11) * (1.0 / 9007199254740992.0); }
static int below(int n) { return n > 0 ? (int)(next64() % (uint64_t)n) : 0; }
static int chance(double p) { return unif() < p; }
static double normal(void) {
    double a = unif(), b = unif();
    return sqrt(-2.0 * log(a + 1e-300)) * cos(6.283185307179586 * b);
}

/* ---------------------------------------------------------------------------------------- */
/* accounting                                                                                */

enum {
    F_Instantiate, F_FreeInstance, F_SetDebugLogging, F_SetupExperiment, F_EnterInitializationMode,
    F_ExitInitializationMode, F_Terminate, F_Reset, F_GetReal, F_SetReal, F_GetInteger, F_SetInteger,
    F_GetBoolean, F_SetBoolean, F_GetString, F_SetString, F_DoStep, F_CancelStep, F_GetFMUstate,
    F_SetFMUstate, F_FreeFMUstate, F_SerializedFMUstateSize, F_SerializeFMUstate, F_DeSerializeFMUstate,
    F_GetDirectionalDerivative, F_SetRealInputDerivatives, F_GetRealOutputDerivatives, F_GetStatus,
    F_GetRealStatus, F_GetIntegerStatus, F_GetBooleanStatus, F_GetStringStatus, F_GetTypesPlatform,
    F_GetVersion, F_COUNT
};
static const char *const FN[F_COUNT] = {
    "fmi2Instantiate", "fmi2FreeInstance", "fmi2SetDebugLogging", "fmi2SetupExperiment",
    "fmi2EnterInitializationMode", "fmi2ExitInitializationMode", "fmi2Terminate", "fmi2Reset", "fmi2GetReal",
    "fmi2SetReal", "fmi2GetInteger", "fmi2SetInteger", "fmi2GetBoolean", "fmi2SetBoolean", "fmi2GetString",
    "fmi2SetString", "fmi2DoStep", "fmi2CancelStep", "fmi2GetFMUstate", "fmi2SetFMUstate", "fmi2FreeFMUstate",
    "fmi2SerializedFMUstateSize", "fmi2SerializeFMUstate", "fmi2DeSerializeFMUstate",
    "fmi2GetDirectionalDerivative", "fmi2SetRealInputDerivatives", "fmi2GetRealOutputDerivatives",
    "fmi2GetStatus", "fmi2GetRealStatus", "fmi2GetIntegerStatus", "fmi2GetBooleanStatus", "fmi2GetStringStatus",
    "fmi2GetTypesPlatform", "fmi2GetVersion"};
enum { S_OK, S_WARNING, S_DISCARD, S_ERROR, S_FATAL, S_PENDING, S_OTHER, S_COUNT };
static const char *const SN[S_COUNT] = {"ok", "warning", "discard", "error", "fatal", "pending", "other"};

static long counts[F_COUNT][S_COUNT];
static long total_calls, failures, sequences, log_lines;
static int verbose;
static const char *mode_name = "random";
static unsigned long long seed0;
static double started;
static char where[160] = "";

static double now(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static void fail(const char *fmt, ...) {
    char buf[2048];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    failures++;
    if (failures <= 60) fprintf(stderr, "FAIL [%s seed %llu sequence %ld call %ld] %s\n", where, seed0, sequences, total_calls, buf);
    if (failures == 60) fprintf(stderr, "(further failures not shown)\n");
}

static void report(int died) {
    long by[S_COUNT] = {0};
    for (int f = 0; f < F_COUNT; f++)
        for (int k = 0; k < S_COUNT; k++) by[k] += counts[f][k];
    printf("fuzz model=%s mode=%s seed=%llu sequences=%ld calls=%ld log_lines=%ld seconds=%.2f%s\n", FMU_MODEL,
           mode_name, seed0, sequences, total_calls, log_lines, now() - started, died ? " died=1" : "");
    printf("statuses");
    for (int k = 0; k < S_COUNT; k++) printf(" %s=%ld", SN[k], by[k]);
    printf("\n");
    for (int f = 0; f < F_COUNT; f++) {
        long n = 0;
        for (int k = 0; k < S_COUNT; k++) n += counts[f][k];
        if (!n) continue;
        printf("fn %s calls=%ld", FN[f], n);
        for (int k = 0; k < S_COUNT; k++) if (counts[f][k]) printf(" %s=%ld", SN[k], counts[f][k]);
        printf("\n");
    }
    printf("failures=%ld\n", failures);
    fflush(stdout);
}

#ifdef HAVE_DEATH_CALLBACK
static void on_death(void) { report(1); }
#endif

/* ---------------------------------------------------------------------------------------- */
/* instances and the logger                                                                  */

/* the log categories: the model of which are on, per instance (fmi2_plumbing.c: the status
   categories on at fmi2Instantiate, logEvents as loggingOn says) */
enum { CAT_EVENTS, CAT_WARNING, CAT_DISCARD, CAT_ERROR, CAT_COUNT };
static const char *const CAT_NAME[CAT_COUNT] = {"logEvents", "logStatusWarning", "logStatusDiscard", "logStatusError"};
#define CAT_ALL ((1u << CAT_COUNT) - 1u)
#define CAT_STATUSES ((1u << CAT_WARNING) | (1u << CAT_DISCARD) | (1u << CAT_ERROR))

static unsigned cat_of_status(fmi2Status st) {
    return 1u << (st == fmi2OK ? CAT_EVENTS : st == fmi2Warning ? CAT_WARNING : st == fmi2Discard ? CAT_DISCARD : CAT_ERROR);
}

typedef struct {
    int lines;
    char last[1024];
    unsigned cats; /* the categories the model says are on */
} Env;

typedef struct {
    fmi2Component c;
    Env env;
    fmi2CallbackFunctions cb;
    int logger;
    int phase;     /* the model's phase */
    int discarded; /* its last step was refused (fmi2Discard) and nothing has moved it since */
} Inst;

#define NINST 2
static Inst inst[NINST];

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                   fmi2String message, ...) {
    char buf[1024];
    va_list ap;
    Env *e = (Env *)env;
    va_start(ap, message);
    vsnprintf(buf, sizeof buf, message ? message : "(null)", ap);
    va_end(ap);
    log_lines++;
    if (!name || !category || !message) fail("the logger was called with a null name, category or message");
    if (status < fmi2OK || status > fmi2Pending) fail("a log line with status %d", (int)status);
#ifndef UIOFMU_LEGACY_RUNTIME
    if (category) {
        int k = 0;
        while (k < CAT_COUNT && strcmp(category, CAT_NAME[k]) != 0) k++;
        if (k == CAT_COUNT) fail("a log line under the undeclared category %s: %s", category, buf);
        else if ((1u << k) != cat_of_status(status)) fail("a log line of status %d under %s: %s", (int)status, category, buf);
        else if (e && !(e->cats & (1u << k))) fail("a log line under %s, which is off: %s", category, buf);
    }
#endif
    if (e) {
        e->lines++;
        snprintf(e->last, sizeof e->last, "%s", buf);
    }
    if (verbose) fprintf(stderr, "    log [%s] %d %s: %s\n", name ? name : "?", (int)status, category ? category : "?", buf);
}

static void *cb_calloc(size_t n, size_t size) { return calloc(n, size); }
static void cb_free(void *p) { free(p); }

static int g_before;
static fmi2Status track(Inst *I, int fn, fmi2Status st, int before) {
    int k = (int)st >= 0 && (int)st <= 5 ? (int)st : S_OTHER;
    counts[fn][k]++;
    total_calls++;
    if (k == S_OTHER) fail("%s returned %d, which is no fmi2Status", FN[fn], (int)st);
    if (I && fn == F_DoStep && (st == fmi2OK || st == fmi2Discard)) I->discarded = st == fmi2Discard;
    if (I && st == fmi2OK && (fn == F_EnterInitializationMode || fn == F_Terminate ||
                              fn == F_Reset || fn == F_SetFMUstate))
        I->discarded = 0; /* the calls that move an instance out of step discarded */
    if (I && I->c && I->logger && st != fmi2OK && (I->env.cats & cat_of_status(st)) && I->env.lines == before)
        fail("%s returned fmi2%s without a log line", FN[fn], SN[k]);
    return st;
}
static int lines_of(const Inst *I) { return I ? I->env.lines : 0; }
#define CALL(I, fn, expr) (g_before = lines_of(I), track((I), (fn), (expr), g_before))

static const char *sname(fmi2Status st) { return (int)st >= 0 && (int)st <= 5 ? SN[st] : "other"; }

/* got must be want; returns whether it was */
static int expect(Inst *I, fmi2Status got, fmi2Status want, const char *fmt, ...) {
    char what[512];
    va_list ap;
    if (got == want) return 1;
    va_start(ap, fmt);
    vsnprintf(what, sizeof what, fmt, ap);
    va_end(ap);
    fail("%s: fmi2%s, expected fmi2%s (last log line: %s)", what, sname(got), sname(want),
         I && I->env.last[0] ? I->env.last : "none");
    return 0;
}

static int last_log_has(Inst *I, const char *word, const char *what) {
    if (!I->logger) return 1;
    if (strstr(I->env.last, word)) return 1;
    fail("%s: the log line does not say \"%s\": %s", what, word, I->env.last);
    return 0;
}

static Inst *live(int i) { return inst[i].c ? &inst[i] : NULL; }
static Inst *any_live(void) {
    int i = below(NINST);
    return live(i) ? live(i) : live(1 - i);
}

static void instance_setup(Inst *I, int with_logger) {
    memset(&I->env, 0, sizeof I->env);
    I->env.cats = CAT_STATUSES; /* what fmi2Instantiate logs under when it refuses */
    I->cb.logger = with_logger ? logger : NULL;
    I->cb.allocateMemory = cb_calloc;
    I->cb.freeMemory = cb_free;
    I->cb.stepFinished = NULL;
    I->cb.componentEnvironment = &I->env;
    I->logger = with_logger;
}

static int make_instance(Inst *I, int with_logger, int logging_on) {
    instance_setup(I, with_logger);
    I->env.cats = CAT_STATUSES | (logging_on ? 1u << CAT_EVENTS : 0u);
    I->c = NULL;
    fmi2Component c = fmi2Instantiate("fuzz", fmi2CoSimulation, FMU_GUID, "file:///tmp", &I->cb, fmi2False,
                                      logging_on ? fmi2True : fmi2False);
    track(NULL, F_Instantiate, c ? fmi2OK : fmi2Error, 0);
    if (!c) {
        fail("fmi2Instantiate with the right GUID returned NULL (%s)", I->env.last);
        return 0;
    }
    I->c = c;
    I->phase = PH_INSTANTIATED;
    I->discarded = 0;
    return 1;
}

static void free_instance(Inst *I) {
    if (!I->c) return;
    fmi2FreeInstance(I->c);
    track(NULL, F_FreeInstance, fmi2OK, 0);
    I->c = NULL;
    I->phase = PH_NONE;
}

/* ---------------------------------------------------------------------------------------- */
/* model of the schedule and of valid states                                                 */

static int nearest_interval(double h, int *exact) {
    int best = 0;
    for (int i = 1; i < D->nintervals; i++)
        if (fabs(h - D->intervals[i]) < fabs(h - D->intervals[best])) best = i;
    *exact = fabs(h - D->intervals[best]) <= D->step_rtol * D->intervals[best];
    return best;
}

static int step_exact(double h) {
    int exact = 0;
    if (INTERVAL) nearest_interval(h, &exact);
    else exact = fabs(h - D->dt) <= D->step_rtol * D->dt;
    return exact;
}

/* a step of at most 1e-9 of the shortest design step is rounding: accepted, nothing computed
   (uiofmu/runtime/step_rules.py; the plumbing applies it before the kernel) */
static int step_rounding(double h) {
    double shortest = D->dt;
    if (INTERVAL) {
        shortest = D->intervals[0];
        for (int i = 1; i < D->nintervals; i++) if (D->intervals[i] < shortest) shortest = D->intervals[i];
    }
    return isfinite(h) && h > 0 && h <= 1e-9 * shortest;
}

/* an interval (or the policy 'nearest' maps it to one) */
static int model_resolves(double h) {
    int exact;
    if (!(isfinite(h) && h > 0)) return 0;
    nearest_interval(h, &exact);
    return exact || D->policy == UIOFMU_POLICY_NEAREST;
}

static int finite_all(const double *x, int n) {
    for (int i = 0; i < n; i++) if (!isfinite(x[i])) return 0;
    return 1;
}

/* NULL when the doubles v[ND] are a state the FMU must accept, else the field at fault */
static const char *model_invalid(const double *v) {
    double k = v[FK], hp = v[FHPREV], hp0 = v[FHPREV0], nt = v[FNOTICED], ph = v[FPHASE];
    if (!(k >= 0 && k < 9007199254740992.0 && floor(k) == k)) return "k";
    if (!(ph == 0 || ph == 1 || ph == 2 || ph == 3)) return "phase";
    if (!(nt == 0 || nt == 1)) return "noticed";
    if (nt == 1 && !(INTERVAL && D->policy == UIOFMU_POLICY_NEAREST)) return "noticed";
    if (ph < 2 && k != 0) return "k";
    if (!(isfinite(hp0) && hp0 > 0)) return "h_prev0";
    if (!INTERVAL && hp0 != D->h_prev0) return "h_prev0";
    if (INTERVAL && ph >= 2 && !model_resolves(hp0)) return "h_prev0";
    if (!(isfinite(hp) && hp > 0)) return "h_prev";
    if (INTERVAL && !model_resolves(hp)) return "h_prev";
    if (k == 0 && (ph >= 2 || !INTERVAL) && hp != hp0) return "h_prev";
    if (!INTERVAL && D->policy == UIOFMU_POLICY_ERROR && k > 0 && !(fabs(hp - D->dt) <= D->step_rtol * D->dt))
        return "h_prev";
    for (size_t i = F_Z; i < F_XHAT0 + (size_t)D->n; i++) {
        const char *name = i < F_PRED ? "z" : i < F_XHAT0 ? "pred" : "xhat0";
        if (!isfinite(v[i])) return name;
        if (i < F_XHAT0 && k == 0 && v[i] != 0) return name;
    }
    return NULL;
}

/* ---------------------------------------------------------------------------------------- */
/* the serialised layout                                                                     */

typedef struct {
    int known, legacy;
    size_t size;     /* bytes of a serialised state */
    size_t data;     /* offset of the doubles */
    size_t guid;     /* offset and length of the GUID */
    size_t glen;
    size_t memsize;  /* bytes of a state in memory */
} Layout;
static Layout L;

#define MAGIC 0x75696f66u

static uint32_t rd32(const unsigned char *b, size_t off) { uint32_t v; memcpy(&v, b + off, 4); return v; }
static void wr32(unsigned char *b, size_t off, uint32_t v) { memcpy(b + off, &v, 4); }
static uint64_t rd64(const unsigned char *b, size_t off) { uint64_t v; memcpy(&v, b + off, 8); return v; }
static void wr64(unsigned char *b, size_t off, uint64_t v) { memcpy(b + off, &v, 8); }
static double rdd(const unsigned char *b, size_t i) { double v; memcpy(&v, b + L.data + 8 * i, 8); return v; }
static void wrd(unsigned char *b, size_t i, double v) { memcpy(b + L.data + 8 * i, &v, 8); }

static void learn_layout(const unsigned char *b, size_t size) {
    size_t g = strlen(FMU_GUID);
    if (L.known) {
        if (size != L.size) fail("a serialised state of %zu bytes, earlier ones had %zu", size, L.size);
        return;
    }
    if (size >= 40 && rd32(b, 0) == MAGIC && rd32(b, 4) == 2) {
        L.legacy = 0;
        L.glen = rd32(b, 16);
        L.guid = 40;
        L.data = 40 + (L.glen + 7) / 8 * 8;
        L.size = L.data + 8 * ND;
        L.memsize = L.size;
        if (L.glen != g || L.size != size) fail("layout 2 state of %zu bytes does not add up", size);
    } else if (size == 12 + 8 * ND + g && rd32(b, 0) == MAGIC) {
        L.legacy = 1;
        L.glen = g;
        L.data = 12;
        L.guid = 12 + 8 * ND;
        L.size = size;
        L.memsize = 16 + 8 * ND;
    } else {
        fail("serialised state of %zu bytes in an unknown layout", size);
        L.size = size;
        L.data = 0;
        L.legacy = 1;
    }
    L.known = 1;
    if (verbose) fprintf(stderr, "layout %d: %zu bytes, doubles at %zu\n", L.legacy ? 1 : 2, L.size, L.data);
}

/* the phase recorded in serialised bytes (PH_NONE when it is none) */
static int phase_in(const unsigned char *b) {
    double ph = rdd(b, FPHASE);
    return ph == 0 || ph == 1 || ph == 2 || ph == 3 ? (int)ph : PH_NONE;
}

static void blob_values(const unsigned char *b, double *v) {
    for (size_t i = 0; i < ND; i++) v[i] = rdd(b, i);
}

static const char *blob_invalid(const unsigned char *b) {
    double *v = malloc(ND * sizeof(double));
    blob_values(b, v);
    const char *why = model_invalid(v);
    free(v);
    return why;
}

/* a state in memory made from serialised bytes (layout 2: the same bytes; layout 1: magic,
   count, doubles, as the legacy runtime kept them) */
static unsigned char *memory_image(const unsigned char *blob) {
    unsigned char *m = malloc(L.memsize);
    if (!L.legacy) {
        memcpy(m, blob, L.size);
    } else { /* the blob's magic and count as they are (a mutation of them carries over) */
        memset(m, 0, 16);
        memcpy(m, blob, 4);
        memcpy(m + 8, blob + 4, 8);
        memcpy(m + 16, blob + L.data, 8 * ND);
    }
    return m;
}

/* a state in memory with the header of one of another size (count doubles) */
static unsigned char *sized_image(const unsigned char *blob, size_t count, size_t *bytes) {
    if (!L.legacy) {
        *bytes = L.data + 8 * count;
        unsigned char *m = calloc(1, *bytes);
        memcpy(m, blob, L.data);
        wr64(m, 8, *bytes);
        wr32(m, 36, (uint32_t)count);
        wr32(m, 20, (uint32_t)(D->n + (count > ND ? 1 : -1)));
        return m;
    }
    *bytes = 16 + 8 * count;
    unsigned char *m = calloc(1, *bytes);
    unsigned magic = MAGIC;
    memcpy(m, &magic, sizeof magic);
    memcpy(m + 8, &count, sizeof count);
    return m;
}

/* ---------------------------------------------------------------------------------------- */
/* states                                                                                    */

#define NSTATES 6
typedef struct {
    void *p;
    int used;
    int forged;   /* 1: its header is not this FMU's (another size or GUID), 2: a layout-1 state made by the
                     fuzzer, which carries no GUID in memory: every use must be refused; 0 otherwise */
    int valid;    /* header this FMU's and values valid by the model */
    int phase;
    int have_out;
    double *out;
} State;
static State pool[NSTATES];
static double *scratch_out;

static int read_outputs(Inst *I, double *out) {
    fmi2ValueReference vr[256];
    int n = NOUT < 256 ? NOUT : 256;
    for (int i = 0; i < n; i++) vr[i] = (fmi2ValueReference)(VR_OUT + i);
    fmi2Status st = CALL(I, F_GetReal, fmi2GetReal(I->c, vr, (size_t)n, out));
    return expect(I, st, fmi2OK, "fmi2GetReal of the outputs");
}

static int read_vector(Inst *I, int first, int n, double *out) {
    fmi2ValueReference vr[256];
    if (n <= 0) return 1;
    for (int i = 0; i < n && i < 256; i++) vr[i] = (fmi2ValueReference)(first + i);
    return expect(I, CALL(I, F_GetReal, fmi2GetReal(I->c, vr, (size_t)n, out)), fmi2OK, "fmi2GetReal");
}

/* The instance's state as serialised bytes (malloc'ed; *len bytes), or NULL. */
static unsigned char *serialise_now(Inst *I, size_t *len) {
    fmi2FMUstate st = NULL;
    size_t size = 0;
    unsigned char *b = NULL;
    if (!expect(I, CALL(I, F_GetFMUstate, fmi2GetFMUstate(I->c, &st)), fmi2OK, "fmi2GetFMUstate (snapshot)")) return NULL;
    if (expect(I, CALL(I, F_SerializedFMUstateSize, fmi2SerializedFMUstateSize(I->c, st, &size)), fmi2OK,
               "fmi2SerializedFMUstateSize (snapshot)")) {
        b = malloc(size ? size : 1);
        if (!expect(I, CALL(I, F_SerializeFMUstate, fmi2SerializeFMUstate(I->c, st, (fmi2Byte *)b, size)), fmi2OK,
                    "fmi2SerializeFMUstate (snapshot)")) {
            free(b);
            b = NULL;
        } else {
            learn_layout(b, size);
            *len = size;
        }
    }
    expect(I, CALL(I, F_FreeFMUstate, fmi2FreeFMUstate(I->c, &st)), fmi2OK, "fmi2FreeFMUstate (snapshot)");
    return b;
}

static int same_snapshot(Inst *I, const unsigned char *before, size_t len, const char *what) {
    size_t len2 = 0;
    unsigned char *after = serialise_now(I, &len2);
    int same = after && len2 == len && memcmp(before, after, len) == 0;
    if (after && !same) fail("%s changed the instance's state although it was refused", what);
    free(after);
    return same;
}

/* the phase the instance is in, read from its state (after an unexpected acceptance) */
static int phase_of(Inst *I) {
    size_t len = 0;
    unsigned char *b = serialise_now(I, &len);
    int ph = b && L.data && len == L.size ? phase_in(b) : PH_NONE;
    free(b);
    return ph != PH_NONE ? ph : I->phase;
}

static State *free_slot(void) {
    for (int i = 0; i < NSTATES; i++) if (!pool[i].used) return &pool[i];
    return NULL;
}
static State *used_slot(void) {
    int start = below(NSTATES);
    for (int i = 0; i < NSTATES; i++) {
        State *s = &pool[(start + i) % NSTATES];
        if (s->used) return s;
    }
    return NULL;
}

/* fill slot s from the state just taken (the outputs are a function of it) */
static void record_state(Inst *I, State *s) {
    size_t len = 0;
    s->have_out = read_outputs(I, s->out);
    unsigned char *b = NULL;
    size_t size = 0;
    if (expect(I, CALL(I, F_SerializedFMUstateSize, fmi2SerializedFMUstateSize(I->c, s->p, &size)), fmi2OK,
               "fmi2SerializedFMUstateSize of a state just taken")) {
        b = malloc(size ? size : 1);
        if (expect(I, CALL(I, F_SerializeFMUstate, fmi2SerializeFMUstate(I->c, s->p, (fmi2Byte *)b, size)), fmi2OK,
                   "fmi2SerializeFMUstate of a state just taken")) {
            learn_layout(b, size);
            len = size;
        }
    }
    if (b && len == L.size && L.data) {
        const char *why = blob_invalid(b);
        s->valid = why == NULL;
        s->phase = phase_in(b);
    } else {
        s->valid = 0;
        s->phase = I->phase;
    }
    free(b);
}

static void release_state(State *s) {
    if (!s->used) return;
    if (s->forged) {
        free(s->p);
    } else {
        Inst *I = live(0) ? live(0) : live(1);
        if (I) expect(I, CALL(I, F_FreeFMUstate, fmi2FreeFMUstate(I->c, &s->p)), fmi2OK, "fmi2FreeFMUstate at cleanup");
        else free(s->p); /* no instance left to ask; the memory is plain malloc'ed */
    }
    s->p = NULL;
    s->used = 0;
    s->forged = 0;
}

/* ---------------------------------------------------------------------------------------- */
/* values                                                                                    */

static double bad_value(void) {
    static const double v[] = {0.0, -0.0, 1e300, -1e300, DBL_MAX, -DBL_MAX, 5e-324, 1e-300, -1.0, 123.0, 1e16};
    switch (below(4)) {
    case 0: return NAN;
    case 1: return chance(0.5) ? INFINITY : -INFINITY;
    default: return v[below((int)(sizeof v / sizeof v[0]))];
    }
}

static double good_step(void) {
    double base = INTERVAL ? D->intervals[below(D->nintervals)] : D->dt;
    if (chance(0.2)) base *= 1.0 + (2 * unif() - 1) * 0.9 * D->step_rtol; /* inside the tolerance */
    return base;
}

static double any_step(void) {
    switch (below(20)) {
    case 0: return 0.0;
    case 1: return -good_step();
    case 2: return NAN;
    case 3: return chance(0.5) ? INFINITY : -INFINITY;
    case 4: return 1e300;
    case 5: return 5e-324;
    case 6: return good_step() * (1 + 3 * D->step_rtol);
    case 7: case 8: return unif() * 2 * (INTERVAL ? D->intervals[D->nintervals - 1] : D->dt);
    default: return good_step();
    }
}

static double input_value(void) { return chance(0.93) ? 10 * normal() : bad_value(); }

static fmi2ValueReference any_vr(void) {
    switch (below(14)) {
    case 0: return (fmi2ValueReference)NV;
    case 1: return (fmi2ValueReference)(NV + 1 + below(100));
    case 2: return 0xFFFFFFFFu;
    case 3: return 0x80000000u;
    case 4: return (fmi2ValueReference)next64();
    default: return (fmi2ValueReference)below(NV);
    }
}

/* ---------------------------------------------------------------------------------------- */
/* actions (random mode)                                                                     */

static void act_instantiate(void) {
    Inst *I = &inst[below(NINST)];
    if (I->c) {
        if (chance(0.7)) return;
        free_instance(I);
    }
    int variant = below(14);
    if (variant < 8) {
        make_instance(I, variant != 0, chance(0.5));
        return;
    }
    Inst tmp;
    instance_setup(&tmp, 1);
    char guid[300];
    const char *g = FMU_GUID, *name = "fuzz";
    fmi2Type type = fmi2CoSimulation;
    const fmi2CallbackFunctions *cb = &tmp.cb;
    switch (variant) {
    case 8: snprintf(guid, sizeof guid, "%s", FMU_GUID); guid[1 + below((int)strlen(FMU_GUID) - 2)] ^= 0x01; g = guid; break;
    case 9: g = chance(0.5) ? NULL : ""; break;
    case 10: type = fmi2ModelExchange; break;
    case 11: cb = NULL; break;
    case 12: name = chance(0.5) ? NULL : ""; break;
    default: memset(guid, 'x', sizeof guid - 1); guid[sizeof guid - 1] = 0; g = guid; break;
    }
    fmi2Component c = fmi2Instantiate(name, type, g, "file:///tmp", cb, fmi2False, fmi2True);
    track(NULL, F_Instantiate, c ? fmi2OK : fmi2Error, 0);
    if (c) {
        fail("fmi2Instantiate accepted a bad call (variant %d: GUID %s, type %d, callbacks %s, name %s)", variant,
             g ? g : "NULL", (int)type, cb ? "set" : "NULL", name ? (name[0] ? name : "empty") : "NULL");
        fmi2FreeInstance(c);
        track(NULL, F_FreeInstance, fmi2OK, 0);
    } else if (cb && tmp.env.lines == 0) {
        fail("fmi2Instantiate refused (variant %d) without a log line", variant);
    }
}

static int params_ok(Inst *I) {
    double x[256], h = 0;
    if (!read_vector(I, VR_XHAT0, D->n, x)) return -1;
    if (!finite_all(x, D->n)) return 0;
    if (INTERVAL) {
        if (!read_vector(I, VR_HPREV0, 1, &h)) return -1;
        int exact;
        if (!(isfinite(h) && h > 0)) return 0;
        nearest_interval(h, &exact);
        if (!exact && D->policy != UIOFMU_POLICY_NEAREST) return 0;
    }
    return 1;
}

static int inputs_finite(Inst *I) {
    double x[512];
    if (!read_vector(I, VR_Y, D->p + D->m, x)) return -1;
    return finite_all(x, D->p + D->m);
}

static void act_phase_call(void) {
    Inst *I = any_live();
    if (!I) return;
    fmi2Status st;
    switch (below(6)) {
    case 0: {
        double v[3] = {unif(), bad_value(), 10 * normal()};
        st = CALL(I, F_SetupExperiment, fmi2SetupExperiment(I->c, below(2), v[below(3)], v[below(3)], below(2), v[below(3)]));
        expect(I, st, I->phase == PH_INSTANTIATED ? fmi2OK : fmi2Error, "fmi2SetupExperiment in phase %d", I->phase);
        break;
    }
    case 1: case 2:
        st = CALL(I, F_EnterInitializationMode, fmi2EnterInitializationMode(I->c));
        if (expect(I, st, I->phase == PH_INSTANTIATED ? fmi2OK : fmi2Error, "fmi2EnterInitializationMode in phase %d",
                   I->phase) && st == fmi2OK)
            I->phase = PH_INIT;
        break;
    case 3: case 4: {
        int ok = I->phase == PH_INIT ? params_ok(I) : 0;
        if (ok < 0) return;
        st = CALL(I, F_ExitInitializationMode, fmi2ExitInitializationMode(I->c));
        if (expect(I, st, ok ? fmi2OK : fmi2Error, "fmi2ExitInitializationMode in phase %d", I->phase) && st == fmi2OK)
            I->phase = PH_RUNNING;
        break;
    }
    default:
        if (chance(0.5)) {
            st = CALL(I, F_Terminate, fmi2Terminate(I->c));
            if (expect(I, st, I->phase == PH_RUNNING ? fmi2OK : fmi2Error, "fmi2Terminate in phase %d", I->phase) &&
                st == fmi2OK)
                I->phase = PH_TERMINATED;
        } else {
            st = CALL(I, F_Reset, fmi2Reset(I->c));
            if (expect(I, st, fmi2OK, "fmi2Reset")) I->phase = PH_INSTANTIATED;
        }
    }
}

/* how fmi2SetReal must answer vr[0..n) in phase ph */
static fmi2Status expected_set(const fmi2ValueReference *vr, int n, int ph) {
    if (ph == PH_TERMINATED) return fmi2Error; /* the mask of fmi2SetXXX, whatever the references */
    for (int i = 0; i < n; i++) {
        if (vr[i] >= (fmi2ValueReference)NV) return fmi2Error;
        if ((int)vr[i] >= VR_OUT) return fmi2Error;
        if ((int)vr[i] < VR_Y && ph != PH_INSTANTIATED && ph != PH_INIT) return fmi2Error;
        if (ph == PH_TERMINATED) return fmi2Error;
    }
    return fmi2OK;
}

static void act_set_real(void) {
    Inst *I = any_live();
    if (!I) return;
    fmi2ValueReference vr[6];
    double v[6];
    int n = below(5);
    for (int i = 0; i < n; i++) {
        int r = below(10);
        if (r < 6) vr[i] = (fmi2ValueReference)(VR_Y + below(D->p + D->m));
        else if (r < 8) vr[i] = (fmi2ValueReference)below(VR_Y);
        else vr[i] = any_vr();
        if ((int)vr[i] == VR_HPREV0) v[i] = chance(0.85) ? good_step() : any_step();
        else v[i] = input_value();
    }
    if (chance(0.03) && n) {
        fmi2Status st = CALL(I, F_SetReal, fmi2SetReal(I->c, chance(0.5) ? NULL : vr, (size_t)n, NULL));
        expect(I, st, fmi2Error, "fmi2SetReal with null arrays");
        return;
    }
    fmi2Status st = CALL(I, F_SetReal, fmi2SetReal(I->c, vr, (size_t)n, v));
    expect(I, st, expected_set(vr, n, I->phase), "fmi2SetReal of %d values in phase %d", n, I->phase);
}

static void act_get_real(void) {
    Inst *I = any_live();
    if (!I) return;
    fmi2ValueReference vr[8];
    double v[8];
    int n = below(8), bad = 0;
    for (int i = 0; i < n; i++) {
        vr[i] = chance(0.85) ? (fmi2ValueReference)below(NV) : any_vr();
        bad |= vr[i] >= (fmi2ValueReference)NV;
    }
    fmi2Status st = CALL(I, F_GetReal, fmi2GetReal(I->c, vr, (size_t)n, v));
    expect(I, st, bad ? fmi2Error : fmi2OK, "fmi2GetReal of %d values", n);
}

static void act_step(void) {
    Inst *I = any_live();
    if (!I) return;
    double h = any_step(), t = chance(0.9) ? 100 * unif() : bad_value();
    int fin = 1;
    fmi2Status want;
    if (I->phase == PH_RUNNING && isfinite(h) && h > 0) {
        fin = inputs_finite(I);
        if (fin < 0) return;
    }
    int rounding = step_rounding(h);
    if (I->phase != PH_RUNNING || !isfinite(t) || !(isfinite(h) && h > 0) || (!fin && !rounding)) want = fmi2Error;
    else if (rounding || step_exact(h)) want = fmi2OK;
    else if (INTERVAL) want = D->policy == UIOFMU_POLICY_NEAREST ? fmi2OK : fmi2Discard;
    else want = D->policy == UIOFMU_POLICY_COUNT ? fmi2OK : fmi2Discard;
    unsigned char *snap = NULL;
    size_t len = 0;
    if (want != fmi2OK && chance(0.3)) snap = serialise_now(I, &len);
    fmi2Status st = CALL(I, F_DoStep, fmi2DoStep(I->c, t, h, fmi2True));
    expect(I, st, want, "fmi2DoStep(h = %.17g) in phase %d", h, I->phase);
    if (snap && st != fmi2OK) same_snapshot(I, snap, len, "a refused fmi2DoStep");
    free(snap);
}

static void act_get_state(void) {
    Inst *I = any_live();
    if (!I) return;
    int r = below(10);
    if (r == 0) {
        expect(I, CALL(I, F_GetFMUstate, fmi2GetFMUstate(I->c, NULL)), fmi2Error, "fmi2GetFMUstate(NULL)");
        return;
    }
    State *s = r < 6 ? free_slot() : used_slot();
    if (!s) s = used_slot();
    if (!s) return;
    if (!s->used) {
        s->p = NULL;
        if (!expect(I, CALL(I, F_GetFMUstate, fmi2GetFMUstate(I->c, &s->p)), fmi2OK, "fmi2GetFMUstate") || !s->p) return;
        s->used = 1;
        s->forged = 0;
        record_state(I, s);
        return;
    }
    void *before = s->p;
    fmi2Status st = CALL(I, F_GetFMUstate, fmi2GetFMUstate(I->c, &s->p));
    if (s->forged) {
        expect(I, st, fmi2Error, "fmi2GetFMUstate reusing a state of another size or FMU");
        if (s->p != before) {
            fail("fmi2GetFMUstate replaced the pointer to a state it refused to reuse");
            s->p = before;
        }
    } else if (expect(I, st, fmi2OK, "fmi2GetFMUstate reusing one of its states")) {
        record_state(I, s);
    }
}

static void act_forge(void) {
    Inst *I = any_live();
    State *s = free_slot();
    if (!I || !s) return;
    size_t len = 0;
    unsigned char *blob = serialise_now(I, &len);
    if (!blob || len != L.size || !L.data) { free(blob); return; }
    int kind = below(4);
    size_t bytes = 0;
    if (kind < 2) { /* another size */
        size_t count = kind == 0 ? (size_t)below((int)ND) : ND + 1 + (size_t)below(8);
        s->p = sized_image(blob, count, &bytes);
        s->forged = 1;
        s->valid = 0;
    } else if (kind == 2) { /* another FMU's GUID, equal dims */
        unsigned char *m = memory_image(blob);
        if (!L.legacy) m[L.guid + 1 + (size_t)below((int)L.glen - 2)] ^= 0x01;
        s->p = m;
        s->forged = !L.legacy ? 1 : 2; /* layout 1 carries no GUID in memory: it cannot tell */
        s->valid = 0;
    } else { /* this FMU's header, one value overwritten */
        size_t f = (size_t)below((int)ND);
        double v = bad_value();
        wrd(blob, f, v);
        s->p = memory_image(blob);
        s->forged = 0; /* this FMU's header (plain malloc'ed memory, which the FMU may free) */
        s->valid = blob_invalid(blob) == NULL;
    }
    s->phase = phase_in(blob);
    s->used = 1;
    s->have_out = 0;
    free(blob);
}

static int must_refuse(const State *s) { return s->forged == 1 || s->forged == 2 || !s->valid; }

static void act_set_state(void) {
    Inst *I = any_live();
    if (!I) return;
    if (chance(0.05)) {
        expect(I, CALL(I, F_SetFMUstate, fmi2SetFMUstate(I->c, NULL)), fmi2Error, "fmi2SetFMUstate(NULL)");
        return;
    }
    State *s = used_slot();
    if (!s) return;
    size_t len = 0;
    unsigned char *snap = must_refuse(s) && chance(0.5) ? serialise_now(I, &len) : NULL;
    fmi2Status st = CALL(I, F_SetFMUstate, fmi2SetFMUstate(I->c, s->p));
    if (must_refuse(s)) {
        if (!expect(I, st, fmi2Error, "fmi2SetFMUstate of a %s state",
                    s->forged == 1 || s->forged == 2 ? "foreign" : "forged or invalid"))
            I->phase = phase_of(I); /* accepted after all: follow it */
        else if (snap)
            same_snapshot(I, snap, len, "a refused fmi2SetFMUstate");
    } else if (expect(I, st, fmi2OK, "fmi2SetFMUstate of a valid state")) {
        I->phase = s->phase;
        if (s->have_out) {
            if (read_outputs(I, scratch_out) && memcmp(scratch_out, s->out, (size_t)NOUT * sizeof(double)) != 0)
                fail("the outputs after fmi2SetFMUstate differ from those when the state was taken");
        }
    }
    free(snap);
}

static void act_free_state(void) {
    Inst *I = any_live();
    if (!I) return;
    if (chance(0.1)) {
        fmi2FMUstate none = NULL;
        expect(I, CALL(I, F_FreeFMUstate, fmi2FreeFMUstate(I->c, chance(0.5) ? NULL : &none)), fmi2OK,
               "fmi2FreeFMUstate of nothing");
        return;
    }
    State *s = used_slot();
    if (!s) return;
    fmi2Status st = CALL(I, F_FreeFMUstate, fmi2FreeFMUstate(I->c, &s->p));
    if (s->forged == 1 || s->forged == 2) {
        if (st == fmi2OK) {
            fail("fmi2FreeFMUstate freed a state that is not one of this FMU's");
            s->used = 0; /* gone: do not free it again */
            s->p = NULL;
        } else {
            expect(I, st, fmi2Error, "fmi2FreeFMUstate of a foreign state");
        }
        return;
    }
    if (expect(I, st, fmi2OK, "fmi2FreeFMUstate") && s->p)
        fail("fmi2FreeFMUstate did not set the state pointer to NULL");
    if (st == fmi2OK) {
        s->used = 0;
        s->p = NULL;
        s->forged = 0;
    }
}

static void act_serialize(void) {
    Inst *I = any_live();
    State *s = used_slot();
    if (!I || !s) return;
    size_t size = 0;
    int foreign = s->forged == 1;
    fmi2Status st = CALL(I, F_SerializedFMUstateSize, fmi2SerializedFMUstateSize(I->c, s->p, &size));
    if (foreign) {
        expect(I, st, fmi2Error, "fmi2SerializedFMUstateSize of a foreign state");
        size = L.size;
    } else if (!expect(I, st, fmi2OK, "fmi2SerializedFMUstateSize") ) {
        return;
    } else if (L.known && size != L.size) {
        fail("fmi2SerializedFMUstateSize says %zu bytes, states are %zu", size, L.size);
    }
    size_t want = size, have;
    switch (below(6)) {
    case 0: have = want > 0 ? want - 1 - (size_t)below((int)want) : 0; break;
    case 1: have = want + 1 + (size_t)below(64); break;
    case 2: have = (size_t)below((int)(2 * want + 2)); break;
    default: have = want;
    }
    if (chance(0.03)) {
        st = CALL(I, F_SerializeFMUstate, fmi2SerializeFMUstate(I->c, s->p, NULL, have));
        expect(I, st, fmi2Error, "fmi2SerializeFMUstate into NULL");
        return;
    }
    unsigned char *buf = malloc(have ? have : 1);
    memset(buf, 0xA5, have ? have : 1);
    st = CALL(I, F_SerializeFMUstate, fmi2SerializeFMUstate(I->c, s->p, (fmi2Byte *)buf, have));
    expect(I, st, !foreign && have >= want ? fmi2OK : fmi2Error, "fmi2SerializeFMUstate of %zu into %zu bytes", want, have);
    if (st == fmi2OK)
        for (size_t i = want; i < have; i++)
            if (buf[i] != 0xA5) {
                fail("fmi2SerializeFMUstate wrote byte %zu of a %zu-byte buffer, past the %zu of the state", i, have, want);
                break;
            }
    free(buf);
}

/* A mutation of serialised bytes: what it did, and whether the result must be refused
   (1), accepted (0) or judged by the value model (-1). */
static int mutate(unsigned char **blob, size_t *len, char *what, size_t wlen) {
    unsigned char *b = *blob;
    static const double values[] = {NAN, INFINITY, -INFINITY, -1.0, 123.0, 1e300, 0.0, 0.5, -0.0, 5e-324};
    static const char *const vnames[] = {"nan", "inf", "-inf", "-1", "123", "1e300", "0", "0.5", "-0", "5e-324"};
    int kind = below(L.legacy ? 8 : 11);
    switch (kind) {
    case 0: case 1: case 2: { /* one double overwritten */
        size_t f = (size_t)below((int)ND);
        int v = below((int)(sizeof values / sizeof values[0]));
        wrd(b, f, values[v]);
        snprintf(what, wlen, "double %zu := %s", f, vnames[v]);
        return -1;
    }
    case 3: { /* a scalar set to an admissible step or a small integer */
        size_t f = (size_t)below(NSCALAR);
        double v = f == FHPREV || f == FHPREV0 ? good_step() : (double)below(5);
        wrd(b, f, v);
        snprintf(what, wlen, "double %zu := %.17g", f, v);
        return -1;
    }
    case 4: { /* bit flip */
        size_t at = (size_t)below((int)*len);
        b[at] ^= (unsigned char)(1u << below(8));
        snprintf(what, wlen, "bit flip in byte %zu", at);
        if (at >= L.data && at < L.data + 8 * ND) return -1;
        return 1;
    }
    case 5: { /* GUID byte */
        size_t at = L.guid + (size_t)below((int)L.glen);
        b[at] = (unsigned char)(b[at] == 'f' ? '0' : b[at] + 1);
        snprintf(what, wlen, "GUID byte %zu changed", at);
        return 1;
    }
    case 6: { /* truncated */
        size_t n = (size_t)below((int)*len);
        *len = n;
        snprintf(what, wlen, "truncated to %zu bytes", n);
        return 1;
    }
    case 7: { /* extended */
        size_t extra = 1 + (size_t)below(32);
        unsigned char *nb = realloc(b, *len + extra);
        memset(nb + *len, below(2) ? 0 : 0x5A, extra);
        *blob = nb;
        *len += extra;
        snprintf(what, wlen, "extended by %zu bytes", extra);
        return 1;
    }
    case 8: { /* layout version */
        uint32_t v = below(2) ? 1u : 3u + (uint32_t)below(1000);
        wr32(b, 4, v);
        snprintf(what, wlen, "layout := %u", (unsigned)v);
        return 1;
    }
    case 9: { /* size or count field */
        if (below(2)) {
            uint64_t v = rd64(b, 8) + (uint64_t)(below(2) ? 8 : -8);
            wr64(b, 8, v);
            snprintf(what, wlen, "size field := %llu", (unsigned long long)v);
        } else {
            wr32(b, 36, rd32(b, 36) + 1);
            snprintf(what, wlen, "count field + 1");
        }
        return 1;
    }
    default: { /* dims or GUID length */
        size_t off = 16 + 4 * (size_t)below(5);
        wr32(b, off, rd32(b, off) + 1);
        snprintf(what, wlen, "header field at %zu + 1", off);
        return 1;
    }
    }
}

static void act_deserialize(void) {
    Inst *I = any_live();
    if (!I) return;
    Inst *src = any_live();
    size_t len = 0;
    unsigned char *blob = serialise_now(src, &len);
    if (!blob || !L.data || len != L.size) { free(blob); return; }
    char what[128] = "honest bytes";
    int verdict = 0;
    int mutated = chance(0.7);
    if (mutated) verdict = mutate(&blob, &len, what, sizeof what);
    if (verdict < 0) verdict = blob_invalid(blob) != NULL;
    else if (!mutated) verdict = blob_invalid(blob) != NULL;
    int phase = len == L.size ? phase_in(blob) : PH_NONE;
    /* into a new state, a state of the pool, or NULL bytes */
    State *target = NULL;
    fmi2FMUstate fresh = NULL, *into = &fresh;
    int r = below(10);
    if (r == 0) {
        expect(I, CALL(I, F_DeSerializeFMUstate, fmi2DeSerializeFMUstate(I->c, NULL, len, &fresh)), fmi2Error,
               "fmi2DeSerializeFMUstate(NULL bytes)");
        free(blob);
        return;
    }
    if (r < 3 && (target = used_slot()) != NULL) into = &target->p;
    int reuse_foreign = target && (target->forged == 1 || target->forged == 2);
    fmi2Status want = verdict || reuse_foreign ? fmi2Error : fmi2OK;
    size_t slen = 0;
    unsigned char *snap = want != fmi2OK && chance(0.3) ? serialise_now(I, &slen) : NULL;
    void *before = target ? target->p : NULL;
    fmi2Status st = CALL(I, F_DeSerializeFMUstate, fmi2DeSerializeFMUstate(I->c, (const fmi2Byte *)blob, len, into));
    expect(I, st, want, "fmi2DeSerializeFMUstate of %s%s", what, reuse_foreign ? " into a foreign state" : "");
    if (snap) same_snapshot(I, snap, slen, "a refused fmi2DeSerializeFMUstate");
    free(snap);
    if (st != fmi2OK) {
        if (target && target->p != before) {
            fail("fmi2DeSerializeFMUstate replaced the pointer to a state it refused");
            target->p = before;
        }
        free(blob);
        return;
    }
    State *s = target;
    if (!s) {
        s = free_slot();
        if (!s) { /* no room: drop it again */
            expect(I, CALL(I, F_FreeFMUstate, fmi2FreeFMUstate(I->c, &fresh)), fmi2OK, "fmi2FreeFMUstate");
            free(blob);
            return;
        }
        s->p = fresh;
        s->forged = 0;
    } else {
        s->forged = 0; /* now holds this FMU's bytes (accepted even if it should not have been) */
    }
    s->used = 1;
    s->valid = !verdict && !reuse_foreign;
    s->phase = phase;
    s->have_out = 0;
    free(blob);
    if (chance(0.6)) act_set_state();
}

/* bitwise replay from a state, in the same instance and through bytes in the other one */
static void act_replay(void) {
    Inst *I = any_live();
    if (!I || I->phase != PH_RUNNING) return;
    int fin = inputs_finite(I);
    if (fin <= 0) return;
    int steps = 1 + below(8);
    double *in = malloc((size_t)steps * (size_t)(D->p + D->m) * sizeof(double)), *h = malloc((size_t)steps * sizeof(double));
    double *out1 = malloc((size_t)steps * (size_t)NOUT * sizeof(double)), *out2 = malloc((size_t)steps * (size_t)NOUT * sizeof(double));
    fmi2ValueReference vr[512];
    for (int i = 0; i < D->p + D->m; i++) vr[i] = (fmi2ValueReference)(VR_Y + i);
    for (int k = 0; k < steps; k++) {
        h[k] = good_step();
        for (int i = 0; i < D->p + D->m; i++) in[k * (D->p + D->m) + i] = 10 * normal();
    }
    fmi2FMUstate st = NULL;
    size_t len = 0;
    unsigned char *blob = NULL;
    if (!expect(I, CALL(I, F_GetFMUstate, fmi2GetFMUstate(I->c, &st)), fmi2OK, "fmi2GetFMUstate (replay)")) goto done;
    {   /* a state that overflowed (z or pred not finite after huge inputs) is refused by design */
        size_t n = 0;
        unsigned char *now_b = serialise_now(I, &n);
        int invalid = !now_b || n != L.size || blob_invalid(now_b) != NULL;
        free(now_b);
        if (invalid) {
            expect(I, CALL(I, F_FreeFMUstate, fmi2FreeFMUstate(I->c, &st)), fmi2OK, "fmi2FreeFMUstate (replay)");
            goto done;
        }
    }
    int ok = 1;
    for (int pass = 0; pass < 2 && ok; pass++) {
        double *out = pass ? out2 : out1;
        for (int k = 0; k < steps && ok; k++) {
            ok &= expect(I, CALL(I, F_SetReal, fmi2SetReal(I->c, vr, (size_t)(D->p + D->m), &in[k * (D->p + D->m)])),
                         fmi2OK, "fmi2SetReal (replay)");
            ok &= read_outputs(I, &out[k * NOUT]);
            ok &= expect(I, CALL(I, F_DoStep, fmi2DoStep(I->c, 0.0, h[k], fmi2True)), fmi2OK, "fmi2DoStep (replay)");
        }
        if (pass == 0 && ok)
            ok &= expect(I, CALL(I, F_SetFMUstate, fmi2SetFMUstate(I->c, st)), fmi2OK, "fmi2SetFMUstate (replay)");
    }
    if (ok && memcmp(out1, out2, (size_t)steps * (size_t)NOUT * sizeof(double)) != 0)
        fail("replaying %d steps from a state gave other outputs", steps);
    /* the same through serialised bytes into the other instance */
    Inst *J = live(I == &inst[0] ? 1 : 0);
    if (ok && J && chance(0.6)) {
        size_t size = 0;
        fmi2FMUstate st2 = NULL;
        if (expect(I, CALL(I, F_SerializedFMUstateSize, fmi2SerializedFMUstateSize(I->c, st, &size)), fmi2OK, "size")) {
            blob = malloc(size);
            len = size;
            if (expect(I, CALL(I, F_SerializeFMUstate, fmi2SerializeFMUstate(I->c, st, (fmi2Byte *)blob, len)), fmi2OK,
                       "fmi2SerializeFMUstate (replay)") &&
                expect(J, CALL(J, F_DeSerializeFMUstate, fmi2DeSerializeFMUstate(J->c, (fmi2Byte *)blob, len, &st2)),
                       fmi2OK, "fmi2DeSerializeFMUstate in the other instance (replay)") &&
                expect(J, CALL(J, F_SetFMUstate, fmi2SetFMUstate(J->c, st2)), fmi2OK, "fmi2SetFMUstate (replay)")) {
                J->phase = PH_RUNNING;
                for (int k = 0; k < steps && ok; k++) {
                    ok &= expect(J, CALL(J, F_SetReal, fmi2SetReal(J->c, vr, (size_t)(D->p + D->m), &in[k * (D->p + D->m)])),
                                 fmi2OK, "fmi2SetReal (replay)");
                    ok &= read_outputs(J, &out2[k * NOUT]);
                    ok &= expect(J, CALL(J, F_DoStep, fmi2DoStep(J->c, 0.0, h[k], fmi2True)), fmi2OK, "fmi2DoStep (replay)");
                }
                if (ok && memcmp(out1, out2, (size_t)steps * (size_t)NOUT * sizeof(double)) != 0)
                    fail("replaying %d steps from a deserialised state in another instance gave other outputs", steps);
            }
            if (st2) expect(J, CALL(J, F_FreeFMUstate, fmi2FreeFMUstate(J->c, &st2)), fmi2OK, "fmi2FreeFMUstate");
        }
    }
    expect(I, CALL(I, F_FreeFMUstate, fmi2FreeFMUstate(I->c, &st)), fmi2OK, "fmi2FreeFMUstate (replay)");
done:
    free(in); free(h); free(out1); free(out2); free(blob);
}

static void act_other_types(void) {
    Inst *I = any_live();
    if (!I) return;
    fmi2ValueReference vr[3] = {0, (fmi2ValueReference)below(NV), 0xFFFFFFFFu};
    fmi2Integer iv[3] = {0, 1, 2};
    fmi2Boolean bv[3] = {0, 1, 0};
    fmi2String sv[3] = {"a", "", NULL};
    size_t n = (size_t)below(4);
    /* no Integer, Boolean or String variables: any reference is refused; fmi2SetXXX is illegal after
       fmi2Terminate even with none */
    fmi2Status want = n ? fmi2Error : fmi2OK, wset = n || I->phase == PH_TERMINATED ? fmi2Error : fmi2OK, st;
    switch (below(6)) {
    case 0: st = CALL(I, F_GetInteger, fmi2GetInteger(I->c, vr, n, iv)); expect(I, st, want, "fmi2GetInteger"); break;
    case 1: st = CALL(I, F_SetInteger, fmi2SetInteger(I->c, vr, n, iv)); expect(I, st, wset, "fmi2SetInteger"); break;
    case 2: st = CALL(I, F_GetBoolean, fmi2GetBoolean(I->c, vr, n, bv)); expect(I, st, want, "fmi2GetBoolean"); break;
    case 3: st = CALL(I, F_SetBoolean, fmi2SetBoolean(I->c, vr, n, bv)); expect(I, st, wset, "fmi2SetBoolean"); break;
    case 4: st = CALL(I, F_GetString, fmi2GetString(I->c, vr, n, sv)); expect(I, st, want, "fmi2GetString"); break;
    default: st = CALL(I, F_SetString, fmi2SetString(I->c, vr, n, sv)); expect(I, st, wset, "fmi2SetString"); break;
    }
}

/* How a status query must answer (fmi2_plumbing.c): legal after initialisation only; each kind to
   its function (fmi2LastSuccessfulTime and fmi2Terminated answered, fmi2Terminated true only in step
   discarded, fmi2DoStepStatus and
   fmi2PendingStatus discarded: no step is ever pending); another kind, or none, is an error. */
static fmi2Status expected_query(const Inst *I, int fn, int kind, int null) {
    if (I->phase != PH_RUNNING && I->phase != PH_TERMINATED) return fmi2Error;
    if (null) return fmi2Error;
    switch (fn) {
    case F_GetStatus: return kind == fmi2DoStepStatus ? fmi2Discard : fmi2Error;
    case F_GetRealStatus: return kind == fmi2LastSuccessfulTime ? fmi2OK : fmi2Error; /* or Discard: see below */
    case F_GetBooleanStatus: return kind == fmi2Terminated ? fmi2OK : fmi2Error;
    case F_GetStringStatus: return kind == fmi2PendingStatus ? fmi2Discard : fmi2Error;
    default: return fmi2Error; /* FMI 2.0 has no Integer status */
    }
}

static void query(Inst *I, int fn, int kind, int null) {
    fmi2Status sv = fmi2OK, want = expected_query(I, fn, kind, null), st;
    fmi2Real rv = -1.0;
    fmi2Integer iv = 0;
    fmi2Boolean bv = 7;
    fmi2String strv = NULL;
    fmi2StatusKind k = (fmi2StatusKind)kind;
    switch (fn) {
    case F_GetStatus: st = CALL(I, F_GetStatus, fmi2GetStatus(I->c, k, null ? NULL : &sv)); break;
    case F_GetRealStatus: st = CALL(I, F_GetRealStatus, fmi2GetRealStatus(I->c, k, null ? NULL : &rv)); break;
    case F_GetIntegerStatus: st = CALL(I, F_GetIntegerStatus, fmi2GetIntegerStatus(I->c, k, null ? NULL : &iv)); break;
    case F_GetBooleanStatus: st = CALL(I, F_GetBooleanStatus, fmi2GetBooleanStatus(I->c, k, null ? NULL : &bv)); break;
    default: st = CALL(I, F_GetStringStatus, fmi2GetStringStatus(I->c, k, null ? NULL : &strv)); break;
    }
    /* fmi2LastSuccessfulTime is not known after fmi2SetFMUstate (the state carries no time) until a step */
    if (fn == F_GetRealStatus && want == fmi2OK && st == fmi2Discard) {
        if (I->env.cats & (1u << CAT_DISCARD))
            last_log_has(I, "not known", "fmi2GetRealStatus(fmi2LastSuccessfulTime) discarded");
        return;
    }
    if (!expect(I, st, want, "%s(kind %d%s) in phase %d", FN[fn], kind, null ? ", NULL" : "", I->phase)) return;
    if (st == fmi2OK && fn == F_GetRealStatus && !isfinite(rv)) fail("fmi2LastSuccessfulTime = %g", rv);
    if (st == fmi2OK && fn == F_GetBooleanStatus && bv != (I->discarded ? fmi2True : fmi2False))
        fail("fmi2Terminated = %d, expected %d (the last step %s)", bv, I->discarded,
             I->discarded ? "was refused: it would be refused again" : "was not refused");
    if (st == fmi2Discard && I->env.cats & (1u << CAT_DISCARD)) last_log_has(I, "no fmi2DoStep is pending", FN[fn]);
}

/* the log categories: fmi2SetDebugLogging with known, unknown and NULL ones (the model follows) */
static void act_debug_logging(Inst *I) {
    static const char *const names[6] = {"logStatusError", "logEvents", "logStatusDiscard", "logStatusWarning",
                                         "nonsense", ""};
    fmi2String cats[3];
    size_t n = (size_t)below(4);
    int null = n && chance(0.05), bad = 0, unknown = 0, on = chance(0.8);
    unsigned named = 0;
    for (size_t i = 0; i < n; i++) {
        int r = below(20);
        cats[i] = r < 16 ? names[r % 4] : r < 18 ? names[4 + (r & 1)] : NULL;
        if (!cats[i]) bad = 1;
        else if (r >= 16) unknown = 1;
        else named |= 1u << (r % 4 == 0 ? CAT_ERROR : r % 4 == 1 ? CAT_EVENTS : r % 4 == 2 ? CAT_DISCARD : CAT_WARNING);
    }
    /* a NULL is refused; an unknown category is ignored with a warning, the known ones applied */
    fmi2Status want = null || bad ? fmi2Error : unknown ? fmi2Warning : fmi2OK;
    fmi2Status st = CALL(I, F_SetDebugLogging, fmi2SetDebugLogging(I->c, on, n, null ? NULL : cats));
    if (!expect(I, st, want, "fmi2SetDebugLogging(%d, %zu categories%s)", on, n,
                null || bad ? ", NULL" : unknown ? ", unknown" : ""))
        return;
    if (st == fmi2Error) {
        if (I->env.cats & (1u << CAT_ERROR)) last_log_has(I, "categor", "fmi2SetDebugLogging refused");
        return;
    }
    if (st == fmi2Warning && I->env.cats & (1u << CAT_WARNING))
        last_log_has(I, "not a log category of this FMU", "an unknown category ignored");
    if (!n) I->env.cats = on ? CAT_ALL : 0u;
    else if (on) I->env.cats = named;
    else I->env.cats &= ~named;
}

/* the status queries, the log categories and the unsupported calls */
static void act_queries(void) {
    Inst *I = any_live();
    if (!I) return;
    int kind = chance(0.9) ? below(4) : (chance(0.5) ? -1 - below(3) : 4 + below(100));
    int null = chance(0.1);
    fmi2ValueReference vr[2] = {0, 1};
    fmi2Integer order[2] = {1, 1};
    double val[2] = {0, 0};
    switch (below(10)) {
    case 0: query(I, F_GetStatus, kind, null); break;
    case 1: query(I, F_GetRealStatus, kind, null); break;
    case 2: query(I, F_GetIntegerStatus, kind, null); break;
    case 3: query(I, F_GetBooleanStatus, kind, null); break;
    case 4: query(I, F_GetStringStatus, kind, null); break;
    case 5: expect(I, CALL(I, F_CancelStep, fmi2CancelStep(I->c)), fmi2Error, "fmi2CancelStep"); break;
    case 6:
        expect(I, CALL(I, F_GetDirectionalDerivative, fmi2GetDirectionalDerivative(I->c, vr, 1, vr, 1, val, val)),
               fmi2Error, "fmi2GetDirectionalDerivative");
        break;
    case 7:
        expect(I, CALL(I, F_SetRealInputDerivatives, fmi2SetRealInputDerivatives(I->c, vr, 1, order, val)), fmi2Error,
               "fmi2SetRealInputDerivatives");
        break;
    case 8:
        expect(I, CALL(I, F_GetRealOutputDerivatives, fmi2GetRealOutputDerivatives(I->c, vr, 1, order, val)), fmi2Error,
               "fmi2GetRealOutputDerivatives");
        break;
    default: act_debug_logging(I);
    }
}

/* every function with a null instance: fmi2Error, nothing else */
static void act_null_component(void) {
    fmi2FMUstate st = NULL;
    size_t size;
    double v = 0;
    fmi2ValueReference vr = 0;
    fmi2Status got;
    switch (below(8)) {
    case 0: got = CALL(NULL, F_DoStep, fmi2DoStep(NULL, 0, 1, 1)); break;
    case 1: got = CALL(NULL, F_GetReal, fmi2GetReal(NULL, &vr, 1, &v)); break;
    case 2: got = CALL(NULL, F_SetReal, fmi2SetReal(NULL, &vr, 1, &v)); break;
    case 3: got = CALL(NULL, F_GetFMUstate, fmi2GetFMUstate(NULL, &st)); break;
    case 4: got = CALL(NULL, F_SetFMUstate, fmi2SetFMUstate(NULL, NULL)); break;
    case 5: got = CALL(NULL, F_SerializedFMUstateSize, fmi2SerializedFMUstateSize(NULL, NULL, &size)); break;
    case 6: got = CALL(NULL, F_Reset, fmi2Reset(NULL)); break;
    default: got = CALL(NULL, F_SetDebugLogging, fmi2SetDebugLogging(NULL, 1, 0, NULL)); break;
    }
    expect(NULL, got, fmi2Error, "a call with a null instance");
    if (chance(0.2)) {
        fmi2FreeInstance(NULL);
        track(NULL, F_FreeInstance, fmi2OK, 0);
    }
}

static void act_versions(void) {
    const char *tp = fmi2GetTypesPlatform(), *v = fmi2GetVersion();
    track(NULL, F_GetTypesPlatform, tp && strcmp(tp, fmi2TypesPlatform) == 0 ? fmi2OK : fmi2Error, 0);
    track(NULL, F_GetVersion, v && strcmp(v, "2.0") == 0 ? fmi2OK : fmi2Error, 0);
    if (!tp || strcmp(tp, fmi2TypesPlatform) != 0 || !v || strcmp(v, "2.0") != 0)
        fail("fmi2GetTypesPlatform/fmi2GetVersion: %s, %s", tp ? tp : "NULL", v ? v : "NULL");
}

/* bring an instance to running with finite inputs (so that sequences get somewhere) */
static void start_instance(Inst *I, int random_params) {
    if (I->phase != PH_INSTANTIATED) {
        if (!expect(I, CALL(I, F_Reset, fmi2Reset(I->c)), fmi2OK, "fmi2Reset")) return;
        I->phase = PH_INSTANTIATED;
    }
    expect(I, CALL(I, F_SetupExperiment, fmi2SetupExperiment(I->c, 0, 0, 0, 0, 0)), fmi2OK, "fmi2SetupExperiment");
    if (!expect(I, CALL(I, F_EnterInitializationMode, fmi2EnterInitializationMode(I->c)), fmi2OK, "enter")) return;
    I->phase = PH_INIT;
    if (random_params) {
        fmi2ValueReference vr[256];
        double v[256];
        int n = 0;
        for (int i = 0; i < D->n && n < 255; i++) { vr[n] = (fmi2ValueReference)(VR_XHAT0 + i); v[n++] = 10 * normal(); }
        if (INTERVAL) { vr[n] = (fmi2ValueReference)VR_HPREV0; v[n++] = good_step(); }
        expect(I, CALL(I, F_SetReal, fmi2SetReal(I->c, vr, (size_t)n, v)), fmi2OK, "fmi2SetReal of the parameters");
    }
    int ok = params_ok(I); /* earlier calls may have left bad parameters */
    if (ok < 0) return;
    if (expect(I, CALL(I, F_ExitInitializationMode, fmi2ExitInitializationMode(I->c)), ok ? fmi2OK : fmi2Error,
               "fmi2ExitInitializationMode") && ok)
        I->phase = PH_RUNNING;
}

static void act_start(void) {
    Inst *I = any_live();
    if (I) start_instance(I, chance(0.5));
}

typedef void (*Action)(void);
static const struct { Action f; int weight; } ACTIONS[] = {
    {act_instantiate, 3}, {act_phase_call, 8}, {act_start, 3}, {act_set_real, 12}, {act_get_real, 6},
    {act_step, 16}, {act_get_state, 5}, {act_forge, 2}, {act_set_state, 5}, {act_free_state, 3},
    {act_serialize, 3}, {act_deserialize, 7}, {act_replay, 2}, {act_other_types, 2}, {act_queries, 2},
    {act_null_component, 1}, {act_versions, 1},
};

static void run_sequence(void) {
    int total = 0;
    for (size_t a = 0; a < sizeof ACTIONS / sizeof ACTIONS[0]; a++) total += ACTIONS[a].weight;
    snprintf(where, sizeof where, "random");
    make_instance(&inst[0], 1, chance(0.5));
    if (chance(0.6)) make_instance(&inst[1], chance(0.9), chance(0.5));
    if (chance(0.8)) act_start();
    int len = 20 + below(380);
    for (int i = 0; i < len; i++) {
        int r = below(total);
        size_t a = 0;
        while (r >= ACTIONS[a].weight) r -= ACTIONS[a++].weight;
        ACTIONS[a].f();
    }
    if (!live(0) && !live(1)) make_instance(&inst[0], 1, 0);
    for (int i = 0; i < NSTATES; i++) release_state(&pool[i]);
    for (int i = 0; i < NINST; i++) free_instance(&inst[i]);
    sequences++;
}

/* ---------------------------------------------------------------------------------------- */
/* scenarios: the known attacks, each with the status it must get                            */

static Inst *A, *B;

/* A running instance after k admissible steps (inputs finite). */
static void drive(Inst *I, int k) {
    fmi2ValueReference vr[512];
    double v[512];
    for (int i = 0; i < D->p + D->m; i++) vr[i] = (fmi2ValueReference)(VR_Y + i);
    for (int s = 0; s < k; s++) {
        for (int i = 0; i < D->p + D->m; i++) v[i] = 1.0 + 0.25 * s + 0.5 * i;
        expect(I, CALL(I, F_SetReal, fmi2SetReal(I->c, vr, (size_t)(D->p + D->m), v)), fmi2OK, "fmi2SetReal (drive)");
        double h = INTERVAL ? D->intervals[(s * 5 + 1) % D->nintervals] : D->dt;
        expect(I, CALL(I, F_DoStep, fmi2DoStep(I->c, 0.0, h, fmi2True)), fmi2OK, "fmi2DoStep (drive)");
    }
}

static void start_both(int steps) {
    for (int i = 0; i < NINST; i++) {
        free_instance(&inst[i]);
        make_instance(&inst[i], 1, 1);
        start_instance(&inst[i], 0);
    }
    A = &inst[0];
    B = &inst[1];
    drive(A, steps);
    drive(B, steps);
}

/* The instance still steps after a refusal: an admissible step with finite inputs is fmi2OK. */
static void still_steps(Inst *I, const char *what) {
    if (I->phase != PH_RUNNING) return;
    fmi2ValueReference vr[512];
    double v[512];
    for (int i = 0; i < D->p + D->m; i++) { vr[i] = (fmi2ValueReference)(VR_Y + i); v[i] = 0.5; }
    expect(I, CALL(I, F_SetReal, fmi2SetReal(I->c, vr, (size_t)(D->p + D->m), v)), fmi2OK, "fmi2SetReal after %s", what);
    expect(I, CALL(I, F_DoStep, fmi2DoStep(I->c, 0.0, good_step(), fmi2True)), fmi2OK, "a step after %s", what);
    read_outputs(I, scratch_out);
}

/* Deserialise bytes into I: want the status, the refusal naming `word`, the state unchanged. */
static fmi2Status try_bytes(Inst *I, const unsigned char *b, size_t len, fmi2Status want, const char *word,
                            const char *what, int set_after) {
    size_t slen = 0;
    unsigned char *snap = serialise_now(I, &slen);
    fmi2FMUstate st = NULL;
    fmi2Status got = CALL(I, F_DeSerializeFMUstate, fmi2DeSerializeFMUstate(I->c, (const fmi2Byte *)b, len, &st));
    expect(I, got, want, "fmi2DeSerializeFMUstate of %s", what);
    if (got != fmi2OK && word) last_log_has(I, word, what);
    if (got == fmi2OK && set_after) {
        fmi2Status s2 = CALL(I, F_SetFMUstate, fmi2SetFMUstate(I->c, st));
        expect(I, s2, fmi2OK, "fmi2SetFMUstate of deserialised %s", what);
        if (s2 == fmi2OK) I->phase = phase_of(I);
    } else if (snap) {
        same_snapshot(I, snap, slen, what);
    }
    if (st) expect(I, CALL(I, F_FreeFMUstate, fmi2FreeFMUstate(I->c, &st)), fmi2OK, "fmi2FreeFMUstate");
    free(snap);
    return got;
}

/* Set a state in memory: want the status, the refusal naming `word`, the state unchanged. */
static fmi2Status try_memory(Inst *I, void *m, fmi2Status want, const char *word, const char *what) {
    size_t slen = 0;
    unsigned char *snap = serialise_now(I, &slen);
    fmi2Status got = CALL(I, F_SetFMUstate, fmi2SetFMUstate(I->c, m));
    expect(I, got, want, "fmi2SetFMUstate of %s", what);
    if (got != fmi2OK && word) last_log_has(I, word, what);
    if (got != fmi2OK && snap) same_snapshot(I, snap, slen, what);
    if (got == fmi2OK) I->phase = phase_of(I);
    free(snap);
    return got;
}

static unsigned char *blob_of(Inst *I, size_t *len) {
    unsigned char *b = serialise_now(I, len);
    if (!b) fail("no serialised state");
    return b;
}

/* set while a scenario needs the instance to stay at its step k */
static int hold_k;

/* bytes of I's state with double f set to v, tried as bytes and in memory; with hold_k, the
   state before the game is put back afterwards (else the instance takes a step) */
static void field_game(Inst *I, size_t f, double v, fmi2Status want, const char *word, const char *what) {
    size_t len;
    unsigned char *orig = blob_of(I, &len);
    if (!orig) return;
    unsigned char *b = malloc(len);
    memcpy(b, orig, len);
    wrd(b, f, v);
    if (try_bytes(I, b, len, want, word, what, 1) == fmi2OK && !hold_k) still_steps(I, what);
    unsigned char *m = memory_image(b);
    char mw[200];
    snprintf(mw, sizeof mw, "%s (in memory)", what);
    try_memory(I, m, want, word, mw);
    if (hold_k) try_bytes(I, orig, len, fmi2OK, NULL, "the state before the game", 1);
    else still_steps(I, mw);
    free(m);
    free(b);
    free(orig);
}

static void sc_foreign_guid(void) {
    size_t len;
    unsigned char *b = blob_of(A, &len);
    if (!b) return;
    b[L.guid + L.glen - 3] = (unsigned char)(b[L.guid + L.glen - 3] == 'a' ? 'b' : 'a');
    try_bytes(A, b, len, fmi2Error, "GUID", "bytes with another FMU's GUID (equal dims)", 0);
    still_steps(A, "a foreign GUID");
    unsigned char *m = memory_image(b);
    try_memory(A, m, fmi2Error, "GUID", "a state of another FMU with equal dims");
    void *p = m;
    fmi2Status st = CALL(A, F_GetFMUstate, fmi2GetFMUstate(A->c, &p));
    expect(A, st, fmi2Error, "fmi2GetFMUstate reusing another FMU's state");
    st = CALL(A, F_FreeFMUstate, fmi2FreeFMUstate(A->c, &p));
    expect(A, st, fmi2Error, "fmi2FreeFMUstate of another FMU's state");
    if (st != fmi2OK) free(m);
    still_steps(A, "a foreign state");
    free(b);
}

static void sc_h_prev(void) {
    /* 123 s: never a design interval nor dt; accepted only when the policy takes any step */
    int any_step_ok = !INTERVAL ? D->policy == UIOFMU_POLICY_COUNT : D->policy == UIOFMU_POLICY_NEAREST;
    field_game(A, FHPREV, 123.0, any_step_ok ? fmi2OK : fmi2Error, "h_prev", "h_prev = 123");
    field_game(A, FHPREV, NAN, fmi2Error, "h_prev", "h_prev = NaN");
    field_game(A, FHPREV, INFINITY, fmi2Error, "h_prev", "h_prev = Inf");
    field_game(A, FHPREV, -1.0, fmi2Error, "h_prev", "h_prev = -1");
    field_game(A, FHPREV, 0.0, fmi2Error, "h_prev", "h_prev = 0");
    field_game(A, FHPREV, 1e300, any_step_ok ? fmi2OK : fmi2Error, "h_prev", "h_prev = 1e300");
    field_game(A, FHPREV, good_step(), fmi2OK, NULL, "h_prev = an admissible step");
}

static void sc_reuse_wrong_size(void) {
    size_t len, bytes;
    unsigned char *b = blob_of(A, &len);
    if (!b) return;
    for (int big = 0; big < 2; big++) {
        unsigned char *m = sized_image(b, big ? ND + 3 : ND - 1, &bytes);
        void *p = m;
        const char *what = big ? "a larger state" : "a smaller state";
        fmi2Status st = CALL(A, F_GetFMUstate, fmi2GetFMUstate(A->c, &p));
        expect(A, st, fmi2Error, "fmi2GetFMUstate reusing %s (%zu bytes)", what, bytes);
        if (p != m) fail("fmi2GetFMUstate replaced the pointer it refused to reuse");
        p = m;
        st = CALL(A, F_DeSerializeFMUstate, fmi2DeSerializeFMUstate(A->c, (const fmi2Byte *)b, len, &p));
        expect(A, st, fmi2Error, "fmi2DeSerializeFMUstate into %s", what);
        p = m;
        try_memory(A, m, fmi2Error, NULL, what);
        size_t size = 0;
        st = CALL(A, F_SerializedFMUstateSize, fmi2SerializedFMUstateSize(A->c, m, &size));
        expect(A, st, fmi2Error, "fmi2SerializedFMUstateSize of %s", what);
        free(m);
        still_steps(A, what);
    }
    free(b);
}

static void sc_bytes_length(void) {
    size_t len;
    unsigned char *b = blob_of(A, &len);
    if (!b) return;
    const size_t cut[] = {1, 8, len - 40, len - 1, len};
    for (size_t i = 0; i < sizeof cut / sizeof cut[0]; i++) {
        char what[64];
        snprintf(what, sizeof what, "bytes truncated by %zu", cut[i]);
        unsigned char *t = malloc(len - cut[i] ? len - cut[i] : 1);
        memcpy(t, b, len - cut[i]);
        try_bytes(A, t, len - cut[i], fmi2Error, L.legacy ? NULL : "bytes", what, 0);
        free(t);
    }
    for (size_t extra = 1; extra <= 16; extra *= 4) {
        char what[64];
        snprintf(what, sizeof what, "bytes extended by %zu", extra);
        unsigned char *t = calloc(1, len + extra);
        memcpy(t, b, len);
        try_bytes(A, t, len + extra, fmi2Error, L.legacy ? NULL : "bytes", what, 0);
        free(t);
    }
    still_steps(A, "bytes of the wrong length");
    free(b);
}

static void sc_header(void) {
    size_t len;
    unsigned char *b = blob_of(A, &len);
    if (!b) return;
    struct { size_t off; int width; long long delta; const char *what; } edits[] = {
        {0, 4, 1, "magic + 1"}, {4, 4, -1, "layout 1"}, {4, 4, 1, "layout 3"}, {8, 8, 8, "size + 8"},
        {8, 8, -8, "size - 8"}, {16, 4, 1, "GUID length + 1"}, {16, 4, -1, "GUID length - 1"}, {20, 4, 1, "n + 1"},
        {24, 4, 1, "m + 1"}, {28, 4, 1, "p + 1"}, {32, 4, 1, "nz + 1"}, {36, 4, 1, "count + 1"},
        {36, 4, -1, "count - 1"}};
    for (size_t i = 0; i < sizeof edits / sizeof edits[0]; i++) {
        if (L.legacy && edits[i].off != 0) continue; /* layout 1 has only a magic and a count */
        unsigned char *t = malloc(len);
        memcpy(t, b, len);
        if (edits[i].width == 4) wr32(t, edits[i].off, rd32(t, edits[i].off) + (uint32_t)edits[i].delta);
        else wr64(t, edits[i].off, rd64(t, edits[i].off) + (uint64_t)edits[i].delta);
        try_bytes(A, t, len, fmi2Error, NULL, edits[i].what, 0);
        unsigned char *m = memory_image(t);
        try_memory(A, m, fmi2Error, NULL, edits[i].what);
        free(m);
        free(t);
    }
    if (!L.legacy && L.data > L.guid + L.glen) { /* padding after the GUID */
        unsigned char *t = malloc(len);
        memcpy(t, b, len);
        t[L.guid + L.glen] = 1;
        try_bytes(A, t, len, fmi2Error, "padding", "a padding byte set", 0);
        free(t);
    }
    still_steps(A, "header games");
    free(b);
}

static void sc_k(void) {
    const double bad[] = {-1.0, 0.5, 9007199254740992.0, 1e300, NAN, INFINITY, -INFINITY};
    const char *names[] = {"k = -1", "k = 0.5", "k = 2^53", "k = 1e300", "k = NaN", "k = Inf", "k = -Inf"};
    for (int i = 0; i < 7; i++) field_game(A, FK, bad[i], fmi2Error, "k =", names[i]);
    field_game(A, FK, 0.0, fmi2Error, NULL, "k = 0 with the z of a later step");
    field_game(A, FK, 1e6, fmi2OK, NULL, "k = 1e6");
}

static void sc_phase_noticed(void) {
    const double bad[] = {4.0, -1.0, 1.5, NAN, 1e300};
    for (int i = 0; i < 5; i++) field_game(A, FPHASE, bad[i], fmi2Error, "phase", "phase out of range");
    field_game(A, FPHASE, 1.0, fmi2Error, "k =", "phase 1 (initialisation mode) with k > 0");
    field_game(A, FPHASE, 3.0, fmi2OK, NULL, "phase 3 (terminated)");
    A->phase = PH_TERMINATED;
    expect(A, CALL(A, F_DoStep, fmi2DoStep(A->c, 0, good_step(), 1)), fmi2Error, "fmi2DoStep after a terminated state");
    expect(A, CALL(A, F_Reset, fmi2Reset(A->c)), fmi2OK, "fmi2Reset");
    A->phase = PH_INSTANTIATED;
    start_instance(A, 0);
    drive(A, 3);
    const double nbad[] = {2.0, -1.0, 0.5, NAN};
    for (int i = 0; i < 4; i++) field_game(A, FNOTICED, nbad[i], fmi2Error, "noticed", "noticed out of range");
    field_game(A, FNOTICED, 1.0, INTERVAL && D->policy == UIOFMU_POLICY_NEAREST ? fmi2OK : fmi2Error, "noticed",
               "noticed = 1");
}

static void sc_vectors(void) {
    field_game(A, F_Z, NAN, fmi2Error, "z[1]", "z[1] = NaN");
    field_game(A, F_Z + (size_t)D->nz - 1, -INFINITY, fmi2Error, "z[", "z[nz] = -Inf");
    field_game(A, F_PRED, INFINITY, fmi2Error, "pred[1]", "pred[1] = Inf");
    field_game(A, F_XHAT0, NAN, fmi2Error, "xhat0[1]", "xhat0[1] = NaN");
    /* inputs: taken as they are, refused by the step */
    field_game(A, F_Y, NAN, fmi2OK, NULL, "y[1] = NaN");
    size_t len;
    unsigned char *b = blob_of(A, &len);
    if (!b) return;
    wrd(b, F_Y, NAN);
    if (try_bytes(A, b, len, fmi2OK, NULL, "y[1] = NaN, set", 1) == fmi2OK) {
        expect(A, CALL(A, F_DoStep, fmi2DoStep(A->c, 0, good_step(), 1)), fmi2Error, "a step with y[1] = NaN");
        last_log_has(A, "input y[1] = nan", "a step with y[1] = NaN");
        still_steps(A, "y[1] = NaN");
    }
    free(b);
    field_game(A, F_Z, 1e300, fmi2OK, NULL, "z[1] = 1e300");
}

/* xhat0 and h_prev0, at k = 0 in each phase */
static void sc_initial(void) {
    Inst *I = A;
    free_instance(I);
    make_instance(I, 1, 1);
    /* instantiated, k = 0 */
    field_game(I, F_XHAT0, NAN, fmi2Error, "xhat0[1]", "xhat0[1] = NaN, instantiated");
    field_game(I, FHPREV0, NAN, fmi2Error, "h_prev0", "h_prev0 = NaN, instantiated");
    field_game(I, FHPREV0, -600.0, fmi2Error, "h_prev0", "h_prev0 = -600, instantiated");
    field_game(I, F_Z, 1.0, fmi2Error, "z[1]", "z[1] = 1 at k = 0");
    field_game(I, FK, 2.0, fmi2Error, "k =", "k = 2, instantiated");
    if (INTERVAL) {
        /* a parameter not yet taken: accepted, and refused where it is taken */
        field_game(I, FHPREV0, 123.0, fmi2OK, NULL, "h_prev0 = 123, instantiated");
        expect(I, CALL(I, F_EnterInitializationMode, fmi2EnterInitializationMode(I->c)), fmi2OK, "enter");
        I->phase = PH_INIT;
        fmi2Status st = CALL(I, F_ExitInitializationMode, fmi2ExitInitializationMode(I->c));
        expect(I, st, D->policy == UIOFMU_POLICY_NEAREST ? fmi2OK : fmi2Error,
               "fmi2ExitInitializationMode with h_prev0 = 123 from a state");
        if (st != fmi2OK) last_log_has(I, "h_prev0", "fmi2ExitInitializationMode with h_prev0 = 123");
        else I->phase = PH_RUNNING;
    } else {
        field_game(I, FHPREV0, 2 * D->h_prev0, fmi2Error, "h_prev0", "h_prev0 = 2 dt");
    }
    /* initialisation mode with a NaN xhat0 set by the master: the state is taken, not given back */
    free_instance(I);
    make_instance(I, 1, 1);
    expect(I, CALL(I, F_EnterInitializationMode, fmi2EnterInitializationMode(I->c)), fmi2OK, "enter");
    I->phase = PH_INIT;
    fmi2ValueReference vr = 0;
    double nan = NAN;
    expect(I, CALL(I, F_SetReal, fmi2SetReal(I->c, &vr, 1, &nan)), fmi2OK, "fmi2SetReal xhat0[1] = NaN");
    fmi2FMUstate st = NULL;
    expect(I, CALL(I, F_GetFMUstate, fmi2GetFMUstate(I->c, &st)), fmi2OK, "fmi2GetFMUstate with xhat0[1] = NaN");
    if (st) {
        try_memory(I, st, fmi2Error, "xhat0[1]", "a state holding xhat0[1] = NaN");
        expect(I, CALL(I, F_FreeFMUstate, fmi2FreeFMUstate(I->c, &st)), fmi2OK, "fmi2FreeFMUstate");
    }
    expect(I, CALL(I, F_ExitInitializationMode, fmi2ExitInitializationMode(I->c)), fmi2Error,
           "fmi2ExitInitializationMode with xhat0[1] = NaN");
    /* running, k = 0: xhat0 and h_prev0 were checked when initialisation ended */
    double one = 1.0;
    expect(I, CALL(I, F_SetReal, fmi2SetReal(I->c, &vr, 1, &one)), fmi2OK, "fmi2SetReal xhat0[1] = 1");
    expect(I, CALL(I, F_ExitInitializationMode, fmi2ExitInitializationMode(I->c)), fmi2OK, "exit");
    I->phase = PH_RUNNING;
    hold_k = 1; /* the games below start from k = 0, each one undone */
    field_game(I, F_XHAT0, NAN, fmi2Error, "xhat0[1]", "xhat0[1] = NaN at k = 0, running");
    field_game(I, F_XHAT0, INFINITY, fmi2Error, "xhat0[1]", "xhat0[1] = Inf at k = 0, running");
    field_game(I, FHPREV0, NAN, fmi2Error, "h_prev0", "h_prev0 = NaN, running");
    if (INTERVAL) {
        field_game(I, FHPREV0, 123.0, fmi2Error, "h_prev0", "h_prev0 = 123, running");
        double other = D->intervals[D->nintervals - 1];
        if (D->nintervals > 1 && other != D->h_prev0)
            field_game(I, FHPREV0, other, fmi2Error, "h_prev", "h_prev0 = another interval than h_prev, k = 0");
        size_t len0;
        unsigned char *k0 = blob_of(I, &len0);
        if (k0 && rdd(k0, FK) != 0) fail("the games at k = 0 did not stay at k = 0");
        free(k0);
        /* both moved together: a consistent state of an instance started with that h_prev0 */
        size_t len;
        unsigned char *b = blob_of(I, &len);
        if (b) {
            wrd(b, FHPREV0, other);
            wrd(b, FHPREV, other);
            if (try_bytes(I, b, len, fmi2OK, NULL, "h_prev0 = h_prev = another interval, k = 0", 1) == fmi2OK)
                still_steps(I, "h_prev0 = h_prev = another interval");
            free(b);
        }
    }
    hold_k = 0;
    drive(I, 2);
    field_game(I, F_XHAT0, NAN, fmi2Error, "xhat0[1]", "xhat0[1] = NaN, k = 2");
}

static void sc_other_instance(void) {
    /* a state of A set into B, and A's bytes deserialised by B: the same outputs */
    fmi2FMUstate st = NULL, st2 = NULL;
    double *outA = malloc((size_t)NOUT * sizeof(double));
    read_outputs(A, outA);
    expect(A, CALL(A, F_GetFMUstate, fmi2GetFMUstate(A->c, &st)), fmi2OK, "fmi2GetFMUstate");
    if (!st) { free(outA); return; }
    if (expect(B, CALL(B, F_SetFMUstate, fmi2SetFMUstate(B->c, st)), fmi2OK, "fmi2SetFMUstate of A's state in B") &&
        read_outputs(B, scratch_out) && memcmp(outA, scratch_out, (size_t)NOUT * sizeof(double)) != 0)
        fail("B's outputs after taking A's state differ from A's");
    size_t size = 0;
    expect(A, CALL(A, F_SerializedFMUstateSize, fmi2SerializedFMUstateSize(A->c, st, &size)), fmi2OK, "size");
    unsigned char *b = malloc(size + 1);
    expect(A, CALL(A, F_SerializeFMUstate, fmi2SerializeFMUstate(A->c, st, (fmi2Byte *)(b + 1), size)), fmi2OK,
           "fmi2SerializeFMUstate into an odd address");
    if (expect(B, CALL(B, F_DeSerializeFMUstate, fmi2DeSerializeFMUstate(B->c, (fmi2Byte *)(b + 1), size, &st2)), fmi2OK,
               "fmi2DeSerializeFMUstate of unaligned bytes in B") &&
        expect(B, CALL(B, F_SetFMUstate, fmi2SetFMUstate(B->c, st2)), fmi2OK, "fmi2SetFMUstate") &&
        read_outputs(B, scratch_out) && memcmp(outA, scratch_out, (size_t)NOUT * sizeof(double)) != 0)
        fail("B's outputs after deserialising A's bytes differ from A's");
    /* B frees A's state, A reuses B's */
    if (st2) expect(A, CALL(A, F_GetFMUstate, fmi2GetFMUstate(A->c, &st2)), fmi2OK, "A reusing a state B made");
    expect(B, CALL(B, F_FreeFMUstate, fmi2FreeFMUstate(B->c, &st)), fmi2OK, "B freeing a state A made");
    if (st2) expect(A, CALL(A, F_FreeFMUstate, fmi2FreeFMUstate(A->c, &st2)), fmi2OK, "fmi2FreeFMUstate");
    /* deserialising into a reused state */
    fmi2FMUstate st3 = NULL;
    expect(B, CALL(B, F_GetFMUstate, fmi2GetFMUstate(B->c, &st3)), fmi2OK, "fmi2GetFMUstate");
    if (st3) {
        void *before = st3;
        expect(B, CALL(B, F_DeSerializeFMUstate, fmi2DeSerializeFMUstate(B->c, (fmi2Byte *)(b + 1), size, &st3)),
               fmi2OK, "fmi2DeSerializeFMUstate into a reused state");
        if (st3 != before) fail("fmi2DeSerializeFMUstate did not reuse the state it was given");
        expect(B, CALL(B, F_FreeFMUstate, fmi2FreeFMUstate(B->c, &st3)), fmi2OK, "fmi2FreeFMUstate");
    }
    free(b);
    free(outA);
    still_steps(B, "another instance's state");
}

static void sc_round_trip(void) {
    for (int i = 0; i < 8; i++) act_replay();
    State *s = &pool[0];
    s->p = NULL;
    if (expect(A, CALL(A, F_GetFMUstate, fmi2GetFMUstate(A->c, &s->p)), fmi2OK, "fmi2GetFMUstate")) {
        s->used = 1;
        record_state(A, s);
        if (!s->valid) fail("the model calls an honest running state invalid");
        drive(A, 4);
        act_set_state(); /* the only used slot: checks the outputs bit for bit */
        release_state(s);
    }
}

static void sc_null_arguments(void) {
    fmi2FMUstate st = NULL;
    size_t size = 0;
    unsigned char buf[8];
    expect(A, CALL(A, F_GetFMUstate, fmi2GetFMUstate(A->c, NULL)), fmi2Error, "fmi2GetFMUstate(NULL)");
    expect(A, CALL(A, F_SetFMUstate, fmi2SetFMUstate(A->c, NULL)), fmi2Error, "fmi2SetFMUstate(NULL)");
    expect(A, CALL(A, F_DeSerializeFMUstate, fmi2DeSerializeFMUstate(A->c, NULL, 10, &st)), fmi2Error,
           "fmi2DeSerializeFMUstate(NULL bytes)");
    expect(A, CALL(A, F_DeSerializeFMUstate, fmi2DeSerializeFMUstate(A->c, (fmi2Byte *)buf, sizeof buf, NULL)),
           fmi2Error, "fmi2DeSerializeFMUstate(NULL state)");
    expect(A, CALL(A, F_FreeFMUstate, fmi2FreeFMUstate(A->c, NULL)), fmi2OK, "fmi2FreeFMUstate(NULL)");
    expect(A, CALL(A, F_FreeFMUstate, fmi2FreeFMUstate(A->c, &st)), fmi2OK, "fmi2FreeFMUstate(&NULL)");
    expect(A, CALL(A, F_GetFMUstate, fmi2GetFMUstate(A->c, &st)), fmi2OK, "fmi2GetFMUstate");
    expect(A, CALL(A, F_SerializedFMUstateSize, fmi2SerializedFMUstateSize(A->c, st, NULL)), fmi2Error,
           "fmi2SerializedFMUstateSize(NULL size)");
    expect(A, CALL(A, F_SerializeFMUstate, fmi2SerializeFMUstate(A->c, st, NULL, 1000)), fmi2Error,
           "fmi2SerializeFMUstate(NULL bytes)");
    expect(A, CALL(A, F_SerializedFMUstateSize, fmi2SerializedFMUstateSize(A->c, st, &size)), fmi2OK, "size");
    unsigned char *big = malloc(size + 64);
    memset(big, 0xA5, size + 64);
    expect(A, CALL(A, F_SerializeFMUstate, fmi2SerializeFMUstate(A->c, st, (fmi2Byte *)big, size + 64)), fmi2OK,
           "fmi2SerializeFMUstate into a long buffer");
    for (size_t i = size; i < size + 64; i++)
        if (big[i] != 0xA5) { fail("fmi2SerializeFMUstate wrote past the state"); break; }
    expect(A, CALL(A, F_SerializeFMUstate, fmi2SerializeFMUstate(A->c, st, (fmi2Byte *)big, size - 1)), fmi2Error,
           "fmi2SerializeFMUstate into a short buffer");
    free(big);
    expect(A, CALL(A, F_FreeFMUstate, fmi2FreeFMUstate(A->c, &st)), fmi2OK, "fmi2FreeFMUstate");
    if (st) fail("fmi2FreeFMUstate left the pointer set");
}

static void sc_instantiate(void) {
    Inst tmp;
    instance_setup(&tmp, 1);
    char guid[300];
    snprintf(guid, sizeof guid, "%s", FMU_GUID);
    guid[3] ^= 1;
    struct { const char *name; fmi2Type type; const char *guid; int cb; const char *what; } cases[] = {
        {"fuzz", fmi2CoSimulation, guid, 1, "another GUID"}, {"fuzz", fmi2CoSimulation, NULL, 1, "a NULL GUID"},
        {"fuzz", fmi2CoSimulation, "", 1, "an empty GUID"}, {"fuzz", fmi2ModelExchange, FMU_GUID, 1, "Model Exchange"},
        {"fuzz", fmi2CoSimulation, FMU_GUID, 0, "NULL callbacks"}, {NULL, fmi2CoSimulation, FMU_GUID, 1, "a NULL name"},
        {"", fmi2CoSimulation, FMU_GUID, 1, "an empty name"}};
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        int lines = tmp.env.lines;
        fmi2Component c = fmi2Instantiate(cases[i].name, cases[i].type, cases[i].guid, "file:///tmp",
                                          cases[i].cb ? &tmp.cb : NULL, fmi2False, fmi2True);
        track(NULL, F_Instantiate, c ? fmi2OK : fmi2Error, 0);
        if (c) {
            fail("fmi2Instantiate accepted %s", cases[i].what);
            fmi2FreeInstance(c);
        } else if (cases[i].cb && tmp.env.lines == lines) {
            fail("fmi2Instantiate refused %s without a log line", cases[i].what);
        }
    }
    Inst quiet;
    if (make_instance(&quiet, 0, 0)) { /* no logger at all: refusals stay silent, nothing breaks */
        fmi2Status st = CALL(&quiet, F_DoStep, fmi2DoStep(quiet.c, 0, 1, 1));
        expect(&quiet, st, fmi2Error, "fmi2DoStep before initialisation without a logger");
        free_instance(&quiet);
    }
}

/* ---- the state masks ---------------------------------------------------------------------- */

/* The states an instance can be brought to (the error state needs a kernel state at odds with
   its design, which the state checks keep out: tests/c/plumbing_test.c reaches it with a kernel
   of its own). */
enum { MS_INSTANTIATED, MS_INIT, MS_COMPLETE, MS_DISCARDED, MS_TERMINATED, MS_COUNT };
static const char *const MS_NAME[MS_COUNT] = {"instantiated", "initialization mode", "step complete",
                                              "step discarded", "terminated"};
#define MS(x) (1u << (x))
#define MS_ALL (MS(MS_COUNT) - 1u)
#define MS_RUN (MS(MS_COMPLETE) | MS(MS_DISCARDED))

/* Where each function is legal: FMI 2.0's table (4.2.4) with the differences fmi2_plumbing.c
   documents (fmi2GetXXX also when instantiated; fmi2SetXXX and fmi2DoStep also after a discarded
   step), written out here on its own. */
static unsigned legal_in(int fn) {
    switch (fn) {
    case F_SetDebugLogging: case F_Reset: case F_GetReal: case F_GetInteger: case F_GetBoolean: case F_GetString:
    case F_GetFMUstate: case F_SetFMUstate: case F_FreeFMUstate: case F_SerializedFMUstateSize:
    case F_SerializeFMUstate: case F_DeSerializeFMUstate:
        return MS_ALL;
    case F_SetupExperiment: case F_EnterInitializationMode: return MS(MS_INSTANTIATED);
    case F_ExitInitializationMode: return MS(MS_INIT);
    case F_Terminate: case F_DoStep: return MS_RUN;
    case F_SetReal: case F_SetInteger: case F_SetBoolean: case F_SetString: return MS_ALL & ~MS(MS_TERMINATED);
    case F_GetDirectionalDerivative: return MS_ALL & ~MS(MS_INSTANTIATED);
    case F_SetRealInputDerivatives: return MS(MS_INSTANTIATED) | MS(MS_INIT) | MS(MS_COMPLETE);
    case F_GetRealOutputDerivatives: case F_GetStatus: case F_GetRealStatus: case F_GetIntegerStatus:
    case F_GetBooleanStatus: case F_GetStringStatus:
        return MS_RUN | MS(MS_TERMINATED);
    default: return 0u; /* fmi2CancelStep: no step is ever pending */
    }
}

/* A step this design refuses with fmi2Discard (0 when its policy takes every step). */
static double refused_step(void) {
    if ((INTERVAL && D->policy == UIOFMU_POLICY_NEAREST) || (!INTERVAL && D->policy == UIOFMU_POLICY_COUNT)) return 0.0;
    double base = INTERVAL ? D->intervals[0] : D->dt;
    for (double f = 0.61; f < 10; f += 0.37)
        if (!step_exact(base * f)) return base * f;
    return 0.0;
}

/* A fresh instance in state st (0 when this design cannot be brought there). */
static int to_state(Inst *I, int st) {
    free_instance(I);
    if (!make_instance(I, 1, 1)) return 0;
    if (st == MS_INSTANTIATED) return 1;
    expect(I, CALL(I, F_SetupExperiment, fmi2SetupExperiment(I->c, 0, 0, 0, 0, 0)), fmi2OK, "fmi2SetupExperiment");
    if (!expect(I, CALL(I, F_EnterInitializationMode, fmi2EnterInitializationMode(I->c)), fmi2OK, "enter")) return 0;
    I->phase = PH_INIT;
    if (st == MS_INIT) return 1;
    if (!expect(I, CALL(I, F_ExitInitializationMode, fmi2ExitInitializationMode(I->c)), fmi2OK, "exit")) return 0;
    I->phase = PH_RUNNING;
    drive(I, 1);
    if (st == MS_COMPLETE) return 1;
    if (st == MS_DISCARDED) {
        double h = refused_step();
        if (h == 0.0) return 0;
        return expect(I, CALL(I, F_DoStep, fmi2DoStep(I->c, 0.0, h, fmi2True)), fmi2Discard, "a refused step");
    }
    if (!expect(I, CALL(I, F_Terminate, fmi2Terminate(I->c)), fmi2OK, "fmi2Terminate")) return 0;
    I->phase = PH_TERMINATED;
    return 1;
}

/* Every fmi2 function (with arguments it takes) in every state: legal calls answer as they
   should, illegal ones fmi2Error with a log line naming the state, and change nothing. */
static void sc_state_masks(void) {
    Inst *I = A, *S = B; /* S: a running instance whose states and bytes I is given */
    fmi2FMUstate theirs = NULL;
    size_t blen = 0;
    unsigned char *bytes = serialise_now(S, &blen);
    if (!bytes) return;
    int fns[] = {F_SetDebugLogging, F_SetupExperiment, F_EnterInitializationMode, F_ExitInitializationMode,
                 F_Terminate, F_Reset, F_GetReal, F_SetReal, F_GetInteger, F_SetInteger, F_GetBoolean, F_SetBoolean,
                 F_GetString, F_SetString, F_DoStep, F_CancelStep, F_GetFMUstate, F_SetFMUstate, F_FreeFMUstate,
                 F_SerializedFMUstateSize, F_SerializeFMUstate, F_DeSerializeFMUstate, F_GetDirectionalDerivative,
                 F_SetRealInputDerivatives, F_GetRealOutputDerivatives, F_GetStatus, F_GetRealStatus,
                 F_GetIntegerStatus, F_GetBooleanStatus, F_GetStringStatus};
    for (int st = 0; st < MS_COUNT; st++)
        for (size_t f = 0; f < sizeof fns / sizeof fns[0]; f++) {
            int fn = fns[f], legal = (legal_in(fn) >> st) & 1u;
            if (!to_state(I, st)) {
                if (st == MS_DISCARDED) break; /* this step policy discards nothing */
                continue;
            }
            char what[160];
            snprintf(what, sizeof what, "%s when %s", FN[fn], MS_NAME[st]);
            size_t slen = 0;
            unsigned char *snap = legal ? NULL : serialise_now(I, &slen);
            fmi2ValueReference vr_in = (fmi2ValueReference)VR_Y, vr_out = (fmi2ValueReference)VR_OUT;
            double v = 1.0, dv[2] = {0, 0};
            fmi2Integer order = 1;
            fmi2Status sv, want = fmi2OK, got;
            fmi2Real rv;
            fmi2Boolean bv;
            fmi2String strv;
            fmi2FMUstate mine = NULL;
            unsigned char buf[4096];
            if (fn == F_FreeFMUstate || fn == F_SerializedFMUstateSize || fn == F_SerializeFMUstate)
                expect(S, CALL(S, F_GetFMUstate, fmi2GetFMUstate(S->c, &theirs)), fmi2OK, "a state to give");
            switch (fn) {
            case F_SetDebugLogging: got = CALL(I, fn, fmi2SetDebugLogging(I->c, fmi2True, 0, NULL)); break;
            case F_SetupExperiment: got = CALL(I, fn, fmi2SetupExperiment(I->c, 0, 0, 0, 0, 0)); break;
            case F_EnterInitializationMode: got = CALL(I, fn, fmi2EnterInitializationMode(I->c)); break;
            case F_ExitInitializationMode: got = CALL(I, fn, fmi2ExitInitializationMode(I->c)); break;
            case F_Terminate: got = CALL(I, fn, fmi2Terminate(I->c)); break;
            case F_Reset: got = CALL(I, fn, fmi2Reset(I->c)); break;
            case F_GetReal: got = CALL(I, fn, fmi2GetReal(I->c, &vr_out, 1, &rv)); break;
            case F_SetReal: got = CALL(I, fn, fmi2SetReal(I->c, &vr_in, 1, &v)); break;
            case F_GetInteger: got = CALL(I, fn, fmi2GetInteger(I->c, &vr_in, 0, &order)); break;
            case F_SetInteger: got = CALL(I, fn, fmi2SetInteger(I->c, &vr_in, 0, &order)); break;
            case F_GetBoolean: got = CALL(I, fn, fmi2GetBoolean(I->c, &vr_in, 0, &bv)); break;
            case F_SetBoolean: got = CALL(I, fn, fmi2SetBoolean(I->c, &vr_in, 0, &bv)); break;
            case F_GetString: got = CALL(I, fn, fmi2GetString(I->c, &vr_in, 0, &strv)); break;
            case F_SetString: got = CALL(I, fn, fmi2SetString(I->c, &vr_in, 0, &strv)); break;
            case F_DoStep: got = CALL(I, fn, fmi2DoStep(I->c, 0.0, good_step(), fmi2True)); break;
            case F_CancelStep: got = CALL(I, fn, fmi2CancelStep(I->c)); break;
            case F_GetFMUstate: got = CALL(I, fn, fmi2GetFMUstate(I->c, &mine)); break;
            case F_SetFMUstate: {
                fmi2FMUstate given = NULL;
                expect(S, CALL(S, F_GetFMUstate, fmi2GetFMUstate(S->c, &given)), fmi2OK, "a state to give");
                got = CALL(I, fn, fmi2SetFMUstate(I->c, given));
                expect(S, CALL(S, F_FreeFMUstate, fmi2FreeFMUstate(S->c, &given)), fmi2OK, "fmi2FreeFMUstate");
                break;
            }
            case F_FreeFMUstate: got = CALL(I, fn, fmi2FreeFMUstate(I->c, &theirs)); break;
            case F_SerializedFMUstateSize: got = CALL(I, fn, fmi2SerializedFMUstateSize(I->c, theirs, &slen)); break;
            case F_SerializeFMUstate:
                got = CALL(I, fn, fmi2SerializeFMUstate(I->c, theirs, (fmi2Byte *)buf, blen <= sizeof buf ? blen : 0));
                if (blen > sizeof buf) want = fmi2Error;
                break;
            case F_DeSerializeFMUstate:
                got = CALL(I, fn, fmi2DeSerializeFMUstate(I->c, (const fmi2Byte *)bytes, blen, &mine));
                break;
            case F_GetDirectionalDerivative:
                got = CALL(I, fn, fmi2GetDirectionalDerivative(I->c, &vr_out, 1, &vr_in, 1, dv, dv + 1));
                want = fmi2Error; /* not supported */
                break;
            case F_SetRealInputDerivatives:
                got = CALL(I, fn, fmi2SetRealInputDerivatives(I->c, &vr_in, 1, &order, dv));
                want = fmi2Error;
                break;
            case F_GetRealOutputDerivatives:
                got = CALL(I, fn, fmi2GetRealOutputDerivatives(I->c, &vr_out, 1, &order, dv));
                want = fmi2Error;
                break;
            case F_GetStatus: got = CALL(I, fn, fmi2GetStatus(I->c, fmi2DoStepStatus, &sv)); want = fmi2Discard; break;
            case F_GetRealStatus: got = CALL(I, fn, fmi2GetRealStatus(I->c, fmi2LastSuccessfulTime, &rv)); break;
            case F_GetIntegerStatus:
                got = CALL(I, fn, fmi2GetIntegerStatus(I->c, fmi2LastSuccessfulTime, &order));
                want = fmi2Error; /* FMI 2.0 has no Integer status */
                break;
            case F_GetBooleanStatus: got = CALL(I, fn, fmi2GetBooleanStatus(I->c, fmi2Terminated, &bv)); break;
            default: got = CALL(I, fn, fmi2GetStringStatus(I->c, fmi2PendingStatus, &strv)); want = fmi2Discard; break;
            }
            if (!legal) want = fmi2Error;
            expect(I, got, want, "%s", what);
            if (!legal) {
                last_log_has(I, "the instance is", what);
                last_log_has(I, MS_NAME[st], what);
                if (snap) same_snapshot(I, snap, slen, what);
            } else if (want == fmi2Error) {
                last_log_has(I, fn == F_GetIntegerStatus ? "no Integer status" : "not supported", what);
            }
            if (mine) expect(I, CALL(I, F_FreeFMUstate, fmi2FreeFMUstate(I->c, &mine)), fmi2OK, "fmi2FreeFMUstate");
            if (theirs) expect(S, CALL(S, F_FreeFMUstate, fmi2FreeFMUstate(S->c, &theirs)), fmi2OK, "fmi2FreeFMUstate");
            free(snap);
            I->phase = phase_of(I);
        }
    free(bytes);
}

/* ---- a refused step: the status queries, then a master going on ---------------------------- */

static void sc_status_after_discard(void) {
    double h = refused_step();
    if (h == 0.0) return; /* this step policy takes every step */
    fmi2ValueReference vr[512];
    double in[512], t = 7.25;
    for (int i = 0; i < D->p + D->m; i++) { vr[i] = (fmi2ValueReference)(VR_Y + i); in[i] = 0.25 * i - 1.0; }
    for (int s = 0; s < 3; s++) /* A and B: the same inputs and steps, at consistent times */
        for (int k = 0; k < NINST; k++) {
            Inst *I = &inst[k];
            double hs = INTERVAL ? D->intervals[(s * 3 + 2) % D->nintervals] : D->dt;
            expect(I, CALL(I, F_SetReal, fmi2SetReal(I->c, vr, (size_t)(D->p + D->m), in)), fmi2OK, "fmi2SetReal");
            expect(I, CALL(I, F_DoStep, fmi2DoStep(I->c, t + 0 * s, hs, fmi2True)), fmi2OK, "a step");
            if (k == NINST - 1) t += hs;
        }
    size_t alen = 0, blen = 0;
    unsigned char *before = serialise_now(A, &alen);
    fmi2Real last = -1;
    fmi2Boolean terminated = 7;
    fmi2Status dss = fmi2OK;
    fmi2String pending = NULL;
    expect(A, CALL(A, F_DoStep, fmi2DoStep(A->c, t, h, fmi2True)), fmi2Discard, "a step of h = %.17g", h);
    last_log_has(A, "t = ", "the refused step");
    expect(A, CALL(A, F_GetRealStatus, fmi2GetRealStatus(A->c, fmi2LastSuccessfulTime, &last)), fmi2OK,
           "fmi2GetRealStatus(fmi2LastSuccessfulTime) after a discarded step");
    if (last != t) fail("fmi2LastSuccessfulTime = %.17g after a step refused at t = %.17g", last, t);
    expect(A, CALL(A, F_GetBooleanStatus, fmi2GetBooleanStatus(A->c, fmi2Terminated, &terminated)), fmi2OK,
           "fmi2GetBooleanStatus(fmi2Terminated) after a discarded step");
    if (terminated != fmi2True) fail("fmi2Terminated = %d after a discarded step, expected fmi2True", terminated);
    expect(A, CALL(A, F_GetStatus, fmi2GetStatus(A->c, fmi2DoStepStatus, &dss)), fmi2Discard,
           "fmi2GetStatus(fmi2DoStepStatus) with no step pending");
    last_log_has(A, "no fmi2DoStep is pending", "fmi2GetStatus(fmi2DoStepStatus)");
    expect(A, CALL(A, F_GetStringStatus, fmi2GetStringStatus(A->c, fmi2PendingStatus, &pending)), fmi2Discard,
           "fmi2GetStringStatus(fmi2PendingStatus) with no step pending");
    if (!pending) fail("fmi2GetStringStatus(fmi2PendingStatus) gave no string");
    /* kinds of another type, or none: errors */
    expect(A, CALL(A, F_GetRealStatus, fmi2GetRealStatus(A->c, fmi2Terminated, &last)), fmi2Error,
           "fmi2GetRealStatus(fmi2Terminated)");
    last_log_has(A, "fmi2Terminated is not a status of this type", "fmi2GetRealStatus(fmi2Terminated)");
    expect(A, CALL(A, F_GetBooleanStatus, fmi2GetBooleanStatus(A->c, fmi2LastSuccessfulTime, &terminated)), fmi2Error,
           "fmi2GetBooleanStatus(fmi2LastSuccessfulTime)");
    expect(A, CALL(A, F_GetStatus, fmi2GetStatus(A->c, (fmi2StatusKind)17, &dss)), fmi2Error, "fmi2GetStatus(17)");
    last_log_has(A, "status kind 17 is none of", "fmi2GetStatus(17)");
    expect(A, CALL(A, F_GetIntegerStatus, fmi2GetIntegerStatus(A->c, fmi2DoStepStatus, &A->env.lines)), fmi2Error,
           "fmi2GetIntegerStatus");
    expect(A, CALL(A, F_GetRealStatus, fmi2GetRealStatus(A->c, fmi2LastSuccessfulTime, NULL)), fmi2Error,
           "fmi2GetRealStatus(NULL)");
    /* nothing changed: A is where B is, and both go on alike */
    unsigned char *after = serialise_now(A, &alen), *twin = serialise_now(B, &blen);
    if (!before || !after || !twin || memcmp(before, after, alen) != 0)
        fail("the refused step or the status queries changed the instance");
    else if (blen != alen || memcmp(after, twin, alen) != 0)
        fail("after a refused step the instance differs from a twin that never took it");
    double *oa = malloc((size_t)NOUT * sizeof(double)), *ob = malloc((size_t)NOUT * sizeof(double));
    for (int s = 0; s < 4; s++) {
        double hs = good_step();
        for (int k = 0; k < NINST; k++) {
            Inst *I = &inst[k];
            in[0] = 1.5 + s;
            expect(I, CALL(I, F_SetReal, fmi2SetReal(I->c, vr, (size_t)(D->p + D->m), in)), fmi2OK, "fmi2SetReal");
            expect(I, CALL(I, F_DoStep, fmi2DoStep(I->c, t, hs, fmi2True)), fmi2OK, "a valid step after the refused one");
            read_outputs(I, k ? ob : oa);
        }
        if (memcmp(oa, ob, (size_t)NOUT * sizeof(double)) != 0)
            fail("step %d after the refused step: the outputs differ from the twin's", s + 1);
        t += hs;
    }
    expect(A, CALL(A, F_GetRealStatus, fmi2GetRealStatus(A->c, fmi2LastSuccessfulTime, &last)), fmi2OK,
           "fmi2LastSuccessfulTime after the valid steps");
    if (last != t) fail("fmi2LastSuccessfulTime = %.17g after steps to t = %.17g", last, t);
    /* a state set: the time is not known until the next step */
    fmi2FMUstate st = NULL;
    expect(A, CALL(A, F_GetFMUstate, fmi2GetFMUstate(A->c, &st)), fmi2OK, "fmi2GetFMUstate");
    expect(A, CALL(A, F_SetFMUstate, fmi2SetFMUstate(A->c, st)), fmi2OK, "fmi2SetFMUstate");
    expect(A, CALL(A, F_GetRealStatus, fmi2GetRealStatus(A->c, fmi2LastSuccessfulTime, &last)), fmi2Discard,
           "fmi2LastSuccessfulTime after fmi2SetFMUstate");
    last_log_has(A, "not known", "fmi2LastSuccessfulTime after fmi2SetFMUstate");
    expect(A, CALL(A, F_DoStep, fmi2DoStep(A->c, t, h, fmi2True)), fmi2Discard, "a refused step after fmi2SetFMUstate");
    expect(A, CALL(A, F_GetRealStatus, fmi2GetRealStatus(A->c, fmi2LastSuccessfulTime, &last)), fmi2OK,
           "fmi2LastSuccessfulTime after a refused step");
    if (last != t) fail("fmi2LastSuccessfulTime = %.17g after a step refused at t = %.17g", last, t);
    expect(A, CALL(A, F_Terminate, fmi2Terminate(A->c)), fmi2OK, "fmi2Terminate after a discarded step");
    A->phase = PH_TERMINATED;
    expect(A, CALL(A, F_FreeFMUstate, fmi2FreeFMUstate(A->c, &st)), fmi2OK, "fmi2FreeFMUstate");
    free(oa); free(ob); free(before); free(after); free(twin);
}

/* ---- log categories --------------------------------------------------------------------- */

/* a call that fmi2Error refuses, and whether it wrote a line */
static int error_line(Inst *I, const char *what) {
    int before = I->env.lines;
    fmi2ValueReference bad = (fmi2ValueReference)NV;
    double v = 0;
    expect(I, CALL(I, F_GetReal, fmi2GetReal(I->c, &bad, 1, &v)), fmi2Error, "%s", what);
    return I->env.lines > before;
}

static int discard_line(Inst *I, const char *what) {
    int before = I->env.lines;
    fmi2Status dss;
    expect(I, CALL(I, F_GetStatus, fmi2GetStatus(I->c, fmi2DoStepStatus, &dss)), fmi2Discard, "%s", what);
    return I->env.lines > before;
}

static int event_line(Inst *I, const char *what) {
    int before = I->env.lines;
    expect(I, CALL(I, F_SetFMUstate, fmi2SetFMUstate(I->c, NULL)), fmi2Error, "%s (null)", what);
    fmi2FMUstate st = NULL;
    before = I->env.lines;
    expect(I, CALL(I, F_GetFMUstate, fmi2GetFMUstate(I->c, &st)), fmi2OK, "%s", what);
    expect(I, CALL(I, F_SetFMUstate, fmi2SetFMUstate(I->c, st)), fmi2OK, "%s", what);
    expect(I, CALL(I, F_FreeFMUstate, fmi2FreeFMUstate(I->c, &st)), fmi2OK, "%s", what);
    return I->env.lines > before;
}

static int set_logging(Inst *I, int on, size_t n, const char *const *cats, fmi2Status want, const char *what) {
    fmi2Status st = CALL(I, F_SetDebugLogging, fmi2SetDebugLogging(I->c, on, n, (const fmi2String *)cats));
    return expect(I, st, want, "fmi2SetDebugLogging(%s)", what);
}

static void sc_log_categories(void) {
    static const char *const err[1] = {"logStatusError"}, *const events[2] = {"logEvents", "logStatusDiscard"};
    static const char *const unknown[2] = {"logStatusDiscard", "logEverything"}, *const null[2] = {"logEvents", NULL};
    Inst *I = A;
    /* loggingOn = false at fmi2Instantiate: the status categories, not logEvents */
    free_instance(I);
    make_instance(I, 1, 0);
    start_instance(I, 0); /* its mode changes write no logEvents line (the logger checks) */
    if (!error_line(I, "an unknown reference")) fail("no logStatusError line with the status categories on");
    if (event_line(I, "a state set")) fail("a logEvents line with loggingOn = false");
    if (!discard_line(I, "no step pending")) fail("no logStatusDiscard line with the status categories on");
    /* (fmi2True, [logStatusError]): only errors */
    if (set_logging(I, 1, 1, err, fmi2OK, "true, [logStatusError]")) I->env.cats = 1u << CAT_ERROR;
    if (discard_line(I, "only logStatusError on")) fail("a logStatusDiscard line with only logStatusError on");
    if (!error_line(I, "only logStatusError on")) fail("no logStatusError line with it on");
    /* (fmi2False, [logStatusError]): nothing */
    if (set_logging(I, 0, 1, err, fmi2OK, "false, [logStatusError]")) I->env.cats = 0;
    if (error_line(I, "every category off")) fail("a logStatusError line with it off");
    /* a NULL category: refused, nothing changes (still silent) */
    set_logging(I, 1, 2, null, fmi2Error, "true, [logEvents, NULL]");
    set_logging(I, 1, 1, NULL, fmi2Error, "true, 1, NULL");
    if (discard_line(I, "after refused settings")) fail("a refused fmi2SetDebugLogging switched a category on");
    /* an unknown category: ignored with fmi2Warning (its line under the categories before: none), the
       known one applied */
    if (set_logging(I, 1, 2, unknown, fmi2Warning, "true, [logStatusDiscard, logEverything]"))
        I->env.cats = 1u << CAT_DISCARD;
    if (!discard_line(I, "the known category of two"))
        fail("no logStatusDiscard line: the known category was not applied");
    if (error_line(I, "the known category of two")) fail("a logStatusError line with only logStatusDiscard on");
    /* (fmi2True, 0): everything, and the warning of an unknown category says so */
    if (set_logging(I, 1, 0, NULL, fmi2OK, "true, 0")) I->env.cats = CAT_ALL;
    if (!event_line(I, "every category on")) fail("no logEvents line with every category on");
    if (!discard_line(I, "every category on")) fail("no logStatusDiscard line with every category on");
    if (set_logging(I, 1, 2, unknown, fmi2Warning, "true, [logStatusDiscard, logEverything]"))
        I->env.cats = 1u << CAT_DISCARD;
    last_log_has(I, "categories[1] = \"logEverything\" is not a log category", "an unknown category");
    if (set_logging(I, 1, 0, NULL, fmi2OK, "true, 0")) I->env.cats = CAT_ALL;
    /* (fmi2False, [logEvents, logStatusDiscard]): those off, the rest kept */
    if (set_logging(I, 0, 2, events, fmi2OK, "false, [logEvents, logStatusDiscard]"))
        I->env.cats = CAT_ALL & ~((1u << CAT_EVENTS) | (1u << CAT_DISCARD));
    if (event_line(I, "logEvents off")) fail("a logEvents line with it off");
    if (discard_line(I, "logStatusDiscard off")) fail("a logStatusDiscard line with it off");
    if (!error_line(I, "logStatusError kept")) fail("no logStatusError line: fmi2False with categories switched it off");
    /* (fmi2False, 0): nothing at all */
    if (set_logging(I, 0, 0, NULL, fmi2OK, "false, 0")) I->env.cats = 0;
    if (error_line(I, "logging off") || discard_line(I, "logging off") || event_line(I, "logging off"))
        fail("a log line with logging off");
    still_steps(I, "the log games");
}

static const struct { const char *name; void (*f)(void); int steps; } SCENARIOS[] = {
    {"foreign-guid", sc_foreign_guid, 3},
    {"h_prev", sc_h_prev, 3},
    {"reuse-wrong-size", sc_reuse_wrong_size, 2},
    {"bytes-length", sc_bytes_length, 2},
    {"header", sc_header, 2},
    {"k", sc_k, 3},
    {"phase-noticed", sc_phase_noticed, 3},
    {"vectors", sc_vectors, 3},
    {"initial", sc_initial, 0},
    {"other-instance", sc_other_instance, 5},
    {"round-trip", sc_round_trip, 4},
    {"null-arguments", sc_null_arguments, 1},
    {"instantiate", sc_instantiate, 0},
    {"state-masks", sc_state_masks, 2},
    {"status-after-discard", sc_status_after_discard, 2},
    {"log-categories", sc_log_categories, 0},
};

static int run_scenarios(const char *only) {
    int found = 0;
    for (size_t i = 0; i < sizeof SCENARIOS / sizeof SCENARIOS[0]; i++) {
        if (only && strcmp(only, SCENARIOS[i].name) != 0) continue;
        found = 1;
        long before = failures;
        snprintf(where, sizeof where, "scenario %s", SCENARIOS[i].name);
        fprintf(stderr, "scenario %s ...\n", SCENARIOS[i].name);
        start_both(SCENARIOS[i].steps);
        SCENARIOS[i].f();
        for (int s = 0; s < NSTATES; s++) release_state(&pool[s]);
        for (int k = 0; k < NINST; k++) free_instance(&inst[k]);
        sequences++;
        printf("scenario %s %s\n", SCENARIOS[i].name, failures == before ? "ok" : "FAIL");
        fflush(stdout);
    }
    if (!found) {
        fprintf(stderr, "no scenario %s\n", only);
        return 2;
    }
    return 0;
}

/* ---------------------------------------------------------------------------------------- */

int main(int argc, char **argv) {
    long iterations = -1;
    double seconds = -1;
    const char *only = NULL;
    if (argc < 2) {
        fprintf(stderr, "usage: %s random [--seed S] [--iterations N] [--seconds T] [--verbose]\n"
                        "       %s scenarios [--scenario NAME] [--verbose]\n       %s list\n", argv[0], argv[0], argv[0]);
        return 2;
    }
    mode_name = argv[1];
    for (int i = 2; i < argc; i++) {
        if (!strcmp(argv[i], "--seed") && i + 1 < argc) seed0 = strtoull(argv[++i], NULL, 10);
        else if (!strcmp(argv[i], "--iterations") && i + 1 < argc) iterations = atol(argv[++i]);
        else if (!strcmp(argv[i], "--seconds") && i + 1 < argc) seconds = atof(argv[++i]);
        else if (!strcmp(argv[i], "--scenario") && i + 1 < argc) only = argv[++i];
        else if (!strcmp(argv[i], "--verbose")) verbose = 1;
        else { fprintf(stderr, "unknown argument %s\n", argv[i]); return 2; }
    }
    design_facts();
    scratch_out = malloc((size_t)(NOUT ? NOUT : 1) * sizeof(double));
    for (int i = 0; i < NSTATES; i++) pool[i].out = malloc((size_t)(NOUT ? NOUT : 1) * sizeof(double));
    for (int i = 0; i < NINST; i++) inst[i].phase = PH_NONE;
    rng = seed0 * 0x2545F4914F6CDD1Dull + 1;
    started = now();
#ifdef HAVE_DEATH_CALLBACK
    __sanitizer_set_death_callback(on_death);
#endif
    int status = 0;
    if (!strcmp(mode_name, "list")) {
        for (size_t i = 0; i < sizeof SCENARIOS / sizeof SCENARIOS[0]; i++) printf("%s\n", SCENARIOS[i].name);
        return 0;
    } else if (!strcmp(mode_name, "scenarios")) {
        status = run_scenarios(only);
    } else if (!strcmp(mode_name, "random")) {
        if (iterations < 0 && seconds < 0) iterations = 1000;
        while ((iterations < 0 || sequences < iterations) && (seconds < 0 || now() - started < seconds)) run_sequence();
    } else {
        fprintf(stderr, "unknown mode %s\n", mode_name);
        return 2;
    }
    report(0);
    for (int i = 0; i < NSTATES; i++) free(pool[i].out);
    free(scratch_out);
    if (status) return status;
    return failures ? 1 : 0;
}
