/* A minimal non-Python FMI 2.0 Co-Simulation host for CanTracker.fmu (Linux).
 *
 * Nothing about Python is set: the FMU's front library (binaries/linux64/CanTracker.so)
 * loads libpython itself (see controller/fmu/front.c):
 *
 *   gcc -O1 -o fmi2_host fmi2_host.c -ldl
 *   unzip CanTracker.fmu -d CanTracker
 *   ./fmi2_host CanTracker/binaries/linux64/CanTracker.so GUID \
 *               file:///abs/path/CanTracker/resources inputs.txt PLANNER [live]
 *
 * pythonfmu's wrapper alone (CanTracker_pythonfmu.so) fails to load here with
 * "undefined symbol: _Py_NoneStruct" (pythonfmu #202).
 *
 * inputs.txt: first line "VR_MASTER_X VR_ENGAGE VR_X" (value references: the 12 master
 * inputs are contiguous from master_x in the order x y z c vx vy vz vc ax ay az ac, the 12
 * real outputs from x in the same order, followed by imfs, state, error); then one line per
 * step of 1 ms: "engage x y z c vx vy vz vc ax ay az ac" (the master at the step start).
 * Output: one line per step, "x y z c vx vy vz vc ax ay az ac imfs state error" (%.17g).
 * "live": exit without fmi2Terminate / fmi2FreeInstance (a host that never frees its
 * instance; the FMU must still let the process end cleanly).
 * Used by tests/test_fmu.py::test_non_python_host.
 */
#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

typedef void *fmi2Component;
typedef unsigned int fmi2ValueReference;
typedef struct {
    void (*logger)(void *, const char *, int, const char *, const char *, ...);
    void *(*allocateMemory)(size_t, size_t);
    void (*freeMemory)(void *);
    void (*stepFinished)(void *, int);
    void *componentEnvironment;
} fmi2CallbackFunctions;

typedef fmi2Component (*Instantiate)(const char *, int, const char *, const char *,
                                     const fmi2CallbackFunctions *, int, int);
typedef int (*SetupExperiment)(fmi2Component, int, double, double, int, double);
typedef int (*ComponentCall)(fmi2Component);
typedef int (*SetReal)(fmi2Component, const fmi2ValueReference *, size_t, const double *);
typedef int (*SetInt)(fmi2Component, const fmi2ValueReference *, size_t, const int *);
typedef int (*GetReal)(fmi2Component, const fmi2ValueReference *, size_t, double *);
typedef int (*GetInt)(fmi2Component, const fmi2ValueReference *, size_t, int *);
typedef int (*DoStep)(fmi2Component, double, double, int);
typedef void (*FreeInstance)(fmi2Component);

static void logger(void *env, const char *name, int status, const char *category,
                   const char *message, ...) {
    (void)env;
    fprintf(stderr, "[%s status %d %s] %s\n", name, status, category ? category : "", message);
}

static void *symbol(void *lib, const char *name) {
    void *f = dlsym(lib, name);
    if (!f) {
        fprintf(stderr, "missing %s\n", name);
        exit(2);
    }
    return f;
}

int main(int argc, char **argv) {
    if (argc != 6 && argc != 7) {
        fprintf(stderr, "usage: %s LIBRARY GUID RESOURCE_URI INPUTS PLANNER [live]\n",
                argv[0]);
        return 2;
    }
    void *lib = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
    if (!lib) {
        fprintf(stderr, "dlopen: %s\n", dlerror());
        return 3;
    }
    Instantiate instantiate = (Instantiate)symbol(lib, "fmi2Instantiate");
    SetupExperiment setup = (SetupExperiment)symbol(lib, "fmi2SetupExperiment");
    ComponentCall enter = (ComponentCall)symbol(lib, "fmi2EnterInitializationMode");
    ComponentCall leave = (ComponentCall)symbol(lib, "fmi2ExitInitializationMode");
    ComponentCall terminate = (ComponentCall)symbol(lib, "fmi2Terminate");
    SetReal set_real = (SetReal)symbol(lib, "fmi2SetReal");
    SetInt set_integer = (SetInt)symbol(lib, "fmi2SetInteger");
    SetInt set_boolean = (SetInt)symbol(lib, "fmi2SetBoolean");
    GetReal get_real = (GetReal)symbol(lib, "fmi2GetReal");
    GetInt get_integer = (GetInt)symbol(lib, "fmi2GetInteger");
    DoStep do_step = (DoStep)symbol(lib, "fmi2DoStep");
    FreeInstance free_instance = (FreeInstance)symbol(lib, "fmi2FreeInstance");

    fmi2CallbackFunctions callbacks = {logger, calloc, free, NULL, NULL};
    fmi2Component c = instantiate("c_host", 1 /* fmi2CoSimulation */, argv[2], argv[3],
                                  &callbacks, 0, 1);
    if (!c) {
        fprintf(stderr, "fmi2Instantiate failed\n");
        return 4;
    }
    FILE *in = fopen(argv[4], "r");
    unsigned vr_master, vr_engage, vr_out;
    if (!in || fscanf(in, "%u %u %u", &vr_master, &vr_engage, &vr_out) != 3) return 5;
    fmi2ValueReference in_vr[12], out_vr[12], int_vr[3], engage_vr = vr_engage;
    fmi2ValueReference planner_vr = 2; /* "planner" */
    for (int i = 0; i < 12; i++) {
        in_vr[i] = vr_master + i;
        out_vr[i] = vr_out + i;
    }
    for (int i = 0; i < 3; i++) int_vr[i] = vr_out + 12 + i;
    int planner = atoi(argv[5]);
    if (setup(c, 0, 0.0, 0.0, 0, 0.0) || enter(c) || set_integer(c, &planner_vr, 1, &planner) ||
        leave(c)) {
        fprintf(stderr, "initialisation failed\n");
        return 6;
    }
    int engage, k = 0, ints[3];
    double master[12], out[12];
    while (fscanf(in, "%d", &engage) == 1) {
        for (int i = 0; i < 12; i++)
            if (fscanf(in, "%lf", &master[i]) != 1) return 7;
        set_real(c, in_vr, 12, master);
        set_boolean(c, &engage_vr, 1, &engage);
        if (do_step(c, k * 0.001, 0.001, 1)) {
            fprintf(stderr, "fmi2DoStep failed at step %d\n", k);
            return 8;
        }
        get_real(c, out_vr, 12, out);
        get_integer(c, int_vr, 3, ints);
        for (int i = 0; i < 12; i++) printf("%.17g ", out[i]);
        printf("%d %d %d\n", ints[0], ints[1], ints[2]);
        k++;
    }
    fclose(in);
    if (argc > 6 && strcmp(argv[6], "live") == 0)
        return 0; /* exit with the instance alive (a host that never frees it) */
    terminate(c);
    free_instance(c);
    return 0;
}
