/* uiofmu: the FMI 2.0 Co-Simulation plumbing shared by every uiofmu C FMU.
 *
 * Everything FMI about an FMU, written once for every model: instances and their states, the
 * legal calls in each state, logging and its categories, get/set through the generated variable
 * table, the FMU state image, the status queries. The model itself is a kernel
 * (UIOFMU_FMU.kernel, see fmi2_plumbing.h), which this file calls and never looks into.
 *
 * Instance states and legal calls
 * -------------------------------
 * An instance is in one of six states; every fmi2 function starts by checking the state
 * against its mask (CALLS below), and a call outside its mask returns fmi2Error with a log
 * line naming the state, and changes nothing:
 *
 *   instantiated        after fmi2Instantiate and fmi2Reset
 *   initialization mode after fmi2EnterInitializationMode
 *   step complete       after fmi2ExitInitializationMode and every fmi2DoStep that returned fmi2OK
 *   step discarded      after fmi2DoStep returned fmi2Discard (FMI 2.0 "stepFailed")
 *   terminated          after fmi2Terminate
 *   error               after a kernel call found the instance's state at odds with its design
 *                       (UIOFMU_BROKEN); left by fmi2SetFMUstate of a sound state or fmi2Reset
 *
 * The masks are FMI 2.0's (section 4.2.4; as the Reference-FMUs write them) with these
 * deliberate differences, all on the side of accepting more:
 *   - a refused call (fmi2Error with nothing changed: NaN inputs, h <= 0, an illegal call, a
 *     forged state) leaves the instance in its state, so a master may go on; only a broken
 *     kernel state leads to the error state;
 *   - a discarded step changed nothing, so step discarded takes what step complete takes
 *     (fmi2SetReal of inputs, fmi2DoStep: a master may go on with a valid step, from the state
 *     the instance was in before the refused one), besides fmi2Terminate and the status queries;
 *   - fmi2GetXXX is legal in every state (FMI 2.0: not in instantiated): the variables hold their
 *     start values there, and the outputs are computed from them;
 *   - fmi2GetFMUstate is refused in the error state (FMI 2.0 allows it there): a state saved
 *     there could not be restored.
 * step in progress and step canceled are never entered (fmi2DoStep completes every step before
 * it returns, canRunAsynchronuously = false), so fmi2CancelStep is never legal.
 *
 * Status queries (FMI 2.0.x, 2.1.3 and 4.2.3)
 * -------------------------------------------
 *   fmi2GetRealStatus(fmi2LastSuccessfulTime)  fmi2OK: the end of the last completed step (the
 *       start time before the first), or, after a discarded step, its communication point (the
 *       refused step did not leave it). fmi2Discard with a log line when the time is not known:
 *       after fmi2SetFMUstate (the FMU state does not carry the master's time) until the next step.
 *   fmi2GetBooleanStatus(fmi2Terminated)       fmi2OK; fmi2True in step discarded (the FMU will
 *       never take the step it refused: the same t and h are refused each time), else fmi2False.
 *       A master that repeats a discarded step while this answers false (fmpy does) would loop for
 *       ever; on true it ends the run with the refusal's log line as its one message. The
 *       instance still takes any other step (a master that changes its step, as uiofmu's does, goes
 *       on), after which the answer is fmi2False again.
 *   fmi2GetStatus(fmi2DoStepStatus), fmi2GetStringStatus(fmi2PendingStatus)  fmi2Discard with a
 *       log line: both are for a step that returned fmi2Pending, and none ever does ("fmi2Discard
 *       is returned also if the slave is not able to return the required status information").
 *   any other kind (one of another type, or none of the four; FMI 2.0 has no Integer status)
 *       fmi2Error with a log line.
 *
 * Logging
 * -------
 * Categories: logEvents (fmi2OK lines: the instance's state changes), logStatusWarning,
 * logStatusDiscard, logStatusError (the lines of calls returning that status). At
 * fmi2Instantiate the three status categories are on and logEvents follows loggingOn.
 * fmi2SetDebugLogging(on, 0, _) switches every category on or off; (fmi2True, n, cats) logs only
 * the n categories named; (fmi2False, n, cats) switches the named ones off and keeps the rest. A
 * NULL array or category refuses the call (fmi2Error, a log line, nothing changed). A category
 * this FMU does not declare is ignored with one fmi2Warning line (under the categories that were on
 * before the call) and the call returns fmi2Warning: FMI 2.0 leaves the allowed categories to the
 * FMU (<LogCategories>) and keeps fmi2Error for "the simulation cannot be continued", while an
 * unknown category changes nothing the simulation depends on ("things are not quite right, but
 * the computation can continue"); the python backend's guard answers alike.
 *
 * Steps (UIOFMU_FMU.steps, see UiofmuSteps)
 * -----------------------------------------
 * Before the kernel sees a step: a step of at most steps->tiny is rounding (OMSimulator ends a run
 * with h = 1.4e-12 s): fmi2OK, the kernel is not called, one warning line per instance (until
 * fmi2Reset); a step within steps->ulps ulps of t of an admissible step H is passed on as H (where
 * those ulps are at most steps->ulps_limit of H: a time that no longer resolves the step snaps nothing).
 */
#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2_plumbing.h"

#define MAX_GUID 255
#define MAX_VARIABLES 16777216
#define MAX_PORTS 64
#define MAX_STEPS 4096
#define MAX_KNOWN_STEPS 256 /* admissible steps whose gap fmi2Instantiate works out (pairs: 32640) */
#define INSTANCE_MAGIC 0x75696e73u /* "uins" */

/* ---------------------------------------------------------------------------------------- */
/* instance states and the legal calls in each                                               */

enum {
    INSTANTIATED = 1u << 0,
    INITIALIZATION_MODE = 1u << 1,
    STEP_COMPLETE = 1u << 2,
    STEP_DISCARDED = 1u << 3,
    TERMINATED = 1u << 4,
    ERROR_STATE = 1u << 5,
    N_STATES = 6
};
#define ANY_STATE (INSTANTIATED | INITIALIZATION_MODE | STEP_COMPLETE | STEP_DISCARDED | TERMINATED | ERROR_STATE)
#define RUNNING (STEP_COMPLETE | STEP_DISCARDED)

static const char *const STATE_NAME[N_STATES] = {"instantiated", "in initialization mode", "step complete",
                                                  "step discarded", "terminated", "in the error state"};

enum {
    C_SetDebugLogging, C_SetupExperiment, C_EnterInitializationMode, C_ExitInitializationMode, C_Terminate,
    C_Reset, C_GetReal, C_GetInteger, C_GetBoolean, C_GetString, C_SetReal, C_SetInteger, C_SetBoolean,
    C_SetString, C_GetFMUstate, C_SetFMUstate, C_FreeFMUstate, C_SerializedFMUstateSize, C_SerializeFMUstate,
    C_DeSerializeFMUstate, C_GetDirectionalDerivative, C_SetRealInputDerivatives, C_GetRealOutputDerivatives,
    C_DoStep, C_CancelStep, C_GetStatus, C_GetRealStatus, C_GetIntegerStatus, C_GetBooleanStatus,
    C_GetStringStatus, C_COUNT
};

