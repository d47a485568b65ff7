/* plant_test: a uiofmu C plant FMU (fmi2_plumbing.c + kernel_plant.c + its design_data.c) driven
 * directly, built by tests/test_c_plant.py under -fsanitize=address,undefined
 * -fno-sanitize-recover=all:
 *
 *   plant_test trajectory H1 H2 ...   initialise (x0 = the design's), set u[i] = 0.3 i - 0.5 and
 *                                     d[i] = 0.2 - 0.1 i, take the steps H1 H2 ... from t = 0 and
 *                                     print "x ..." (%.17g) after each; the caller compares them
 *                                     with the reference runtime
 *   plant_test scenario H DT_OTHER    the bad calls (NaN inputs, h <= 0 or not finite: fmi2Error
 *                                     with a log line, nothing changed), a step other than dt
 *                                     (DT_OTHER > 0: fmi2Discard, the status queries, a valid step
 *                                     goes on), FMU states got/set/serialised bit-identical,
 *                                     forged and truncated bytes refused; every fmi2 function in
 *                                     every state an instance can be brought to (the masks of
 *                                     fmi2_plumbing.c, written out again here)
 *
 * Prints "FAIL ..." lines on stderr and exits 1 when a check failed, 0 otherwise.
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "fmi2_plumbing.h"
#include "kernel_plant.h"

#include "check.h"

static int lines;

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                   fmi2String message, ...) {
    va_list ap;
    (void)env; (void)name; (void)status; (void)category;
    va_start(ap, message);
    vsnprintf(last, sizeof last, message, ap);
    va_end(ap);
    lines++;
}

static fmi2CallbackFunctions callbacks = {logger, calloc, free, NULL, NULL};
static const UiofmuPlant *P = &UIOFMU_PLANT;

/* value references: x0 0.., u n.., d n+m.., y n+m+q.., x n+m+q+p.., mismatch, mismatch_seed */
static fmi2ValueReference VR_X0(int i) { return (fmi2ValueReference)i; }
static fmi2ValueReference VR_U(int i) { return (fmi2ValueReference)(P->n + i); }
static fmi2ValueReference VR_D(int i) { return (fmi2ValueReference)(P->n + P->m + i); }
static fmi2ValueReference VR_Y(int i) { return (fmi2ValueReference)(P->n + P->m + P->q + i); }
static fmi2ValueReference VR_X(int i) { return (fmi2ValueReference)(P->n + P->m + P->q + P->p + i); }
/* after x (a linear plant): the Real parameter mismatch, the Integer parameter mismatch_seed */
static fmi2ValueReference VR_MISMATCH(void) { return VR_X(P->n); }
static fmi2ValueReference VR_MISMATCH_SEED(void) { return VR_X(P->n) + 1; }

static fmi2Component make(void) {
    fmi2Component c = fmi2Instantiate("plant", fmi2CoSimulation, UIOFMU_FMU.guid, "file:///tmp", &callbacks, fmi2False, fmi2True);
    CHECK(c != NULL, "fmi2Instantiate failed");
    return c;
}

static void start(fmi2Component c) {
    CHECK(fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0) == fmi2OK, "setup");
    CHECK(fmi2EnterInitializationMode(c) == fmi2OK, "enter");
    CHECK(fmi2ExitInitializationMode(c) == fmi2OK, "exit");
}

static void set_inputs(fmi2Component c) {
    for (int i = 0; i < P->m; i++) {
        fmi2ValueReference vr = VR_U(i);
        double v = 0.3 * (i + 1) - 0.5;
        CHECK(fmi2SetReal(c, &vr, 1, &v) == fmi2OK, "set u");
    }
    for (int i = 0; i < P->q; i++) {
        fmi2ValueReference vr = VR_D(i);
        double v = 0.2 - 0.1 * (i + 1);
        CHECK(fmi2SetReal(c, &vr, 1, &v) == fmi2OK, "set d");
    }
}

/* outputs y and x in out (p + n doubles) */
static void outputs(fmi2Component c, double *out) {
    for (int i = 0; i < P->p; i++) {
        fmi2ValueReference vr = VR_Y(i);
        CHECK(fmi2GetReal(c, &vr, 1, &out[i]) == fmi2OK, "get y");
    }
    for (int i = 0; i < P->n; i++) {
        fmi2ValueReference vr = VR_X(i);
        CHECK(fmi2GetReal(c, &vr, 1, &out[P->p + i]) == fmi2OK, "get x");
    }
}

