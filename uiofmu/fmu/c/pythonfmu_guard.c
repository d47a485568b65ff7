/* uiofmu's guard in front of pythonfmu 0.7.0's native binary (FMI 2.0 Co-Simulation, linux64).
 *
 * A pythonfmu FMU built by uiofmu ships this file, compiled, as binaries/linux64/MODEL.so and
 * pythonfmu's own binary beside it as binaries/linux64/MODEL_pythonfmu.so. The guard adds what
 * pythonfmu's binary does not do and forwards every FMI call to it otherwise:
 *
 *   fmi2Instantiate   refuses (log line, NULL) a GUID other than this FMU's, an fmuType other
 *                     than fmi2CoSimulation, an empty or non-UTF-8 instance name, and a resource
 *                     location that is not a file URI of an existing folder holding
 *                     slavemodule.txt; pythonfmu dereferences a NULL class for those and
 *                     crashes. It then hands pythonfmu "file://" + the canonical absolute path
 *                     with every percent-escape decoded (pythonfmu itself only strips
 *                     "file://" and decodes "%20"), and loads pythonfmu's binary on first use
 *                     (dlopen, RTLD_LOCAL | RTLD_NOW; found beside this library with dladdr).
 *   statuses          pythonfmu's Python methods can only yield fmi2OK (or fmi2Discard from
 *                     do_step), so uiofmu's slave reports a refused call with a log line of
 *                     status fmi2Error. The guard sees every line (pythonfmu's logger is always
 *                     switched on underneath) and returns the worst of the call's own status and
 *                     the fmi2Discard, fmi2Error or fmi2Fatal lines logged during it.
 *   log lines         forwarded to the importer's logger with "%s" and the text unchanged:
 *                     pythonfmu passes a message as the format with no arguments, so a '%' in
 *                     it (a path, say) must not be formatted again. Lines of status fmi2OK are
 *                     forwarded only while the importer's debug logging is on (and then only
 *                     for the categories it asked for, if any); all others always are, as in
 *                     uiofmu's C backend. fmi2SetDebugLogging ignores a category that the
 *                     FMU's <LogCategories> (pythonfmu's, LOG_CATEGORIES below) does not list,
 *                     with one fmi2Warning line, and returns fmi2Warning, as the C backend does.
 *   pointers          NULL arrays with a positive count, NULL output pointers and FMU states
 *                     that this library did not hand out (or that were freed) are refused
 *                     with a log line and fmi2Error instead of being dereferenced.
 *   fmi2Fatal         pythonfmu keeps dangling pointers in an instance after fmi2Fatal (the
 *                     next call crashes): the guard refuses every later call on that instance
 *                     and fmi2FreeInstance frees only the guard's record of it.
 *   unloading         finalizePythonInterpreter is exported and forwarded. pythonfmu's binary
 *                     frees its interpreter state from a static destructor and again from a
 *                     library destructor; the guard releases the state through the binary's
 *                     finalizePythonInterpreter while it is still loaded, both when this library
 *                     is closed (before it closes pythonfmu's) and at exit (from an exit
 *                     handler that runs before the binary's static destructors).
 *
 * Compile: cc -std=c99 -shared -fPIC -fvisibility=hidden -DGUARD_GUID='"..."'
 *          -DGUARD_MODEL='"..."' -I<fmi2 headers> pythonfmu_guard.c -ldl -pthread
 * (uiofmu/fmu/pythonfmu_guard.py does this with the GUID and model identifier of the FMU's
 * modelDescription.xml, both checked before they become string literals).
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <errno.h>
#include <limits.h>
#include <pthread.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "fmi2Functions.h"

#ifndef GUARD_GUID
#error "compile with -DGUARD_GUID='\"<the GUID of modelDescription.xml>\"'"
#endif
#ifndef GUARD_MODEL
#error "compile with -DGUARD_MODEL='\"<the model identifier>\"'"
#endif

/* pythonfmu's binary, beside this library. */
#define REAL_LIBRARY GUARD_MODEL "_pythonfmu.so"
/* Marks a live instance record (cleared when it is freed). */
#define GUARD_MAGIC 0x67756172u
/* Longest log line the guard writes itself. */
#define LINE 1024

FMI2_Export void finalizePythonInterpreter(void);

/* ---------------------------------------------------------------------------------------
 * pythonfmu's binary: loaded once, on the first fmi2Instantiate, and closed with this library.
 * ------------------------------------------------------------------------------------- */