/* The one table of legal calls: each fmi2 function's states, and what its refusal says. */
static const struct {
    const char *name;
    unsigned mask;
    const char *hint;
} CALLS[C_COUNT] = {
    [C_SetDebugLogging] = {"fmi2SetDebugLogging", ANY_STATE, ""},
    [C_SetupExperiment] = {"fmi2SetupExperiment", INSTANTIATED, "only after fmi2Instantiate"},
    [C_EnterInitializationMode] = {"fmi2EnterInitializationMode", INSTANTIATED, "only after fmi2Instantiate"},
    [C_ExitInitializationMode] = {"fmi2ExitInitializationMode", INITIALIZATION_MODE, "only in initialisation mode"},
    [C_Terminate] = {"fmi2Terminate", RUNNING, "only after initialisation"},
    [C_Reset] = {"fmi2Reset", ANY_STATE, ""},
    [C_GetReal] = {"fmi2GetReal", ANY_STATE, ""},
    [C_GetInteger] = {"fmi2GetInteger", ANY_STATE, ""},
    [C_GetBoolean] = {"fmi2GetBoolean", ANY_STATE, ""},
    [C_GetString] = {"fmi2GetString", ANY_STATE, ""},
    [C_SetReal] = {"fmi2SetReal", INSTANTIATED | INITIALIZATION_MODE | RUNNING, "not after fmi2Terminate"},
    [C_SetInteger] = {"fmi2SetInteger", INSTANTIATED | INITIALIZATION_MODE | RUNNING, "not after fmi2Terminate"},
    [C_SetBoolean] = {"fmi2SetBoolean", INSTANTIATED | INITIALIZATION_MODE | RUNNING, "not after fmi2Terminate"},
    [C_SetString] = {"fmi2SetString", INSTANTIATED | INITIALIZATION_MODE | RUNNING, "not after fmi2Terminate"},
    [C_GetFMUstate] = {"fmi2GetFMUstate", ANY_STATE & ~ERROR_STATE,
                       "a state taken in the error state could not be restored (restore an earlier one, or fmi2Reset)"},
    [C_SetFMUstate] = {"fmi2SetFMUstate", ANY_STATE, ""},
    [C_FreeFMUstate] = {"fmi2FreeFMUstate", ANY_STATE, ""},
    [C_SerializedFMUstateSize] = {"fmi2SerializedFMUstateSize", ANY_STATE, ""},
    [C_SerializeFMUstate] = {"fmi2SerializeFMUstate", ANY_STATE, ""},
    [C_DeSerializeFMUstate] = {"fmi2DeSerializeFMUstate", ANY_STATE, ""},
    [C_GetDirectionalDerivative] = {"fmi2GetDirectionalDerivative", ANY_STATE & ~INSTANTIATED,
                                    "not before initialisation mode"},
    [C_SetRealInputDerivatives] = {"fmi2SetRealInputDerivatives", INSTANTIATED | INITIALIZATION_MODE | STEP_COMPLETE,
                                   "not after a discarded step or fmi2Terminate"},
    [C_GetRealOutputDerivatives] = {"fmi2GetRealOutputDerivatives", RUNNING | TERMINATED | ERROR_STATE,
                                    "only after initialisation"},
    [C_DoStep] = {"fmi2DoStep", RUNNING, "called before fmi2ExitInitializationMode or after fmi2Terminate"},
    [C_CancelStep] = {"fmi2CancelStep", 0u,
                      "no step is pending: this FMU completes every step within fmi2DoStep (canRunAsynchronuously = false)"},
    [C_GetStatus] = {"fmi2GetStatus", RUNNING | TERMINATED, "only after initialisation"},
    [C_GetRealStatus] = {"fmi2GetRealStatus", RUNNING | TERMINATED, "only after initialisation"},
    [C_GetIntegerStatus] = {"fmi2GetIntegerStatus", RUNNING | TERMINATED, "only after initialisation"},
    [C_GetBooleanStatus] = {"fmi2GetBooleanStatus", RUNNING | TERMINATED, "only after initialisation"},
    [C_GetStringStatus] = {"fmi2GetStringStatus", RUNNING | TERMINATED, "only after initialisation"},
};

/* ---------------------------------------------------------------------------------------- */
/* the instance and its log                                                                  */

enum { LOG_EVENTS, LOG_WARNING, LOG_DISCARD, LOG_ERROR, LOG_COUNT };
static const char *const CATEGORY[LOG_COUNT] = {"logEvents", "logStatusWarning", "logStatusDiscard", "logStatusError"};
#define LOG_ALL ((1u << LOG_COUNT) - 1u)
#define LOG_STATUSES ((1u << LOG_WARNING) | (1u << LOG_DISCARD) | (1u << LOG_ERROR))

struct FmuInstance {
    uint32_t magic;
    fmi2CallbackFunctions cb;
    char name[128];
    unsigned log;   /* one bit per category */
    unsigned state; /* one of the state bits */
    const UiofmuFmu *fmu;
    const UiofmuKernel *kernel;
    void *model;    /* the kernel's instance */
    double time;    /* for fmi2LastSuccessfulTime */
    int time_known;
    int rounding_noted; /* the line of a rounding step was logged (once per instance) */
    int known[UIOFMU_SLOTS]; /* by uiofmu_slot(H) of each admissible step H: its index (-1: none) */
    double gap; /* the least |H - H'| of two different admissible steps (inf: fewer than two; 0: not worked out) */
    char *resources;    /* the importer's fmuResourceLocation (a copy; NULL when it gave none) */
    double **storage;   /* by value reference: where each Real variable lives (kernel->real_storage), or NULL */
};

static unsigned category_of(fmi2Status status) {
    switch (status) {
    case fmi2OK: return LOG_EVENTS;
    case fmi2Warning: return LOG_WARNING;
    case fmi2Discard: return LOG_DISCARD;
    default: return LOG_ERROR;
    }
}

static void vlog(FmuInstance *s, fmi2Status status, const char *fmt, va_list ap) {
    char buf[1024];
    unsigned cat = category_of(status);
    if (!s || !s->cb.logger || !(s->log & (1u << cat))) return;
    vsnprintf(buf, sizeof buf, fmt, ap);
    s->cb.logger(s->cb.componentEnvironment, s->name, status, CATEGORY[cat], "%s", buf);
}


void uiofmu_log(FmuInstance *s, fmi2Status status, const char *fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    vlog(s, status, fmt, ap);
    va_end(ap);
}

static int hex_digit(char c) {
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
}

int uiofmu_resource_path(FmuInstance *s, const char *file, char *out, size_t len) {
    const char *location = s->resources, *p = location;
    int uri = 0;
    if (!location || !location[0]) {
        uiofmu_log(s, fmi2Error, "fmi2Instantiate: no resource location was given; the FMU reads resources/%s",
                   file);
        return 0;
    }
    if (strncmp(p, "file:", 5) == 0) {
        uri = 1;
        p += 5;
        if (strncmp(p, "//", 2) == 0) {
            p += 2;
            if (strncmp(p, "localhost/", 10) == 0) p += 9;
            else if (p[0] != '/') p = NULL; /* another host */
        }
    }
    if (!p || p[0] != '/') {
        uiofmu_log(s, fmi2Error, "fmi2Instantiate: the resource location \"%.200s\" is no file URI or absolute "
                   "path of this machine", location);
        return 0;
    }
    size_t o = 0;
    for (; *p; p++) {
        char c = *p;
        if (uri && c == '%') {
            int hi = hex_digit(p[1]), lo = hi < 0 ? -1 : hex_digit(p[2]);
            if (lo < 0 || (hi == 0 && lo == 0)) {
                uiofmu_log(s, fmi2Error, "fmi2Instantiate: the resource location \"%.200s\" has a bad percent "
                           "escape", location);
                return 0;
            }
            c = (char)(hi * 16 + lo);
            p += 2;
        }
        if (o + 1 >= len) break;
        out[o++] = c;
    }
    size_t need = strlen(file) + 2;
    if (*p || o + need > len) {
        uiofmu_log(s, fmi2Error, "fmi2Instantiate: the resource location is longer than %zu bytes", len - need);
        return 0;
    }
    if (out[o - 1] != '/') out[o++] = '/';
    memcpy(out + o, file, need - 1);
    out[o + need - 1] = 0;
    return 1;
}

