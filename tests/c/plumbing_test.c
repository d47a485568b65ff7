/* plumbing_test: uiofmu's FMI 2.0 plumbing with a second model plugged in (kernel_toy.c).
 *
 * Built by tests/test_c_plumbing.py with uiofmu/fmu/c/fmi2_plumbing.c and tests/c/kernel_toy.c
 * under -fsanitize=address,undefined -fno-sanitize-recover=all:
 *
 *   plumbing_test run                 Integer get/set and the type checks of both directions, a
 *                                     refused and a discarded step and a master going on, the
 *                                     error state (every fmi2 function in it), log categories
 *   plumbing_test refused FRAGMENT    fmi2Instantiate must refuse (a broken variable table,
 *                                     -DTOY_TABLE=n) with a log line holding FRAGMENT
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

#include "check.h"

static int lines;
static char last_category[64];
static unsigned on = 14u; /* the categories the model says are on: bit 0 logEvents, 1 warning, 2 discard, 3 error */
static const char *const CATS[4] = {"logEvents", "logStatusWarning", "logStatusDiscard", "logStatusError"};

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                   fmi2String message, ...) {
    va_list ap;
    (void)env;
    (void)name;
    va_start(ap, message);
    vsnprintf(last, sizeof last, message, ap);
    va_end(ap);
    snprintf(last_category, sizeof last_category, "%s", category);
    lines++;
    int k = 0;
    while (k < 4 && strcmp(category, CATS[k]) != 0) k++;
    if (k == 4) fail(__FILE__, __LINE__, "a line under the undeclared category %s", category);
    else if (!(on & (1u << k))) fail(__FILE__, __LINE__, "a line under %s, which is off", category);
    else if (k != (status == fmi2OK ? 0 : status == fmi2Warning ? 1 : status == fmi2Discard ? 2 : 3))
        fail(__FILE__, __LINE__, "a line of status %d under %s", (int)status, category);
}

static fmi2CallbackFunctions callbacks = {logger, calloc, free, NULL, NULL};

/* got must be want, and a status other than fmi2OK comes with a line saying `word` */
static void status_is(int line, fmi2Status got, fmi2Status want, int lines_before, const char *word, const char *what) {
    if (got != want) fail(__FILE__, line, "%s: status %d, expected %d", what, (int)got, (int)want);
    if (want != fmi2OK && word && lines == lines_before) fail(__FILE__, line, "%s: no log line", what);
    if (want != fmi2OK && word && !strstr(last, word)) fail(__FILE__, line, "%s: the log line does not say \"%s\"", what, word);
}
#define STATUS(call, want, word) do { int before_ = lines; status_is(__LINE__, (call), (want), before_, (word), #call); } while (0)

enum { VR_X0, VR_MODE, VR_U1, VR_U2, VR_X, VR_COUNT };

static fmi2Component make(int logging) {
    return fmi2Instantiate("toy", fmi2CoSimulation, UIOFMU_FMU.guid, "file:///tmp", &callbacks, fmi2False,
                           logging ? fmi2True : fmi2False);
}

static int get_int(fmi2Component c, fmi2ValueReference vr) {
    fmi2Integer v = -99;
    STATUS(fmi2GetInteger(c, &vr, 1, &v), fmi2OK, NULL);
    return v;
}

static double get_real(fmi2Component c, fmi2ValueReference vr) {
    fmi2Real v = -99;
    STATUS(fmi2GetReal(c, &vr, 1, &v), fmi2OK, NULL);
    return v;
}

static void set_int(fmi2Component c, fmi2ValueReference vr, int v) {
    fmi2Integer x = v;
    STATUS(fmi2SetInteger(c, &vr, 1, &x), fmi2OK, NULL);
}

static void set_u(fmi2Component c, double u1, double u2) {
    fmi2ValueReference vr[2] = {VR_U1, VR_U2};
    fmi2Real v[2] = {u1, u2};
    STATUS(fmi2SetReal(c, vr, 2, v), fmi2OK, NULL);
}