typedef struct {
    fmi2GetTypesPlatformTYPE *GetTypesPlatform;
    fmi2GetVersionTYPE *GetVersion;
    fmi2SetDebugLoggingTYPE *SetDebugLogging;
    fmi2InstantiateTYPE *Instantiate;
    fmi2FreeInstanceTYPE *FreeInstance;
    fmi2SetupExperimentTYPE *SetupExperiment;
    fmi2EnterInitializationModeTYPE *EnterInitializationMode;
    fmi2ExitInitializationModeTYPE *ExitInitializationMode;
    fmi2TerminateTYPE *Terminate;
    fmi2ResetTYPE *Reset;
    fmi2GetRealTYPE *GetReal;
    fmi2GetIntegerTYPE *GetInteger;
    fmi2GetBooleanTYPE *GetBoolean;
    fmi2GetStringTYPE *GetString;
    fmi2SetRealTYPE *SetReal;
    fmi2SetIntegerTYPE *SetInteger;
    fmi2SetBooleanTYPE *SetBoolean;
    fmi2SetStringTYPE *SetString;
    fmi2GetFMUstateTYPE *GetFMUstate;
    fmi2SetFMUstateTYPE *SetFMUstate;
    fmi2FreeFMUstateTYPE *FreeFMUstate;
    fmi2SerializedFMUstateSizeTYPE *SerializedFMUstateSize;
    fmi2SerializeFMUstateTYPE *SerializeFMUstate;
    fmi2DeSerializeFMUstateTYPE *DeSerializeFMUstate;
    fmi2GetDirectionalDerivativeTYPE *GetDirectionalDerivative;
    fmi2SetRealInputDerivativesTYPE *SetRealInputDerivatives;
    fmi2GetRealOutputDerivativesTYPE *GetRealOutputDerivatives;
    fmi2DoStepTYPE *DoStep;
    fmi2CancelStepTYPE *CancelStep;
    fmi2GetStatusTYPE *GetStatus;
    fmi2GetRealStatusTYPE *GetRealStatus;
    fmi2GetIntegerStatusTYPE *GetIntegerStatus;
    fmi2GetBooleanStatusTYPE *GetBooleanStatus;
    fmi2GetStringStatusTYPE *GetStringStatus;
    void (*finalize)(void); /* finalizePythonInterpreter, optional */
} RealLibrary;

static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;
static void *real_handle; /* written under the lock; only ever set once it is complete */
static RealLibrary real;
static int exit_handler_registered;
static int exiting; /* set by the exit handler: the process is ending */

/* An anchor whose address dladdr maps back to this library's file. */
static const char anchor = 0;

/* At exit, before pythonfmu's static destructors (registered earlier, so run later): release
 * its interpreter state while the library is intact. Also runs when this library is closed
 * (from __cxa_finalize): before guard_unload it releases the state, after it there is nothing
 * left to do (real_handle is NULL); either order is safe. */
static void at_exit(void) {
    pthread_mutex_lock(&lock);
    if (real_handle && real.finalize) real.finalize();
    exiting = 1;
    pthread_mutex_unlock(&lock);
}

/* Closing this library: release pythonfmu's state, then close its binary. During exit the
 * state was released by at_exit and the loader finalises pythonfmu's binary on its own
 * (dlclose then only drops a reference). */
__attribute__((destructor)) static void guard_unload(void) {
    pthread_mutex_lock(&lock);
    if (real_handle) {
        if (!exiting && real.finalize) real.finalize();
        dlclose(real_handle);
        real_handle = NULL;
    }
    pthread_mutex_unlock(&lock);
}

#define SYMBOL(field, name)                                            \
    do {                                                               \
        *(void **)(&loaded.field) = dlsym(handle, name);               \
        if (!loaded.field) {                                           \
            snprintf(why, cap, "%.400s has no symbol %s", path, name); \
            dlclose(handle);                                           \
            return 0;                                                  \
        }                                                              \
    } while (0)