const char *uiofmu_num(double v, char *buf) {
    int digits = 1;
    for (; digits <= 17; digits++) {
        snprintf(buf, 32, "%.*g", digits, v);
        if (strtod(buf, NULL) == v) break;
    }
    double a = fabs(v);
    if (strpbrk(buf, "eE") && a >= 1e-4 && a < 1e16) {
        int decimals = digits - ((int)floor(log10(a)) + 1);
        snprintf(buf, 32, "%.*f", decimals > 0 ? decimals : 0, v);
    }
    if (isfinite(v) && !strpbrk(buf, ".eE")) strcat(buf, ".0");
    return buf;
}

UIOFMU_COLD static fmi2Status refuse(FmuInstance *s, const char *fn, const char *fmt, ...) UIOFMU_PRINTF(3, 4);
UIOFMU_COLD static fmi2Status refuse(FmuInstance *s, const char *fn, const char *fmt, ...) {
    char buf[768];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    uiofmu_log(s, fmi2Error, "%s: %s", fn, buf);
    return fmi2Error;
}

static const char *state_name(unsigned state) {
    for (int i = 0; i < N_STATES; i++)
        if (state == 1u << i) return STATE_NAME[i];
    return "in no known state";
}

/* "step complete or step discarded" */
static void states_text(unsigned mask, char *buf, size_t len) {
    size_t off = 0;
    int count = 0, total = 0;
    for (int i = 0; i < N_STATES; i++) total += (mask >> i) & 1u;
    buf[0] = 0;
    for (int i = 0; i < N_STATES && off < len; i++)
        if (mask & (1u << i)) {
            count++;
            off += (size_t)snprintf(buf + off, len - off, "%s%s", count == 1 ? "" : count == total ? " or " : ", ",
                                    STATE_NAME[i]);
        }
}

UIOFMU_COLD static fmi2Status illegal(FmuInstance *s, int call) {
    char legal[200];
    const char *hint = CALLS[call].hint[0] ? CALLS[call].hint : "illegal call";
    if (!CALLS[call].mask)
        return refuse(s, CALLS[call].name, "%s (the instance is %s)", hint, state_name(s->state));
    states_text(CALLS[call].mask, legal, sizeof legal);
    return refuse(s, CALLS[call].name, "%s (the instance is %s; %s is legal when it is %s)%s", hint,
                  state_name(s->state), CALLS[call].name, legal,
                  s->state == ERROR_STATE ? "; fmi2SetFMUstate of an earlier state or fmi2Reset leave the error state" : "");
}

static FmuInstance *instance_of(fmi2Component c) {
    FmuInstance *s = (FmuInstance *)c;
    return s && s->magic == INSTANCE_MAGIC ? s : NULL;
}

/* The start of every fmi2 function that takes an instance. */
#define BEGIN(call) \
    FmuInstance *s = instance_of(c); \
    if (!s) return fmi2Error; \
    if (!(s->state & CALLS[call].mask)) return illegal(s, call);

/* An instance state after a kernel call. */
static fmi2Status outcome(FmuInstance *s, UiofmuResult r) {
    switch (r) {
    case UIOFMU_DONE: return fmi2OK;
    case UIOFMU_DISCARDED: return fmi2Discard;
    case UIOFMU_REFUSED: return fmi2Error;
    default: /* the kernel's line said why; the next call refused says where the instance is */
        s->state = ERROR_STATE;
        return fmi2Error;
    }
}

/* ---------------------------------------------------------------------------------------- */
/* fmi2Instantiate: the data compiled in, checked once                                        */

int uiofmu_design_error(char *msg, size_t len, const char *fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, len, fmt, ap);
    va_end(ap);
    return 0;
}

static const char *const CAUSALITY_NAME[3] = {"a parameter", "an input", "an output"};
static const char *const TYPE_OF[2] = {"Real", "Integer"};

/* The GUID, the kernel, its design data and the variable table: every value reference is an
   element of one of the kernel's ports, with the port's causality and type, each element of
   each port exactly once and in order. */
static int check_fmu(const UiofmuFmu *f, char *msg, size_t len) {
    const UiofmuKernel *k = f->kernel;
    size_t g = 0;
    int seen[MAX_PORTS] = {0};
    UiofmuPort p;
    if (!f->guid || !f->model) return uiofmu_design_error(msg, len, "the design has no GUID or no model identifier");
    while (g <= MAX_GUID && f->guid[g]) g++;
    if (g == 0 || g > MAX_GUID)
        return uiofmu_design_error(msg, len, "the design's GUID is empty or longer than %d bytes", MAX_GUID);
    if (!k || !k->check_design || !k->port || !k->instantiate || !k->free_instance || !k->reset ||
        !k->exit_initialization || !k->calculate || !k->step || !k->state_count ||
        !k->state_shape || !k->save_state || !k->check_state || !k->load_state || !k->real_storage != !k->changed ||
        k->ports < 1 || k->ports > MAX_PORTS)
        return uiofmu_design_error(msg, len, "the FMU's kernel is incomplete");
    if (!k->check_design(msg, len)) return 0;
    if (f->steps) {
        const UiofmuSteps *r = f->steps;
        if (!(isfinite(r->tiny) && r->tiny >= 0) || !(isfinite(r->ulps) && r->ulps >= 0) ||
            !(isfinite(r->ulps_limit) && r->ulps_limit >= 0) || r->nsteps < 0 ||
            r->nsteps > MAX_STEPS || !r->steps || r->steps_length != (size_t)(r->nsteps ? r->nsteps : 1))
            return uiofmu_design_error(msg, len, "the step rule (tiny %g, %g ulps, %d steps in a list of %zu) is "
                                       "out of range", r->tiny, r->ulps, r->nsteps, r->steps ? r->steps_length : 0);
        for (int i = 0; i < r->nsteps; i++)
            if (!(isfinite(r->steps[i]) && r->steps[i] > r->tiny))
                return uiofmu_design_error(msg, len, "admissible step %d = %g: expected a finite step above %g", i,
                                           r->steps[i], r->tiny);
    }
    if (f->nvariables < 0 || f->nvariables > MAX_VARIABLES || !f->variables ||
        f->variables_length != (size_t)(f->nvariables ? f->nvariables : 1))
        return uiofmu_design_error(msg, len, "%d variables in a table of %zu", f->nvariables,
                                   f->variables ? f->variables_length : 0);
    for (int vr = 0; vr < f->nvariables; vr++) {
        const UiofmuVariable *v = &f->variables[vr];
        if (v->port < 0 || v->port >= k->ports || !k->port(v->port, &p))
            return uiofmu_design_error(msg, len, "value reference %d: port %d is none of the %s kernel's", vr, v->port,
                                       k->name);
        if (v->index != seen[v->port])
            return uiofmu_design_error(msg, len, "value reference %d: element %d of port %s, expected element %d", vr,
                                       v->index, p.name, seen[v->port]);
        if (v->index >= p.size)
            return uiofmu_design_error(msg, len, "value reference %d: element %d of port %s, which has %d in this "
                                       "design", vr, v->index, p.name, p.size);
        if (v->causality < UIOFMU_PARAMETER || v->causality > UIOFMU_OUTPUT || v->type < UIOFMU_REAL ||
            v->type > UIOFMU_INTEGER)
            return uiofmu_design_error(msg, len, "value reference %d (%s[%d]): causality %d or type %d is unknown", vr,
                                       p.name, v->index + 1, v->causality, v->type);
        if (v->causality != p.causality || v->type != p.type)
            return uiofmu_design_error(msg, len, "value reference %d (%s[%d]) is listed as %s %s, the kernel's port is "
                                       "%s %s", vr, p.name, v->index + 1, CAUSALITY_NAME[v->causality],
                                       TYPE_OF[v->type], CAUSALITY_NAME[p.causality], TYPE_OF[p.type]);
        if (v->type == UIOFMU_REAL && !k->real_storage &&
            (!k->get_real || (v->causality != UIOFMU_OUTPUT && !k->set_real)))
            return uiofmu_design_error(msg, len, "value reference %d (%s[%d]) is a Real the kernel cannot get or set",
                                       vr, p.name, v->index + 1);
        if (v->type == UIOFMU_INTEGER && (!k->get_integer || (v->causality != UIOFMU_OUTPUT && !k->set_integer)))
            return uiofmu_design_error(msg, len, "value reference %d (%s[%d]) is an Integer the kernel cannot get or "
                                       "set", vr, p.name, v->index + 1);
        seen[v->port]++;
    }
    for (int id = 0; id < k->ports; id++)
        if (k->port(id, &p) && seen[id] != p.size)
            return uiofmu_design_error(msg, len, "port %s has %d elements in this design, the variable table lists %d",
                                       p.name, p.size, seen[id]);
    return 1;
}

