/* A minimal FMI 2.0 co-simulation master in C, with no Python anywhere in it: it loads the
 * plant and the controller with dlopen(RTLD_LOCAL) and runs the closed loop the way
 * orchestration/cosim/master.py does by default (Gauss-Seidel, controller first, inputs held over each
 * step; the controller's inputs are moved to their values at the end of the step before its
 * output is read, as the master does for a slave with direct feedthrough).
 *
 *   fmi2_host H STEPS EVERY  PLANT.so PLANT_URI PLANT_GUID  CTRL.so CTRL_URI CTRL_GUID
 *             VR_x VR_phi VR_omega VR_Fin  VR_cx VR_cphi VR_comega VR_Fout  [p|c:R|I|B|S:VR=VALUE ...]
 *
 * prints "t x_o phi_o omega_o F_c" (%.17g) at t = 0 and every EVERY steps, and on stderr the wall
 * time per macro step. Exit status: 0 done; 5 an fmi2Instantiate returned NULL (after freeing
 * what was made); 4 a library did not load; 6.. a call failed.
 */
#include <dlfcn.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

typedef void *fmi2Component;
typedef unsigned int fmi2ValueReference;
typedef int fmi2Boolean;
typedef const char *fmi2String;
typedef enum { fmi2OK, fmi2Warning, fmi2Discard, fmi2Error, fmi2Fatal, fmi2Pending } fmi2Status;
typedef struct {
    void (*logger)(void *, fmi2String, fmi2Status, fmi2String, fmi2String, ...);
    void *(*allocateMemory)(size_t, size_t);
    void (*freeMemory)(void *);
    void (*stepFinished)(void *, fmi2Status);
    void *componentEnvironment;
} fmi2CallbackFunctions;

typedef struct {
    fmi2Component (*instantiate)(fmi2String, int, fmi2String, fmi2String,
                                 const fmi2CallbackFunctions *, fmi2Boolean, fmi2Boolean);
    fmi2Status (*setup)(fmi2Component, fmi2Boolean, double, double, fmi2Boolean, double);
    fmi2Status (*enter)(fmi2Component);
    fmi2Status (*exit_)(fmi2Component);
    fmi2Status (*set_real)(fmi2Component, const fmi2ValueReference *, size_t, const double *);
    fmi2Status (*set_integer)(fmi2Component, const fmi2ValueReference *, size_t, const int *);
    fmi2Status (*set_boolean)(fmi2Component, const fmi2ValueReference *, size_t, const int *);
    fmi2Status (*set_string)(fmi2Component, const fmi2ValueReference *, size_t, const fmi2String *);
    fmi2Status (*get_real)(fmi2Component, const fmi2ValueReference *, size_t, double *);
    fmi2Status (*do_step)(fmi2Component, double, double, fmi2Boolean);
    fmi2Status (*terminate)(fmi2Component);
    void (*free_)(fmi2Component);
    fmi2Component c;
} Fmu;

static void logger(void *env, fmi2String name, fmi2Status s, fmi2String cat, fmi2String msg, ...)
{
    (void)env;
    fprintf(stderr, "log [%d] %s %s: %s\n", (int)s, name, cat ? cat : "(NULL category)", msg);
}

static int load(Fmu *f, const char *path)
{
    void *lib = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (!lib) {
        fprintf(stderr, "dlopen: %s\n", dlerror());
        return 4;
    }
#define SYM(field, name)                                                                       \
    if (!(*(void **)&f->field = dlsym(lib, name))) {                                           \
        fprintf(stderr, "no %s\n", name);                                                      \
        return 4;                                                                              \
    }
    SYM(instantiate, "fmi2Instantiate")
    SYM(setup, "fmi2SetupExperiment")
    SYM(enter, "fmi2EnterInitializationMode")
    SYM(exit_, "fmi2ExitInitializationMode")
    SYM(set_real, "fmi2SetReal")
    SYM(set_integer, "fmi2SetInteger")
    SYM(set_boolean, "fmi2SetBoolean")
    SYM(set_string, "fmi2SetString")
    SYM(get_real, "fmi2GetReal")
    SYM(do_step, "fmi2DoStep")
    SYM(terminate, "fmi2Terminate")
    SYM(free_, "fmi2FreeInstance")
    return 0;
}

