/* Soak of one FMU in a C host (dlopen RTLD_LOCAL, no Python in the host): N lifecycles of
 * instantiate, setupExperiment, enter/exit initialisation, 5 doSteps of 1 ms, getReal,
 * terminate, freeInstance; the resident set size every EVERY lifecycles.
 *
 *   fmi2_soak BINARY URI GUID N EVERY OUTPUT_VR
 *
 * prints "lifecycles rss_kib seconds" lines.
 */
#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include <unistd.h>

typedef void *C;
typedef struct {
    void (*logger)(void *, const char *, int, const char *, const char *, ...);
    void *(*alloc)(size_t, size_t);
    void (*free_)(void *);
    void *step_finished;
    void *env;
} Callbacks;

static void logger(void *e, const char *n, int s, const char *c, const char *m, ...)
{
    (void)e, (void)n, (void)c;
    if (s > 1) fprintf(stderr, "log [%d] %s\n", s, m);
}

static long rss_kib(void)
{
    long pages = 0, resident = 0;
    FILE *f = fopen("/proc/self/statm", "r");
    if (!f) return -1;
    if (fscanf(f, "%ld %ld", &pages, &resident) != 2) resident = -1;
    fclose(f);
    return resident * (sysconf(_SC_PAGESIZE) / 1024);
}

int main(int argc, char **argv)
{
    if (argc < 7) return 2;
    void *lib = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
    if (!lib) {
        fprintf(stderr, "%s\n", dlerror());
        return 4;
    }
    C (*inst)(const char *, int, const char *, const char *, const Callbacks *, int, int) =
        (C(*)(const char *, int, const char *, const char *, const Callbacks *, int, int))
            dlsym(lib, "fmi2Instantiate");
    int (*setup)(C, int, double, double, int, double) =
        (int (*)(C, int, double, double, int, double))dlsym(lib, "fmi2SetupExperiment");
    int (*enter)(C) = (int (*)(C))dlsym(lib, "fmi2EnterInitializationMode");
    int (*exit_)(C) = (int (*)(C))dlsym(lib, "fmi2ExitInitializationMode");
    int (*step)(C, double, double, int) = (int (*)(C, double, double, int))dlsym(lib, "fmi2DoStep");
    int (*get)(C, const unsigned *, size_t, double *) =
        (int (*)(C, const unsigned *, size_t, double *))dlsym(lib, "fmi2GetReal");
    int (*term)(C) = (int (*)(C))dlsym(lib, "fmi2Terminate");
    void (*fr)(C) = (void (*)(C))dlsym(lib, "fmi2FreeInstance");
    static Callbacks cb = {logger, calloc, free, NULL, NULL};
    long n = atol(argv[4]), every = atol(argv[5]);
    unsigned vr = (unsigned)atoi(argv[6]);
    struct timespec t0, t1;
    clock_gettime(CLOCK_MONOTONIC, &t0);
    for (long i = 0; i < n; ++i) {
        C c = inst("soak", 1, argv[3], argv[2], &cb, 0, 0);
        if (!c) return 5;
        double y = 0;
        if (setup(c, 0, 0, 0, 0, 0) || enter(c) || exit_(c)) return 6;
        for (int k = 0; k < 5; ++k)
            if (step(c, k * 1e-3, 1e-3, 1)) return 7;
        if (get(c, &vr, 1, &y)) return 8;
        term(c);
        fr(c);
        if ((i + 1) % every == 0 || i == 0) {
            clock_gettime(CLOCK_MONOTONIC, &t1);
            printf("%ld %ld %.3f\n", i + 1, rss_kib(),
                   (t1.tv_sec - t0.tv_sec) + (t1.tv_nsec - t0.tv_nsec) / 1e9);
            fflush(stdout);
        }
    }
    return 0;
}