/* Load pythonfmu's binary (once); 0 and a reason in why when it cannot be. */
static int load_real(char *why, size_t cap) {
    Dl_info info;
    char path[PATH_MAX];
    RealLibrary loaded;
    if (real_handle) return 1;
    if (!dladdr(&anchor, &info) || !info.dli_fname || !info.dli_fname[0]) {
        snprintf(why, cap, "cannot find the file of the FMU's binary (dladdr failed)");
        return 0;
    }
    const char *slash = strrchr(info.dli_fname, '/');
    int n = slash ? snprintf(path, sizeof path, "%.*s/%s", (int)(slash - info.dli_fname), info.dli_fname, REAL_LIBRARY)
                  : snprintf(path, sizeof path, "./%s", REAL_LIBRARY);
    if (n < 0 || (size_t)n >= sizeof path) {
        snprintf(why, cap, "the path of the FMU's binary is too long");
        return 0;
    }
    dlerror();
    void *handle = dlopen(path, RTLD_LOCAL | RTLD_NOW);
    if (!handle) {
        const char *e = dlerror();
        snprintf(why, cap, "cannot load pythonfmu's binary: %.600s", e ? e : path);
        return 0;
    }
    memset(&loaded, 0, sizeof loaded);
    SYMBOL(GetTypesPlatform, "fmi2GetTypesPlatform");
    SYMBOL(GetVersion, "fmi2GetVersion");
    SYMBOL(SetDebugLogging, "fmi2SetDebugLogging");
    SYMBOL(Instantiate, "fmi2Instantiate");
    SYMBOL(FreeInstance, "fmi2FreeInstance");
    SYMBOL(SetupExperiment, "fmi2SetupExperiment");
    SYMBOL(EnterInitializationMode, "fmi2EnterInitializationMode");
    SYMBOL(ExitInitializationMode, "fmi2ExitInitializationMode");
    SYMBOL(Terminate, "fmi2Terminate");
    SYMBOL(Reset, "fmi2Reset");
    SYMBOL(GetReal, "fmi2GetReal");
    SYMBOL(GetInteger, "fmi2GetInteger");
    SYMBOL(GetBoolean, "fmi2GetBoolean");
    SYMBOL(GetString, "fmi2GetString");
    SYMBOL(SetReal, "fmi2SetReal");
    SYMBOL(SetInteger, "fmi2SetInteger");
    SYMBOL(SetBoolean, "fmi2SetBoolean");
    SYMBOL(SetString, "fmi2SetString");
    SYMBOL(GetFMUstate, "fmi2GetFMUstate");
    SYMBOL(SetFMUstate, "fmi2SetFMUstate");
    SYMBOL(FreeFMUstate, "fmi2FreeFMUstate");
    SYMBOL(SerializedFMUstateSize, "fmi2SerializedFMUstateSize");
    SYMBOL(SerializeFMUstate, "fmi2SerializeFMUstate");
    SYMBOL(DeSerializeFMUstate, "fmi2DeSerializeFMUstate");
    SYMBOL(GetDirectionalDerivative, "fmi2GetDirectionalDerivative");
    SYMBOL(SetRealInputDerivatives, "fmi2SetRealInputDerivatives");
    SYMBOL(GetRealOutputDerivatives, "fmi2GetRealOutputDerivatives");
    SYMBOL(DoStep, "fmi2DoStep");
    SYMBOL(CancelStep, "fmi2CancelStep");
    SYMBOL(GetStatus, "fmi2GetStatus");
    SYMBOL(GetRealStatus, "fmi2GetRealStatus");
    SYMBOL(GetIntegerStatus, "fmi2GetIntegerStatus");
    SYMBOL(GetBooleanStatus, "fmi2GetBooleanStatus");
    SYMBOL(GetStringStatus, "fmi2GetStringStatus");
    *(void **)(&loaded.finalize) = dlsym(handle, "finalizePythonInterpreter");
    if (!exit_handler_registered) {
        /* Registered after the binary's static destructors: runs before them at exit. */
        if (atexit(at_exit) != 0) {
            snprintf(why, cap, "cannot register an exit handler");
            dlclose(handle);
            return 0;
        }
        exit_handler_registered = 1;
    }
    real = loaded;
    real_handle = handle;
    return 1;
}

/* ---------------------------------------------------------------------------------------
 * Instances, their log lines and the statuses those lines imply.
 * ------------------------------------------------------------------------------------- */

typedef struct {
    unsigned magic;
    fmi2Component inner;            /* pythonfmu's instance */
    fmi2CallbackFunctions user;     /* the importer's callbacks */
    fmi2CallbackFunctions cb;       /* handed to pythonfmu (it keeps the pointer) */
    char *name;
    fmi2Boolean logging;            /* the importer's debug logging */
    char **categories;              /* the importer's known categories */
    size_t ncategories;
    int restricted;                 /* the importer named categories: only those (else all) */
    fmi2Status worst;               /* worst fmi2Discard/fmi2Error/fmi2Fatal line of this call */
    int dead;                       /* pythonfmu returned fmi2Fatal: never call it again */
} Guard;

static const char *category_of(fmi2Status status) {
    switch (status) {
        case fmi2OK: return "logAll";
        case fmi2Warning: return "logStatusWarning";
        case fmi2Discard: return "logStatusDiscard";
        case fmi2Error: return "logStatusError";
        default: return "logStatusFatal";
    }
}

/* A line of the guard's own, formatted here and passed on with "%s". */
static void say(const fmi2CallbackFunctions *f, fmi2String name, fmi2Status status, const char *fmt, ...) {
    char line[LINE];
    va_list ap;
    if (!f || !f->logger) return;
    va_start(ap, fmt);
    vsnprintf(line, sizeof line, fmt, ap);
    va_end(ap);
    f->logger(f->componentEnvironment, name ? name : "", status, category_of(status), "%s", line);
}

/* The <LogCategories> of pythonfmu 0.7.0's modelDescription.xml (Fmi2Slave.log_categories). */
static const char *const LOG_CATEGORIES[] = {"logStatusWarning", "logStatusDiscard", "logStatusError",
                                             "logStatusFatal", "logAll"};
#define N_LOG_CATEGORIES (sizeof LOG_CATEGORIES / sizeof LOG_CATEGORIES[0])

static int known_category(const char *category) {
    for (size_t i = 0; i < N_LOG_CATEGORIES; i++)
        if (strcmp(category, LOG_CATEGORIES[i]) == 0) return 1;
    return 0;
}

static int category_enabled(const Guard *g, fmi2String category) {
    if (!g->restricted) return 1;
    for (size_t i = 0; i < g->ncategories; i++)
        if (category && strcmp(category, g->categories[i]) == 0) return 1;
    return 0;
}

/* The logger pythonfmu calls: note the status, forward the text unchanged. pythonfmu passes
 * the message as the format without arguments, so it is taken literally (no formatting: a '%'
 * in a path or value must not read arguments that are not there). */