/* s->storage: where each Real variable lives, when the kernel gives real_storage (else NULL:
   get_real and set_real). 0 after a log line when out of memory or when the kernel has no storage
   for one. */
static int find_storage(FmuInstance *s) {
    const UiofmuFmu *f = s->fmu;
    if (!s->kernel->real_storage || f->nvariables < 1) return 1;
    s->storage = (double **)calloc((size_t)f->nvariables, sizeof(double *));
    if (!s->storage) {
        uiofmu_log(s, fmi2Error, "fmi2Instantiate: out of memory");
        return 0;
    }
    for (int vr = 0; vr < f->nvariables; vr++) {
        const UiofmuVariable *v = &f->variables[vr];
        if (v->type != UIOFMU_REAL) continue;
        s->storage[vr] = s->kernel->real_storage(s->model, v->port, v->index);
        if (!s->storage[vr]) {
            uiofmu_log(s, fmi2Error, "fmi2Instantiate: the design data compiled into this FMU is inconsistent: the %s "
                       "kernel has no storage for value reference %d", s->kernel->name, vr);
            free(s->storage);
            s->storage = NULL;
            return 0;
        }
    }
    return 1;
}

/* s->known and s->gap of the admissible steps (see fmi2DoStep). */
static void know_steps(FmuInstance *s) {
    const UiofmuSteps *rule = s->fmu->steps;
    s->gap = INFINITY;
    for (int k = 0; k < UIOFMU_SLOTS; k++) s->known[k] = -1;
    if (!rule || rule->nsteps > MAX_KNOWN_STEPS) {
        s->gap = 0.0;
        return;
    }
    for (int i = rule->nsteps - 1; i >= 0; i--) { /* the first of equal steps keeps its slot */
        s->known[uiofmu_slot(rule->steps[i])] = i;
        for (int k = i + 1; k < rule->nsteps; k++)
            if (rule->steps[k] != rule->steps[i] && fabs(rule->steps[k] - rule->steps[i]) < s->gap)
                s->gap = fabs(rule->steps[k] - rule->steps[i]);
    }
}

/* A log line before there is an instance (fmi2Instantiate refusing). */
static void log_early(const fmi2CallbackFunctions *f, fmi2String name, const char *fmt, ...) UIOFMU_PRINTF(3, 4);
static void log_early(const fmi2CallbackFunctions *f, fmi2String name, const char *fmt, ...) {
    char buf[1024];
    va_list ap;
    if (!f->logger) return;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    f->logger(f->componentEnvironment, name ? name : "", fmi2Error, CATEGORY[LOG_ERROR], "%s", buf);
}

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn) {
    const UiofmuFmu *f = &UIOFMU_FMU;
    char msg[512];
    (void)visible;
    if (!functions) return NULL;
    if (!instanceName || !instanceName[0]) {
        log_early(functions, instanceName, "fmi2Instantiate: the instance name is %s (FMI 2.0 asks for a non-empty name)",
                  instanceName ? "empty" : "a null pointer");
        return NULL;
    }
    if (!check_fmu(f, msg, sizeof msg)) {
        log_early(functions, instanceName, "fmi2Instantiate: the design data compiled into this FMU is inconsistent: %s",
                  msg);
        return NULL;
    }
    if (fmuType != fmi2CoSimulation || !fmuGUID || strcmp(fmuGUID, f->guid) != 0) {
        log_early(functions, instanceName, "fmi2Instantiate: expected a Co-Simulation instance with GUID %s", f->guid);
        return NULL;
    }
    FmuInstance *s = (FmuInstance *)calloc(1, sizeof(FmuInstance));
    if (!s) {
        log_early(functions, instanceName, "fmi2Instantiate: out of memory");
        return NULL;
    }
    s->magic = INSTANCE_MAGIC;
    s->cb = *functions;
    snprintf(s->name, sizeof s->name, "%s", instanceName);
    s->log = LOG_STATUSES | (loggingOn ? 1u << LOG_EVENTS : 0u);
    s->fmu = f;
    s->kernel = f->kernel;
    s->state = INSTANTIATED;
    s->time = 0.0;
    s->time_known = 1;
    know_steps(s);
    if (fmuResourceLocation) {
        size_t len = strlen(fmuResourceLocation);
        s->resources = (char *)malloc(len + 1);
        if (!s->resources) {
            log_early(functions, instanceName, "fmi2Instantiate: out of memory");
            free(s);
            return NULL;
        }
        memcpy(s->resources, fmuResourceLocation, len + 1);
    }
    s->model = s->kernel->instantiate(s);
    if (!s->model || !find_storage(s)) {
        if (s->model) s->kernel->free_instance(s->model);
        free(s->resources);
        free(s);
        return NULL;
    }
    uiofmu_log(s, fmi2OK, "fmi2Instantiate: %s, %s kernel, %d variables", f->model, s->kernel->name, f->nvariables);
    return s;
}

void fmi2FreeInstance(fmi2Component c) {
    FmuInstance *s = instance_of(c);
    if (!s) return;
    s->kernel->free_instance(s->model);
    s->magic = 0;
    free(s->storage);
    free(s->resources);
    free(s);
}

/* ---------------------------------------------------------------------------------------- */
/* logging, experiment, modes                                                               */