static void integers(fmi2Component c) {
    fmi2ValueReference vr;
    fmi2Real r = 0;
    fmi2Integer i = 0;
    set_int(c, VR_MODE, 0);
    CHECK(get_int(c, VR_MODE) == 0, "mode after fmi2SetInteger");
    set_int(c, VR_MODE, 1);
    CHECK(get_int(c, VR_MODE) == 1 && get_int(c, VR_COUNT) == 0, "mode and count");
    /* a Real call on an Integer variable and the other way round */
    vr = VR_MODE;
    STATUS(fmi2SetReal(c, &vr, 1, &r), fmi2Error, "value reference 1 (mode[1]) is an Integer variable");
    vr = VR_COUNT;
    STATUS(fmi2GetReal(c, &vr, 1, &r), fmi2Error, "(count[1]) is an Integer variable, not a Real one");
    vr = VR_X;
    STATUS(fmi2GetInteger(c, &vr, 1, &i), fmi2Error, "value reference 4 (x[1]) is a Real variable, not an Integer one");
    vr = VR_U1;
    STATUS(fmi2SetInteger(c, &vr, 1, &i), fmi2Error, "(u[1]) is a Real variable");
    vr = VR_COUNT;
    STATUS(fmi2SetInteger(c, &vr, 1, &i), fmi2Error, "is an output (count[1])");
    vr = 99;
    STATUS(fmi2GetInteger(c, &vr, 1, &i), fmi2Error, "unknown value reference 99");
    fmi2Boolean b = 0;
    vr = VR_MODE;
    STATUS(fmi2GetBoolean(c, &vr, 1, &b), fmi2Error, "is an Integer variable, not a Boolean one");
    /* a refused call sets nothing: mode stays 1 although the bad reference comes second */
    fmi2ValueReference two[2] = {VR_MODE, VR_U1};
    fmi2Integer vals[2] = {5, 5};
    STATUS(fmi2SetInteger(c, two, 2, vals), fmi2Error, "(u[1]) is a Real variable");
    CHECK(get_int(c, VR_MODE) == 1, "a refused fmi2SetInteger set mode");
}