static void guard_logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                         fmi2String message, ...) {
    Guard *g = (Guard *)env;
    if (!g || g->magic != GUARD_MAGIC) return;
    if ((status == fmi2Discard || status == fmi2Error || status == fmi2Fatal) && status > g->worst)
        g->worst = status;
    if (!g->user.logger) return;
    if (status == fmi2OK && (!g->logging || !category_enabled(g, category))) return;
    g->user.logger(g->user.componentEnvironment, name ? name : g->name, status, category, "%s",
                   message ? message : "");
}

/* The instance behind c, ready for a call into pythonfmu (NULL: refuse the call). */
static Guard *begin(fmi2Component c, const char *function) {
    Guard *g = (Guard *)c;
    if (!g || g->magic != GUARD_MAGIC) return NULL;
    if (g->dead) {
        say(&g->user, g->name, fmi2Error,
            "%s: refused: this instance returned fmi2Fatal before and cannot be used any more (only "
            "fmi2FreeInstance is accepted)", function);
        return NULL;
    }
    g->worst = fmi2OK;
    return g;
}

/* The status of a call: its own, or worse where the slave logged worse during it. */
static fmi2Status finish(Guard *g, fmi2Status status) {
    if (status <= fmi2Fatal && g->worst > status) status = g->worst;
    if (status == fmi2Fatal) g->dead = 1;
    return status;
}

static fmi2Status refuse(Guard *g, const char *function, const char *why) {
    say(&g->user, g->name, fmi2Error, "%s: %s; the call was refused", function, why);
    return fmi2Error;
}

#define BEGIN(function)                     \
    Guard *g = begin(c, function);          \
    if (!g) return fmi2Error;

/* A positive count needs both arrays. */
#define ARRAYS(function, vr, nvr, value)                                                        \
    if ((nvr) > 0 && (!(vr) || !(value))) return refuse(g, function, "a NULL array with nvr > 0"); \
    if ((nvr) > (size_t)INT_MAX) return refuse(g, function, "more than INT_MAX value references");

/* ---------------------------------------------------------------------------------------
 * FMU states: only those this library handed out and did not free yet reach pythonfmu (its
 * states are Python objects; anything else would be dereferenced as one).
 * ------------------------------------------------------------------------------------- */

static pthread_mutex_t states_lock = PTHREAD_MUTEX_INITIALIZER;
static fmi2FMUstate *states;
static size_t nstates, capstates;

static int state_index(fmi2FMUstate s) {
    for (size_t i = 0; i < nstates; i++)
        if (states[i] == s) return (int)i;
    return -1;
}

static int state_known(fmi2FMUstate s) {
    pthread_mutex_lock(&states_lock);
    int known = s && state_index(s) >= 0;
    pthread_mutex_unlock(&states_lock);
    return known;
}

static int state_add(fmi2FMUstate s) {
    int ok = 1;
    pthread_mutex_lock(&states_lock);
    if (nstates == capstates) {
        size_t cap = capstates ? 2 * capstates : 16;
        fmi2FMUstate *grown = cap < SIZE_MAX / sizeof *states ? realloc(states, cap * sizeof *states) : NULL;
        if (grown) {
            states = grown;
            capstates = cap;
        } else {
            ok = 0;
        }
    }
    if (ok) states[nstates++] = s;
    pthread_mutex_unlock(&states_lock);
    return ok;
}

static void state_remove(fmi2FMUstate s) {
    pthread_mutex_lock(&states_lock);
    int i = state_index(s);
    if (i >= 0) states[i] = states[--nstates];
    if (nstates == 0) {
        free(states);
        states = NULL;
        capstates = 0;
    }
    pthread_mutex_unlock(&states_lock);
}

static fmi2Status unknown_state(Guard *g, const char *function, fmi2FMUstate s) {
    say(&g->user, g->name, fmi2Error, "%s: the FMU state %p is not a live state of this FMU (one made by its "
        "fmi2GetFMUstate or fmi2DeSerializeFMUstate and not freed yet): a state of another FMU, a freed one or "
        "NULL is refused; nothing changed", function, s);
    return fmi2Error;
}

/* Register a state pythonfmu just made (1), or free it when the call failed (0, *status set). */
static int keep_state(Guard *g, const char *function, fmi2Status *status, fmi2FMUstate *fresh) {
    if (*status > fmi2Warning) {
        if (*fresh && !g->dead) real.FreeFMUstate(g->inner, fresh);
        return 0;
    }
    if (!*fresh) {
        *status = refuse(g, function, "pythonfmu returned no state");
        return 0;
    }
    if (!state_add(*fresh)) {
        real.FreeFMUstate(g->inner, fresh);
        *status = refuse(g, function, "out of memory");
        return 0;
    }
    return 1;
}

#define KNOWN_STATE(function, s) \
    if (!state_known(s)) return unknown_state(g, function, s);

/* ---------------------------------------------------------------------------------------
 * fmi2Instantiate: the GUID, the type, the instance name and the resource location.
 * ------------------------------------------------------------------------------------- */

