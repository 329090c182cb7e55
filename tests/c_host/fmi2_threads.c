/* Threads in a C host: ROUNDS rounds of 8 threads at once, each thread with its own instance of
 * one FMU (dlopen RTLD_LOCAL): instantiate, initialise, 200 steps of 1 ms with phi_o = 0.1 held,
 * read the output, free; then the thread ends (the loader deletes its Python thread state).
 *
 *   fmi2_threads BINARY URI GUID ROUNDS INPUT_VR OUTPUT_VR
 *
 * prints the output of the main thread's run, then "rss_kib" before and after the rounds; exit
 * status 0 when every thread's output equals the main thread's, bit for bit.
 */
#include <dlfcn.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
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

static C (*inst)(const char *, int, const char *, const char *, const Callbacks *, int, int);
static int (*setup)(C, int, double, double, int, double), (*enter)(C), (*exit_)(C);
static int (*step)(C, double, double, int), (*term)(C);
static int (*set)(C, const unsigned *, size_t, const double *);
static int (*get)(C, const unsigned *, size_t, double *);
static void (*fr)(C);
static const char *uri, *guid;
static unsigned vr_in, vr_out;
static Callbacks cb = {logger, calloc, free, NULL, NULL};

static long rss_kib(void)
{
    long pages = 0, resident = 0;
    FILE *f = fopen("/proc/self/statm", "r");
    if (!f || fscanf(f, "%ld %ld", &pages, &resident) != 2) resident = -1;
    if (f) fclose(f);
    return resident * (sysconf(_SC_PAGESIZE) / 1024);
}

static void *run(void *out)
{
    double u = 0.1;
    C c = inst("thread", 1, guid, uri, &cb, 0, 0);
    if (!c) exit(5);
    if (setup(c, 0, 0, 0, 0, 0) || set(c, &vr_in, 1, &u) || enter(c) || exit_(c)) exit(6);
    for (int k = 0; k < 200; ++k)
        if (step(c, k * 1e-3, 1e-3, 1)) exit(7);
    if (get(c, &vr_out, 1, (double *)out)) exit(8);
    term(c);
    fr(c);
    return NULL;
}

int main(int argc, char **argv)
{
    if (argc < 7) return 2;
    void *l = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
    if (!l) return 4;
    uri = argv[2];
    guid = argv[3];
    int rounds = atoi(argv[4]);
    vr_in = (unsigned)atoi(argv[5]);
    vr_out = (unsigned)atoi(argv[6]);
    *(void **)&inst = dlsym(l, "fmi2Instantiate");
    *(void **)&setup = dlsym(l, "fmi2SetupExperiment");
    *(void **)&enter = dlsym(l, "fmi2EnterInitializationMode");
    *(void **)&exit_ = dlsym(l, "fmi2ExitInitializationMode");
    *(void **)&step = dlsym(l, "fmi2DoStep");
    *(void **)&term = dlsym(l, "fmi2Terminate");
    *(void **)&set = dlsym(l, "fmi2SetReal");
    *(void **)&get = dlsym(l, "fmi2GetReal");
    *(void **)&fr = dlsym(l, "fmi2FreeInstance");
    double first;
    run(&first);
    printf("%.17g\n", first);
    for (int r = 0; r < 2; ++r) {         /* warm-up rounds: allocator arenas of new threads */
        pthread_t t[8];
        double out[8];
        for (int i = 0; i < 8; ++i) pthread_create(&t[i], NULL, run, &out[i]);
        for (int i = 0; i < 8; ++i) pthread_join(t[i], NULL);
    }
    printf("rss_kib %ld\n", rss_kib());
    int bad = 0;
    for (int r = 0; r < rounds; ++r) {
        pthread_t t[8];
        double out[8];
        for (int i = 0; i < 8; ++i) pthread_create(&t[i], NULL, run, &out[i]);
        for (int i = 0; i < 8; ++i) pthread_join(t[i], NULL);
        for (int i = 0; i < 8; ++i) bad += out[i] != first;
    }
    printf("rss_kib %ld\n", rss_kib());
    return bad ? 1 : 0;
}