static int trajectory(int argc, char **argv) {
    fmi2Component c = make();
    if (!c) return 1;
    start(c);
    set_inputs(c);
    double t = 0.0, *out = calloc((size_t)(P->p + P->n), sizeof(double));
    for (int k = 0; k < argc; k++) {
        double h = strtod(argv[k], NULL);
        fmi2Status st = fmi2DoStep(c, t, h, fmi2True);
        CHECK(st == fmi2OK, "step %d (h = %s): status %d", k, argv[k], (int)st);
        t += h;
        outputs(c, out);
        printf("x");
        for (int i = 0; i < P->n; i++) printf(" %.17g", out[P->p + i]);
        printf("\n");
    }
    free(out);
    fmi2FreeInstance(c);
    return 0;
}

/* the status `want`, and for a status other than fmi2OK a new log line holding `word` */
static void expect(int line, fmi2Status got, fmi2Status want, int before, const char *word, const char *what) {
    if (got != want) fail(__FILE__, line, "%s: status %d, expected %d", what, (int)got, (int)want);
    else if (want != fmi2OK && (lines == before || (word && !strstr(last, word))))
        fail(__FILE__, line, "%s: no log line saying '%s'", what, word ? word : "");
}
#define EXPECT(got, want, word, what) do { int b_ = lines; fmi2Status g_ = (got); expect(__LINE__, g_, want, b_, word, what); } while (0)

static unsigned char *serialise(fmi2Component c, size_t *len) {
    fmi2FMUstate st = NULL;
    CHECK(fmi2GetFMUstate(c, &st) == fmi2OK, "get state");
    CHECK(fmi2SerializedFMUstateSize(c, st, len) == fmi2OK, "size");
    unsigned char *b = malloc(*len);
    CHECK(fmi2SerializeFMUstate(c, st, (fmi2Byte *)b, *len) == fmi2OK, "serialise");
    fmi2FreeFMUstate(c, &st);
    return b;
}

/* ---- the state masks ---------------------------------------------------------------------- */

enum { S_INST, S_INIT, S_COMPLETE, S_DISCARDED, S_TERMINATED, S_COUNT };
static const char *const S_NAME[S_COUNT] = {"instantiated", "initialization mode", "step complete", "step discarded",
                                            "terminated"};
#define ANY 0x1fu
#define RUN ((1u << S_COMPLETE) | (1u << S_DISCARDED))
enum { F_SetDebugLogging, F_SetupExperiment, F_EnterInit, F_ExitInit, F_Terminate, F_Reset, F_GetReal, F_SetReal,
       F_GetInteger, F_SetInteger, F_GetBoolean, F_SetBoolean, F_GetString, F_SetString, F_GetFMUstate,
       F_SetFMUstate, F_DeSerialize, F_GetDirectionalDerivative, F_SetRealInputDerivatives,
       F_GetRealOutputDerivatives, F_DoStep, F_CancelStep, F_GetStatus, F_GetRealStatus, F_GetIntegerStatus,
       F_GetBooleanStatus, F_GetStringStatus, F_COUNT };
/* FMI 2.0 section 4.2.4 with the plumbing's documented differences (fmi2_plumbing.c) */
static const struct { const char *name; unsigned legal; } FN[F_COUNT] = {
    {"fmi2SetDebugLogging", ANY}, {"fmi2SetupExperiment", 1u << S_INST}, {"fmi2EnterInitializationMode", 1u << S_INST},
    {"fmi2ExitInitializationMode", 1u << S_INIT}, {"fmi2Terminate", RUN}, {"fmi2Reset", ANY},
    {"fmi2GetReal", ANY}, {"fmi2SetReal", ANY & ~(1u << S_TERMINATED)}, {"fmi2GetInteger", ANY},
    {"fmi2SetInteger", ANY & ~(1u << S_TERMINATED)}, {"fmi2GetBoolean", ANY},
    {"fmi2SetBoolean", ANY & ~(1u << S_TERMINATED)}, {"fmi2GetString", ANY},
    {"fmi2SetString", ANY & ~(1u << S_TERMINATED)}, {"fmi2GetFMUstate", ANY}, {"fmi2SetFMUstate", ANY},
    {"fmi2DeSerializeFMUstate", ANY}, {"fmi2GetDirectionalDerivative", ANY & ~(1u << S_INST)},
    {"fmi2SetRealInputDerivatives", (1u << S_INST) | (1u << S_INIT) | (1u << S_COMPLETE)},
    {"fmi2GetRealOutputDerivatives", RUN | (1u << S_TERMINATED)}, {"fmi2DoStep", RUN}, {"fmi2CancelStep", 0u},
    {"fmi2GetStatus", RUN | (1u << S_TERMINATED)}, {"fmi2GetRealStatus", RUN | (1u << S_TERMINATED)},
    {"fmi2GetIntegerStatus", RUN | (1u << S_TERMINATED)}, {"fmi2GetBooleanStatus", RUN | (1u << S_TERMINATED)},
    {"fmi2GetStringStatus", RUN | (1u << S_TERMINATED)},
};