/* The GUID without one pair of surrounding braces, lower-cased, into out. */
static int normal_guid(const char *guid, char *out, size_t cap) {
    size_t n = strlen(guid);
    if (n >= 2 && guid[0] == '{' && guid[n - 1] == '}') {
        guid++;
        n -= 2;
    }
    if (n >= cap) return 0;
    for (size_t i = 0; i < n; i++) out[i] = (char)((guid[i] >= 'A' && guid[i] <= 'Z') ? guid[i] - 'A' + 'a' : guid[i]);
    out[n] = '\0';
    return 1;
}

static int utf8_valid(const unsigned char *s) {
    while (*s) {
        unsigned c = *s++;
        int more;
        unsigned min;
        if (c < 0x80) continue;
        if (c >= 0xC2 && c <= 0xDF) { more = 1; min = 0x80; }
        else if (c >= 0xE0 && c <= 0xEF) { more = 2; min = 0x800; }
        else if (c >= 0xF0 && c <= 0xF4) { more = 3; min = 0x10000; }
        else return 0;
        unsigned cp = c & (0x3Fu >> more);
        for (int k = 0; k < more; k++, s++) {
            if ((*s & 0xC0) != 0x80) return 0;
            cp = (cp << 6) | (*s & 0x3Fu);
        }
        if (cp < min || cp > 0x10FFFF || (cp >= 0xD800 && cp <= 0xDFFF)) return 0;
    }
    return 1;
}

static int hex(int ch) {
    if (ch >= '0' && ch <= '9') return ch - '0';
    if (ch >= 'a' && ch <= 'f') return ch - 'a' + 10;
    if (ch >= 'A' && ch <= 'F') return ch - 'A' + 10;
    return -1;
}

static int starts_nocase(const char *s, const char *prefix) {
    for (; *prefix; s++, prefix++) {
        int a = (unsigned char)*s, b = (unsigned char)*prefix;
        if (a >= 'A' && a <= 'Z') a += 'a' - 'A';
        if (a != b) return 0;
    }
    return 1;
}

/* The resource folder of a file URI: "file://" + canonical absolute path into out (1), or a
 * reason in why (0). Accepts file:///p, file://localhost/p and file:/p; decodes every
 * percent-escape; '?' and '#' are path characters (an importer that does not escape them
 * means the folder of that name). */