int run(void) {
    on = 15u; /* loggingOn: logEvents too */
    fmi2Component c = make(1);
    CHECK(c != NULL, "fmi2Instantiate");
    if (!c) return 1;
    CHECK(lines == 1 && strstr(last, "toy kernel") && !strcmp(last_category, "logEvents"), "the logEvents line of fmi2Instantiate");
    integers(c); /* instantiated */
    STATUS(fmi2SetupExperiment(c, fmi2False, 0, 10.0, fmi2False, 0), fmi2OK, NULL);
    STATUS(fmi2EnterInitializationMode(c), fmi2OK, NULL);
    integers(c); /* initialization mode */
    STATUS(fmi2ExitInitializationMode(c), fmi2OK, NULL);
    integers(c); /* step complete */
    fmi2Real t = 10.0, got;
    fmi2Boolean term = 7;
    fmi2Status dss;
    STATUS(fmi2GetRealStatus(c, fmi2LastSuccessfulTime, &got), fmi2OK, NULL);
    CHECK(got == 10.0, "fmi2LastSuccessfulTime before the first step = %g, expected the start time 10", got);
    set_u(c, 1.0, 2.0);
    STATUS(fmi2DoStep(c, t, 0.5, fmi2True), fmi2OK, NULL);
    t += 0.5;
    CHECK(get_real(c, VR_X) == 2.5 && get_int(c, VR_COUNT) == 1, "x = 1 + 0.5 * 3 after one step");
    /* an unknown mode: refused, nothing changed, the instance goes on */
    set_int(c, VR_MODE, 7);
    STATUS(fmi2DoStep(c, t, 0.5, fmi2True), fmi2Error, "unknown mode 7");
    CHECK(get_real(c, VR_X) == 2.5 && get_int(c, VR_COUNT) == 1, "a refused step changed x or count");
    /* a discarded step: the status queries, then a valid step */
    set_int(c, VR_MODE, 2);
    STATUS(fmi2DoStep(c, t, 0.5, fmi2True), fmi2Discard, "mode 2 takes no step");
    STATUS(fmi2GetRealStatus(c, fmi2LastSuccessfulTime, &got), fmi2OK, NULL);
    CHECK(got == t, "fmi2LastSuccessfulTime = %g after a step refused at %g", got, t);
    STATUS(fmi2GetBooleanStatus(c, fmi2Terminated, &term), fmi2OK, NULL);
    CHECK(term == fmi2True, "fmi2Terminated = %d after a refused step, expected true", term);
    STATUS(fmi2GetStatus(c, fmi2DoStepStatus, &dss), fmi2Discard, "no fmi2DoStep is pending");
    set_int(c, VR_MODE, 1); /* legal after a discarded step */
    STATUS(fmi2DoStep(c, t, 0.25, fmi2True), fmi2OK, NULL);
    t += 0.25;
    STATUS(fmi2GetBooleanStatus(c, fmi2Terminated, &term), fmi2OK, NULL);
    CHECK(term == fmi2False, "fmi2Terminated = %d after a step taken, expected false", term);
    CHECK(get_real(c, VR_X) == 3.25 && get_int(c, VR_COUNT) == 2, "x after the step that followed the discarded one");
    /* the error state: a kernel state at odds with its design */
    fmi2FMUstate good = NULL, mine = NULL;
    STATUS(fmi2GetFMUstate(c, &good), fmi2OK, NULL);
    size_t size = 0;
    STATUS(fmi2SerializedFMUstateSize(c, good, &size), fmi2OK, NULL);
    unsigned char *bytes = malloc(size);
    STATUS(fmi2SerializeFMUstate(c, good, (fmi2Byte *)bytes, size), fmi2OK, NULL);
    set_u(c, 666.0, 0.0);
    STATUS(fmi2DoStep(c, t, 0.5, fmi2True), fmi2Error, "u[1] = 666: the state does not fit the design");
    {
        /* every function in the error state: FMI 2.0's table, and fmi2GetFMUstate refused */
        fmi2ValueReference vr = VR_X, vin = VR_U1;
        fmi2Real r = 0, dv[2] = {0, 0};
        fmi2Integer i = 0, order = 1;
        fmi2String s = NULL;
        const char *err = "the instance is in the error state";
        STATUS(fmi2SetupExperiment(c, 0, 0, 0, 0, 0), fmi2Error, err);
        STATUS(fmi2EnterInitializationMode(c), fmi2Error, err);
        STATUS(fmi2ExitInitializationMode(c), fmi2Error, err);
        STATUS(fmi2Terminate(c), fmi2Error, err);
        STATUS(fmi2DoStep(c, t, 0.5, fmi2True), fmi2Error, err);
        STATUS(fmi2CancelStep(c), fmi2Error, err);
        STATUS(fmi2SetReal(c, &vin, 1, &r), fmi2Error, err);
        STATUS(fmi2SetInteger(c, &vin, 0, &i), fmi2Error, err);
        STATUS(fmi2GetFMUstate(c, &mine), fmi2Error, err);
        STATUS(fmi2SetRealInputDerivatives(c, &vin, 1, &order, dv), fmi2Error, err);
        STATUS(fmi2GetStatus(c, fmi2DoStepStatus, &dss), fmi2Error, err);
        STATUS(fmi2GetRealStatus(c, fmi2LastSuccessfulTime, &r), fmi2Error, err);
        STATUS(fmi2GetIntegerStatus(c, fmi2LastSuccessfulTime, &i), fmi2Error, err);
        STATUS(fmi2GetBooleanStatus(c, fmi2Terminated, &term), fmi2Error, err);
        STATUS(fmi2GetStringStatus(c, fmi2PendingStatus, &s), fmi2Error, err);
        STATUS(fmi2GetDirectionalDerivative(c, &vr, 1, &vin, 1, dv, dv + 1), fmi2Error, "not supported");
        STATUS(fmi2GetRealOutputDerivatives(c, &vr, 1, &order, dv), fmi2Error, "not supported");
        STATUS(fmi2SetDebugLogging(c, fmi2True, 0, NULL), fmi2OK, NULL);
        STATUS(fmi2GetReal(c, &vr, 1, &r), fmi2OK, NULL); /* values for debugging */
        CHECK(r == 3.25, "x in the error state = %g", r);
        STATUS(fmi2SerializedFMUstateSize(c, good, &size), fmi2OK, NULL);
        STATUS(fmi2SerializeFMUstate(c, good, (fmi2Byte *)bytes, size), fmi2OK, NULL);
        STATUS(fmi2DeSerializeFMUstate(c, (const fmi2Byte *)bytes, size, &mine), fmi2OK, NULL);
        STATUS(fmi2FreeFMUstate(c, &mine), fmi2OK, NULL);
    }
    /* fmi2SetFMUstate of a sound state leaves it */
    STATUS(fmi2SetFMUstate(c, good), fmi2OK, NULL);
    STATUS(fmi2DoStep(c, t, 0.5, fmi2True), fmi2OK, NULL);
    CHECK(get_real(c, VR_X) == 4.75 && get_int(c, VR_COUNT) == 3, "x after leaving the error state by a state");
    /* and fmi2Reset does too */
    set_u(c, 666.0, 0.0);
    STATUS(fmi2DoStep(c, t, 0.5, fmi2True), fmi2Error, "u[1] = 666");
    STATUS(fmi2Reset(c), fmi2OK, NULL);
    STATUS(fmi2EnterInitializationMode(c), fmi2OK, NULL);
    STATUS(fmi2ExitInitializationMode(c), fmi2OK, NULL);
    STATUS(fmi2DoStep(c, 0.0, 1.0, fmi2True), fmi2OK, NULL);
    CHECK(get_real(c, VR_X) == 1.0 && get_int(c, VR_COUNT) == 1, "x and count after fmi2Reset");
    /* log categories: only logStatusDiscard */
    fmi2String discard[1] = {"logStatusDiscard"}, bad[1] = {"logStatusFatal"};
    STATUS(fmi2SetDebugLogging(c, fmi2True, 1, discard), fmi2OK, NULL);
    on = 4u;
    int before = lines;
    fmi2ValueReference nope = 99;
    fmi2Real r = 0;
    STATUS(fmi2GetReal(c, &nope, 1, &r), fmi2Error, NULL);
    CHECK(lines == before, "a logStatusError line with only logStatusDiscard on");
    set_int(c, VR_MODE, 2);
    STATUS(fmi2DoStep(c, 1.0, 1.0, fmi2True), fmi2Discard, "mode 2 takes no step");
    /* unknown: ignored with fmi2Warning, its line a warning's (off); no known category named: nothing on */
    STATUS(fmi2SetDebugLogging(c, fmi2True, 1, bad), fmi2Warning, NULL);
    on = 0u;
    CHECK(lines == before + 1, "the warning about logStatusFatal logged under a category that is off");
    STATUS(fmi2SetDebugLogging(c, fmi2False, 0, NULL), fmi2OK, NULL);
    on = 0u;
    STATUS(fmi2DoStep(c, 1.0, 1.0, fmi2True), fmi2Discard, NULL);
    STATUS(fmi2Terminate(c), fmi2OK, NULL);
    CHECK(lines == before + 1, "a line with logging off");
    fmi2FreeFMUstate(c, &good);
    fmi2FreeInstance(c);
    free(bytes);
    return failures ? 1 : 0;
}

