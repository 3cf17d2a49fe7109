/* The front library of the cantrack FMUs (Linux x86_64): binaries/<platform>/<MODEL>.so.
 *
 * `cantrack fmu build` compiles this file into each FMU as the library the importer loads and
 * renames pythonfmu's FMI wrapper to <MODEL>_pythonfmu.so beside it.  The front
 *
 * 1. loads Python when the host has none (a C/C++ importer: fmusim, OMSimulator, ...):
 *    pythonfmu's wrapper does not link libpython (its symbols must already be in the process,
 *    pythonfmu issue #202), so the front dlopen()s libpython with RTLD_GLOBAL first:
 *    $CANTRACK_LIBPYTHON, else the library of the Python that built the FMU (LIBPYTHON_BUILD),
 *    else libpython3.X.so.1.0 through the dynamic loader's search path.  Unless PYTHONHOME is
 *    set it points Python at the prefix of the library it loaded (<prefix>/lib/libpython*),
 *    when <prefix>/lib/python3.X/os.py exists.  Neither library is ever unloaded: Python
 *    cannot be initialised again after finalising once numpy was imported;
 * 2. returns the worst status the FMU logged during a call as that call's status (at most
 *    Error): pythonfmu can only return OK or Fatal from exitInitializationMode and OK or
 *    Discard from an FMI 2 doStep, and Fatal makes its FreeInstance crash; so the Python part
 *    logs an error (one line) and returns normally, and the importer gets fmiXError;
 * 3. always lets the wrapper log (loggingOn) and forwards errors and warnings to the importer
 *    whatever its loggingOn, the other messages only with loggingOn;
 * 4. refuses what the FMU does not support before Python is involved: Model Exchange,
 *    Scheduled Execution, FMI 3 event mode; never calls the wrapper's FreeInstance after a
 *    Fatal (pythonfmu frees the instance twice then);
 * 5. FMI 3: passes fmi3EnterInitializationMode's startTime to the Python part (pythonfmu3 does
 *    not) by setting the independent variable `time` (VR_TIME) just before it.
 * Every other FMI function jumps straight into the wrapper (an x86_64 trampoline, no cost).
 *
 * Compile-time definitions (set by the build): FMI_VERSION (2 or 3), MODEL (model
 * identifier), REAL_LIBRARY (file name of the wrapper), LIBPYTHON_BUILD (path), PY_MINOR
 * (X of 3.X of the building Python), VR_TIME (FMI 3).
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <limits.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#define EXPORT __attribute__((visibility("default")))
#define STATUS_WARNING 1
#define STATUS_DISCARD 2
#define STATUS_ERROR 3
#define STATUS_FATAL 4

static char load_error[4096];
static void *real_lib;
static pthread_once_t load_once = PTHREAD_ONCE_INIT;
static pthread_mutex_t instances_lock = PTHREAD_MUTEX_INITIALIZER;

static int missing_function(void) { return STATUS_ERROR; }

/* ---- trampolines: exported FMI functions forwarded unchanged to the wrapper ---------- */
#define TRAMPOLINE(name)                                                                  \
    __attribute__((visibility("hidden"))) void *p_##name = (void *)missing_function;      \
    __asm__(".text\n.globl " #name "\n.type " #name ", @function\n" #name ":\n"          \
            "\tjmp *p_" #name "(%rip)\n.size " #name ", .-" #name "\n");

#if FMI_VERSION == 2
#define FORWARDED(X)                                                                      \
    X(fmi2SetupExperiment) X(fmi2EnterInitializationMode) X(fmi2GetReal) X(fmi2GetInteger) \
    X(fmi2GetBoolean) X(fmi2GetString) X(fmi2SetReal) X(fmi2SetInteger) X(fmi2SetBoolean)  \
    X(fmi2SetString) X(fmi2GetFMUstate) X(fmi2SetFMUstate) X(fmi2FreeFMUstate)            \
    X(fmi2SerializedFMUstateSize) X(fmi2SerializeFMUstate) X(fmi2DeSerializeFMUstate)      \
    X(fmi2GetDirectionalDerivative) X(fmi2SetRealInputDerivatives)                        \
    X(fmi2GetRealOutputDerivatives) X(fmi2CancelStep) X(fmi2GetStatus) X(fmi2GetRealStatus) \
    X(fmi2GetIntegerStatus) X(fmi2GetBooleanStatus) X(fmi2GetStringStatus)
#else
#define FORWARDED(X)                                                                      \
    X(fmi3EnterConfigurationMode) X(fmi3ExitConfigurationMode) X(fmi3GetFloat32)           \
    X(fmi3GetFloat64) X(fmi3GetInt8) X(fmi3GetUInt8) X(fmi3GetInt16) X(fmi3GetUInt16)      \
    X(fmi3GetInt32) X(fmi3GetUInt32) X(fmi3GetInt64) X(fmi3GetUInt64) X(fmi3GetBoolean)    \
    X(fmi3GetString) X(fmi3GetBinary) X(fmi3GetClock) X(fmi3SetFloat32) X(fmi3SetInt8)     \
    X(fmi3SetUInt8) X(fmi3SetInt16) X(fmi3SetUInt16) X(fmi3SetInt32) X(fmi3SetUInt32)      \
    X(fmi3SetInt64) X(fmi3SetUInt64) X(fmi3SetBoolean) X(fmi3SetString) X(fmi3SetBinary)   \
    X(fmi3SetClock) X(fmi3SetFloat64) X(fmi3GetNumberOfVariableDependencies)               \
    X(fmi3GetVariableDependencies) X(fmi3GetFMUState) X(fmi3SetFMUState)                 \
    X(fmi3FreeFMUState) X(fmi3SerializedFMUStateSize) X(fmi3SerializeFMUState)             \
    X(fmi3DeserializeFMUState) X(fmi3GetDirectionalDerivative)                            \
    X(fmi3GetAdjointDerivative) X(fmi3EvaluateDiscreteStates) X(fmi3UpdateDiscreteStates)  \
    X(fmi3EnterContinuousTimeMode) X(fmi3CompletedIntegratorStep) X(fmi3SetTime)           \
    X(fmi3SetContinuousStates) X(fmi3GetContinuousStateDerivatives)                        \
    X(fmi3GetEventIndicators) X(fmi3GetContinuousStates)                                   \
    X(fmi3GetNominalsOfContinuousStates) X(fmi3GetNumberOfEventIndicators)                 \
    X(fmi3GetNumberOfContinuousStates) X(fmi3EnterStepMode) X(fmi3GetOutputDerivatives)    \
    X(fmi3ActivateModelPartition) X(fmi3GetIntervalDecimal) X(fmi3GetIntervalFraction)     \
    X(fmi3GetShiftDecimal) X(fmi3GetShiftFraction) X(fmi3SetIntervalDecimal)               \
    X(fmi3SetIntervalFraction) X(fmi3SetShiftDecimal) X(fmi3SetShiftFraction)              \
    X(fmi3EnterEventMode)
#endif
FORWARDED(TRAMPOLINE)

/* ---- instances: the wrapper's handle -> what the front keeps about it ----------------- */
typedef struct Instance {
    void *handle;        /* the wrapper's instance (also the importer's handle) */
    int worst;           /* worst status logged during the current call */
    int logging_on;      /* the importer's loggingOn */
    int fatal;           /* the wrapper returned Fatal: never call its FreeInstance */
    char *name;
    void *env;           /* the importer's environment (FMI 2: componentEnvironment) */
    void *importer_logger;
#if FMI_VERSION == 2
    void *callbacks[5];  /* fmi2CallbackFunctions handed to the wrapper (logger replaced) */
#endif
    struct Instance *next;
} Instance;

static Instance *instances;

static Instance *find(void *handle) {
    pthread_mutex_lock(&instances_lock);
    Instance *i = instances;
    while (i && i->handle != handle) i = i->next;
    pthread_mutex_unlock(&instances_lock);
    return i;
}

static void forget(Instance *inst) {
    pthread_mutex_lock(&instances_lock);
    for (Instance **p = &instances; *p; p = &(*p)->next) {
        if (*p == inst) {
            *p = inst->next;
            break;
        }
    }
    pthread_mutex_unlock(&instances_lock);
    free(inst->name);
    free(inst);
}

static int status_of(Instance *inst, int status) {
    int logged = inst->worst > STATUS_ERROR ? STATUS_ERROR : inst->worst;
    if (status == STATUS_FATAL) inst->fatal = 1;
    return status > logged ? status : logged;
}

/* ---- loading Python and the wrapper ---------------------------------------------------- */
static void append(const char *fmt, ...) {
    size_t n = strlen(load_error);
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(load_error + n, sizeof load_error - n, fmt, ap);
    va_end(ap);
}

static void point_python_home_at(const char *libpython) {
    char prefix[PATH_MAX], probe[PATH_MAX + 64];
    if (getenv("PYTHONHOME") || !realpath(libpython, prefix)) return;
    for (int up = 0; up < 2; up++) { /* <prefix>/lib/libpython3.X.so -> <prefix> */
        char *slash = strrchr(prefix, '/');
        if (!slash) return;
        *slash = '\0';
    }
    snprintf(probe, sizeof probe, "%s/lib/python3.%d/os.py", prefix, PY_MINOR);
    if (access(probe, R_OK) == 0) setenv("PYTHONHOME", prefix, 0);
}

static int load_python(void) {
    if (dlsym(RTLD_DEFAULT, "Py_IsInitialized")) return 1; /* a Python host */
    char names[8][PATH_MAX];
    int n = 0;
    const char *env = getenv("CANTRACK_LIBPYTHON");
    if (env && *env) snprintf(names[n++], PATH_MAX, "%s", env);
    snprintf(names[n++], PATH_MAX, "%s", LIBPYTHON_BUILD);
    snprintf(names[n++], PATH_MAX, "libpython3.%d.so.1.0", PY_MINOR);
    snprintf(names[n++], PATH_MAX, "libpython3.%d.so", PY_MINOR);
    for (int i = 0; i < n; i++) {
        void *h = dlopen(names[i], RTLD_NOW | RTLD_GLOBAL);
        if (h) {
            void *sym = dlsym(h, "Py_IsInitialized");
            Dl_info info;
            if (sym && dladdr(sym, &info) && info.dli_fname) point_python_home_at(info.dli_fname);
            return 1;
        }
        append("%s%s", i ? "; " : "", dlerror());
    }
    char head[sizeof load_error + 512];
    snprintf(head, sizeof head,
             MODEL ": the host process has no Python and none could be loaded (tried: %s). Set "
             "CANTRACK_LIBPYTHON to the shared library of a Python 3.%d with numpy (e.g. "
             "<prefix>/lib/libpython3.%d.so); 'cantrack fmu doctor' prints what a host needs",
             load_error, PY_MINOR, PY_MINOR);
    snprintf(load_error, sizeof load_error, "%s", head);
    return 0;
}

static void load(void) {
    if (!load_python()) return;
    Dl_info self;
    char path[PATH_MAX];
    if (!dladdr((void *)&load, &self) || !self.dli_fname) {
        snprintf(load_error, sizeof load_error, MODEL ": cannot locate its own library file");
        return;
    }
    snprintf(path, sizeof path, "%s", self.dli_fname);
    char *slash = strrchr(path, '/');
    snprintf(slash ? slash + 1 : path, sizeof path - (slash ? (size_t)(slash + 1 - path) : 0),
             "%s", REAL_LIBRARY);
    real_lib = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (!real_lib) {
        snprintf(load_error, sizeof load_error, MODEL ": cannot load %s: %s", path, dlerror());
        return;
    }
#define RESOLVE(name)                                  \
    {                                                  \
        void *f = dlsym(real_lib, #name);              \
        if (f) p_##name = f;                           \
    }
    FORWARDED(RESOLVE)
}

static void *real(const char *name) { return real_lib ? dlsym(real_lib, name) : NULL; }

#if FMI_VERSION == 2
/* ======================================= FMI 2 ======================================= */
typedef void (*Logger2)(void *, const char *, int, const char *, const char *, ...);
typedef struct {
    Logger2 logger;
    void *allocateMemory, *freeMemory, *stepFinished;
    void *componentEnvironment;
} Callbacks2;

static char *format(const char *fmt, va_list ap) {
    va_list copy;
    va_copy(copy, ap);
    int n = vsnprintf(NULL, 0, fmt, copy);
    va_end(copy);
    char *text = malloc(n > 0 ? (size_t)n + 1 : 1);
    if (text) vsnprintf(text, (size_t)(n > 0 ? n + 1 : 1), fmt, ap);
    return text;
}

static void importer_log2(Instance *inst, int status, const char *category, const char *text) {
    Logger2 logger = (Logger2)inst->importer_logger;
    if (!logger || !(inst->logging_on || status >= STATUS_WARNING)) return;
    /* the message is a format string (FMI 2): the text with '%' doubled, no arguments, so
       importers that print it as it is show it right too */
    size_t n = 0;
    for (const char *p = text; *p; p++) n += *p == '%' ? 2 : 1;
    char *escaped = malloc(n + 1);
    if (!escaped) return;
    char *q = escaped;
    for (const char *p = text; *p; p++) {
        *q++ = *p;
        if (*p == '%') *q++ = '%';
    }
    *q = '\0';
    logger(inst->env, inst->name, status, category, escaped);
    free(escaped);
}

static void front_logger(void *env, const char *name, int status, const char *category,
                         const char *fmt, ...) {
    (void)name;
    Instance *inst = env;
    if (status > inst->worst) inst->worst = status;
    va_list ap;
    va_start(ap, fmt);
    char *text = format(fmt, ap);
    va_end(ap);
    importer_log2(inst, status, category, text ? text : fmt);
    free(text);
}

EXPORT const char *fmi2GetTypesPlatform(void) { return "default"; }
EXPORT const char *fmi2GetVersion(void) { return "2.0"; }

EXPORT void *fmi2Instantiate(const char *name, int type, const char *guid, const char *resources,
                             const Callbacks2 *callbacks, int visible, int loggingOn) {
    Instance *inst = calloc(1, sizeof *inst);
    if (!inst || !callbacks) return free(inst), NULL;
    inst->name = strdup(name ? name : "");
    inst->env = callbacks->componentEnvironment;
    inst->importer_logger = (void *)callbacks->logger;
    inst->logging_on = loggingOn;
    pthread_once(&load_once, load);
    const char *refusal = type != 1 ? MODEL " is a Co-Simulation FMU: fmi2ModelExchange "
                                            "is not supported" : NULL;
    if (!refusal && !real_lib) refusal = load_error;
    void *(*inst_real)(const char *, int, const char *, const char *, const void *, int, int) =
        refusal ? NULL : real("fmi2Instantiate");
    if (!refusal && !inst_real) refusal = MODEL ": the wrapper has no fmi2Instantiate";
    if (refusal) {
        importer_log2(inst, STATUS_ERROR, "logStatusError", refusal);
        free(inst->name);
        free(inst);
        return NULL;
    }
    Callbacks2 *mine = (Callbacks2 *)inst->callbacks;
    *mine = *callbacks;
    mine->logger = front_logger;
    mine->componentEnvironment = inst;
    inst->handle = inst_real(name, type, guid, resources, mine, visible, 1);
    if (!inst->handle) {
        free(inst->name);
        free(inst);
        return NULL;
    }
    pthread_mutex_lock(&instances_lock);
    inst->next = instances;
    instances = inst;
    pthread_mutex_unlock(&instances_lock);
    return inst->handle;
}

#define CALL2(fname, proto, args)                                                        \
    EXPORT int fname proto {                                                              \
        static void *cached;                                                              \
        if (!cached) cached = real(#fname);                                               \
        Instance *inst = find(c);                                                         \
        int (*f) proto = (int(*) proto)cached;                                            \
        if (!inst || !f) return STATUS_ERROR;                                             \
        if (inst->fatal) return STATUS_ERROR;                                             \
        inst->worst = 0;                                                                  \
        return status_of(inst, f args);                                                   \
    }

CALL2(fmi2ExitInitializationMode, (void *c), (c))
CALL2(fmi2Terminate, (void *c), (c))
CALL2(fmi2Reset, (void *c), (c))
CALL2(fmi2DoStep, (void *c, double t, double h, int noSetPrior), (c, t, h, noSetPrior))

EXPORT int fmi2SetDebugLogging(void *c, int loggingOn, size_t n, const char *const categories[]) {
    Instance *inst = find(c);
    if (!inst) return STATUS_ERROR;
    inst->logging_on = loggingOn; /* the wrapper keeps logging: the front filters */
    (void)n;
    (void)categories;
    return 0;
}

EXPORT void fmi2FreeInstance(void *c) {
    Instance *inst = find(c);
    void (*f)(void *) = (void (*)(void *))real("fmi2FreeInstance");
    if (!inst) return;
    if (f && !inst->fatal) f(c);
    forget(inst);
}

#else
/* ======================================= FMI 3 ======================================= */
typedef void (*LogMessage3)(void *, int, const char *, const char *);

static void importer_log3(Instance *inst, int status, const char *category, const char *text) {
    LogMessage3 logger = (LogMessage3)inst->importer_logger;
    if (logger && (inst->logging_on || status >= STATUS_WARNING))
        logger(inst->env, status, category, text);
}

static void front_log_message(void *env, int status, const char *category, const char *text) {
    Instance *inst = env;
    if (status > inst->worst) inst->worst = status;
    importer_log3(inst, status, category, text);
}

EXPORT const char *fmi3GetVersion(void) { return "3.0"; }

static void refuse3(void *env, void *logMessage, const char *text) {
    if (logMessage) ((LogMessage3)logMessage)(env, STATUS_ERROR, "logStatusError", text);
}

EXPORT void *fmi3InstantiateModelExchange(const char *name, const char *token,
                                          const char *resources, int visible, int loggingOn,
                                          void *env, void *logMessage) {
    (void)name, (void)token, (void)resources, (void)visible, (void)loggingOn;
    refuse3(env, logMessage, MODEL " is a Co-Simulation FMU: Model Exchange is not supported");
    return NULL;
}

EXPORT void *fmi3InstantiateScheduledExecution(const char *name, const char *token,
                                               const char *resources, int visible,
                                               int loggingOn, void *env, void *logMessage,
                                               void *clockUpdate, void *lockPreemption,
                                               void *unlockPreemption) {
    (void)name, (void)token, (void)resources, (void)visible, (void)loggingOn;
    (void)clockUpdate, (void)lockPreemption, (void)unlockPreemption;
    refuse3(env, logMessage,
            MODEL " is a Co-Simulation FMU: Scheduled Execution is not supported");
    return NULL;
}

EXPORT void *fmi3InstantiateCoSimulation(const char *name, const char *token,
                                         const char *resources, int visible, int loggingOn,
                                         int eventModeUsed, int earlyReturnAllowed,
                                         const unsigned int required[], size_t nRequired,
                                         void *env, void *logMessage,
                                         void *intermediateUpdate) {
    if (eventModeUsed) {
        refuse3(env, logMessage, MODEL ": eventModeUsed=true refused: the FMU has no event "
                                       "mode (hasEventMode=false); instantiate it with "
                                       "eventModeUsed=false");
        return NULL;
    }
    pthread_once(&load_once, load);
    void *(*inst_real)(const char *, const char *, const char *, int, int, int, int,
                       const unsigned int[], size_t, void *, void *, void *) =
        real_lib ? real("fmi3InstantiateCoSimulation") : NULL;
    if (!inst_real) {
        refuse3(env, logMessage, real_lib ? MODEL ": the wrapper has no "
                                                  "fmi3InstantiateCoSimulation" : load_error);
        return NULL;
    }
    Instance *inst = calloc(1, sizeof *inst);
    if (!inst) return NULL;
    inst->name = strdup(name ? name : "");
    inst->env = env;
    inst->importer_logger = logMessage;
    inst->logging_on = loggingOn;
    inst->handle = inst_real(name, token, resources, visible, 1, 0, earlyReturnAllowed,
                             required, nRequired, inst, (void *)front_log_message,
                             intermediateUpdate);
    if (!inst->handle) {
        free(inst->name);
        free(inst);
        return NULL;
    }
    pthread_mutex_lock(&instances_lock);
    inst->next = instances;
    instances = inst;
    pthread_mutex_unlock(&instances_lock);
    return inst->handle;
}

#define CALL3(fname, proto, args)                                                        \
    EXPORT int fname proto {                                                              \
        static void *cached;                                                              \
        if (!cached) cached = real(#fname);                                               \
        Instance *inst = find(c);                                                         \
        int (*f) proto = (int(*) proto)cached;                                            \
        if (!inst || !f) return STATUS_ERROR;                                             \
        if (inst->fatal) return STATUS_ERROR;                                             \
        inst->worst = 0;                                                                  \
        return status_of(inst, f args);                                                   \
    }

CALL3(fmi3ExitInitializationMode, (void *c), (c))
CALL3(fmi3Terminate, (void *c), (c))
CALL3(fmi3Reset, (void *c), (c))
CALL3(fmi3DoStep,
      (void *c, double t, double h, int noSetPrior, int *eventHandlingNeeded,
       int *terminateSimulation, int *earlyReturn, double *lastSuccessfulTime),
      (c, t, h, noSetPrior, eventHandlingNeeded, terminateSimulation, earlyReturn,
       lastSuccessfulTime))

EXPORT int fmi3EnterInitializationMode(void *c, int toleranceDefined, double tolerance,
                                       double startTime, int stopTimeDefined, double stopTime) {
    Instance *inst = find(c);
    int (*enter)(void *, int, double, double, int, double) =
        (int (*)(void *, int, double, double, int, double))real("fmi3EnterInitializationMode");
    int (*set)(void *, const unsigned int *, size_t, const double *, size_t) =
        (int (*)(void *, const unsigned int *, size_t, const double *, size_t))real(
            "fmi3SetFloat64");
    if (!inst || !enter || inst->fatal) return STATUS_ERROR;
    inst->worst = 0;
    const unsigned int vr_time = VR_TIME;
    int status = set ? set(c, &vr_time, 1, &startTime, 1) : 0;
    if (status > STATUS_WARNING) return status_of(inst, status);
    return status_of(inst, enter(c, toleranceDefined, tolerance, startTime, stopTimeDefined,
                                 stopTime));
}

EXPORT int fmi3SetDebugLogging(void *c, int loggingOn, size_t n, const char *const categories[]) {
    Instance *inst = find(c);
    if (!inst) return STATUS_ERROR;
    inst->logging_on = loggingOn; /* the wrapper keeps logging: the front filters */
    (void)n;
    (void)categories;
    return 0;
}

EXPORT void fmi3FreeInstance(void *c) {
    Instance *inst = find(c);
    void (*f)(void *) = (void (*)(void *))real("fmi3FreeInstance");
    if (!inst) return;
    if (f && !inst->fatal) f(c);
    forget(inst);
}
#endif