static int resource_folder(const char *uri, char *out, size_t cap, char *why, size_t whycap) {
    char decoded[PATH_MAX], canonical[PATH_MAX], probe[PATH_MAX + 32];
    struct stat st;
    const char *p;
    size_t n = 0;
    if (!uri) {
        snprintf(why, whycap, "no resource location (NULL)");
        return 0;
    }
    if (!starts_nocase(uri, "file:")) {
        snprintf(why, whycap, "the resource location \"%.300s\" is not a file URI", uri);
        return 0;
    }
    p = uri + 5;
    if (p[0] == '/' && p[1] == '/') {
        const char *host = p + 2, *end = strchr(host, '/');
        size_t len = end ? (size_t)(end - host) : strlen(host);
        if (!(len == 0 || (len == 9 && starts_nocase(host, "localhost")))) {
            snprintf(why, whycap, "the resource location \"%.300s\" names the host \"%.*s\"; only local files "
                     "(file:///path) can be read", uri, (int)(len > 100 ? 100 : len), host);
            return 0;
        }
        p = end;
    }
    if (!p || p[0] != '/') {
        snprintf(why, whycap, "the resource location \"%.300s\" has no absolute path", uri);
        return 0;
    }
    for (; *p; p++) {
        int ch = (unsigned char)*p;
        if (ch == '%') {
            int hi = hex((unsigned char)p[1]), lo = hi < 0 ? -1 : hex((unsigned char)p[2]);
            if (hi < 0 || lo < 0) {
                snprintf(why, whycap, "the resource location \"%.300s\" has a malformed percent-escape", uri);
                return 0;
            }
            ch = hi * 16 + lo;
            if (ch == 0) {
                snprintf(why, whycap, "the resource location \"%.300s\" encodes a NUL byte", uri);
                return 0;
            }
            p += 2;
        }
        if (n + 1 >= sizeof decoded) {
            snprintf(why, whycap, "the resource location is longer than PATH_MAX");
            return 0;
        }
        decoded[n++] = (char)ch;
    }
    decoded[n] = '\0';
    if (!utf8_valid((const unsigned char *)decoded)) {
        snprintf(why, whycap, "the resource location \"%.300s\" is not UTF-8 once decoded (Python cannot take it)",
                 uri);
        return 0;
    }
    if (!realpath(decoded, canonical)) {
        snprintf(why, whycap, "the resource folder \"%.300s\" cannot be resolved: %s", decoded, strerror(errno));
        return 0;
    }
    if (stat(canonical, &st) != 0 || !S_ISDIR(st.st_mode)) {
        snprintf(why, whycap, "the resource location \"%.300s\" is not a folder", decoded);
        return 0;
    }
    snprintf(probe, sizeof probe, "%s/slavemodule.txt", strcmp(canonical, "/") == 0 ? "" : canonical);
    if (stat(probe, &st) != 0 || !S_ISREG(st.st_mode)) {
        snprintf(why, whycap, "the resource folder \"%.300s\" holds no slavemodule.txt (not this FMU's resources)",
                 canonical);
        return 0;
    }
    if (strstr(canonical, "%20")) { /* pythonfmu would turn it into a space */
        snprintf(why, whycap, "the resource folder \"%.300s\" has \"%%20\" in its path, which pythonfmu "
                 "would read as a space", canonical);
        return 0;
    }
    if ((size_t)snprintf(out, cap, "file://%s", canonical) >= cap) {
        snprintf(why, whycap, "the resource folder's path is too long");
        return 0;
    }
    return 1;
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn) {
    char why[LINE], location[PATH_MAX + 16], a[80], b[80];
    if (!functions) return NULL; /* nowhere to say why */
    if (!instanceName || !instanceName[0] || !utf8_valid((const unsigned char *)instanceName)) {
        say(functions, instanceName && utf8_valid((const unsigned char *)instanceName) ? instanceName : "", fmi2Error,
            "fmi2Instantiate: the instance name is %s (FMI 2.0 asks for a non-empty name, Python for UTF-8); "
            "instantiation refused", !instanceName ? "a NULL pointer" : !instanceName[0] ? "empty" : "not UTF-8");
        return NULL;
    }
    if (fmuType != fmi2CoSimulation) {
        say(functions, instanceName, fmi2Error, "fmi2Instantiate: fmuType %d requested; this FMU is Co-Simulation "
            "only (fmi2CoSimulation = %d); instantiation refused", (int)fmuType, (int)fmi2CoSimulation);
        return NULL;
    }
    if (!fmuGUID || !normal_guid(fmuGUID, a, sizeof a) || !normal_guid(GUARD_GUID, b, sizeof b) || strcmp(a, b) != 0) {
        say(functions, instanceName, fmi2Error, "fmi2Instantiate: GUID \"%.100s\" is not this FMU's (%s); "
            "instantiation refused", fmuGUID ? fmuGUID : "(NULL)", GUARD_GUID);
        return NULL;
    }
    if (!resource_folder(fmuResourceLocation, location, sizeof location, why, sizeof why)) {
        say(functions, instanceName, fmi2Error, "fmi2Instantiate: %s; instantiation refused", why);
        return NULL;
    }
    pthread_mutex_lock(&lock);
    int loaded = load_real(why, sizeof why);
    pthread_mutex_unlock(&lock);
    if (!loaded) {
        say(functions, instanceName, fmi2Error, "fmi2Instantiate: %s; instantiation refused", why);
        return NULL;
    }
    Guard *g = (Guard *)calloc(1, sizeof *g);
    char *name = g ? strdup(instanceName) : NULL;
    if (!name) {
        free(g);
        say(functions, instanceName, fmi2Error, "fmi2Instantiate: out of memory; instantiation refused");
        return NULL;
    }
    g->magic = GUARD_MAGIC;
    g->name = name;
    /* Copied, not assigned: FMI 2.0.0's header declares the members const. No stepFinished:
     * pythonfmu never steps asynchronously (and would pass the guard's environment). */
    const fmi2CallbackFunctions mine = {guard_logger, functions->allocateMemory, functions->freeMemory, NULL, g};
    memcpy(&g->user, functions, sizeof g->user);
    memcpy(&g->cb, &mine, sizeof g->cb);
    g->logging = loggingOn;
    /* pythonfmu's own logging stays on: the guard has to see every line to know the status. */
    g->inner = real.Instantiate(instanceName, fmi2CoSimulation, fmuGUID, location, &g->cb, visible, fmi2True);
    if (!g->inner) {
        g->magic = 0;
        free(g->name);
        free(g);
        return NULL;
    }
    return g;
}

void fmi2FreeInstance(fmi2Component c) {
    Guard *g = (Guard *)c;
    if (!g || g->magic != GUARD_MAGIC) return;
    if (!g->dead) real.FreeInstance(g->inner);
    g->magic = 0;
    for (size_t i = 0; i < g->ncategories; i++) free(g->categories[i]);
    free(g->categories);
    free(g->name);
    free(g);
}

/* ---------------------------------------------------------------------------------------
 * The other functions: forwarded.
 * ------------------------------------------------------------------------------------- */

const char *fmi2GetTypesPlatform(void) {
    pthread_mutex_lock(&lock);
    const char *platform = real_handle ? real.GetTypesPlatform() : fmi2TypesPlatform;
    pthread_mutex_unlock(&lock);
    return platform;
}

const char *fmi2GetVersion(void) {
    pthread_mutex_lock(&lock);
    const char *version = real_handle ? real.GetVersion() : fmi2Version;
    pthread_mutex_unlock(&lock);
    return version;
}