/* At most 60 printable characters of a master's string, for a log line. */
static const char *shown(const char *text, char *buf, size_t len) {
    size_t i = 0;
    for (; text[i] && i + 4 < len && i < 60; i++)
        buf[i] = text[i] >= 0x20 && text[i] < 0x7f ? text[i] : '?';
    strcpy(buf + i, text[i] ? "..." : "");
    return buf;
}

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t n, const fmi2String cats[]) {
    BEGIN(C_SetDebugLogging)
    static const char fn[] = "fmi2SetDebugLogging";
    unsigned named = 0;
    size_t unknown = 0, first = 0;
    char buf[80];
    if (n && !cats) return refuse(s, fn, "categories is a null pointer, nCategories = %zu", n);
    for (size_t i = 0; i < n; i++)
        if (!cats[i]) return refuse(s, fn, "categories[%zu] is a null pointer", i);
    for (size_t i = 0; i < n; i++) {
        unsigned bit = 0;
        for (int k = 0; k < LOG_COUNT; k++)
            if (strcmp(cats[i], CATEGORY[k]) == 0) bit = 1u << k;
        if (!bit && unknown++ == 0) first = i;
        named |= bit;
    }
    if (unknown)
        uiofmu_log(s, fmi2Warning, "%s: categories[%zu] = \"%s\"%s %s not a log category of this FMU (logEvents, "
                   "logStatusWarning, logStatusDiscard, logStatusError): ignored", fn, first,
                   shown(cats[first], buf, sizeof buf), unknown > 1 ? " and others" : "", unknown > 1 ? "are" : "is");
    if (n == 0) s->log = loggingOn ? LOG_ALL : 0u;
    else if (loggingOn) s->log = named;
    else s->log &= ~named;
    return unknown ? fmi2Warning : fmi2OK;
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean tolDefined, fmi2Real tol, fmi2Real start,
                               fmi2Boolean stopDefined, fmi2Real stop) {
    BEGIN(C_SetupExperiment)
    char b1[32];
    (void)tolDefined; (void)tol; (void)stopDefined; (void)stop;
    s->time = start;
    s->time_known = isfinite(start);
    uiofmu_log(s, fmi2OK, "fmi2SetupExperiment: start time %s", uiofmu_num(start, b1));
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    BEGIN(C_EnterInitializationMode)
    s->state = INITIALIZATION_MODE;
    uiofmu_log(s, fmi2OK, "fmi2EnterInitializationMode: in initialization mode");
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    BEGIN(C_ExitInitializationMode)
    fmi2Status st = outcome(s, s->kernel->exit_initialization(s->model));
    if (st != fmi2OK) return st;
    s->state = STEP_COMPLETE;
    uiofmu_log(s, fmi2OK, "fmi2ExitInitializationMode: initialized, step 0");
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c) {
    BEGIN(C_Terminate)
    s->state = TERMINATED;
    uiofmu_log(s, fmi2OK, "fmi2Terminate: terminated");
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c) {
    BEGIN(C_Reset)
    s->kernel->reset(s->model);
    s->state = INSTANTIATED;
    s->time = 0.0;
    s->time_known = 1;
    s->rounding_noted = 0;
    uiofmu_log(s, fmi2OK, "fmi2Reset: instantiated, start values");
    return fmi2OK;
}

/* ---------------------------------------------------------------------------------------- */
/* get and set through the variable table                                                    */

enum { T_REAL = UIOFMU_REAL, T_INTEGER = UIOFMU_INTEGER, T_BOOLEAN, T_STRING };
static const char *const TYPE_NAME[] = {"Real", "Integer", "Boolean", "String"};
static const char *const A_TYPE[] = {"a Real", "an Integer", "a Boolean", "a String"};

/* The variable of value reference vr, if it is one of type `type` (else NULL and a log line). */
UIOFMU_COLD static const UiofmuVariable *variable(FmuInstance *s, const char *fn, fmi2ValueReference vr, int type) {
    UiofmuPort p = {"?", 0, 0, 0};
    if ((size_t)vr >= (size_t)s->fmu->nvariables) { /* unsigned all the way: no reference wraps */
        refuse(s, fn, "unknown value reference %u", vr);
        return NULL;
    }
    const UiofmuVariable *v = &s->fmu->variables[vr];
    if (v->type != type) {
        s->kernel->port(v->port, &p);
        refuse(s, fn, "value reference %u (%s[%d]) is %s variable, not %s one (fmi2Get%s and fmi2Set%s take it)",
               vr, p.name, v->index + 1, A_TYPE[v->type], A_TYPE[type], TYPE_NAME[v->type], TYPE_NAME[v->type]);
        return NULL;
    }
    return v;
}

/* Whether the variable may be set now (else a log line). */
UIOFMU_COLD static int settable(FmuInstance *s, const char *fn, fmi2ValueReference vr, const UiofmuVariable *v) {
    UiofmuPort p = {"?", 0, 0, 0};
    if (v->causality == UIOFMU_INPUT) return 1;
    s->kernel->port(v->port, &p);
    if (v->causality == UIOFMU_OUTPUT) {
        refuse(s, fn, "value reference %u is an output (%s[%d]), which the FMU computes", vr, p.name, v->index + 1);
        return 0;
    }
    if (!(s->state & (INSTANTIATED | INITIALIZATION_MODE))) {
        refuse(s, fn, "value reference %u is a fixed parameter (%s[%d]), settable only before initialisation ends", vr,
               p.name, v->index + 1);
        return 0;
    }
    return 1;
}

/* Whether vr[i] is a variable of type `type` (variable() without its lines: the check of every
   element of a call, in one pass; variable() says why not). */
static int of_type(const FmuInstance *s, fmi2ValueReference vr, int type) {
    return (size_t)vr < (size_t)s->fmu->nvariables && s->fmu->variables[vr].type == type;
}

/* fmi2Get<type>: every reference checked, then the outputs brought up to date, then read. */
static fmi2Status get_values(FmuInstance *s, int call, int type, const fmi2ValueReference vr[], size_t nvr,
                             void *values) {
    const char *fn = CALLS[call].name;
    if (!nvr) return fmi2OK;
    if (!vr || !values) return refuse(s, fn, "null argument");
    for (size_t i = 0; i < nvr; i++)
        if (!of_type(s, vr[i], type)) {
            variable(s, fn, vr[i], type);
            return fmi2Error;
        }
    fmi2Status st = outcome(s, s->kernel->calculate(s->model, fn));
    if (st != fmi2OK) return st;
    if (type == T_REAL && s->storage) {
        for (size_t i = 0; i < nvr; i++) ((fmi2Real *)values)[i] = *s->storage[vr[i]];
        return fmi2OK;
    }
    for (size_t i = 0; i < nvr; i++) {
        const UiofmuVariable *v = &s->fmu->variables[vr[i]];
        if (type == T_REAL) ((fmi2Real *)values)[i] = s->kernel->get_real(s->model, v->port, v->index);
        else ((fmi2Integer *)values)[i] = s->kernel->get_integer(s->model, v->port, v->index);
    }
    return fmi2OK;
}

/* fmi2Set<type>: every reference checked before any value is stored (a refused call sets none). */
static fmi2Status set_values(FmuInstance *s, int call, int type, const fmi2ValueReference vr[], size_t nvr,
                             const void *values) {
    const char *fn = CALLS[call].name;
    if (!nvr) return fmi2OK;
    if (!vr || !values) return refuse(s, fn, "null argument");
    for (size_t i = 0; i < nvr; i++) {
        if (!of_type(s, vr[i], type)) {
            variable(s, fn, vr[i], type);
            return fmi2Error;
        }
        const UiofmuVariable *v = &s->fmu->variables[vr[i]];
        if (v->causality != UIOFMU_INPUT && !settable(s, fn, vr[i], v)) return fmi2Error;
    }
    if (type == T_REAL && s->storage) {
        for (size_t i = 0; i < nvr; i++) *s->storage[vr[i]] = ((const fmi2Real *)values)[i];
        s->kernel->changed(s->model);
        return fmi2OK;
    }
    for (size_t i = 0; i < nvr; i++) {
        const UiofmuVariable *v = &s->fmu->variables[vr[i]];
        if (type == T_REAL) s->kernel->set_real(s->model, v->port, v->index, ((const fmi2Real *)values)[i]);
        else s->kernel->set_integer(s->model, v->port, v->index, ((const fmi2Integer *)values)[i]);
    }
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]) {
    BEGIN(C_GetReal)
    return get_values(s, C_GetReal, T_REAL, vr, nvr, value);
}
fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[]) {
    BEGIN(C_GetInteger)
    return get_values(s, C_GetInteger, T_INTEGER, vr, nvr, value);
}
fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[]) {
    BEGIN(C_SetReal)
    return set_values(s, C_SetReal, T_REAL, vr, nvr, value);
}
fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Integer value[]) {
    BEGIN(C_SetInteger)
    return set_values(s, C_SetInteger, T_INTEGER, vr, nvr, value);
}