static double good_step(void) { return P->time == UIOFMU_DISCRETE ? P->dt : 0.25; }

/* an instance brought to state st; NULL when the plant cannot get there (a continuous plant
   discards no step) */
static fmi2Component in_state(int st) {
    if (st == S_DISCARDED && P->time != UIOFMU_DISCRETE) return NULL;
    fmi2Component c = make();
    if (!c || st == S_INST) return c;
    CHECK(fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0) == fmi2OK, "setup");
    CHECK(fmi2EnterInitializationMode(c) == fmi2OK, "enter");
    if (st == S_INIT) return c;
    CHECK(fmi2ExitInitializationMode(c) == fmi2OK, "exit");
    if (st == S_DISCARDED) CHECK(fmi2DoStep(c, 0.0, P->dt * 1.5, fmi2True) == fmi2Discard, "discard");
    if (st == S_TERMINATED) CHECK(fmi2Terminate(c) == fmi2OK, "terminate");
    return c;
}

static void state_masks(const unsigned char *bytes, size_t blen) {
    fmi2Component giver = in_state(S_COMPLETE);
    for (int st = 0; st < S_COUNT; st++)
        for (int f = 0; f < F_COUNT; f++) {
            fmi2Component c = in_state(st);
            if (!c) continue;
            fmi2ValueReference vr_in = VR_U(0) < VR_Y(0) ? (P->m ? VR_U(0) : VR_D(0)) : 0, vr_out = VR_X(0);
            if (!P->m && !P->q) vr_in = VR_X0(0);
            double v = 0.5, dv[2] = {0, 0};
            fmi2Integer order = 1;
            fmi2Boolean bv;
            fmi2String sv;
            fmi2Status status;
            fmi2Real rv;
            fmi2FMUstate mine = NULL, given = NULL;
            int before = lines;
            fmi2Status got = fmi2OK;
            switch (f) {
            case F_SetDebugLogging: got = fmi2SetDebugLogging(c, fmi2True, 0, NULL); break;
            case F_SetupExperiment: got = fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0); break;
            case F_EnterInit: got = fmi2EnterInitializationMode(c); break;
            case F_ExitInit: got = fmi2ExitInitializationMode(c); break;
            case F_Terminate: got = fmi2Terminate(c); break;
            case F_Reset: got = fmi2Reset(c); break;
            case F_GetReal: got = fmi2GetReal(c, &vr_out, 1, &rv); break;
            case F_SetReal: got = fmi2SetReal(c, &vr_in, 1, &v); break;
            case F_GetInteger: got = fmi2GetInteger(c, &vr_in, 0, &order); break;
            case F_SetInteger: got = fmi2SetInteger(c, &vr_in, 0, &order); break;
            case F_GetBoolean: got = fmi2GetBoolean(c, &vr_in, 0, &bv); break;
            case F_SetBoolean: got = fmi2SetBoolean(c, &vr_in, 0, &bv); break;
            case F_GetString: got = fmi2GetString(c, &vr_in, 0, &sv); break;
            case F_SetString: got = fmi2SetString(c, &vr_in, 0, &sv); break;
            case F_GetFMUstate: got = fmi2GetFMUstate(c, &mine); break;
            case F_SetFMUstate:
                CHECK(fmi2GetFMUstate(giver, &given) == fmi2OK, "a state to give");
                got = fmi2SetFMUstate(c, given);
                fmi2FreeFMUstate(giver, &given);
                break;
            case F_DeSerialize: got = fmi2DeSerializeFMUstate(c, (const fmi2Byte *)bytes, blen, &mine); break;
            case F_GetDirectionalDerivative: got = fmi2GetDirectionalDerivative(c, &vr_out, 1, &vr_in, 1, dv, dv + 1); break;
            case F_SetRealInputDerivatives: got = fmi2SetRealInputDerivatives(c, &vr_in, 1, &order, dv); break;
            case F_GetRealOutputDerivatives: got = fmi2GetRealOutputDerivatives(c, &vr_out, 1, &order, dv); break;
            case F_DoStep: got = fmi2DoStep(c, 0.0, good_step(), fmi2True); break;
            case F_CancelStep: got = fmi2CancelStep(c); break;
            case F_GetStatus: got = fmi2GetStatus(c, fmi2DoStepStatus, &status); break;
            case F_GetRealStatus: got = fmi2GetRealStatus(c, fmi2LastSuccessfulTime, &rv); break;
            case F_GetIntegerStatus: got = fmi2GetIntegerStatus(c, fmi2LastSuccessfulTime, &order); break;
            case F_GetBooleanStatus: got = fmi2GetBooleanStatus(c, fmi2Terminated, &bv); break;
            case F_GetStringStatus: got = fmi2GetStringStatus(c, fmi2PendingStatus, &sv); break;
            }
            int legal = (FN[f].legal >> st) & 1u;
            int refused = got == fmi2Error && lines > before && strstr(last, "(the instance is ") != NULL;
            if (legal && refused) fail(__FILE__, __LINE__, "%s when %s: refused as illegal", FN[f].name, S_NAME[st]);
            if (!legal && !refused) fail(__FILE__, __LINE__, "%s when %s: status %d, expected a refusal as illegal", FN[f].name, S_NAME[st], (int)got);
            if (legal && (f == F_GetRealStatus || f == F_GetBooleanStatus) && got != fmi2OK)
                fail(__FILE__, __LINE__, "%s when %s: status %d, expected fmi2OK", FN[f].name, S_NAME[st], (int)got);
            if (mine) fmi2FreeFMUstate(c, &mine);
            fmi2FreeInstance(c);
        }
    fmi2FreeInstance(giver);
}

