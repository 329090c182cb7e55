/*
 * fmi2_host.c - a plain FMI 2.0 co-simulation host in C, with no Python anywhere: it loads the
 * plant and the controller FMU binaries (dlopen with RTLD_LOCAL, or LoadLibrary on Windows),
 * runs the closed loop with the Jacobi coupling and held inputs (every FMU gets its sources'
 * outputs of the last communication point, then both step), and prints one line per step:
 * t, x_o, phi_o, omega_o, F_c (%.17g). Used by tests/export/test_native_importers.py (linux64,
 * win64 under wine, and under the sanitizers) and by bench/bench_native.py (argument "bench": the
 * time per macro step instead of the trajectory).
 *
 * usage: fmi2_host PLANT_LIB PLANT_GUID CTRL_LIB CTRL_GUID STEPS H
 *                  VR_F_c VR_x_o VR_phi_o VR_omega_o  CVR_x_o CVR_phi_o CVR_omega_o CVR_F_c
 *                  [PLANT_PARAM_VR=VALUE ...] [bench]
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "fmi2FunctionTypes.h"

#if defined(_WIN32)
#include <windows.h>
#define OPEN(path) ((void *)LoadLibraryA(path))
#define SYM(lib, name) ((void *)GetProcAddress((HMODULE)(lib), name))
#else
#include <dlfcn.h>
#define OPEN(path) dlopen(path, RTLD_NOW | RTLD_LOCAL)
#define SYM(lib, name) dlsym(lib, name)
#endif

typedef struct api {
    fmi2InstantiateTYPE *instantiate;
    fmi2SetupExperimentTYPE *setup;
    fmi2EnterInitializationModeTYPE *enter;
    fmi2ExitInitializationModeTYPE *exit_;
    fmi2SetRealTYPE *set;
    fmi2GetRealTYPE *get;
    fmi2DoStepTYPE *step;
    fmi2TerminateTYPE *terminate;
    fmi2FreeInstanceTYPE *free_;
} api;

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status s, fmi2String cat,
                   fmi2String msg, ...)
{
    (void)env;
    fprintf(stderr, "log %s [%d] %s: %s\n", name, (int)s, cat ? cat : "(null)", msg);
}

static int load(const char *path, api *a)
{
    void *lib = OPEN(path);
    if (!lib) {
        fprintf(stderr, "cannot load %s\n", path);
        return 0;
    }
#define GET(field, name)                                                                     \
    *(void **)(&a->field) = SYM(lib, name);                                                  \
    if (!a->field) {                                                                         \
        fprintf(stderr, "%s has no %s\n", path, name);                                       \
        return 0;                                                                            \
    }
    GET(instantiate, "fmi2Instantiate")
    GET(setup, "fmi2SetupExperiment")
    GET(enter, "fmi2EnterInitializationMode")
    GET(exit_, "fmi2ExitInitializationMode")
    GET(set, "fmi2SetReal")
    GET(get, "fmi2GetReal")
    GET(step, "fmi2DoStep")
    GET(terminate, "fmi2Terminate")
    GET(free_, "fmi2FreeInstance")
    return 1;
}

static double now(void)
{
#if defined(_WIN32)
    LARGE_INTEGER f, c;
    QueryPerformanceFrequency(&f);
    QueryPerformanceCounter(&c);
    return (double)c.QuadPart / (double)f.QuadPart;
#else
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
#endif
}

int main(int argc, char **argv)
{
    api P, C;
    fmi2CallbackFunctions cb = {logger, calloc, free, NULL, NULL};
    fmi2Component p, c;
    fmi2ValueReference pin, pout[3], cin[3], cout;
    double y[3], F = 0.0, h, t0, t1;
    long steps, k;
    int i, bench = 0, first = 15;
    if (argc < 15) {
        fprintf(stderr, "usage: see fmi2_host.c\n");
        return 2;
    }
    if (strcmp(argv[argc - 1], "bench") == 0) {
        bench = 1;
        argc--;
    }
    if (!load(argv[1], &P) || !load(argv[3], &C)) return 3;
    steps = atol(argv[5]);
    h = atof(argv[6]);
    pin = (fmi2ValueReference)atoi(argv[7]);
    for (i = 0; i < 3; i++) {
        pout[i] = (fmi2ValueReference)atoi(argv[8 + i]);
        cin[i] = (fmi2ValueReference)atoi(argv[11 + i]);
    }
    cout = (fmi2ValueReference)atoi(argv[14]);
    p = P.instantiate("plant", fmi2CoSimulation, argv[2], "", &cb, fmi2False, fmi2False);
    c = C.instantiate("controller", fmi2CoSimulation, argv[4], "", &cb, fmi2False, fmi2False);
    if (!p || !c) return 4;
    if (P.setup(p, fmi2False, 0.0, 0.0, fmi2False, 0.0) || C.setup(c, fmi2False, 0.0, 0.0,
                                                                   fmi2False, 0.0))
        return 5;
    for (i = first; i < argc; i++) {
        fmi2ValueReference vr = (fmi2ValueReference)atoi(argv[i]);
        double v = atof(strchr(argv[i], '=') + 1);
        if (P.set(p, &vr, 1, &v) != fmi2OK) return 6;
    }
    if (P.enter(p) || P.exit_(p) || C.enter(c) || C.exit_(c)) return 7;
    if (P.get(p, pout, 3, y) || C.get(c, &cout, 1, &F)) return 8;
    t0 = now();
    for (k = 0; k < steps; k++) {
        double t = k * h;
        if (C.set(c, cin, 3, y) || P.set(p, &pin, 1, &F)) return 9;
        if (P.step(p, t, h, fmi2True) != fmi2OK || C.step(c, t, h, fmi2True) != fmi2OK) return 10;
        if (P.get(p, pout, 3, y) || C.get(c, &cout, 1, &F)) return 11;
        if (!bench) printf("%.17g %.17g %.17g %.17g %.17g\n", (k + 1) * h, y[0], y[1], y[2], F);
    }
    t1 = now();
    if (bench) printf("%.6g\n", (t1 - t0) / (double)steps);
    P.terminate(p);
    C.terminate(c);
    P.free_(p);
    C.free_(c);
    return 0;
}