/* Boolean and String: no kernel has such variables; a reference is unknown or of another type. */
static fmi2Status no_values(FmuInstance *s, int call, int type, const fmi2ValueReference vr[], size_t nvr,
                            const void *values) {
    const char *fn = CALLS[call].name;
    if (!nvr) return fmi2OK;
    if (!vr || !values) return refuse(s, fn, "null argument");
    variable(s, fn, vr[0], type);
    return fmi2Error;
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[]) {
    BEGIN(C_GetBoolean)
    return no_values(s, C_GetBoolean, T_BOOLEAN, vr, nvr, value);
}
fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Boolean value[]) {
    BEGIN(C_SetBoolean)
    return no_values(s, C_SetBoolean, T_BOOLEAN, vr, nvr, value);
}
fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2String value[]) {
    BEGIN(C_GetString)
    return no_values(s, C_GetString, T_STRING, vr, nvr, value);
}
fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2String value[]) {
    BEGIN(C_SetString)
    return no_values(s, C_SetString, T_STRING, vr, nvr, value);
}

/* ---------------------------------------------------------------------------------------- */
/* stepping                                                                                  */

/* nextafter(a, INFINITY) - a for a finite a >= 0, without the library call: the next double above a
   is the one whose bits are a's plus one (DBL_MAX's plus one are infinity's). */
static double ulp_of(double a) {
    uint64_t bits;
    double above;
    memcpy(&bits, &a, sizeof bits);
    bits += 1u;
    memcpy(&above, &bits, sizeof above);
    return above - a;
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noSetPrior) {
    FmuInstance *s = instance_of(c);
    if (!s) return fmi2Error;
#ifdef UIOFMU_CALL_FLOOR
    (void)t; (void)h; (void)noSetPrior;
    return fmi2OK; /* benchmark build only: the cost of the FMI call itself */
#endif
    static const char fn[] = "fmi2DoStep";
    char bt[32], bh[32];
    (void)noSetPrior;
    if (!(s->state & CALLS[C_DoStep].mask)) return illegal(s, C_DoStep);
    if (!isfinite(t)) return refuse(s, fn, "currentCommunicationPoint t = %s is not a time", uiofmu_num(t, bt));
    if (!(isfinite(h) && h > 0))
        return refuse(s, fn, "t = %s: communication step h = %s: expected h > 0", uiofmu_num(t, bt), uiofmu_num(h, bh));
    const UiofmuSteps *rule = s->fmu->steps;
    if (rule && h <= rule->tiny) { /* rounding: accepted, nothing computed */
        if (!s->rounding_noted) {
            s->rounding_noted = 1;
            uiofmu_log(s, fmi2Warning, "t = %s: step h = %s s is rounding (at most %.3g s, 1e-9 of the shortest step "
                       "this FMU takes): accepted, the state unchanged (noted once)", uiofmu_num(t, bt),
                       uiofmu_num(h, bh), rule->tiny);
        }
        s->state = STEP_COMPLETE;
        s->time = t + h;
        s->time_known = 1;
        return fmi2OK;
    }
    if (rule) { /* within a few ulps of t of an admissible step: that step */
        double slack = rule->ulps * ulp_of(fabs(t));
        /* h an admissible step, and every other one further from it than slack: the loop below would
           find h itself or nothing, and leave h as it is */
        int at = s->known[uiofmu_slot(h)], settled = at >= 0 && rule->steps[at] == h && slack < s->gap;
        for (int i = 0; i < rule->nsteps && !settled; i++)
            if (fabs(h - rule->steps[i]) <= slack && slack <= rule->ulps_limit * rule->steps[i]) {
                h = rule->steps[i];
                break;
            }
    }
    fmi2Status st = outcome(s, s->kernel->step(s->model, t, h));
    if (st == fmi2OK) {
        s->state = STEP_COMPLETE;
        s->time = t + h;
        s->time_known = 1;
    } else if (st == fmi2Discard) { /* nothing of the step was computed: the FMU stands at t */
        s->state = STEP_DISCARDED;
        s->time = t;
        s->time_known = 1;
    }
    return st;
}

fmi2Status fmi2CancelStep(fmi2Component c) {
    BEGIN(C_CancelStep)
    return fmi2Error; /* never reached: the mask is empty */
}

/* ---------------------------------------------------------------------------------------- */
/* FMU state
 *
 * One byte image, the same in memory (what fmi2GetFMUstate returns: a malloc'ed block of
 * exactly `size` bytes) and serialised. Every field is read and written with memcpy (no
 * alignment assumed, serialised bytes may sit anywhere), in the platform's byte order:
 *
 *   offset   bytes  field
 *        0       4  magic        0x75696f66 ("uiof")
 *        4       4  layout       STATE_LAYOUT = 2 (layout 1 had magic, count, doubles, GUID)
 *        8       8  size         bytes of the whole image
 *       16       4  guid_length  G
 *       20      16  shape        four words of the kernel's (the affine kernel's n, m, p, nz)
 *       36       4  count        D, the kernel's doubles below
 *       40       G  the GUID of the FMU that made it, then zero bytes up to a multiple of 8
 *   40 + G'    8 D  the kernel's doubles (kernel_<name>.c documents them), the phase among them
 *
 * fmi2SetFMUstate and fmi2DeSerializeFMUstate refuse a state (fmi2Error and a log line with
 * the numbers) unless every header field is this FMU's (magic, layout, size, GUID, shape,
 * count, zero padding; and serialised bytes fill the buffer exactly) and the kernel takes its
 * doubles (check_state), all checked before any of it is used. A state is this FMU's when its
 * GUID is: two FMUs with equal dims and other matrices (or only another xhat0) have other
 * GUIDs. fmi2GetFMUstate and fmi2DeSerializeFMUstate reuse a non-NULL *FMUstate only when its
 * header is this FMU's (same size), fmi2FreeFMUstate frees only such a state. A state records
 * the phase (0 instantiated, 1 initialisation mode, 2 initialised: step complete or step
 * discarded, 3 terminated); fmi2SetFMUstate puts the instance in it.
 */

#define STATE_MAGIC 0x75696f66u
#define STATE_LAYOUT 2u
#define STATE_HEADER 40

typedef unsigned char Byte;

static size_t state_data(const FmuInstance *s) { return STATE_HEADER + (strlen(s->fmu->guid) + 7) / 8 * 8; }
static size_t state_size(const FmuInstance *s) { return state_data(s) + sizeof(double) * s->kernel->state_count(); }

static uint32_t get32(const Byte *b, size_t off) { uint32_t v; memcpy(&v, b + off, sizeof v); return v; }
static uint64_t get64(const Byte *b, size_t off) { uint64_t v; memcpy(&v, b + off, sizeof v); return v; }
static void put32(Byte *b, size_t off, uint32_t v) { memcpy(b + off, &v, sizeof v); }
static void put64(Byte *b, size_t off, uint64_t v) { memcpy(b + off, &v, sizeof v); }