static int scenario(double h, double other) {
    fmi2Component c = make();
    if (!c) return 1;
    size_t no = (size_t)(P->p + P->n);
    double *a = calloc(no, sizeof(double)), *b = calloc(no, sizeof(double)), *e = calloc(no, sizeof(double));
    double nan = NAN, inf = INFINITY, t = 0.0;
    /* a non-finite x0 is refused when initialisation ends */
    CHECK(fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0) == fmi2OK, "setup");
    CHECK(fmi2EnterInitializationMode(c) == fmi2OK, "enter");
    fmi2ValueReference vx0 = VR_X0(0);
    double x00 = P->x0[0];
    CHECK(fmi2SetReal(c, &vx0, 1, &nan) == fmi2OK, "set x0 nan");
    EXPECT(fmi2ExitInitializationMode(c), fmi2Error, "x0[1]", "exit with x0[1] = nan");
    CHECK(fmi2SetReal(c, &vx0, 1, &x00) == fmi2OK, "set x0");
    /* a mismatch that is not a finite number >= 0 is refused the same way; then the scenario runs on
       a perturbed plant (its state carries the two parameters) */
    fmi2ValueReference vmm = VR_MISMATCH(), vms = VR_MISMATCH_SEED();
    double below = -0.01, mismatch = 0.02;
    fmi2Integer mseed = -5;
    CHECK(fmi2SetReal(c, &vmm, 1, &below) == fmi2OK, "set mismatch < 0");
    EXPECT(fmi2ExitInitializationMode(c), fmi2Error, "mismatch", "exit with mismatch < 0");
    CHECK(fmi2SetReal(c, &vmm, 1, &nan) == fmi2OK, "set mismatch nan");
    EXPECT(fmi2ExitInitializationMode(c), fmi2Error, "mismatch", "exit with mismatch = nan");
    CHECK(fmi2SetReal(c, &vmm, 1, &mismatch) == fmi2OK, "set mismatch");
    CHECK(fmi2SetInteger(c, &vms, 1, &mseed) == fmi2OK, "set mismatch_seed");
    CHECK(fmi2ExitInitializationMode(c) == fmi2OK, "exit");
    set_inputs(c);
    EXPECT(fmi2DoStep(c, t, h, fmi2True), fmi2OK, NULL, "a valid step");
    t += h;
    outputs(c, a);
    /* bad calls: nothing changes */
    EXPECT(fmi2DoStep(c, t, 0.0, fmi2True), fmi2Error, "h", "h = 0");
    EXPECT(fmi2DoStep(c, t, -h, fmi2True), fmi2Error, "h", "h < 0");
    EXPECT(fmi2DoStep(c, t, nan, fmi2True), fmi2Error, "h", "h = nan");
    EXPECT(fmi2DoStep(c, t, inf, fmi2True), fmi2Error, "h", "h = inf");
    if (P->m || P->q) {
        fmi2ValueReference vr = P->m ? VR_U(0) : VR_D(0);
        double keep;
        CHECK(fmi2GetReal(c, &vr, 1, &keep) == fmi2OK, "get input");
        CHECK(fmi2SetReal(c, &vr, 1, &nan) == fmi2OK, "set nan");
        EXPECT(fmi2DoStep(c, t, h, fmi2True), fmi2Error, "not finite", "a nan input");
        CHECK(fmi2SetReal(c, &vr, 1, &inf) == fmi2OK, "set inf");
        EXPECT(fmi2DoStep(c, t, h, fmi2True), fmi2Error, "not finite", "an inf input");
        CHECK(fmi2SetReal(c, &vr, 1, &keep) == fmi2OK, "restore input");
    }
    outputs(c, b);
    CHECK(memcmp(a, b, no * sizeof(double)) == 0, "a refused call changed the outputs");
    /* a step other than dt (discrete plants): fmi2Discard, the status queries, then on */
    if (other > 0) {
        EXPECT(fmi2DoStep(c, t, other, fmi2True), fmi2Discard, "dt", "a step other than dt");
        CHECK(strstr(last, "received h") != NULL, "the discard line names h: %s", last);
        fmi2Real lt = -1;
        fmi2Boolean term = fmi2False;
        fmi2Status ds;
        EXPECT(fmi2GetRealStatus(c, fmi2LastSuccessfulTime, &lt), fmi2OK, NULL, "last successful time");
        CHECK(lt == t, "last successful time %g, expected %g", lt, t);
        EXPECT(fmi2GetBooleanStatus(c, fmi2Terminated, &term), fmi2OK, NULL, "terminated");
        CHECK(term == fmi2True, "terminated = false after a refused step (fmpy would repeat it for ever)");
        EXPECT(fmi2GetStatus(c, fmi2DoStepStatus, &ds), fmi2Discard, "", "do step status");
        outputs(c, b);
        CHECK(memcmp(a, b, no * sizeof(double)) == 0, "the discarded step changed the outputs");
    }
    /* FMU state: saved, the instance goes on, restored bit for bit; bytes the same */
    fmi2FMUstate st = NULL, st2 = NULL;
    CHECK(fmi2GetFMUstate(c, &st) == fmi2OK, "get state");
    size_t len = 0;
    unsigned char *bytes = serialise(c, &len);
    EXPECT(fmi2DoStep(c, t, h, fmi2True), fmi2OK, NULL, "a step after the state");
    outputs(c, e);
    CHECK(fmi2SetFMUstate(c, st) == fmi2OK, "set state");
    outputs(c, b);
    CHECK(memcmp(a, b, no * sizeof(double)) == 0, "the restored outputs differ");
    EXPECT(fmi2DoStep(c, t, h, fmi2True), fmi2OK, NULL, "the step again");
    outputs(c, b);
    CHECK(memcmp(e, b, no * sizeof(double)) == 0, "the replayed step differs");
    CHECK(fmi2DeSerializeFMUstate(c, (const fmi2Byte *)bytes, len, &st2) == fmi2OK, "deserialise");
    CHECK(fmi2SetFMUstate(c, st2) == fmi2OK, "set deserialised");
    outputs(c, b);
    CHECK(memcmp(a, b, no * sizeof(double)) == 0, "the deserialised outputs differ");
    size_t len2 = 0;
    unsigned char *again = serialise(c, &len2);
    CHECK(len2 == len && memcmp(bytes, again, len) == 0, "the serialised state differs after a round trip");
    free(again);
    /* forged bytes: refused, nothing changes */
    size_t data = len - (size_t)(3 + 2 * P->n + P->m + P->q) * sizeof(double);
    size_t at_mismatch = 1 + 2 * (size_t)P->n + (size_t)P->m + (size_t)P->q;
    struct { size_t index; double value; const char *word; } forged[] = {
        {0, 7.0, "phase"}, {0, 0.5, "phase"}, {0, NAN, "phase"}, {1, NAN, "x0[1]"}, {1 + (size_t)P->n, INFINITY, "x[1]"},
        {1 + (size_t)P->n, 1e300, NULL}, {at_mismatch, -0.5, "mismatch"}, {at_mismatch, NAN, "mismatch"},
        {at_mismatch, INFINITY, "mismatch"}, {at_mismatch + 1, 0.5, "mismatch_seed"},
        {at_mismatch + 1, 3e9, "mismatch_seed"}, {at_mismatch, 0.3, NULL}};
    for (size_t i = 0; i < sizeof forged / sizeof forged[0]; i++) {
        unsigned char *copy = malloc(len);
        memcpy(copy, bytes, len);
        memcpy(copy + data + forged[i].index * sizeof(double), &forged[i].value, sizeof(double));
        fmi2FMUstate f = NULL;
        if (forged[i].word) {
            EXPECT(fmi2DeSerializeFMUstate(c, (const fmi2Byte *)copy, len, &f), fmi2Error, forged[i].word, "forged bytes");
        } else {
            CHECK(fmi2DeSerializeFMUstate(c, (const fmi2Byte *)copy, len, &f) == fmi2OK, "a finite x is a state");
        }
        if (f) fmi2FreeFMUstate(c, &f);
        free(copy);
    }
    /* phase 0 with x other than the design's x0 */
    {
        unsigned char *copy = malloc(len);
        memcpy(copy, bytes, len);
        double zero = 0.0, other_x = P->x0[0] + 1.0;
        memcpy(copy + data, &zero, sizeof zero);
        memcpy(copy + data + (1 + (size_t)P->n) * sizeof(double), &other_x, sizeof other_x);
        fmi2FMUstate f = NULL;
        EXPECT(fmi2DeSerializeFMUstate(c, (const fmi2Byte *)copy, len, &f), fmi2Error, "before initialisation", "x moved before initialisation");
        if (f) fmi2FreeFMUstate(c, &f);
        free(copy);
    }
    fmi2FMUstate f = NULL;
    EXPECT(fmi2DeSerializeFMUstate(c, (const fmi2Byte *)bytes, len - 1, &f), fmi2Error, "", "truncated bytes");
    if (f) fmi2FreeFMUstate(c, &f);
    outputs(c, b);
    CHECK(memcmp(a, b, no * sizeof(double)) == 0, "refused bytes changed the outputs");
    /* many distinct steps (past the cache) and back to the first: the same numbers as before */
    if (P->time == UIOFMU_CONTINUOUS) {
        CHECK(fmi2SetFMUstate(c, st) == fmi2OK, "set state");
        for (int k = 0; k < 20; k++) CHECK(fmi2DoStep(c, t, h * (1 + 0.1 * k), fmi2True) == fmi2OK, "cache step %d", k);
        CHECK(fmi2SetFMUstate(c, st) == fmi2OK, "set state");
        EXPECT(fmi2DoStep(c, t, h, fmi2True), fmi2OK, NULL, "the step after the cache turned over");
        outputs(c, b);
        CHECK(memcmp(e, b, no * sizeof(double)) == 0, "a step recomputed after eviction differs");
    }
    fmi2FreeFMUstate(c, &st);
    fmi2FreeFMUstate(c, &st2);
    EXPECT(fmi2Reset(c), fmi2OK, NULL, "reset");
    start(c);
    fmi2FreeInstance(c);
    state_masks(bytes, len);
    free(bytes);
    free(a);
    free(b);
    free(e);
    return 0;
}

int main(int argc, char **argv) {
    if (argc >= 2 && !strcmp(argv[1], "trajectory")) trajectory(argc - 2, argv + 2);
    else if (argc == 4 && !strcmp(argv[1], "scenario")) scenario(strtod(argv[2], NULL), strtod(argv[3], NULL));
    else {
        fprintf(stderr, "usage: %s trajectory H... | scenario H DT_OTHER\n", argv[0]);
        return 2;
    }
    fprintf(stderr, "failures=%d\n", failures);
    return failures ? 1 : 0;
}