void finalizePythonInterpreter(void) {
    pthread_mutex_lock(&lock);
    if (real_handle && real.finalize) real.finalize();
    pthread_mutex_unlock(&lock);
}

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    BEGIN("fmi2SetDebugLogging")
    if (nCategories > 0 && !categories) return refuse(g, "fmi2SetDebugLogging", "a NULL array with nCategories > 0");
    size_t unknown = 0, first = 0, known = 0;
    for (size_t i = 0; i < nCategories; i++)
        if (!categories[i]) return refuse(g, "fmi2SetDebugLogging", "a NULL category");
    for (size_t i = 0; i < nCategories; i++) {
        if (known_category(categories[i])) known++;
        else if (unknown++ == 0) first = i;
    }
    char **copy = known ? (char **)calloc(known, sizeof *copy) : NULL;
    if (known && !copy) return refuse(g, "fmi2SetDebugLogging", "out of memory");
    for (size_t i = 0, j = 0; i < nCategories; i++) {
        if (!known_category(categories[i])) continue;
        copy[j] = strdup(categories[i]);
        if (!copy[j]) {
            for (size_t k = 0; k < j; k++) free(copy[k]);
            free(copy);
            return refuse(g, "fmi2SetDebugLogging", "out of memory");
        }
        j++;
    }
    if (unknown) {       /* under the categories that were on before the call, as the C backend */
        char shown[64];
        snprintf(shown, sizeof shown, "%s", categories[first]);
        for (char *p = shown; *p; p++)
            if (*p < 0x20 || *p > 0x7e) *p = '?';
        say(&g->user, g->name, fmi2Warning, "fmi2SetDebugLogging: categories[%zu] = \"%s\"%s %s not a log category of "
            "this FMU (logStatusWarning, logStatusDiscard, logStatusError, logStatusFatal, logAll): ignored", first,
            shown, unknown > 1 ? " and others" : "", unknown > 1 ? "are" : "is");
    }
    for (size_t i = 0; i < g->ncategories; i++) free(g->categories[i]);
    free(g->categories);
    g->categories = copy;
    g->ncategories = known;
    g->restricted = nCategories > 0;
    g->logging = loggingOn;
    /* pythonfmu keeps logging everything to the guard, which filters. */
    fmi2Status status = finish(g, real.SetDebugLogging(g->inner, fmi2True, 0, NULL));
    return unknown && status == fmi2OK ? fmi2Warning : status;
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    BEGIN("fmi2SetupExperiment")
    return finish(g, real.SetupExperiment(g->inner, toleranceDefined, tolerance, startTime, stopTimeDefined, stopTime));
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    BEGIN("fmi2EnterInitializationMode")
    return finish(g, real.EnterInitializationMode(g->inner));
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    BEGIN("fmi2ExitInitializationMode")
    return finish(g, real.ExitInitializationMode(g->inner));
}

fmi2Status fmi2Terminate(fmi2Component c) {
    BEGIN("fmi2Terminate")
    return finish(g, real.Terminate(g->inner));
}