static int phase_of(unsigned state) {
    switch (state) {
    case INSTANTIATED: return UIOFMU_PHASE_INSTANTIATED;
    case INITIALIZATION_MODE: return UIOFMU_PHASE_INITIALIZATION;
    case TERMINATED: return UIOFMU_PHASE_TERMINATED;
    default: return UIOFMU_PHASE_RUNNING; /* step complete, step discarded */
    }
}

int uiofmu_state_refused(FmuInstance *s, const char *ctx, const char *fmt, ...) {
    char buf[768];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    uiofmu_log(s, fmi2Error, "%s: %s", ctx, buf);
    return 0;
}

static void write_state(FmuInstance *s, Byte *b) {
    size_t g = strlen(s->fmu->guid), off = state_data(s);
    uint32_t shape[UIOFMU_SHAPE];
    const char *names[UIOFMU_SHAPE];
    s->kernel->state_shape(shape, names);
    memset(b, 0, off);
    put32(b, 0, STATE_MAGIC);
    put32(b, 4, STATE_LAYOUT);
    put64(b, 8, (uint64_t)state_size(s));
    put32(b, 16, (uint32_t)g);
    for (int i = 0; i < UIOFMU_SHAPE; i++) put32(b, 20 + 4 * (size_t)i, shape[i]);
    put32(b, 36, (uint32_t)s->kernel->state_count());
    memcpy(b + STATE_HEADER, s->fmu->guid, g);
    s->kernel->save_state(s->model, phase_of(s->state), b + off);
}

/* Whether the image at b is a state of this FMU, header only (a log line from ctx saying why
   not). Serialised bytes (in_memory 0) are avail bytes long, and nothing past them is read; a
   state in memory is as long as its own size field says. */
static int check_header(FmuInstance *s, const char *ctx, const Byte *b, size_t avail, int in_memory) {
    const char *guid = s->fmu->guid;
    size_t want = state_size(s), g = strlen(guid), data = state_data(s), count = s->kernel->state_count();
    if (!in_memory && avail < STATE_HEADER)
        return uiofmu_state_refused(s, ctx, "%zu bytes are too few for a state of this FMU (%zu bytes)", avail, want);
    uint32_t magic = get32(b, 0), layout = get32(b, 4), glen;
    uint64_t size = get64(b, 8);
    if (magic != STATE_MAGIC)
        return uiofmu_state_refused(s, ctx, "not a uiofmu FMU state (magic 0x%08lx, expected 0x%08lx)",
                                    (unsigned long)magic, (unsigned long)STATE_MAGIC);
    if (layout != STATE_LAYOUT)
        return uiofmu_state_refused(s, ctx, "state layout version %lu, this FMU reads version %lu",
                                    (unsigned long)layout, (unsigned long)STATE_LAYOUT);
    if (!in_memory && size != (uint64_t)avail)
        return uiofmu_state_refused(s, ctx, "the buffer holds %zu bytes, the state in it says %llu bytes (truncated or "
                                    "extended; this FMU's states are %zu bytes)", avail, (unsigned long long)size,
                                    want);
    if (size < STATE_HEADER)
        return uiofmu_state_refused(s, ctx, "the state says it is %llu bytes, less than its %d-byte header",
                                    (unsigned long long)size, STATE_HEADER);
    glen = get32(b, 16);
    if ((uint64_t)glen > size - STATE_HEADER)
        return uiofmu_state_refused(s, ctx, "its GUID length %lu does not fit in a %llu-byte state",
                                    (unsigned long)glen, (unsigned long long)size);
    if ((size_t)glen != g || memcmp(b + STATE_HEADER, guid, g) != 0) {
        char other[80];
        size_t i, shown_len = glen < sizeof other - 4 ? glen : sizeof other - 4;
        for (i = 0; i < shown_len; i++) {
            Byte ch = b[STATE_HEADER + i];
            other[i] = ch >= 0x20 && ch < 0x7f ? (char)ch : '?';
        }
        strcpy(other + i, shown_len < glen ? "..." : "");
        return uiofmu_state_refused(s, ctx, "the state belongs to the FMU with GUID %s, not to this FMU (GUID %s)",
                                    other, guid);
    }
    uint32_t shape[UIOFMU_SHAPE];
    const char *names[UIOFMU_SHAPE];
    s->kernel->state_shape(shape, names);
    int same = get32(b, 36) == (uint32_t)count;
    for (int i = 0; i < UIOFMU_SHAPE; i++) same &= get32(b, 20 + 4 * (size_t)i) == shape[i];
    if (!same) {
        char theirs[200], ours[200];
        size_t a = 0, o = 0;
        for (int i = 0; i < UIOFMU_SHAPE; i++) {
            a += (size_t)snprintf(theirs + a, sizeof theirs - a, "%s = %lu, ", names[i],
                                  (unsigned long)get32(b, 20 + 4 * (size_t)i));
            o += (size_t)snprintf(ours + o, sizeof ours - o, "%s = %lu, ", names[i], (unsigned long)shape[i]);
        }
        if (a >= 2) theirs[a - 2] = 0;
        if (o >= 2) ours[o - 2] = 0;
        return uiofmu_state_refused(s, ctx, "the state has %s and %lu numbers; this FMU has %s and %zu", theirs,
                                    (unsigned long)get32(b, 36), ours, count);
    }
    if (size != (uint64_t)want)
        return uiofmu_state_refused(s, ctx, "the state is %llu bytes, this FMU's states are %zu bytes",
                                    (unsigned long long)size, want);
    for (size_t i = STATE_HEADER + g; i < data; i++)
        if (b[i])
            return uiofmu_state_refused(s, ctx, "byte %zu (padding after the GUID) is %u, expected 0", i,
                                        (unsigned)b[i]);
    return 1;
}

