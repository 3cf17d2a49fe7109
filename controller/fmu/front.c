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
 *    when <prefix>/lib/python3.X/os.py exists.  There neither library is unloaded (Python
 *    cannot be initialised again after finalising once numpy was imported); in a Python
 *    host the wrapper is unloaded with the front;
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
 * 6. keeps the inputs and outputs of the trackers (N_IN, N_OUT > 0) and moves them to and
 *    from the Python engine's value list (engine.TrackerEngine.v) itself, through Python's
 *    C API with the GIL held: after initialisation setting inputs only stores them and
 *    getting outputs reads the front's copy, in C, so a co-simulation step is one call into
 *    Python (doStep: the inputs set since the last step go into the list before it, all
 *    outputs are read from it after it).  The list's address comes from Python once per
 *    Python instance (a get of the private reference VALUE_LIST_VR, engine.VALUE_LIST_VR),
 *    the front holds a reference to it.  Inputs are stored as Python's own setters store
 *    them (a float; a bool for Booleans), outputs read as doubles (the integer outputs fit
 *    exactly): the values are the same.  Before any other call into Python the inputs set
 *    since the last step go into the list too, so FMU states and pass-through gets see
 *    every value; a set the front does not keep (inputs mixed with parameters) goes to
 *    Python and into the front's copy; after exitInitializationMode and SetFMUState the
 *    front reads the inputs back.  The importer's references from PRIVATE_BASE on are
 *    refused.  Where the list cannot be had (Python's C API not found), every call goes to
 *    Python as it is.  FMI 2: the front calls the engine's step itself (fmi2DoStep), not
 *    through the wrapper's doStep; FMI 3 steps through pythonfmu3's.
 * 7. resets the wrapper's Python state at exit before the wrapper's own exit handlers do, in a
 *    Python host (see release_wrapper_state: pythonfmu's use-after-free at exit).
 * Every other FMI function jumps straight into the wrapper (an x86_64 trampoline, no cost).
 *
 * Compile-time definitions (set by the build): FMI_VERSION (2 or 3), MODEL (model
 * identifier), REAL_LIBRARY (file name of the wrapper), LIBPYTHON_BUILD (path), PY_MINOR
 * (X of 3.X of the building Python), VR_TIME (FMI 3), PRIVATE_BASE, VALUE_LIST_VR,
 * N_VARIABLES (the list's length), N_IN, IN_VRS, IN_TYPES, N_OUT, OUT_VRS, OUT_TYPES (the
 * kept variables: value references = positions in the list, types r/i/b).
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <limits.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#ifndef N_IN /* no shared variables (CanConveyor) */
#define N_IN 0
#define IN_VRS {0}
#define IN_TYPES ""
#define N_OUT 0
#define OUT_VRS {0}
#define OUT_TYPES ""
#define PRIVATE_BASE 0
#define VALUE_LIST_VR 0
#define N_VARIABLES 0
#endif
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
    X(fmi2SetupExperiment) X(fmi2EnterInitializationMode) X(fmi2GetString)                \
    X(fmi2SetString) X(fmi2FreeFMUstate)                                                  \
    X(fmi2SerializedFMUstateSize) X(fmi2SerializeFMUstate) X(fmi2DeSerializeFMUstate)      \
    X(fmi2GetDirectionalDerivative) X(fmi2SetRealInputDerivatives)                        \
    X(fmi2GetRealOutputDerivatives) X(fmi2CancelStep) X(fmi2GetStatus) X(fmi2GetRealStatus) \
    X(fmi2GetIntegerStatus) X(fmi2GetBooleanStatus) X(fmi2GetStringStatus)
#else
#define FORWARDED(X)                                                                      \
    X(fmi3EnterConfigurationMode) X(fmi3ExitConfigurationMode) X(fmi3GetFloat32)           \
    X(fmi3GetInt8) X(fmi3GetUInt8) X(fmi3GetInt16) X(fmi3GetUInt16)                        \
    X(fmi3GetUInt32) X(fmi3GetInt64) X(fmi3GetUInt64)                                      \
    X(fmi3GetString) X(fmi3GetBinary) X(fmi3GetClock) X(fmi3SetFloat32) X(fmi3SetInt8)     \
    X(fmi3SetUInt8) X(fmi3SetInt16) X(fmi3SetUInt16) X(fmi3SetUInt32)                     \
    X(fmi3SetUInt64) X(fmi3SetString) X(fmi3SetBinary)                                    \
    X(fmi3SetClock) X(fmi3GetNumberOfVariableDependencies)                                 \
    X(fmi3GetVariableDependencies)                                                         \
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
    /* the shared variables (see 6. above) */
    int io_on;           /* after a successful exitInitializationMode */
    int terminated;      /* after fmiXTerminate: setters refused (until reset) */
    int step_failed;     /* FMI 2: an exception escaped the engine's step: steps refused
                            (until reset or SetFMUstate), the tracker may be half updated */
    int n_dirty;         /* inputs set since Python last got them */
    int out_valid;       /* out_value holds Python's current outputs */
    char in_dirty[N_IN + 1];
    double in_value[N_IN + 1];
    double out_value[N_OUT + 1];
    void *values;        /* the engine's value list (a PyObject *, a reference held) */
    void *step_fn;       /* FMI 2: the engine's do_step (a reference held), see fmi2DoStep */
    void *log_queue;     /* FMI 2: the wrapper's log queue (a reference held) */
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

static void log_error(Instance *inst, const char *text);

/* FMI: after Terminate only getters, reset and free are allowed */
static int refuse_if_terminated(Instance *inst, const char *function) {
    if (!inst->terminated) return 0;
    char text[256];
    snprintf(text, sizeof text, "%s: %s refused: the instance is terminated (only get "
             "values, reset or free it)", inst->name, function);
    log_error(inst, text);
    return 1;
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

/* the front loaded libpython (a host without Python): then the wrapper stays loaded */
static int loaded_python;

static int load_python(void) {
    if (dlsym(RTLD_DEFAULT, "Py_IsInitialized")) return 1; /* a Python host */
    loaded_python = 1;
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

/* pythonfmu's wrapper (0.7.0, PySlaveInstance.cpp) keeps its Python state in a global
 * std::shared_ptr (pyState) and resets it again from a destructor function
 * (onLibraryUnload -> finalizePythonInterpreter: pyState = nullptr).  The wrapper cannot be
 * unloaded (it defines GNU unique symbols, so dlclose keeps it), so it is still loaded at
 * exit(), where the exit handlers run the shared_ptr's static destructor first (the state
 * freed) and the loader's fini then runs the destructor function on the destroyed shared_ptr:
 * it decrements the use count in the freed block (valgrind: an invalid read in
 * finalizePythonInterpreter of a block freed by __run_exit_handlers, allocated in
 * createInstance), which corrupts the heap when glibc has reused the chunk or put it in a
 * bin (an abort "corrupted double-linked list" at exit, seen once).  This exit handler is
 * registered after the wrapper was loaded, so it runs before the wrapper's (last in, first
 * out): it resets the state while it is alive and both later resets find it empty.  Only
 * in a Python host with no instance left: where the front started Python (a C host) the
 * state's release finalises it, which a front unloaded early (dlclose runs this handler
 * then) must not do. */
static void release_wrapper_state(void) {
    if (!real_lib || loaded_python || instances) return;
    void (*reset)(void) = (void (*)(void))dlsym(real_lib, "finalizePythonInterpreter");
    if (reset) reset();
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
    atexit(release_wrapper_state);
#define RESOLVE(name)                                  \
    {                                                  \
        void *f = dlsym(real_lib, #name);              \
        if (f) p_##name = f;                           \
    }
    FORWARDED(RESOLVE)
}

static void *real(const char *name) { return real_lib ? dlsym(real_lib, name) : NULL; }

/* The front is unloaded (dlclose): in a Python host the wrapper goes with it, as it would
 * without the front (a process that loads many FMU copies does not accumulate them).  In
 * a host without Python it stays: unloading it would finalise the Python it started, and
 * Python cannot be initialised again once numpy was imported. */
__attribute__((destructor)) static void unload(void) {
    if (real_lib && !loaded_python && !instances) dlclose(real_lib);
}

/* ---- shared variables (see 6. above) -------------------------------------------------- */
static const unsigned int in_vrs[N_IN + 1] = IN_VRS;
static const char in_types[] = IN_TYPES;
static const unsigned int out_vrs[N_OUT + 1] = OUT_VRS;
static const char out_types[] = OUT_TYPES;

static int position(const unsigned int *vrs, const char *types, int n, unsigned int vr,
                    char type) {
    for (int i = 0; i < n; i++)
        if (vrs[i] == vr && types[i] == type) return i;
    return -1;
}

static double input_value(size_t i, const double *reals, const int *ints,
                          const unsigned char *bools) {
    return reals ? reals[i] : ints ? (double)ints[i] : bools[i] ? 1.0 : 0.0;
}

/* all of vr[0..n) are cached inputs of ``type``: store the values (doubles), mark them */
static int cache_inputs(Instance *inst, const unsigned int *vr, size_t n, char type,
                        const double *reals, const int *ints, const unsigned char *bools) {
    if (!inst->io_on || n > N_IN) return 0;
    int pos[N_IN + 1];
    for (size_t i = 0; i < n; i++)
        if ((pos[i] = position(in_vrs, in_types, N_IN, vr[i], type)) < 0) return 0;
    for (size_t i = 0; i < n; i++) {
        inst->in_value[pos[i]] = input_value(i, reals, ints, bools);
        if (!inst->in_dirty[pos[i]]) {
            inst->in_dirty[pos[i]] = 1;
            inst->n_dirty++;
        }
    }
    return 1;
}

/* a set the cache does not take (some of vr[0..n) are not cached inputs) goes to Python
   as it is: the cached inputs among them are copied too, so the shared block stays equal
   to Python's inputs */
static void mirror_inputs(Instance *inst, const unsigned int *vr, size_t n, char type,
                          const double *reals, const int *ints, const unsigned char *bools) {
    if (!inst->io_on) return;
    for (size_t i = 0; i < n; i++) {
        int pos = position(in_vrs, in_types, N_IN, vr[i], type);
        if (pos < 0) continue;
        double x = input_value(i, reals, ints, bools);
        inst->in_value[pos] = type == 'b' ? x != 0.0 : x; /* FMI 2 Booleans are ints */
    }
}

/* an importer's value reference from PRIVATE_BASE on (the front's): refused, never passed
   to Python */
static int private_reference(Instance *inst, const unsigned int *vr, size_t n,
                             const char *function) {
#if N_IN + N_OUT > 0
    for (size_t i = 0; i < n; i++) {
        if (vr[i] < PRIVATE_BASE) continue;
        char text[256];
        snprintf(text, sizeof text, "%s: %s refused: valueReference %u is not a variable of "
                 MODEL, inst->name, function, vr[i]);
        log_error(inst, text);
        return 1;
    }
#else
    (void)inst, (void)vr, (void)n, (void)function;
#endif
    return 0;
}

/* the wrapper's get of doubles (fmi2GetReal, fmi3GetFloat64) */
static int wrapper_get_doubles(Instance *inst, const unsigned int *vr, size_t n,
                               double *values);

/* ---- the engine's value list through Python's C API (the stable ABI's functions, found
   in the process: the host's Python or the one the front loaded) ------------------------ */
typedef struct PyObject PyObject;
static struct {
    int (*GILState_Ensure)(void);
    void (*GILState_Release)(int);
    PyObject *(*Float_FromDouble)(double);
    double (*Float_AsDouble)(PyObject *);
    PyObject *(*Bool_FromLong)(long);
    PyObject *(*Long_FromLong)(long);
    int (*List_SetItem)(PyObject *, ssize_t, PyObject *);
    PyObject *(*List_GetItem)(PyObject *, ssize_t);
    ssize_t (*List_Size)(PyObject *);
    void (*IncRef)(PyObject *);
    void (*DecRef)(PyObject *);
    PyObject *(*Err_Occurred)(void);
    void (*Err_Clear)(void);
    void (*Err_WriteUnraisable)(PyObject *);
    PyObject *(*Vectorcall)(PyObject *, PyObject *const *, size_t, PyObject *);
    long (*Long_AsLong)(PyObject *);
    int (*Callable_Check)(PyObject *);
    int ok;
} py;
static pthread_once_t py_once = PTHREAD_ONCE_INIT;

static void resolve_python_api(void) {
    int ok = 1;
#define PY_API(field, name) ok &= (*(void **)&py.field = dlsym(RTLD_DEFAULT, name)) != NULL;
    PY_API(GILState_Ensure, "PyGILState_Ensure")
    PY_API(GILState_Release, "PyGILState_Release")
    PY_API(Float_FromDouble, "PyFloat_FromDouble")
    PY_API(Float_AsDouble, "PyFloat_AsDouble")
    PY_API(Bool_FromLong, "PyBool_FromLong")
    PY_API(Long_FromLong, "PyLong_FromLong")
    PY_API(List_SetItem, "PyList_SetItem")
    PY_API(List_GetItem, "PyList_GetItem")
    PY_API(List_Size, "PyList_Size")
    PY_API(IncRef, "Py_IncRef")
    PY_API(DecRef, "Py_DecRef")
    PY_API(Err_Occurred, "PyErr_Occurred")
    PY_API(Err_Clear, "PyErr_Clear")
    PY_API(Err_WriteUnraisable, "PyErr_WriteUnraisable")
    PY_API(Vectorcall, "PyObject_Vectorcall")
    PY_API(Long_AsLong, "PyLong_AsLong")
    PY_API(Callable_Check, "PyCallable_Check")
#undef PY_API
    py.ok = ok;
}

/* the inputs set since the last transfer into the list, as Python's setters store them
   (GIL held); 0, or Error if Python refused (no memory) */
static int push_inputs(Instance *inst) {
    int status = 0;
    for (int i = 0; i < N_IN; i++) {
        if (!inst->in_dirty[i]) continue;
        inst->in_dirty[i] = 0;
        double x = inst->in_value[i];
        PyObject *item = in_types[i] == 'r' ? py.Float_FromDouble(x)
                         : in_types[i] == 'b' ? py.Bool_FromLong(x != 0.0)
                                              : py.Long_FromLong((long)x);
        if (!item || py.List_SetItem(inst->values, in_vrs[i], item) != 0) status = STATUS_ERROR;
    }
    inst->n_dirty = 0;
    if (status) py.Err_Clear();
    return status;
}

/* n values of the list at vrs into out, as doubles (GIL held); 0 or Error */
static int read_values(Instance *inst, const unsigned int *vrs, int n, double *out) {
    for (int i = 0; i < n; i++) {
        PyObject *item = py.List_GetItem(inst->values, vrs[i]);
        double x = item ? py.Float_AsDouble(item) : -1.0;
        if (x == -1.0 && py.Err_Occurred()) {
            py.Err_Clear();
            return STATUS_ERROR;
        }
        out[i] = x;
    }
    return 0;
}

/* before a call into Python other than doStep: the set inputs go into the list */
static int flush(Instance *inst) {
    if (!inst->n_dirty || !inst->values) return 0;
    int gil = py.GILState_Ensure();
    int status = push_inputs(inst);
    py.GILState_Release(gil);
    return status;
}

/* the outputs from the list (the first get after a call that may have changed them) */
static int fetch(Instance *inst) {
    int gil = py.GILState_Ensure();
    int status = read_values(inst, out_vrs, N_OUT, inst->out_value);
    py.GILState_Release(gil);
    inst->out_valid = status == 0;
    return status;
}

/* the inputs from the list (after exitInitializationMode, SetFMUState) */
static int fetch_inputs(Instance *inst) {
    int gil = py.GILState_Ensure();
    int status = read_values(inst, in_vrs, N_IN, inst->in_value);
    py.GILState_Release(gil);
    return status;
}

static void detach(Instance *inst) {
    if (!inst->values) return;
    int gil = py.GILState_Ensure();
    py.DecRef(inst->values);
    if (inst->step_fn) py.DecRef(inst->step_fn);
    if (inst->log_queue) py.DecRef(inst->log_queue);
    py.GILState_Release(gil);
    inst->values = inst->step_fn = inst->log_queue = NULL;
}

/* from a get of the private references (the objects' addresses as doubles): the engine's
   value list (VALUE_LIST_VR, checked to be a list of N_VARIABLES), and for FMI 2 its step
   function and the wrapper's log queue (VALUE_LIST_VR + 1, + 2; see fmi2DoStep); without
   the list every call goes to Python */
static void attach(Instance *inst) {
    if (N_IN + N_OUT == 0) return;
    detach(inst);
    pthread_once(&py_once, resolve_python_api);
    if (!py.ok) return;
    const unsigned int vrs[3] = {VALUE_LIST_VR, VALUE_LIST_VR + 1, VALUE_LIST_VR + 2};
    double address[3] = {0.0, 0.0, 0.0};
    size_t n = FMI_VERSION == 2 ? 3 : 1;
    inst->worst = 0;
    /* a warning is no reason to go without the list: the slave's instantiation warning
       (e.g. ruckig cannot be imported) is delivered during this get */
    if (wrapper_get_doubles(inst, vrs, n, address) > STATUS_WARNING ||
        inst->worst > STATUS_WARNING || address[0] <= 0.0)
        return;
    PyObject *list = (PyObject *)(uintptr_t)address[0];
    PyObject *step = n == 3 ? (PyObject *)(uintptr_t)address[1] : NULL;
    PyObject *queue = n == 3 ? (PyObject *)(uintptr_t)address[2] : NULL;
    int gil = py.GILState_Ensure();
    if (py.List_Size(list) == N_VARIABLES) {
        py.IncRef(list);
        inst->values = list;
        if (step && queue && py.Callable_Check(step) && py.List_Size(queue) >= 0) {
            py.IncRef(step);
            py.IncRef(queue);
            inst->step_fn = step, inst->log_queue = queue;
        }
    }
    py.Err_Clear();
    py.GILState_Release(gil);
}

/* doStep with the list: the set inputs into it, the step, every output out of it, the GIL
   held throughout (the wrapper's own PyGILState_Ensure nests) */
#define STEP(inst, call)                                                                  \
    do {                                                                                  \
        if (inst->values && inst->io_on) {                                                \
            int gil = py.GILState_Ensure();                                               \
            int pushed = push_inputs(inst);                                               \
            if (pushed) {                                                                 \
                py.GILState_Release(gil);                                                 \
                return pushed;                                                            \
            }                                                                             \
            inst->worst = 0;                                                              \
            int stepped = status_of(inst, call);                                          \
            inst->out_valid = read_values(inst, out_vrs, N_OUT, inst->out_value) == 0;    \
            py.GILState_Release(gil);                                                     \
            return stepped;                                                               \
        }                                                                                 \
        inst->out_valid = 0;                                                              \
        PASS_THROUGH(inst, call);                                                         \
    } while (0)

/* after a call that may have changed Python's inputs and outputs */
static int resync(Instance *inst, int status) {
    inst->out_valid = 0;
    if (inst->io_on && status <= STATUS_WARNING) {
        int fetched = fetch_inputs(inst);
        if (fetched > status) status = fetched;
    }
    return status;
}

/* positions of vr[0..n) among the cached outputs of ``type``, or 0 if one is not */
static int cached_outputs(Instance *inst, const unsigned int *vr, size_t n, char type,
                          int *pos) {
    if (!inst->io_on || n > N_OUT) return 0;
    for (size_t i = 0; i < n; i++)
        if ((pos[i] = position(out_vrs, out_types, N_OUT, vr[i], type)) < 0) return 0;
    return 1;
}

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

static void log_error(Instance *inst, const char *text) {
    importer_log2(inst, STATUS_ERROR, "logStatusError", text);
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
    attach(inst);
    return inst->handle;
}


/* the wrapper's functions the front calls (resolved on first use) */
typedef int (*SetReal2)(void *, const unsigned int *, size_t, const double *);
typedef int (*SetInt2)(void *, const unsigned int *, size_t, const int *);
typedef int (*GetReal2)(void *, const unsigned int *, size_t, double *);
typedef int (*GetInt2)(void *, const unsigned int *, size_t, int *);
typedef int (*Call2)(void *);
typedef int (*State2)(void *, void *);
#define WRAPPED(type, name) ((type)wrapped(&w_##name, #name))
static void *w_fmi2SetReal, *w_fmi2SetInteger, *w_fmi2SetBoolean, *w_fmi2GetReal,
    *w_fmi2GetInteger, *w_fmi2GetBoolean, *w_fmi2GetFMUstate, *w_fmi2SetFMUstate,
    *w_fmi2DoStep, *w_fmi2ExitInitializationMode, *w_fmi2Terminate, *w_fmi2Reset;
static void *wrapped(void **slot, const char *name) {
    if (!*slot) *slot = real(name);
    return *slot;
}

static int wrapper_get_doubles(Instance *inst, const unsigned int *vr, size_t n,
                               double *values) {
    return WRAPPED(GetReal2, fmi2GetReal)(inst->handle, vr, n, values);
}

/* the instance of c, or NULL (then the call returns Error) */
static Instance *usable(void *c) {
    Instance *inst = find(c);
    return inst && !inst->fatal && real_lib ? inst : NULL;
}

/* before a call the cache cannot serve: the set inputs go to Python first */
#define PASS_THROUGH(inst, call)                                                          \
    do {                                                                                  \
        int flushed = flush(inst);                                                        \
        if (flushed > STATUS_WARNING) return flushed;                                     \
        inst->worst = 0;                                                                  \
        return status_of(inst, call);                                                     \
    } while (0)

EXPORT int fmi2SetReal(void *c, const unsigned int vr[], size_t n, const double value[]) {
    Instance *inst = usable(c);
    if (!inst) return STATUS_ERROR;
    if (refuse_if_terminated(inst, "fmi2SetReal")) return STATUS_ERROR;
    if (cache_inputs(inst, vr, n, 'r', value, NULL, NULL)) return 0;
    if (private_reference(inst, vr, n, "fmi2SetReal")) return STATUS_ERROR;
    inst->out_valid = 0;
    mirror_inputs(inst, vr, n, 'r', value, NULL, NULL);
    PASS_THROUGH(inst, WRAPPED(SetReal2, fmi2SetReal)(c, vr, n, value));
}

EXPORT int fmi2SetInteger(void *c, const unsigned int vr[], size_t n, const int value[]) {
    Instance *inst = usable(c);
    if (!inst) return STATUS_ERROR;
    if (refuse_if_terminated(inst, "fmi2SetInteger")) return STATUS_ERROR;
    if (cache_inputs(inst, vr, n, 'i', NULL, value, NULL)) return 0;
    if (private_reference(inst, vr, n, "fmi2SetInteger")) return STATUS_ERROR;
    inst->out_valid = 0;
    mirror_inputs(inst, vr, n, 'i', NULL, value, NULL);
    PASS_THROUGH(inst, WRAPPED(SetInt2, fmi2SetInteger)(c, vr, n, value));
}

EXPORT int fmi2SetBoolean(void *c, const unsigned int vr[], size_t n, const int value[]) {
    Instance *inst = usable(c);
    if (!inst) return STATUS_ERROR;
    if (refuse_if_terminated(inst, "fmi2SetBoolean")) return STATUS_ERROR;
    if (inst->io_on && n <= N_IN) {
        unsigned char b[N_IN + 1];
        for (size_t i = 0; i < n; i++) b[i] = value[i] != 0;
        if (cache_inputs(inst, vr, n, 'b', NULL, NULL, b)) return 0;
    }
    if (private_reference(inst, vr, n, "fmi2SetBoolean")) return STATUS_ERROR;
    inst->out_valid = 0;
    mirror_inputs(inst, vr, n, 'b', NULL, value, NULL);
    PASS_THROUGH(inst, WRAPPED(SetInt2, fmi2SetBoolean)(c, vr, n, value));
}

EXPORT int fmi2GetReal(void *c, const unsigned int vr[], size_t n, double value[]) {
    Instance *inst = usable(c);
    int pos[N_OUT + 1];
    if (!inst) return STATUS_ERROR;
    if (cached_outputs(inst, vr, n, 'r', pos)) {
        int status = inst->out_valid ? 0 : fetch(inst);
        if (status > STATUS_WARNING) return status;
        for (size_t i = 0; i < n; i++) value[i] = inst->out_value[pos[i]];
        return 0;
    }
    if (private_reference(inst, vr, n, "fmi2GetReal")) return STATUS_ERROR;
    PASS_THROUGH(inst, WRAPPED(GetReal2, fmi2GetReal)(c, vr, n, value));
}

static int get_ints2(void *c, const unsigned int vr[], size_t n, int value[], char type,
                     void **slot, const char *name) {
    Instance *inst = usable(c);
    int pos[N_OUT + 1];
    if (!inst) return STATUS_ERROR;
    if (cached_outputs(inst, vr, n, type, pos)) {
        int status = inst->out_valid ? 0 : fetch(inst);
        if (status > STATUS_WARNING) return status;
        for (size_t i = 0; i < n; i++)
            value[i] = type == 'b' ? inst->out_value[pos[i]] != 0.0
                                   : (int)inst->out_value[pos[i]];
        return 0;
    }
    if (private_reference(inst, vr, n, name)) return STATUS_ERROR;
    PASS_THROUGH(inst, ((GetInt2)wrapped(slot, name))(c, vr, n, value));
}

EXPORT int fmi2GetInteger(void *c, const unsigned int vr[], size_t n, int value[]) {
    return get_ints2(c, vr, n, value, 'i', &w_fmi2GetInteger, "fmi2GetInteger");
}

EXPORT int fmi2GetBoolean(void *c, const unsigned int vr[], size_t n, int value[]) {
    return get_ints2(c, vr, n, value, 'b', &w_fmi2GetBoolean, "fmi2GetBoolean");
}

EXPORT int fmi2GetFMUstate(void *c, void *state) {
    Instance *inst = usable(c);
    if (!inst) return STATUS_ERROR;
    PASS_THROUGH(inst, WRAPPED(State2, fmi2GetFMUstate)(c, state));
}

EXPORT int fmi2SetFMUstate(void *c, void *state) {
    Instance *inst = usable(c);
    if (!inst) return STATUS_ERROR;
    inst->out_valid = 0;
    int flushed = flush(inst);
    if (flushed > STATUS_WARNING) return flushed;
    inst->worst = 0;
    int status = status_of(inst, WRAPPED(State2, fmi2SetFMUstate)(c, state));
    if (status <= STATUS_WARNING) inst->step_failed = 0; /* the engine's whole state restored */
    return resync(inst, status);
}

/* The engine's do_step called directly (GIL held): it returns the FMI status (OK, Discard,
   Error) and catches its own exceptions, as the slave's do_step that the wrapper would call
   does; the wrapper's path around it (a method looked up by name, its arguments built from
   a format, its log queue read back) costs more than the call itself.  Messages the step
   logged are in the wrapper's queue: a get of no values lets the wrapper hand them to the
   front's logger (and so to the call's status) as after any of its calls.
   An exception that escapes the engine (any BaseException: SystemExit, KeyboardInterrupt
   too, which the engine's own guard does not catch) goes to sys.unraisablehook (its
   traceback on stderr; PyErr_Print would end the host on SystemExit), the step is Error
   and later steps are refused until reset or SetFMUstate: the engine did not mark itself
   failed and its tracker may be half updated. */
static int direct_step2(Instance *inst, double t, double h) {
    PyObject *args[2] = {py.Float_FromDouble(t), py.Float_FromDouble(h)};
    PyObject *result = args[0] && args[1] ? py.Vectorcall(inst->step_fn, args, 2, NULL) : NULL;
    if (args[0]) py.DecRef(args[0]);
    if (args[1]) py.DecRef(args[1]);
    long code = result ? py.Long_AsLong(result) : -1;
    if (result) py.DecRef(result);
    int status;
    if (code >= 0 && code <= STATUS_ERROR) {
        status = (int)code;
    } else {
        if (py.Err_Occurred()) py.Err_WriteUnraisable(inst->step_fn);
        log_error(inst, MODEL ": doStep: the engine raised an exception (printed on stderr); "
                        "later steps are refused until reset or a saved FMU state is set");
        inst->step_failed = 1;
        status = STATUS_ERROR;
    }
    if (py.List_Size(inst->log_queue) > 0) {
        unsigned int none = 0;
        double nothing = 0.0;
        WRAPPED(GetReal2, fmi2GetReal)(inst->handle, &none, 0, &nothing);
    }
    return status;
}

EXPORT int fmi2DoStep(void *c, double t, double h, int noSetPrior) {
    Instance *inst = usable(c);
    if (!inst) return STATUS_ERROR;
    if (inst->step_failed) {
        char text[320];
        snprintf(text, sizeof text, "%s: fmi2DoStep at t=%.17g s refused: an earlier step "
                 "raised an exception out of the engine (printed on stderr), its state may be "
                 "half updated (reset the instance or set a saved FMU state)", inst->name, t);
        log_error(inst, text);
        return STATUS_ERROR;
    }
    if (inst->step_fn && inst->io_on)   /* (attach sets step_fn only with the list: STEP's
                                            list path, which returns) */
        STEP(inst, direct_step2(inst, t, h));
    STEP(inst, ((int (*)(void *, double, double, int))wrapped(&w_fmi2DoStep, "fmi2DoStep"))(
                   c, t, h, noSetPrior));
}

EXPORT int fmi2ExitInitializationMode(void *c) {
    Instance *inst = usable(c);
    if (!inst) return STATUS_ERROR;
    inst->worst = 0;
    int status = status_of(inst, WRAPPED(Call2, fmi2ExitInitializationMode)(c));
    inst->io_on = status <= STATUS_WARNING && inst->values != NULL;
    return resync(inst, status);
}

EXPORT int fmi2Terminate(void *c) {
    Instance *inst = usable(c);
    if (!inst) return STATUS_ERROR;
    int flushed = flush(inst);
    if (flushed > STATUS_WARNING) return flushed;
    inst->worst = 0;
    int status = status_of(inst, WRAPPED(Call2, fmi2Terminate)(c));
    if (status <= STATUS_WARNING) inst->terminated = 1;
    return status;
}

EXPORT int fmi2Reset(void *c) {
    Instance *inst = usable(c);
    if (!inst) return STATUS_ERROR;
    inst->io_on = inst->out_valid = inst->n_dirty = inst->terminated = 0;
    memset(inst->in_dirty, 0, sizeof inst->in_dirty);
    inst->worst = 0;
    int status = status_of(inst, WRAPPED(Call2, fmi2Reset)(c));
    if (status <= STATUS_WARNING) inst->step_failed = 0;
    if (status <= STATUS_WARNING) attach(inst); /* the wrapper made a new Python instance */
    return status;
}
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
    detach(inst);
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

static void log_error(Instance *inst, const char *text) {
    importer_log3(inst, STATUS_ERROR, "logStatusError", text);
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
    attach(inst);
    return inst->handle;
}


/* the wrapper's functions the front calls (resolved on first use) */
typedef int (*SetF64)(void *, const unsigned int *, size_t, const double *, size_t);
typedef int (*GetF64)(void *, const unsigned int *, size_t, double *, size_t);
typedef int (*SetI32)(void *, const unsigned int *, size_t, const int *, size_t);
typedef int (*GetI32)(void *, const unsigned int *, size_t, int *, size_t);
typedef int (*SetB3)(void *, const unsigned int *, size_t, const unsigned char *, size_t);
typedef int (*GetB3)(void *, const unsigned int *, size_t, unsigned char *, size_t);
typedef int (*Call3)(void *);
typedef int (*State3)(void *, void *);
#define WRAPPED(type, name) ((type)wrapped(&w_##name, #name))
static void *w_fmi3SetFloat64, *w_fmi3GetFloat64, *w_fmi3SetInt32, *w_fmi3GetInt32,
    *w_fmi3SetBoolean, *w_fmi3GetBoolean, *w_fmi3GetFMUState, *w_fmi3SetFMUState,
    *w_fmi3DoStep, *w_fmi3ExitInitializationMode, *w_fmi3EnterInitializationMode,
    *w_fmi3Terminate, *w_fmi3Reset;
static void *wrapped(void **slot, const char *name) {
    if (!*slot) *slot = real(name);
    return *slot;
}

static int wrapper_get_doubles(Instance *inst, const unsigned int *vr, size_t n,
                               double *values) {
    return WRAPPED(GetF64, fmi3GetFloat64)(inst->handle, vr, n, values, n);
}

static Instance *usable(void *c) {
    Instance *inst = find(c);
    return inst && !inst->fatal && real_lib ? inst : NULL;
}

#define PASS_THROUGH(inst, call)                                                          \
    do {                                                                                  \
        int flushed = flush(inst);                                                        \
        if (flushed > STATUS_WARNING) return flushed;                                     \
        inst->worst = 0;                                                                  \
        return status_of(inst, call);                                                     \
    } while (0)

EXPORT int fmi3SetFloat64(void *c, const unsigned int vr[], size_t n, const double value[],
                          size_t nValues) {
    Instance *inst = usable(c);
    if (!inst) return STATUS_ERROR;
    if (refuse_if_terminated(inst, "fmi3SetFloat64")) return STATUS_ERROR;
    if (n == nValues && cache_inputs(inst, vr, n, 'r', value, NULL, NULL)) return 0;
    if (private_reference(inst, vr, n, "fmi3SetFloat64")) return STATUS_ERROR;
    inst->out_valid = 0;
    if (n == nValues) mirror_inputs(inst, vr, n, 'r', value, NULL, NULL);
    PASS_THROUGH(inst, WRAPPED(SetF64, fmi3SetFloat64)(c, vr, n, value, nValues));
}

EXPORT int fmi3SetInt32(void *c, const unsigned int vr[], size_t n, const int value[],
                        size_t nValues) {
    Instance *inst = usable(c);
    if (!inst) return STATUS_ERROR;
    if (refuse_if_terminated(inst, "fmi3SetInt32")) return STATUS_ERROR;
    if (n == nValues && cache_inputs(inst, vr, n, 'i', NULL, value, NULL)) return 0;
    if (private_reference(inst, vr, n, "fmi3SetInt32")) return STATUS_ERROR;
    inst->out_valid = 0;
    if (n == nValues) mirror_inputs(inst, vr, n, 'i', NULL, value, NULL);
    PASS_THROUGH(inst, WRAPPED(SetI32, fmi3SetInt32)(c, vr, n, value, nValues));
}

EXPORT int fmi3SetInt64(void *c, const unsigned int vr[], size_t n, const long long value[],
                        size_t nValues) {  /* Enumerations (mode): not cached, statuses */
    static void *w;
    Instance *inst = usable(c);
    if (!inst) return STATUS_ERROR;
    if (refuse_if_terminated(inst, "fmi3SetInt64")) return STATUS_ERROR;
    if (private_reference(inst, vr, n, "fmi3SetInt64")) return STATUS_ERROR;
    inst->out_valid = 0;
    PASS_THROUGH(inst, ((int (*)(void *, const unsigned int *, size_t, const long long *,
                                 size_t))wrapped(&w, "fmi3SetInt64"))(c, vr, n, value, nValues));
}

EXPORT int fmi3SetBoolean(void *c, const unsigned int vr[], size_t n,
                          const unsigned char value[], size_t nValues) {
    Instance *inst = usable(c);
    if (!inst) return STATUS_ERROR;
    if (refuse_if_terminated(inst, "fmi3SetBoolean")) return STATUS_ERROR;
    if (n == nValues && cache_inputs(inst, vr, n, 'b', NULL, NULL, value)) return 0;
    if (private_reference(inst, vr, n, "fmi3SetBoolean")) return STATUS_ERROR;
    inst->out_valid = 0;
    if (n == nValues) mirror_inputs(inst, vr, n, 'b', NULL, NULL, value);
    PASS_THROUGH(inst, WRAPPED(SetB3, fmi3SetBoolean)(c, vr, n, value, nValues));
}

/* outputs from the cache: 0 served, 1 not cached, > 1 the status of a failed fetch */
static int from_cache(Instance *inst, const unsigned int vr[], size_t n, size_t nValues,
                      char type, int pos[]) {
    if (n != nValues || !cached_outputs(inst, vr, n, type, pos)) return 1;
    int status = inst->out_valid ? 0 : fetch(inst);
    return status > STATUS_WARNING ? status : 0;
}

EXPORT int fmi3GetFloat64(void *c, const unsigned int vr[], size_t n, double value[],
                          size_t nValues) {
    Instance *inst = usable(c);
    int pos[N_OUT + 1];
    if (!inst) return STATUS_ERROR;
    int cached = from_cache(inst, vr, n, nValues, 'r', pos);
    if (cached == 0) {
        for (size_t i = 0; i < n; i++) value[i] = inst->out_value[pos[i]];
        return 0;
    }
    if (cached > 1) return cached;
    if (private_reference(inst, vr, n, "fmi3GetFloat64")) return STATUS_ERROR;
    PASS_THROUGH(inst, WRAPPED(GetF64, fmi3GetFloat64)(c, vr, n, value, nValues));
}

EXPORT int fmi3GetInt32(void *c, const unsigned int vr[], size_t n, int value[],
                        size_t nValues) {
    Instance *inst = usable(c);
    int pos[N_OUT + 1];
    if (!inst) return STATUS_ERROR;
    int cached = from_cache(inst, vr, n, nValues, 'i', pos);
    if (cached == 0) {
        for (size_t i = 0; i < n; i++) value[i] = (int)inst->out_value[pos[i]];
        return 0;
    }
    if (cached > 1) return cached;
    if (private_reference(inst, vr, n, "fmi3GetInt32")) return STATUS_ERROR;
    PASS_THROUGH(inst, WRAPPED(GetI32, fmi3GetInt32)(c, vr, n, value, nValues));
}

EXPORT int fmi3GetBoolean(void *c, const unsigned int vr[], size_t n, unsigned char value[],
                          size_t nValues) {
    Instance *inst = usable(c);
    int pos[N_OUT + 1];
    if (!inst) return STATUS_ERROR;
    int cached = from_cache(inst, vr, n, nValues, 'b', pos);
    if (cached == 0) {
        for (size_t i = 0; i < n; i++) value[i] = inst->out_value[pos[i]] != 0.0;
        return 0;
    }
    if (cached > 1) return cached;
    if (private_reference(inst, vr, n, "fmi3GetBoolean")) return STATUS_ERROR;
    PASS_THROUGH(inst, WRAPPED(GetB3, fmi3GetBoolean)(c, vr, n, value, nValues));
}

EXPORT int fmi3GetFMUState(void *c, void *state) {
    Instance *inst = usable(c);
    if (!inst) return STATUS_ERROR;
    PASS_THROUGH(inst, WRAPPED(State3, fmi3GetFMUState)(c, state));
}

EXPORT int fmi3SetFMUState(void *c, void *state) {
    Instance *inst = usable(c);
    if (!inst) return STATUS_ERROR;
    inst->out_valid = 0;
    int flushed = flush(inst);
    if (flushed > STATUS_WARNING) return flushed;
    inst->worst = 0;
    return resync(inst, status_of(inst, WRAPPED(State3, fmi3SetFMUState)(c, state)));
}

EXPORT int fmi3DoStep(void *c, double t, double h, int noSetPrior, int *eventHandlingNeeded,
                      int *terminateSimulation, int *earlyReturn, double *lastSuccessfulTime) {
    Instance *inst = usable(c);
    if (!inst) return STATUS_ERROR;
    STEP(inst, ((int (*)(void *, double, double, int, int *, int *, int *, double *))wrapped(
                   &w_fmi3DoStep, "fmi3DoStep"))(c, t, h, noSetPrior, eventHandlingNeeded,
                                                 terminateSimulation, earlyReturn,
                                                 lastSuccessfulTime));
}

EXPORT int fmi3ExitInitializationMode(void *c) {
    Instance *inst = usable(c);
    if (!inst) return STATUS_ERROR;
    inst->worst = 0;
    int status = status_of(inst, WRAPPED(Call3, fmi3ExitInitializationMode)(c));
    inst->io_on = status <= STATUS_WARNING && inst->values != NULL;
    return resync(inst, status);
}

EXPORT int fmi3Terminate(void *c) {
    Instance *inst = usable(c);
    if (!inst) return STATUS_ERROR;
    int flushed = flush(inst);
    if (flushed > STATUS_WARNING) return flushed;
    inst->worst = 0;
    int status = status_of(inst, WRAPPED(Call3, fmi3Terminate)(c));
    if (status <= STATUS_WARNING) inst->terminated = 1;
    return status;
}

EXPORT int fmi3Reset(void *c) {
    Instance *inst = usable(c);
    if (!inst) return STATUS_ERROR;
    inst->io_on = inst->out_valid = inst->n_dirty = inst->terminated = 0;
    memset(inst->in_dirty, 0, sizeof inst->in_dirty);
    inst->worst = 0;
    int status = status_of(inst, WRAPPED(Call3, fmi3Reset)(c));
    if (status <= STATUS_WARNING) attach(inst); /* the wrapper made a new Python instance */
    return status;
}

EXPORT int fmi3EnterInitializationMode(void *c, int toleranceDefined, double tolerance,
                                       double startTime, int stopTimeDefined, double stopTime) {
    Instance *inst = usable(c);
    if (!inst) return STATUS_ERROR;
    inst->worst = 0;
    const unsigned int vr_time = VR_TIME;
    int status = WRAPPED(SetF64, fmi3SetFloat64)(c, &vr_time, 1, &startTime, 1);
    if (status > STATUS_WARNING) return status_of(inst, status);
    return status_of(inst, ((int (*)(void *, int, double, double, int, double))wrapped(
                               &w_fmi3EnterInitializationMode, "fmi3EnterInitializationMode"))(
                               c, toleranceDefined, tolerance, startTime, stopTimeDefined,
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
    detach(inst);
    forget(inst);
}
#endif