/* The plumbing's step rule (UIOFMU_STEPS of kernel_toy.c): a rounding step is accepted without the
   kernel, logged once per instance (again after fmi2Reset); a step within 4 ulps of a large t of 0.5 is
   0.5 for the kernel; one beyond 1e-3 of the step in ulps is passed on as it is. */
int steps(void) {
    on = 15u;
    fmi2Component c = make(1);
    CHECK(c != NULL, "fmi2Instantiate");
    if (!c) return 1;
    for (int round = 0; round < 2; round++) {
        double t0 = 1e9; /* ulp(t0) = 1.19e-7 */
        STATUS(fmi2SetupExperiment(c, fmi2False, 0, t0, fmi2False, 0), fmi2OK, NULL);
        STATUS(fmi2EnterInitializationMode(c), fmi2OK, NULL);
        STATUS(fmi2ExitInitializationMode(c), fmi2OK, NULL);
        set_u(c, 1.0, 1.0);
        double h = 0.5 + 3 * (nextafter(t0, INFINITY) - t0);
        STATUS(fmi2DoStep(c, t0, h, fmi2True), fmi2OK, NULL);
        CHECK(get_real(c, VR_X) == 2.0 && get_int(c, VR_COUNT) == 1, "the kernel took 0.5: x = %.17g",
              get_real(c, VR_X));
        int before = lines;
        for (int i = 0; i < 3; i++) {
            STATUS(fmi2DoStep(c, t0 + 0.5, i ? 1e-12 : 0.25e-9, fmi2True), fmi2OK, NULL);
            CHECK(get_real(c, VR_X) == 2.0 && get_int(c, VR_COUNT) == 1, "a rounding step reached the kernel");
        }
        CHECK(lines == before + 1 && strstr(last, "is rounding") && !strcmp(last_category, "logStatusWarning"),
              "one warning line for the rounding steps of an instance (%d lines)", lines - before);
        fmi2Real got;
        STATUS(fmi2GetRealStatus(c, fmi2LastSuccessfulTime, &got), fmi2OK, NULL);
        CHECK(got == t0 + 0.5 + 1e-12, "fmi2LastSuccessfulTime after a rounding step = %.17g", got);
        STATUS(fmi2DoStep(c, 1e16, 0.5 + 4.0, fmi2True), fmi2OK, NULL); /* ulp(1e16) = 2: not taken for 0.5 */
        CHECK(get_real(c, VR_X) == 2.0 + 4.5 * 2.0, "a step 4 s off at t = 1e16 was snapped: x = %.17g",
              get_real(c, VR_X));
        STATUS(fmi2Reset(c), fmi2OK, NULL);
    }
    fmi2FreeInstance(c);
    return failures ? 1 : 0;
}

int main(int argc, char **argv) {
    if (argc >= 2 && !strcmp(argv[1], "steps")) {
        int status = steps();
        printf("plumbing_test steps: %d failed checks\n", failures);
        return status;
    }
    if (argc >= 2 && !strcmp(argv[1], "run")) {
        int status = run();
        printf("plumbing_test run: %d failed checks\n", failures);
        return status;
    }
    if (argc >= 3 && !strcmp(argv[1], "refused")) {
        fmi2Component c = make(1);
        CHECK(c == NULL, "fmi2Instantiate accepted a broken variable table");
        CHECK(strstr(last, "the design data compiled into this FMU is inconsistent") && strstr(last, argv[2]),
              "fmi2Instantiate's refusal does not say \"%s\"", argv[2]);
        if (c) fmi2FreeInstance(c);
        printf("plumbing_test refused: %d failed checks\n", failures);
        return failures ? 1 : 0;
    }
    fprintf(stderr, "usage: %s run | steps | refused FRAGMENT\n", argv[0]);
    return 2;
}