#define CHECK(call, code)                                                                      \
    if ((call) > fmi2Warning) {                                                                \
        fprintf(stderr, "%s failed\n", #call);                                                 \
        rc = code;                                                                             \
        goto done;                                                                             \
    }

int main(int argc, char **argv)
{
    if (argc < 18) {
        fprintf(stderr, "usage: see the comment at the top of fmi2_host.c\n");
        return 2;
    }
    double H = atof(argv[1]);
    long steps = atol(argv[2]), every = atol(argv[3]);
    Fmu p = {0}, k = {0};
    int rc = load(&p, argv[4]);
    if (!rc) rc = load(&k, argv[7]);
    if (rc) return rc;
    fmi2ValueReference p_out[3], p_in, c_in[3], c_out;
    for (int i = 0; i < 3; ++i) p_out[i] = (fmi2ValueReference)atoi(argv[10 + i]);
    p_in = (fmi2ValueReference)atoi(argv[13]);
    for (int i = 0; i < 3; ++i) c_in[i] = (fmi2ValueReference)atoi(argv[14 + i]);
    c_out = (fmi2ValueReference)atoi(argv[17]);
    static fmi2CallbackFunctions cb = {logger, calloc, free, NULL, NULL};
    p.c = p.instantiate("plant", 1, argv[6], argv[5], &cb, 0, 0);
    k.c = k.instantiate("controller", 1, argv[9], argv[8], &cb, 0, 0);
    if (!p.c || !k.c) {
        fprintf(stderr, "fmi2Instantiate returned NULL\n");
        rc = 5;
        goto done;
    }
    CHECK(p.setup(p.c, 0, 0.0, 0.0, 0, 0.0), 6)
    CHECK(k.setup(k.c, 0, 0.0, 0.0, 0, 0.0), 6)
    for (int i = 18; i < argc; ++i) {   /* p|c:T:VR=VALUE */
        Fmu *f = argv[i][0] == 'p' ? &p : &k;
        char type = argv[i][2];
        fmi2ValueReference vr = (fmi2ValueReference)atoi(argv[i] + 4);
        const char *val = strchr(argv[i], '=') + 1;
        fmi2Status s;
        if (type == 'R') {
            double v = strtod(val, NULL);
            s = f->set_real(f->c, &vr, 1, &v);
        } else if (type == 'I' || type == 'B') {
            int v = atoi(val);
            s = type == 'I' ? f->set_integer(f->c, &vr, 1, &v) : f->set_boolean(f->c, &vr, 1, &v);
        } else {
            s = f->set_string(f->c, &vr, 1, &val);
        }
        CHECK(s, 7)
    }
    CHECK(p.enter(p.c), 8)
    CHECK(k.enter(k.c), 8)
    CHECK(p.exit_(p.c), 8)
    CHECK(k.exit_(k.c), 8)
    double y[3], F;
    /* consistent initial outputs (the master's _initial_outputs: twice, in coupling order) */
    CHECK(p.get_real(p.c, p_out, 3, y), 10)
    for (int pass = 0; pass < 2; ++pass) {
        CHECK(k.set_real(k.c, c_in, 3, y), 10)
        CHECK(k.get_real(k.c, &c_out, 1, &F), 10)
        CHECK(p.set_real(p.c, &p_in, 1, &F), 10)
        CHECK(p.get_real(p.c, p_out, 3, y), 10)
    }
    printf("%.17g %.17g %.17g %.17g %.17g\n", 0.0, y[0], y[1], y[2], F);
    struct timespec t0, t1;
    clock_gettime(CLOCK_MONOTONIC, &t0);
    for (long i = 0; i < steps; ++i) {
        double ta = i * H, tb = (i + 1) * H;
        CHECK(k.set_real(k.c, c_in, 3, y), 11)
        CHECK(k.do_step(k.c, ta, H, 1), 9)
        CHECK(k.set_real(k.c, c_in, 3, y), 11)   /* inputs at tb (held): feedthrough slave */
        CHECK(k.get_real(k.c, &c_out, 1, &F), 11)
        CHECK(p.set_real(p.c, &p_in, 1, &F), 11)
        CHECK(p.do_step(p.c, ta, H, 1), 9)
        CHECK(p.get_real(p.c, p_out, 3, y), 11)
        if ((i + 1) % every == 0) printf("%.17g %.17g %.17g %.17g %.17g\n", tb, y[0], y[1], y[2], F);
    }
    clock_gettime(CLOCK_MONOTONIC, &t1);
    fprintf(stderr, "us_per_step=%.4f\n",
            ((t1.tv_sec - t0.tv_sec) * 1e9 + (t1.tv_nsec - t0.tv_nsec)) / 1e3 / (steps ? steps : 1));
    p.terminate(p.c);
    k.terminate(k.c);
done:
    if (p.c) p.free_(p.c);
    if (k.c) k.free_(k.c);
    return rc;
}