/* Header and doubles of an image: whether the instance can take it, and the phase it records. */
static int check_image(FmuInstance *s, const char *ctx, const Byte *b, size_t avail, int in_memory, int *phase) {
    if (!check_header(s, ctx, b, avail, in_memory)) return 0;
    if (!s->kernel->check_state(s->model, ctx, b + state_data(s), phase)) return 0;
    if (*phase < UIOFMU_PHASE_INSTANTIATED || *phase > UIOFMU_PHASE_TERMINATED)
        return uiofmu_state_refused(s, ctx, "phase %d is none of 0 .. 3", *phase);
    return 1;
}

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *state) {
    BEGIN(C_GetFMUstate)
    if (!state) return refuse(s, "fmi2GetFMUstate", "null argument");
    Byte *b = (Byte *)*state;
    if (b && !check_header(s, "fmi2GetFMUstate: cannot reuse *FMUstate, which is not a state of this FMU "
                           "(pass NULL for a new one)", b, 0, 1))
        return fmi2Error;
    if (!b) {
        b = (Byte *)malloc(state_size(s));
        if (!b) return refuse(s, "fmi2GetFMUstate", "out of memory");
    }
    write_state(s, b);
    *state = b;
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate state) {
    BEGIN(C_SetFMUstate)
    static const char ctx[] = "fmi2SetFMUstate: state refused";
    static const unsigned STATE_OF[4] = {INSTANTIATED, INITIALIZATION_MODE, STEP_COMPLETE, TERMINATED};
    const Byte *b = (const Byte *)state;
    int phase = -1;
    if (!b) return refuse(s, "fmi2SetFMUstate", "null state");
    if (!check_image(s, ctx, b, 0, 1, &phase)) return fmi2Error;
    s->kernel->load_state(s->model, b + state_data(s));
    s->state = STATE_OF[phase];
    s->time_known = 0; /* the state does not carry the master's time; the next step tells it */
    uiofmu_log(s, fmi2OK, "fmi2SetFMUstate: the instance is %s", state_name(s->state));
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *state) {
    BEGIN(C_FreeFMUstate)
    if (!state || !*state) return fmi2OK;
    Byte *b = (Byte *)*state;
    if (!check_header(s, "fmi2FreeFMUstate: not freed, not a state of this FMU", b, 0, 1)) return fmi2Error;
    put32(b, 0, 0); /* whatever still points here no longer points at a state */
    free(b);
    *state = NULL;
    return fmi2OK;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate state, size_t *size) {
    BEGIN(C_SerializedFMUstateSize)
    if (!size || !state) return refuse(s, "fmi2SerializedFMUstateSize", "null argument");
    if (!check_header(s, "fmi2SerializedFMUstateSize: not a state of this FMU", (const Byte *)state, 0, 1))
        return fmi2Error;
    *size = state_size(s);
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate state, fmi2Byte bytes[], size_t size) {
    BEGIN(C_SerializeFMUstate)
    size_t need = state_size(s);
    if (!state || !bytes) return refuse(s, "fmi2SerializeFMUstate", "null argument");
    if (!check_header(s, "fmi2SerializeFMUstate: not a state of this FMU", (const Byte *)state, 0, 1)) return fmi2Error;
    if (size < need)
        return refuse(s, "fmi2SerializeFMUstate", "the buffer holds %zu bytes, the state needs %zu "
                      "(fmi2SerializedFMUstateSize)", size, need);
    memcpy(bytes, state, need);
    return fmi2OK;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte bytes[], size_t size, fmi2FMUstate *state) {
    BEGIN(C_DeSerializeFMUstate)
    static const char ctx[] = "fmi2DeSerializeFMUstate: bytes refused";
    const Byte *in = (const Byte *)bytes;
    size_t need = state_size(s);
    int phase = -1;
    if (!in || !state) return refuse(s, "fmi2DeSerializeFMUstate", "null argument");
    if (!check_image(s, ctx, in, size, 0, &phase)) return fmi2Error;
    Byte *b = (Byte *)*state;
    if (b && !check_header(s, "fmi2DeSerializeFMUstate: cannot reuse *FMUstate, which is not a state of this FMU "
                           "(pass NULL for a new one)", b, 0, 1))
        return fmi2Error;
    if (!b) {
        b = (Byte *)malloc(need);
        if (!b) return refuse(s, "fmi2DeSerializeFMUstate", "out of memory");
    }
    memcpy(b, in, need);
    *state = b;
    return fmi2OK;
}

/* ---------------------------------------------------------------------------------------- */
/* not supported                                                                             */

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference u[], size_t nu,
                                        const fmi2ValueReference z[], size_t nz, const fmi2Real dv[],
                                        fmi2Real dz[]) {
    BEGIN(C_GetDirectionalDerivative)
    (void)u; (void)nu; (void)z; (void)nz; (void)dv; (void)dz;
    return refuse(s, "fmi2GetDirectionalDerivative", "not supported (providesDirectionalDerivative = false)");
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    BEGIN(C_SetRealInputDerivatives)
    (void)vr; (void)nvr; (void)order; (void)value;
    return refuse(s, "fmi2SetRealInputDerivatives", "not supported (canInterpolateInputs = false)");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    BEGIN(C_GetRealOutputDerivatives)
    (void)vr; (void)nvr; (void)order; (void)value;
    return refuse(s, "fmi2GetRealOutputDerivatives", "not supported (MaxOutputDerivativeOrder = 0)");
}

/* ---------------------------------------------------------------------------------------- */
/* status queries (see the top of this file)                                                 */

static const char *kind_name(fmi2StatusKind kind) {
    static const char *const NAME[] = {"fmi2DoStepStatus", "fmi2PendingStatus", "fmi2LastSuccessfulTime",
                                       "fmi2Terminated"};
    return (int)kind >= 0 && (int)kind < 4 ? NAME[kind] : NULL;
}

/* A kind the function does not answer: fmi2Error with a log line. */
static fmi2Status wrong_kind(FmuInstance *s, int call, fmi2StatusKind kind, const char *answers) {
    const char *name = kind_name(kind);
    if (!name)
        return refuse(s, CALLS[call].name, "status kind %d is none of fmi2DoStepStatus, fmi2PendingStatus, "
                      "fmi2LastSuccessfulTime, fmi2Terminated", (int)kind);
    return refuse(s, CALLS[call].name, "%s is not a status of this type (%s)", name, answers);
}

/* fmi2DoStepStatus and fmi2PendingStatus: for a step that returned fmi2Pending, never the case. */
static fmi2Status no_step_pending(FmuInstance *s, int call, fmi2StatusKind kind) {
    uiofmu_log(s, fmi2Discard, "%s(%s): no fmi2DoStep is pending: this FMU completes every step within fmi2DoStep "
               "(it never returns fmi2Pending; canRunAsynchronuously = false)", CALLS[call].name, kind_name(kind));
    return fmi2Discard;
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind kind, fmi2Status *value) {
    BEGIN(C_GetStatus)
    if (!value) return refuse(s, CALLS[C_GetStatus].name, "null argument");
    if (kind == fmi2DoStepStatus) return no_step_pending(s, C_GetStatus, kind);
    return wrong_kind(s, C_GetStatus, kind, "fmi2GetStatus answers fmi2DoStepStatus");
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind kind, fmi2Real *value) {
    BEGIN(C_GetRealStatus)
    if (!value) return refuse(s, CALLS[C_GetRealStatus].name, "null argument");
    if (kind != fmi2LastSuccessfulTime)
        return wrong_kind(s, C_GetRealStatus, kind, "fmi2GetRealStatus answers fmi2LastSuccessfulTime");
    if (!s->time_known) {
        uiofmu_log(s, fmi2Discard, "fmi2GetRealStatus(fmi2LastSuccessfulTime): not known since fmi2SetFMUstate (an FMU "
                   "state does not carry the master's time) or fmi2SetupExperiment with a non-finite start time; the "
                   "next fmi2DoStep tells it");
        return fmi2Discard;
    }
    *value = s->time;
    return fmi2OK;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind kind, fmi2Integer *value) {
    BEGIN(C_GetIntegerStatus)
    if (!value) return refuse(s, CALLS[C_GetIntegerStatus].name, "null argument");
    return wrong_kind(s, C_GetIntegerStatus, kind, "FMI 2.0 defines no Integer status");
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind kind, fmi2Boolean *value) {
    BEGIN(C_GetBooleanStatus)
    if (!value) return refuse(s, CALLS[C_GetBooleanStatus].name, "null argument");
    if (kind != fmi2Terminated)
        return wrong_kind(s, C_GetBooleanStatus, kind, "fmi2GetBooleanStatus answers fmi2Terminated");
    *value = s->state == STEP_DISCARDED ? fmi2True : fmi2False; /* a refused step is refused for ever */
    return fmi2OK;
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind kind, fmi2String *value) {
    BEGIN(C_GetStringStatus)
    if (!value) return refuse(s, CALLS[C_GetStringStatus].name, "null argument");
    if (kind != fmi2PendingStatus)
        return wrong_kind(s, C_GetStringStatus, kind, "fmi2GetStringStatus answers fmi2PendingStatus");
    *value = "no fmi2DoStep is pending";
    return no_step_pending(s, C_GetStringStatus, kind);
}