fmi2Status fmi2Reset(fmi2Component c) {
    BEGIN("fmi2Reset")
    return finish(g, real.Reset(g->inner));
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]) {
    BEGIN("fmi2GetReal")
    ARRAYS("fmi2GetReal", vr, nvr, value)
    return finish(g, real.GetReal(g->inner, vr, nvr, value));
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[]) {
    BEGIN("fmi2GetInteger")
    ARRAYS("fmi2GetInteger", vr, nvr, value)
    return finish(g, real.GetInteger(g->inner, vr, nvr, value));
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[]) {
    BEGIN("fmi2GetBoolean")
    ARRAYS("fmi2GetBoolean", vr, nvr, value)
    return finish(g, real.GetBoolean(g->inner, vr, nvr, value));
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2String value[]) {
    BEGIN("fmi2GetString")
    ARRAYS("fmi2GetString", vr, nvr, value)
    return finish(g, real.GetString(g->inner, vr, nvr, value));
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[]) {
    BEGIN("fmi2SetReal")
    ARRAYS("fmi2SetReal", vr, nvr, value)
    return finish(g, real.SetReal(g->inner, vr, nvr, value));
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Integer value[]) {
    BEGIN("fmi2SetInteger")
    ARRAYS("fmi2SetInteger", vr, nvr, value)
    return finish(g, real.SetInteger(g->inner, vr, nvr, value));
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Boolean value[]) {
    BEGIN("fmi2SetBoolean")
    ARRAYS("fmi2SetBoolean", vr, nvr, value)
    return finish(g, real.SetBoolean(g->inner, vr, nvr, value));
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2String value[]) {
    BEGIN("fmi2SetString")
    ARRAYS("fmi2SetString", vr, nvr, value)
    for (size_t i = 0; i < nvr; i++)
        if (!value[i]) return refuse(g, "fmi2SetString", "a NULL string");
    return finish(g, real.SetString(g->inner, vr, nvr, value));
}

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    BEGIN("fmi2GetFMUstate")
    if (!FMUstate) return refuse(g, "fmi2GetFMUstate", "a NULL pointer for the state");
    fmi2FMUstate previous = *FMUstate, fresh = NULL;
    fmi2Status status = finish(g, real.GetFMUstate(g->inner, &fresh));
    if (!keep_state(g, "fmi2GetFMUstate", &status, &fresh)) return status;
    /* FMI 2.0: a state given on entry is overwritten (pythonfmu would leak it). */
    if (previous && state_known(previous)) {
        real.FreeFMUstate(g->inner, &previous);
        state_remove(previous);
    }
    *FMUstate = fresh;
    return status;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    BEGIN("fmi2SetFMUstate")
    KNOWN_STATE("fmi2SetFMUstate", FMUstate)
    return finish(g, real.SetFMUstate(g->inner, FMUstate));
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    BEGIN("fmi2FreeFMUstate")
    if (!FMUstate) return refuse(g, "fmi2FreeFMUstate", "a NULL pointer for the state");
    if (!*FMUstate) return fmi2OK; /* FMI 2.0: nothing to free */
    KNOWN_STATE("fmi2FreeFMUstate", *FMUstate)
    fmi2FMUstate s = *FMUstate;
    fmi2Status status = real.FreeFMUstate(g->inner, FMUstate);
    if (status <= fmi2Warning) {
        state_remove(s);
        *FMUstate = NULL;
    }
    return finish(g, status);
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    BEGIN("fmi2SerializedFMUstateSize")
    if (!size) return refuse(g, "fmi2SerializedFMUstateSize", "a NULL pointer for the size");
    KNOWN_STATE("fmi2SerializedFMUstateSize", FMUstate)
    return finish(g, real.SerializedFMUstateSize(g->inner, FMUstate, size));
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[], size_t size) {
    size_t needed = 0;
    BEGIN("fmi2SerializeFMUstate")
    KNOWN_STATE("fmi2SerializeFMUstate", FMUstate)
    if (size > 0 && !serializedState) return refuse(g, "fmi2SerializeFMUstate", "a NULL buffer with size > 0");
    /* pythonfmu copies size bytes whatever the length of the serialised state. */
    fmi2Status status = real.SerializedFMUstateSize(g->inner, FMUstate, &needed);
    if (status > fmi2Warning) return finish(g, status);
    if (size < needed) {
        say(&g->user, g->name, fmi2Error, "fmi2SerializeFMUstate: the buffer has %zu bytes, the serialised state "
            "%zu (see fmi2SerializedFMUstateSize); the call was refused", size, needed);
        return fmi2Error;
    }
    status = real.SerializeFMUstate(g->inner, FMUstate, serializedState, needed);
    if (size > needed) memset(serializedState + needed, 0, size - needed);
    return finish(g, status);
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate) {
    BEGIN("fmi2DeSerializeFMUstate")
    if (!FMUstate) return refuse(g, "fmi2DeSerializeFMUstate", "a NULL pointer for the state");
    if (size > 0 && !serializedState) return refuse(g, "fmi2DeSerializeFMUstate", "a NULL buffer with size > 0");
    if (size > (size_t)PTRDIFF_MAX) return refuse(g, "fmi2DeSerializeFMUstate", "an impossible size");
    fmi2FMUstate previous = *FMUstate, fresh = NULL;
    fmi2Status status = finish(g, real.DeSerializeFMUstate(g->inner, size ? serializedState : "", size, &fresh));
    if (!keep_state(g, "fmi2DeSerializeFMUstate", &status, &fresh)) return status;
    if (previous && state_known(previous)) {
        real.FreeFMUstate(g->inner, &previous);
        state_remove(previous);
    }
    *FMUstate = fresh;
    return status;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[], size_t nUnknown,
                                        const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[]) {
    BEGIN("fmi2GetDirectionalDerivative")
    return finish(g, real.GetDirectionalDerivative(g->inner, vUnknown_ref, nUnknown, vKnown_ref, nKnown, dvKnown,
                                                   dvUnknown));
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    BEGIN("fmi2SetRealInputDerivatives")
    return finish(g, real.SetRealInputDerivatives(g->inner, vr, nvr, order, value));
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    BEGIN("fmi2GetRealOutputDerivatives")
    return finish(g, real.GetRealOutputDerivatives(g->inner, vr, nvr, order, value));
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    BEGIN("fmi2DoStep")
    return finish(g, real.DoStep(g->inner, currentCommunicationPoint, communicationStepSize,
                                 noSetFMUStatePriorToCurrentPoint));
}

fmi2Status fmi2CancelStep(fmi2Component c) {
    BEGIN("fmi2CancelStep")
    return finish(g, real.CancelStep(g->inner));
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    BEGIN("fmi2GetStatus")
    if (!value) return refuse(g, "fmi2GetStatus", "a NULL pointer for the value");
    return finish(g, real.GetStatus(g->inner, s, value));
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    BEGIN("fmi2GetRealStatus")
    if (!value) return refuse(g, "fmi2GetRealStatus", "a NULL pointer for the value");
    return finish(g, real.GetRealStatus(g->inner, s, value));
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    BEGIN("fmi2GetIntegerStatus")
    if (!value) return refuse(g, "fmi2GetIntegerStatus", "a NULL pointer for the value");
    return finish(g, real.GetIntegerStatus(g->inner, s, value));
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    BEGIN("fmi2GetBooleanStatus")
    if (!value) return refuse(g, "fmi2GetBooleanStatus", "a NULL pointer for the value");
    return finish(g, real.GetBooleanStatus(g->inner, s, value));
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    BEGIN("fmi2GetStringStatus")
    if (!value) return refuse(g, "fmi2GetStringStatus", "a NULL pointer for the value");
    return finish(g, real.GetStringStatus(g->inner, s, value));
}
