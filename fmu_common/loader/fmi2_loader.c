/* The binary of the flexpend pythonfmu FMUs: a small loader in front of pythonfmu's library.
 *
 * pythonfmu's library (shipped beside this one as <model>_pythonfmu.so / .dll) runs the FMU's
 * Python code, but it does not link libpython: it needs a Python already in the host process.
 * This loader makes the FMU load in any host:
 *
 *   1. at the first fmi2Instantiate it finds a Python: the process's own if it has one (fmpy,
 *      libcosimpy), else the interpreter named by the environment variable FLEXPEND_PYTHON, else
 *      the one recorded when the FMU was built (resources/flexpend_loader.txt), else python3 on
 *      PATH. Each candidate is first asked, in a child process, where its shared libpython is and
 *      whether numpy imports (resources/flexpend_loader.py); the first usable one is
 *      loaded with RTLD_GLOBAL and initialised (isolated configuration: no signal handlers, no
 *      PYTHONPATH) before pythonfmu's library is loaded. When none is usable, fmi2Instantiate
 *      logs what is missing and how to name a Python, and returns NULL.
 *   2. every FMI 2.0 function is checked here before it is forwarded: the call order (the
 *      co-simulation state machine), value references and types against the model's table of
 *      variables, causality (no setting of outputs, parameters only before initialisation),
 *      step sizes, FMU state pointers (only states this FMU handed out) and sizes. A bad call is
 *      answered with fmi2Error and a log message; pythonfmu never sees it (any Python exception
 *      there would become fmi2Fatal and leave pythonfmu's instance with dangling pointers).
 *   3. the calls into pythonfmu's C++ go through guard.cpp, which turns any C++ exception into
 *      fmi2Error. A message the Python code logs with status error during a call makes the call
 *      return fmi2Error (Python cannot return that status through pythonfmu).
 *   4. one Python thread state per calling thread is kept alive (pythonfmu's PyGILState_Ensure
 *      otherwise creates and destroys one per call), and released when the thread ends.
 *   5. Python is never finalised. pythonfmu finalises the interpreter it started from a library
 *      destructor at process exit, which runs after the destructors of libraries loaded later
 *      (scipy's libgfortran) and aborts the host; since this loader starts the interpreter,
 *      pythonfmu leaves it alone (see docs/fmus.md, "The exit abort").
 */
#if !defined(_WIN32)
#define _GNU_SOURCE
#endif

#include <ctype.h>
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2_api.h"

#if defined(_WIN32)
#include <windows.h>
#define FLX_EXPORT __declspec(dllexport)
#define FLX_SEP '\\'
#define FLX_LIB_SUFFIX ".dll"
#define FLX_PATH_LIST_SEP ';'
#else
#include <dlfcn.h>
#include <poll.h>
#include <pthread.h>
#include <signal.h>
#include <spawn.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>
extern char **environ;
#define FLX_EXPORT __attribute__((visibility("default")))
#define FLX_SEP '/'
#define FLX_LIB_SUFFIX ".so"
#define FLX_PATH_LIST_SEP ':'
#endif

#define FLX_ENV "FLEXPEND_PYTHON"
#define FLX_CONFIG "flexpend_loader.txt"
#define FLX_HELPER "flexpend_loader.py"
#define FLX_MAGIC 0x464c5850u /* "FLXP" */
#define FLX_MSG 8192
#define FLX_PROBE_SECONDS 120

/* ------------------------------------------------------------------------------------------ *
 * Python's C API, resolved at run time (the loader is compiled without Python's headers; it
 * uses only functions of the stable ABI plus PyConfig through pointers to an ample buffer).
 * ------------------------------------------------------------------------------------------ */
typedef struct _object PyObject;
typedef struct _ts PyThreadState;
typedef enum { PyGILState_LOCKED, PyGILState_UNLOCKED } PyGILState_STATE;
typedef struct {
    int type;
    const char *func;
    const char *err_msg;
    int exitcode;
} PyStatus;

typedef struct {
    int (*Py_IsInitialized)(void);
    void (*PyConfig_InitIsolatedConfig)(void *);
    PyStatus (*PyConfig_SetBytesArgv)(void *, ssize_t, char *const *);
    PyStatus (*Py_InitializeFromConfig)(const void *);
    void (*PyConfig_Clear)(void *);
    int (*PyStatus_Exception)(PyStatus);
    PyThreadState *(*PyEval_SaveThread)(void);
    void (*PyEval_RestoreThread)(PyThreadState *);
    PyGILState_STATE (*PyGILState_Ensure)(void);
    void (*PyGILState_Release)(PyGILState_STATE);
    PyThreadState *(*PyGILState_GetThisThreadState)(void);
    void (*PyThreadState_Clear)(PyThreadState *);
    void (*PyThreadState_DeleteCurrent)(void);
    PyObject *(*Py_CompileString)(const char *, const char *, int);
    PyObject *(*PyEval_EvalCode)(PyObject *, PyObject *, PyObject *);
    PyObject *(*PyDict_New)(void);
    int (*PyDict_SetItemString)(PyObject *, const char *, PyObject *);
    PyObject *(*PyDict_GetItemString)(PyObject *, const char *);
    PyObject *(*PyEval_GetBuiltins)(void);
    PyObject *(*PyObject_CallFunction)(PyObject *, const char *, ...);
    PyObject *(*PyObject_GetAttrString)(PyObject *, const char *);
    const char *(*PyUnicode_AsUTF8)(PyObject *);
    PyObject *(*PyUnicode_FromString)(const char *);
    PyObject *(*PyErr_Occurred)(void);
    void (*PyErr_Fetch)(PyObject **, PyObject **, PyObject **);
    PyObject *(*PyObject_Str)(PyObject *);
    void (*PyErr_Clear)(void);
    void (*Py_DecRef)(PyObject *);
    PyObject *(*PySys_GetObject)(const char *);
    ssize_t (*PyList_Size)(PyObject *);
    PyObject *(*PyList_GetItem)(PyObject *, ssize_t);
    int (*PySequence_DelItem)(PyObject *, ssize_t);
    int (*PyObject_RichCompareBool)(PyObject *, PyObject *, int);
    PyObject *Py_None;
} PyApi;

#define FLX_Py_file_input 257
#define FLX_Py_EQ 2

/* ------------------------------------------------------------------------------------------ *
 * Per-process state of this copy of the loader (each FMU has its own copy of this binary).
 * ------------------------------------------------------------------------------------------ */
typedef struct {
    fmi2InstantiateTYPE instantiate;
    fmi2FreeInstanceTYPE free_instance;
    fmi2SetupExperimentTYPE setup;
    fmi2ComponentTYPE enter_init, exit_init, terminate, reset;
    fmi2GetRealTYPE get_real;
    fmi2GetIntegerTYPE get_integer;
    fmi2GetBooleanTYPE get_boolean;
    fmi2GetStringTYPE get_string;
    fmi2SetRealTYPE set_real;
    fmi2SetIntegerTYPE set_integer;
    fmi2SetBooleanTYPE set_boolean;
    fmi2SetStringTYPE set_string;
    fmi2GetFMUstateTYPE get_state;
    fmi2SetFMUstateTYPE set_state;
    fmi2FreeFMUstateTYPE free_state;
    fmi2SerializedFMUstateSizeTYPE state_size;
    fmi2SerializeFMUstateTYPE serialize;
    fmi2DeSerializeFMUstateTYPE deserialize;
    fmi2DoStepTYPE do_step;
} PyFmuApi;

typedef struct {
    void *state;
    void *owner;
} LiveState;

static struct {
    int tried;              /* 0: not yet; 1: ready; -1: failed (message in why) */
    char why[FLX_MSG];      /* why loading failed */
    char python[2048];      /* the interpreter in use, for messages */
    PyApi py;
    PyFmuApi fmu;
    PyObject *helper;       /* the namespace of resources/flexpend_loader.py */
    LiveState *states;      /* FMU states handed out and not yet freed */
    size_t n_states, cap_states;
} G;

/* the exception reported by guard.cpp during the current call of this thread */
static _Thread_local char tls_exception[512];

/* ------------------------------------------------------------------------------------------ *
 * Small portability layer: a process-wide lock, the loader's own path, libraries, threads.
 * ------------------------------------------------------------------------------------------ */
#if defined(_WIN32)
static SRWLOCK g_lock = SRWLOCK_INIT;
static void lock(void) { AcquireSRWLockExclusive(&g_lock); }
static void unlock(void) { ReleaseSRWLockExclusive(&g_lock); }

static void *lib_open(const char *path, int global, char *err, size_t n)
{
    (void)global;
    wchar_t wpath[4096];
    if (!MultiByteToWideChar(CP_UTF8, 0, path, -1, wpath, 4096)) {
        snprintf(err, n, "path too long: %s", path);
        return NULL;
    }
    HMODULE h = LoadLibraryExW(wpath, NULL, LOAD_WITH_ALTERED_SEARCH_PATH);
    if (!h) snprintf(err, n, "LoadLibrary(%s) failed with error %lu", path, GetLastError());
    return (void *)h;
}
static void *lib_sym(void *lib, const char *name) { return (void *)GetProcAddress((HMODULE)lib, name); }

/* a module of the process that exports Py_IsInitialized (the host's Python), or NULL */
static void *process_python(void)
{
    static const char *names[] = {"python314.dll", "python313.dll", "python312.dll",
                                  "python311.dll", "python310.dll", NULL};
    for (int i = 0; names[i]; ++i) {
        HMODULE h = GetModuleHandleA(names[i]);
        if (h && GetProcAddress(h, "Py_IsInitialized")) return (void *)h;
    }
    return NULL;
}

static int self_path(char *out, size_t n)
{
    HMODULE h = NULL;
    if (!GetModuleHandleExA(GET_MODULE_HANDLE_EX_FLAG_FROM_ADDRESS |
                                GET_MODULE_HANDLE_EX_FLAG_PIN,  /* never unloaded */
                            (LPCSTR)(void *)&self_path, &h))
        return -1;
    wchar_t w[4096];
    DWORD k = GetModuleFileNameW(h, w, 4096);
    if (k == 0 || k >= 4096) return -1;
    return WideCharToMultiByte(CP_UTF8, 0, w, -1, out, (int)n, NULL, NULL) ? 0 : -1;
}

static int file_exists(const char *path)
{
    wchar_t w[4096];
    if (!MultiByteToWideChar(CP_UTF8, 0, path, -1, w, 4096)) return 0;
    DWORD a = GetFileAttributesW(w);
    return a != INVALID_FILE_ATTRIBUTES && !(a & FILE_ATTRIBUTE_DIRECTORY);
}
#else
static pthread_mutex_t g_lock = PTHREAD_MUTEX_INITIALIZER;
static void lock(void) { pthread_mutex_lock(&g_lock); }
static void unlock(void) { pthread_mutex_unlock(&g_lock); }

static void *lib_open(const char *path, int global, char *err, size_t n)
{
    void *h = dlopen(path, RTLD_NOW | (global ? RTLD_GLOBAL : RTLD_LOCAL));
    if (!h) snprintf(err, n, "%s", dlerror());
    return h;
}
static void *lib_sym(void *lib, const char *name) { return dlsym(lib, name); }

static void *process_python(void)
{
    return dlsym(RTLD_DEFAULT, "Py_IsInitialized") ? RTLD_DEFAULT : NULL;
}

static int self_path(char *out, size_t n)
{
    Dl_info info;
    if (!dladdr((void *)&self_path, &info) || !info.dli_fname) return -1;
    if (strlen(info.dli_fname) >= n) return -1;
    strcpy(out, info.dli_fname);
    /* pin this library: thread-exit destructors and pythonfmu point into it */
    dlopen(out, RTLD_NOW | RTLD_NOLOAD | RTLD_NODELETE);
    return 0;
}

static int file_exists(const char *path)
{
    struct stat st;
    return stat(path, &st) == 0 && S_ISREG(st.st_mode);
}
#endif

/* ------------------------------------------------------------------------------------------ *
 * Strings
 * ------------------------------------------------------------------------------------------ */
static void append(char *buf, size_t n, const char *fmt, ...)
{
    size_t k = strlen(buf);
    if (k + 1 >= n) return;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(buf + k, n - k, fmt, ap);
    va_end(ap);
}

static char *read_file(const char *path, size_t *size)
{
    FILE *f = fopen(path, "rb");
    if (!f) return NULL;
    size_t cap = 1 << 16, k = 0, r;
    char *buf = malloc(cap + 1);
    while (buf && (r = fread(buf + k, 1, cap - k, f)) > 0) {
        k += r;
        if (k == cap) {
            char *b = realloc(buf, 2 * cap + 1);
            if (!b) {
                free(buf);
                buf = NULL;
                break;
            }
            buf = b;
            cap *= 2;
        }
    }
    fclose(f);
    if (buf) buf[k] = 0;
    if (size) *size = k;
    return buf;
}

/* fmuResourceLocation (a file URI) -> a path; 0 on success */
static int uri_to_path(const char *uri, char *out, size_t n)
{
    const char *p = uri;
    if (strncmp(p, "file://", 7) == 0) {
        p += 7;
        if (strncmp(p, "localhost/", 10) == 0) p += 9;
    } else if (strncmp(p, "file:", 5) == 0) {
        p += 5;
    } else {
        return -1;
    }
#if defined(_WIN32)
    if (p[0] == '/' && isalpha((unsigned char)p[1]) && p[2] == ':') ++p;  /* /C:/... */
#endif
    size_t k = 0;
    for (; *p && k + 1 < n; ++p) {
        if (*p == '%' && isxdigit((unsigned char)p[1]) && isxdigit((unsigned char)p[2])) {
            char hex[3] = {p[1], p[2], 0};
            out[k++] = (char)strtol(hex, NULL, 16);
            p += 2;
        } else {
            out[k++] = *p;
        }
    }
    if (*p) return -1;
    while (k > 1 && (out[k - 1] == '/' || out[k - 1] == '\\')) --k;
    out[k] = 0;
    return 0;
}

/* ------------------------------------------------------------------------------------------ *
 * The model's table (resources/flexpend_loader.txt, written by the build from the one table of
 * variables): "model\t<name>", "python\t<interpreter recorded at build time>",
 * "category\t<log category>", "var\t<vr>\t<R|I|B|S>\t<p|i|o>\t<name>".
 * ------------------------------------------------------------------------------------------ */
#define FLX_MAX_VARS 4096
#define FLX_MAX_CATS 32

typedef struct {
    char model[256];
    char python[2048];
    unsigned n_vars;
    char type[FLX_MAX_VARS];      /* 'R', 'I', 'B', 'S' */
    char causality[FLX_MAX_VARS]; /* 'p' (fixed parameter), 'i' (input), 'o' (output) */
    char *names;                  /* n_vars names, NUL-separated */
    unsigned n_cats;
    char cats[FLX_MAX_CATS][64];
} Table;

static int read_table(const char *resources, Table *t, char *why, size_t n)
{
    char path[4096];
    snprintf(path, sizeof path, "%s%c%s", resources, FLX_SEP, FLX_CONFIG);
    size_t size;
    char *text = read_file(path, &size);
    if (!text) {
        snprintf(why, n, "cannot read %s: the FMU's resources are incomplete", path);
        return -1;
    }
    memset(t, 0, sizeof *t);
    t->names = calloc(1, size + 1);
    size_t names_k = 0;
    int ok = t->names != NULL;
    for (char *line = text; ok && line && *line;) {
        char *next = strchr(line, '\n');
        if (next) *next++ = 0;
        char *f[6] = {0};
        int nf = 0;
        for (char *s = line; s && nf < 6; ++nf) {
            f[nf] = s;
            s = strchr(s, '\t');
            if (s) *s++ = 0;
        }
        if (nf == 2 && !strcmp(f[0], "model")) {
            snprintf(t->model, sizeof t->model, "%s", f[1]);
        } else if (nf == 2 && !strcmp(f[0], "python")) {
            snprintf(t->python, sizeof t->python, "%s", f[1]);
        } else if (nf == 2 && !strcmp(f[0], "category") && t->n_cats < FLX_MAX_CATS) {
            snprintf(t->cats[t->n_cats++], 64, "%s", f[1]);
        } else if (nf == 5 && !strcmp(f[0], "var")) {
            unsigned long vr = strtoul(f[1], NULL, 10);
            if (vr != t->n_vars || vr >= FLX_MAX_VARS || !strchr("RIBS", f[2][0]) ||
                !strchr("pio", f[3][0])) {
                ok = 0;
                break;
            }
            t->type[vr] = f[2][0];
            t->causality[vr] = f[3][0];
            strcpy(t->names + names_k, f[4]);
            names_k += strlen(f[4]) + 1;
            t->n_vars++;
        }
        line = next;
    }
    free(text);
    if (!ok || !t->model[0] || !t->n_vars) {
        snprintf(why, n, "%s is not a valid variable table", path);
        free(t->names);
        t->names = NULL;
        return -1;
    }
    return 0;
}

static const char *var_name(const Table *t, unsigned vr)
{
    const char *s = t->names;
    for (unsigned i = 0; i < vr; ++i) s += strlen(s) + 1;
    return s;
}

/* ------------------------------------------------------------------------------------------ *
 * Instances
 * ------------------------------------------------------------------------------------------ */
enum { FLX_INSTANTIATED = 1, FLX_INIT = 2, FLX_STEPPING = 4, FLX_TERMINATED = 8, FLX_BROKEN = 16 };

typedef struct {
    unsigned magic;
    fmi2Component inner;            /* pythonfmu's instance */
    fmi2CallbackFunctions host;     /* the host's callbacks */
    fmi2CallbackFunctions mine;     /* given to pythonfmu: relay_logger, environment = this */
    char name[256];
    int state;
    int logging_on;
    unsigned n_filter;              /* categories of fmi2SetDebugLogging (0: all) */
    char filter[FLX_MAX_CATS][64];
    int worst;                      /* worst status logged during the current call */
    double time;                    /* last successful communication point */
    int discarded;                  /* the last doStep was refused (fmi2Terminated) */
    Table table;
} Instance;

static void emit(Instance *inst, fmi2Status status, const char *category, const char *msg)
{
    if (!inst->host.logger) return;
    if (status == fmi2OK && !inst->logging_on) return;
    if (status == fmi2OK && inst->n_filter) {
        unsigned i = 0;
        while (i < inst->n_filter && strcmp(inst->filter[i], category)) ++i;
        if (i == inst->n_filter) return;
    }
    /* the message is a printf format for the host: escape % */
    char buf[FLX_MSG];
    size_t k = 0;
    for (const char *p = msg; *p && k + 2 < sizeof buf; ++p) {
        if (*p == '%') buf[k++] = '%';
        buf[k++] = *p;
    }
    buf[k] = 0;
    inst->host.logger(inst->host.componentEnvironment, inst->name, status, category, buf);
}

static const char *status_category(fmi2Status s)
{
    switch (s) {
    case fmi2OK: return "logAll";
    case fmi2Warning: return "logStatusWarning";
    case fmi2Discard: return "logStatusDiscard";
    case fmi2Error: return "logStatusError";
    case fmi2Fatal: return "logStatusFatal";
    default: return "logStatusPending";
    }
}

static void logf_(Instance *inst, fmi2Status status, const char *fmt, ...)
{
    char msg[FLX_MSG];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    if ((int)status > inst->worst) inst->worst = (int)status;
    emit(inst, status, status_category(status), msg);
}

/* pythonfmu's messages come here: never a NULL category, never formatted */
static void relay_logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status,
                         fmi2String category, fmi2String message, ...)
{
    (void)name;
    Instance *inst = (Instance *)env;
    if (!inst || inst->magic != FLX_MAGIC) return;
    if ((int)status > inst->worst && status <= fmi2Pending) inst->worst = (int)status;
    emit(inst, status, (category && *category) ? category : status_category(status),
         message ? message : "(no message)");
}

void flx_exception(const char *what, const char *message)
{
    snprintf(tls_exception, sizeof tls_exception, "%s: C++ exception: %s", what, message);
}

static Instance *get(fmi2Component c) { return (c && ((Instance *)c)->magic == FLX_MAGIC) ? c : NULL; }

/* one check of the call order; logs and returns 0 when the call is not allowed now */
static int allowed(Instance *inst, const char *fn, int mask)
{
    if (inst->state & mask) return 1;
    const char *now = inst->state == FLX_INSTANTIATED ? "instantiated (before fmi2EnterInitializationMode)"
                    : inst->state == FLX_INIT ? "in initialization mode"
                    : inst->state == FLX_STEPPING ? "initialized (stepping)"
                    : inst->state == FLX_TERMINATED ? "terminated"
                    : "unusable after an internal error (free it)";
    logf_(inst, fmi2Error, "%s is not allowed: the instance is %s", fn, now);
    return 0;
}

/* ------------------------------------------------------------------------------------------ *
 * Python
 * ------------------------------------------------------------------------------------------ */
#if !defined(_WIN32)
static pthread_key_t g_thread_key;
static pthread_once_t g_thread_once = PTHREAD_ONCE_INIT;

static void thread_ends(void *ts)
{
    /* the thread that got a thread state from us ends: delete it (if Python still runs). By now
     * glibc has cleared Python's own thread-specific pointer to it (every key's value is cleared
     * at thread exit), so PyGILState_Release cannot be used: clear and delete it directly. */
    if (ts && G.py.Py_IsInitialized && G.py.Py_IsInitialized() && G.py.PyThreadState_Clear &&
        G.py.PyThreadState_DeleteCurrent) {
        G.py.PyEval_RestoreThread((PyThreadState *)ts);
        G.py.PyThreadState_Clear((PyThreadState *)ts);
        G.py.PyThreadState_DeleteCurrent();  /* releases the GIL */
    }
}
static void make_key(void) { pthread_key_create(&g_thread_key, thread_ends); }
#endif

static _Thread_local int tls_has_state;

/* Give the calling thread a Python thread state that lives as long as the thread, so that
 * pythonfmu's PyGILState_Ensure/Release pairs find it instead of creating and destroying one. */
static void thread_state(void)
{
    if (tls_has_state) return;
    tls_has_state = 1;
    if (G.py.PyGILState_GetThisThreadState()) return;  /* a Python thread, or the first one */
    G.py.PyGILState_Ensure();
    PyThreadState *ts = G.py.PyEval_SaveThread();
#if !defined(_WIN32)
    pthread_once(&g_thread_once, make_key);
    pthread_setspecific(g_thread_key, ts);
#else
    (void)ts; /* kept until the process ends */
#endif
}

/* the text of the pending Python exception (cleared), or "" */
static void py_error(char *out, size_t n)
{
    out[0] = 0;
    if (!G.py.PyErr_Occurred()) return;
    PyObject *type, *value, *tb;
    G.py.PyErr_Fetch(&type, &value, &tb);
    PyObject *s = value ? G.py.PyObject_Str(value) : NULL;
    const char *text = s ? G.py.PyUnicode_AsUTF8(s) : NULL;
    snprintf(out, n, "%s", text ? text : "unknown Python error");
    if (s) G.py.Py_DecRef(s);
    if (type) G.py.Py_DecRef(type);
    if (value) G.py.Py_DecRef(value);
    if (tb) G.py.Py_DecRef(tb);
    G.py.PyErr_Clear();
}

/* Call helper function `fn` (GIL held) with a format and arguments; returns its str result
 * ("" for None) in out; -1 if the call raised (the message in out). */
static int helper_call(const char *fn, char *out, size_t n, const char *fmt, ...)
{
    out[0] = 0;
    PyObject *f = G.py.PyDict_GetItemString(G.helper, fn);
    if (!f) {
        snprintf(out, n, "%s has no function %s", FLX_HELPER, fn);
        return -1;
    }
    va_list ap;
    va_start(ap, fmt);
    void *a0 = va_arg(ap, void *);
    void *a1 = va_arg(ap, void *);
    va_end(ap);
    PyObject *r = G.py.PyObject_CallFunction(f, fmt, a0, a1);
    if (!r) {
        py_error(out, n);
        return -1;
    }
    if (r != G.py.Py_None) {
        const char *s = G.py.PyUnicode_AsUTF8(r);
        snprintf(out, n, "%s", s ? s : "");
        if (!s) G.py.PyErr_Clear();
    }
    G.py.Py_DecRef(r);
    return 0;
}

#define RESOLVE(api, lib, name)                                                                \
    do {                                                                                       \
        *(void **)&api.name = lib_sym(lib, #name);                                             \
        if (!api.name) {                                                                       \
            snprintf(why, n, "%s has no function %s", what, #name);                            \
            return -1;                                                                         \
        }                                                                                      \
    } while (0)

static int resolve_python(void *lib, const char *what, char *why, size_t n)
{
    RESOLVE(G.py, lib, Py_IsInitialized);
    RESOLVE(G.py, lib, PyConfig_InitIsolatedConfig);
    RESOLVE(G.py, lib, PyConfig_SetBytesArgv);
    RESOLVE(G.py, lib, Py_InitializeFromConfig);
    RESOLVE(G.py, lib, PyConfig_Clear);
    RESOLVE(G.py, lib, PyStatus_Exception);
    RESOLVE(G.py, lib, PyEval_SaveThread);
    RESOLVE(G.py, lib, PyEval_RestoreThread);
    RESOLVE(G.py, lib, PyGILState_Ensure);
    RESOLVE(G.py, lib, PyGILState_Release);
    RESOLVE(G.py, lib, PyGILState_GetThisThreadState);
    /* optional: without them a thread's state is kept after the thread ends */
    *(void **)&G.py.PyThreadState_Clear = lib_sym(lib, "PyThreadState_Clear");
    *(void **)&G.py.PyThreadState_DeleteCurrent = lib_sym(lib, "PyThreadState_DeleteCurrent");
    RESOLVE(G.py, lib, Py_CompileString);
    RESOLVE(G.py, lib, PyEval_EvalCode);
    RESOLVE(G.py, lib, PyDict_New);
    RESOLVE(G.py, lib, PyDict_SetItemString);
    RESOLVE(G.py, lib, PyDict_GetItemString);
    RESOLVE(G.py, lib, PyEval_GetBuiltins);
    RESOLVE(G.py, lib, PyObject_CallFunction);
    RESOLVE(G.py, lib, PyObject_GetAttrString);
    RESOLVE(G.py, lib, PyUnicode_AsUTF8);
    RESOLVE(G.py, lib, PyUnicode_FromString);
    RESOLVE(G.py, lib, PyErr_Occurred);
    RESOLVE(G.py, lib, PyErr_Fetch);
    RESOLVE(G.py, lib, PyObject_Str);
    RESOLVE(G.py, lib, PyErr_Clear);
    RESOLVE(G.py, lib, Py_DecRef);
    RESOLVE(G.py, lib, PySys_GetObject);
    RESOLVE(G.py, lib, PyList_Size);
    RESOLVE(G.py, lib, PyList_GetItem);
    RESOLVE(G.py, lib, PySequence_DelItem);
    RESOLVE(G.py, lib, PyObject_RichCompareBool);
    G.py.Py_None = lib_sym(lib, "_Py_NoneStruct");
    if (!G.py.Py_None) {
        snprintf(why, n, "%s has no _Py_NoneStruct", what);
        return -1;
    }
    return 0;
}

/* ---- finding a Python: the probe runs a candidate interpreter on resources/flexpend_loader.py
 * in a child process, which prints "libpython=...", "version=...", "missing=..." lines. */
#if defined(_WIN32)
static int run_probe(const char *exe, const char *script, char *out, size_t n)
{
    wchar_t cmd[8192];
    char cmd8[8192];
    snprintf(cmd8, sizeof cmd8, "\"%s\" -I \"%s\"", exe, script);
    if (!MultiByteToWideChar(CP_UTF8, 0, cmd8, -1, cmd, 8192)) return -1;
    SECURITY_ATTRIBUTES sa = {sizeof sa, NULL, TRUE};
    HANDLE rd, wr;
    if (!CreatePipe(&rd, &wr, &sa, 0)) return -1;
    SetHandleInformation(rd, HANDLE_FLAG_INHERIT, 0);
    STARTUPINFOW si;
    memset(&si, 0, sizeof si);
    si.cb = sizeof si;
    si.dwFlags = STARTF_USESTDHANDLES;
    si.hStdOutput = wr;
    si.hStdError = wr;
    si.hStdInput = GetStdHandle(STD_INPUT_HANDLE);
    PROCESS_INFORMATION pi;
    if (!CreateProcessW(NULL, cmd, NULL, NULL, TRUE, CREATE_NO_WINDOW, NULL, NULL, &si, &pi)) {
        CloseHandle(rd);
        CloseHandle(wr);
        snprintf(out, n, "cannot run it (error %lu)", GetLastError());
        return -1;
    }
    CloseHandle(wr);
    size_t k = 0;
    DWORD got;
    while (k + 1 < n && ReadFile(rd, out + k, (DWORD)(n - 1 - k), &got, NULL) && got > 0) k += got;
    out[k] = 0;
    CloseHandle(rd);
    WaitForSingleObject(pi.hProcess, FLX_PROBE_SECONDS * 1000);
    DWORD code = 1;
    GetExitCodeProcess(pi.hProcess, &code);
    CloseHandle(pi.hProcess);
    CloseHandle(pi.hThread);
    return code == 0 ? 0 : -1;
}
#else
static int run_probe(const char *exe, const char *script, char *out, size_t n)
{
    int fd[2];
    out[0] = 0;
    if (pipe(fd) != 0) return -1;
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    posix_spawn_file_actions_adddup2(&fa, fd[1], 1);
    posix_spawn_file_actions_adddup2(&fa, fd[1], 2);
    posix_spawn_file_actions_addclose(&fa, fd[0]);
    char *argv[] = {(char *)exe, "-I", (char *)script, NULL};
    pid_t pid;
    int rc = posix_spawn(&pid, exe, &fa, NULL, argv, environ);
    posix_spawn_file_actions_destroy(&fa);
    close(fd[1]);
    if (rc != 0) {
        close(fd[0]);
        snprintf(out, n, "cannot run it (%s)", strerror(rc));
        return -1;
    }
    size_t k = 0;
    time_t start = time(NULL);
    for (;;) {
        struct pollfd p = {fd[0], POLLIN, 0};
        int r = poll(&p, 1, 1000);
        if (r < 0 && errno == EINTR) continue;
        if (r > 0) {
            ssize_t got = read(fd[0], out + k, k + 1 < n ? n - 1 - k : 0);
            if (got <= 0) break;
            k += (size_t)got;
        }
        if (time(NULL) - start > FLX_PROBE_SECONDS) {
            kill(pid, SIGKILL);
            append(out, n, "\nno answer within %d s", FLX_PROBE_SECONDS);
            break;
        }
    }
    out[k < n ? k : n - 1] = 0;
    close(fd[0]);
    int status = 0;
    while (waitpid(pid, &status, 0) < 0 && errno == EINTR) {}
    return (WIFEXITED(status) && WEXITSTATUS(status) == 0) ? 0 : -1;
}
#endif

/* the value of "key=" in the probe's output */
static void probe_value(const char *out, const char *key, char *val, size_t n)
{
    val[0] = 0;
    size_t kl = strlen(key);
    for (const char *line = out; line && *line;) {
        const char *end = strchr(line, '\n');
        size_t len = end ? (size_t)(end - line) : strlen(line);
        if (len > kl && !strncmp(line, key, kl) && line[kl] == '=') {
            size_t vl = len - kl - 1;
            if (vl >= n) vl = n - 1;
            memcpy(val, line + kl + 1, vl);
            val[vl] = 0;
            while (vl && (val[vl - 1] == '\r')) val[--vl] = 0;
            return;
        }
        line = end ? end + 1 : NULL;
    }
}

/* python3 on PATH, or "" */
static void on_path(char *out, size_t n)
{
    out[0] = 0;
    const char *path = getenv("PATH");
#if defined(_WIN32)
    const char *names[] = {"python3.exe", "python.exe", NULL};
#else
    const char *names[] = {"python3", NULL};
#endif
    for (int i = 0; names[i] && path; ++i) {
        for (const char *p = path; *p;) {
            const char *e = strchr(p, FLX_PATH_LIST_SEP);
            size_t len = e ? (size_t)(e - p) : strlen(p);
            if (len) {
                snprintf(out, n, "%.*s%c%s", (int)len, p, FLX_SEP, names[i]);
                if (file_exists(out)) return;
            }
            p = e ? e + 1 : p + len;
        }
    }
    out[0] = 0;
}

/* Try one interpreter: probe it, load its libpython, initialise it. 1: loaded; 0: not usable
 * (reason appended to why); -1: loaded but failed (why set; no other may be tried). */
static int try_python(const char *exe, const char *origin, const char *resources, char *why,
                      size_t n)
{
    char script[4096], out[FLX_MSG], lib[4096], version[64], missing[2048];
    snprintf(script, sizeof script, "%s%c%s", resources, FLX_SEP, FLX_HELPER);
    if (!file_exists(exe)) {
        append(why, n, "\n  - %s (%s): no such file", exe, origin);
        return 0;
    }
    if (run_probe(exe, script, out, sizeof out) != 0 && !strstr(out, "libpython=")) {
        char *last = out + strlen(out);
        while (last > out && (last[-1] == '\n' || last[-1] == '\r')) *--last = 0;
        char *line = strrchr(out, '\n');
        append(why, n, "\n  - %s (%s): it failed to run: %s", exe, origin, line ? line + 1 : out);
        return 0;
    }
    probe_value(out, "libpython", lib, sizeof lib);
    probe_value(out, "version", version, sizeof version);
    probe_value(out, "missing", missing, sizeof missing);
    if (missing[0]) {
        append(why, n, "\n  - %s (%s, Python %s): %s", exe, origin, version, missing);
        return 0;
    }
    if (!lib[0] || !file_exists(lib)) {
        append(why, n, "\n  - %s (%s, Python %s): no shared libpython (a Python built without "
               "--enable-shared cannot be embedded)", exe, origin, version);
        return 0;
    }
    char err[2048];
    void *h = lib_open(lib, 1, err, sizeof err);
    if (!h) {
        append(why, n, "\n  - %s (%s): cannot load %s: %s", exe, origin, lib, err);
        return 0;
    }
    if (resolve_python(h, lib, err, sizeof err) != 0) {
        append(why, n, "\n  - %s (%s): %s", exe, origin, err);
        return 0;
    }
    if (!G.py.Py_IsInitialized()) {
        /* the isolated configuration: no signal handlers, no PYTHON* variables, no user site;
         * argv[0] = the interpreter, so that a virtual environment's pyvenv.cfg is found */
        void *config = calloc(1, 1 << 16);  /* far larger than any version's PyConfig */
        char *argv[] = {(char *)exe, NULL};
        G.py.PyConfig_InitIsolatedConfig(config);
        PyStatus st = G.py.PyConfig_SetBytesArgv(config, 1, argv);
        if (!G.py.PyStatus_Exception(st)) st = G.py.Py_InitializeFromConfig(config);
        G.py.PyConfig_Clear(config);
        free(config);
        if (G.py.PyStatus_Exception(st) || !G.py.Py_IsInitialized()) {
            snprintf(why, n, "the Python %s (%s) failed to start: %s%s%s", exe, origin,
                     st.func ? st.func : "", st.func ? ": " : "", st.err_msg ? st.err_msg : "");
            return -1;
        }
        G.py.PyEval_SaveThread();  /* the GIL is taken per call from now on */
    }
    snprintf(G.python, sizeof G.python, "%s (%s, Python %s)", exe, origin, version);
    return 1;
}

/* Load the helper module, then pythonfmu's library. GIL not held on entry. */
static int load_rest(const char *resources, char *why, size_t n)
{
    char path[4096], err[FLX_MSG];
    snprintf(path, sizeof path, "%s%c%s", resources, FLX_SEP, FLX_HELPER);
    char *src = read_file(path, NULL);
    if (!src) {
        snprintf(why, n, "cannot read %s", path);
        return -1;
    }
    thread_state();
    PyGILState_STATE g = G.py.PyGILState_Ensure();
    PyObject *code = G.py.Py_CompileString(src, path, FLX_Py_file_input);
    free(src);
    PyObject *ns = G.py.PyDict_New(), *r = NULL;
    if (code && ns) {
        PyObject *name = G.py.PyUnicode_FromString("flexpend_loader");
        G.py.PyDict_SetItemString(ns, "__name__", name);
        G.py.Py_DecRef(name);
        G.py.PyDict_SetItemString(ns, "__builtins__", G.py.PyEval_GetBuiltins());
        r = G.py.PyEval_EvalCode(code, ns, ns);
    }
    int rc = 0;
    if (!r) {
        py_error(err, sizeof err);
        snprintf(why, n, "%s failed: %s", path, err);
        rc = -1;
    } else {
        G.py.Py_DecRef(r);
        G.helper = ns;
        ns = NULL;
        /* the Python in use must have what the FMU needs (the host's own Python was not probed) */
        if (helper_call("missing_in_host", err, sizeof err, "()", NULL, NULL) != 0 || err[0]) {
            snprintf(why, n, "the Python in this process, %s, cannot run this FMU: %s", G.python,
                     err);
            rc = -1;
        }
    }
    if (code) G.py.Py_DecRef(code);
    if (ns) G.py.Py_DecRef(ns);
    G.py.PyGILState_Release(g);
    if (rc) return rc;

    char self[4096];
    if (self_path(self, sizeof self) != 0) {
        snprintf(why, n, "cannot find the path of the FMU's binary");
        return -1;
    }
    size_t k = strlen(self);
    size_t sl = strlen(FLX_LIB_SUFFIX);
    if (k > sl && !strcmp(self + k - sl, FLX_LIB_SUFFIX)) self[k - sl] = 0;
    snprintf(path, sizeof path, "%s_pythonfmu%s", self, FLX_LIB_SUFFIX);
    void *h = lib_open(path, 0, err, sizeof err);
    if (!h) {
        snprintf(why, n, "cannot load pythonfmu's library %s: %s", path, err);
        return -1;
    }
    const char *what = path;
#define RESOLVE_FMU(field, name)                                                               \
    do {                                                                                       \
        *(void **)&G.fmu.field = lib_sym(h, name);                                             \
        if (!G.fmu.field) {                                                                    \
            snprintf(why, n, "%s has no function %s", what, name);                             \
            return -1;                                                                         \
        }                                                                                      \
    } while (0)
    RESOLVE_FMU(instantiate, "fmi2Instantiate");
    RESOLVE_FMU(free_instance, "fmi2FreeInstance");
    RESOLVE_FMU(setup, "fmi2SetupExperiment");
    RESOLVE_FMU(enter_init, "fmi2EnterInitializationMode");
    RESOLVE_FMU(exit_init, "fmi2ExitInitializationMode");
    RESOLVE_FMU(terminate, "fmi2Terminate");
    RESOLVE_FMU(reset, "fmi2Reset");
    RESOLVE_FMU(get_real, "fmi2GetReal");
    RESOLVE_FMU(get_integer, "fmi2GetInteger");
    RESOLVE_FMU(get_boolean, "fmi2GetBoolean");
    RESOLVE_FMU(get_string, "fmi2GetString");
    RESOLVE_FMU(set_real, "fmi2SetReal");
    RESOLVE_FMU(set_integer, "fmi2SetInteger");
    RESOLVE_FMU(set_boolean, "fmi2SetBoolean");
    RESOLVE_FMU(set_string, "fmi2SetString");
    RESOLVE_FMU(get_state, "fmi2GetFMUstate");
    RESOLVE_FMU(set_state, "fmi2SetFMUstate");
    RESOLVE_FMU(free_state, "fmi2FreeFMUstate");
    RESOLVE_FMU(state_size, "fmi2SerializedFMUstateSize");
    RESOLVE_FMU(serialize, "fmi2SerializeFMUstate");
    RESOLVE_FMU(deserialize, "fmi2DeSerializeFMUstate");
    RESOLVE_FMU(do_step, "fmi2DoStep");
    return 0;
}

/* Make Python and pythonfmu ready (once per process); 0 on success, else G.why says why. */
static int ensure_python(const Table *t, const char *resources)
{
    if (G.tried) return G.tried > 0 ? 0 : -1;
    char *why = G.why;
    size_t n = sizeof G.why;
    why[0] = 0;
    void *proc = process_python();
    int found = 0;
    if (proc) {
        char err[1024];
        if (resolve_python(proc, "the process's Python", err, sizeof err) != 0) {
            snprintf(why, n, "%s", err);
            found = -1;
        } else if (!G.py.Py_IsInitialized()) {
            snprintf(why, n, "the process has a Python that is not initialised; initialise it "
                     "before instantiating this FMU");
            found = -1;
        } else {
            snprintf(G.python, sizeof G.python, "the Python of the host process");
            found = 1;
        }
    } else {
        const char *env = getenv(FLX_ENV);
        char buf[4096];
        if (env && *env) {
            found = try_python(env, "named by " FLX_ENV, resources, why, n);
        } else {
            if (t->python[0]) found = try_python(t->python, "recorded at build time", resources, why, n);
            if (!found) {
                on_path(buf, sizeof buf);
                if (buf[0]) found = try_python(buf, "python3 on PATH", resources, why, n);
                else append(why, n, "\n  - python3 on PATH: none");
            }
        }
        if (found == 0) {
            char tried[FLX_MSG];
            snprintf(tried, sizeof tried, "%s", why);
            snprintf(why, n, "no usable Python was found for this FMU (it needs CPython >= 3.10 "
                     "with a shared libpython and numpy). Tried:%s\nName one with the "
                     "environment variable " FLX_ENV "=/path/to/python3 (for example a virtual "
                     "environment with numpy installed).", tried);
        }
    }
    if (found == 1 && load_rest(resources, why, n) != 0) found = -1;
    G.tried = found == 1 ? 1 : -1;
    return found == 1 ? 0 : -1;
}

/* ------------------------------------------------------------------------------------------ *
 * FMU states handed out: only those may come back.
 * ------------------------------------------------------------------------------------------ */
static int state_known(void *s, void *owner)
{
    lock();
    int found = 0;
    for (size_t i = 0; i < G.n_states; ++i)
        if (G.states[i].state == s && (!owner || G.states[i].owner == owner)) found = 1;
    unlock();
    return found;
}

static void state_add(void *s, void *owner)
{
    lock();
    if (G.n_states == G.cap_states) {
        size_t cap = G.cap_states ? 2 * G.cap_states : 16;
        LiveState *p = realloc(G.states, cap * sizeof *p);
        if (p) {
            G.states = p;
            G.cap_states = cap;
        }
    }
    if (G.n_states < G.cap_states) G.states[G.n_states++] = (LiveState){s, owner};
    unlock();
}

static void state_remove(void *s)
{
    lock();
    for (size_t i = 0; i < G.n_states; ++i)
        if (G.states[i].state == s) {
            G.states[i] = G.states[--G.n_states];
            break;
        }
    unlock();
}

/* ------------------------------------------------------------------------------------------ *
 * Forwarding
 * ------------------------------------------------------------------------------------------ */
static void begin(Instance *inst)
{
    inst->worst = fmi2OK;
    tls_exception[0] = 0;
    thread_state();
}

/* the status to return for pythonfmu's status `s`: a logged error makes it an error; a Fatal
 * (a Python exception escaped, pythonfmu's instance is now unusable) makes the instance broken */
static fmi2Status finish(Instance *inst, const char *fn, fmi2Status s)
{
    if (tls_exception[0]) {
        logf_(inst, fmi2Error, "%s; the instance cannot be used any more", tls_exception);
        inst->state = FLX_BROKEN;
        return fmi2Error;
    }
    if (s >= fmi2Fatal) {
        logf_(inst, fmi2Error, "%s failed inside the FMU's Python code (see the message above); "
              "the instance cannot be used any more: free it", fn);
        inst->state = FLX_BROKEN;
        return fmi2Error;
    }
    if (inst->worst >= fmi2Error && s < fmi2Error) return fmi2Error;
    if (inst->worst == fmi2Warning && s == fmi2OK) return fmi2Warning;
    return s;
}

#define INSTANCE(fn)                                                                           \
    Instance *inst = get(c);                                                                   \
    if (!inst) return fmi2Error;                                                               \
    begin(inst);

static int check_vrs(Instance *inst, const char *fn, const fmi2ValueReference vr[], size_t nvr,
                     const void *values, char type, int set)
{
    if (nvr == 0) return 1;
    if (!vr || !values) {
        logf_(inst, fmi2Error, "%s: the value reference or value array is NULL", fn);
        return 0;
    }
    const Table *t = &inst->table;
    for (size_t i = 0; i < nvr; ++i) {
        if (vr[i] >= t->n_vars) {
            logf_(inst, fmi2Error, "%s: value reference %u is unknown (this FMU has 0..%u)", fn,
                  vr[i], t->n_vars - 1);
            return 0;
        }
        if (t->type[vr[i]] != type) {
            char k = t->type[vr[i]];
            const char *have = k == 'R' ? "Real" : k == 'I' ? "Integer" : k == 'B' ? "Boolean"
                                                                          : "String";
            logf_(inst, fmi2Error, "%s: variable %s (value reference %u) is of type %s", fn,
                  var_name(t, vr[i]), vr[i], have);
            return 0;
        }
        if (set) {
            char c = t->causality[vr[i]];
            if (c == 'o') {
                logf_(inst, fmi2Error, "%s: %s (value reference %u) is an output; it cannot be "
                      "set", fn, var_name(t, vr[i]), vr[i]);
                return 0;
            }
            if (c == 'p' && !(inst->state & (FLX_INSTANTIATED | FLX_INIT))) {
                logf_(inst, fmi2Error, "%s: parameter %s is fixed: it can be set only before "
                      "fmi2ExitInitializationMode", fn, var_name(t, vr[i]));
                return 0;
            }
        }
    }
    return 1;
}

/* ------------------------------------------------------------------------------------------ *
 * The FMI 2.0 functions
 * ------------------------------------------------------------------------------------------ */
FLX_EXPORT const char *fmi2GetTypesPlatform(void) { return "default"; }
FLX_EXPORT const char *fmi2GetVersion(void) { return "2.0"; }

FLX_EXPORT fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType,
                                         fmi2String fmuGUID, fmi2String fmuResourceLocation,
                                         const fmi2CallbackFunctions *functions,
                                         fmi2Boolean visible, fmi2Boolean loggingOn)
{
    Instance *inst = calloc(1, sizeof *inst);
    if (!inst) return NULL;
    inst->magic = FLX_MAGIC;
    inst->logging_on = loggingOn != fmi2False;
    if (functions) inst->host = *functions;
    snprintf(inst->name, sizeof inst->name, "%s", instanceName ? instanceName : "(unnamed)");
    inst->mine.logger = relay_logger;
    inst->mine.allocateMemory = inst->host.allocateMemory ? inst->host.allocateMemory : calloc;
    inst->mine.freeMemory = inst->host.freeMemory ? inst->host.freeMemory : free;
    inst->mine.componentEnvironment = inst;
    char resources[4096], why[FLX_MSG];
    fmi2Component inner = NULL;
    if (fmuType != fmi2CoSimulation) {
        logf_(inst, fmi2Error, "fmi2Instantiate: this FMU supports co-simulation only");
    } else if (!fmuResourceLocation || uri_to_path(fmuResourceLocation, resources, sizeof resources)) {
        logf_(inst, fmi2Error, "fmi2Instantiate: the resource location %s is not a file URI",
              fmuResourceLocation ? fmuResourceLocation : "(NULL)");
    } else if (read_table(resources, &inst->table, why, sizeof why) != 0) {
        logf_(inst, fmi2Error, "fmi2Instantiate: %s", why);
    } else {
        lock();
        int rc = ensure_python(&inst->table, resources);
        unlock();
        if (rc != 0) {
            logf_(inst, fmi2Error, "fmi2Instantiate of %s: %s", inst->table.model, G.why);
        } else {
            begin(inst);
            char msg[FLX_MSG];
            PyGILState_STATE g = G.py.PyGILState_Ensure();
            ssize_t before = -1;
            PyObject *path = G.py.PySys_GetObject("path");
            if (helper_call("before_instantiate", msg, sizeof msg, "(ss)", resources,
                            inst->table.model) != 0 || msg[0])
                logf_(inst, fmi2Warning, "fmi2Instantiate: %s", msg);
            if (path) before = G.py.PyList_Size(path);
            G.py.PyGILState_Release(g);
            /* pythonfmu always logs (its messages are filtered here) */
            lock();  /* pythonfmu's first instantiation starts a thread; keep it serial */
            inner = flx_guard_instantiate(G.fmu.instantiate, inst->name, fmuType, fmuGUID,
                                          fmuResourceLocation, &inst->mine, visible, fmi2True);
            unlock();
            g = G.py.PyGILState_Ensure();
            /* pythonfmu put the resources folder first on sys.path (once per instance, with one
             * reference too many): take it off again, so that the host's imports are not
             * changed by the FMU and sys.path does not grow with every instance */
            path = G.py.PySys_GetObject("path");
            if (path && before >= 0 && G.py.PyList_Size(path) == before + 1) {
                PyObject *first = G.py.PyList_GetItem(path, 0);
                PyObject *want = G.py.PyUnicode_FromString(resources);
                if (first && want && G.py.PyObject_RichCompareBool(first, want, FLX_Py_EQ) == 1) {
                    /* ob_refcnt is the first field of every object */
                    ssize_t refs = *(ssize_t *)first;
                    if (refs == 2) {  /* the list's reference and the leaked one */
                        G.py.PySequence_DelItem(path, 0);
                        G.py.Py_DecRef(first);
                    } else {
                        G.py.PySequence_DelItem(path, 0);
                    }
                }
                if (want) G.py.Py_DecRef(want);
                G.py.PyErr_Clear();
            }
            /* pythonfmu 0.7.0 releases, at every instantiation, one reference to the slave
             * module's dict that it never took (Py_DECREF of the borrowed PyModule_GetDict):
             * take one here and keep it, so that the count stays right (else the dict is freed
             * while in use once the interpreter finalises the module: a heap corruption at the
             * exit of a Python host) */
            PyObject *fn = G.py.PyDict_GetItemString(G.helper, "slave_module");
            PyObject *mod = fn ? G.py.PyObject_CallFunction(fn, "(s)", resources) : NULL;
            if (mod && mod != G.py.Py_None) G.py.PyObject_GetAttrString(mod, "__dict__");
            if (mod) G.py.Py_DecRef(mod);
            G.py.PyErr_Clear();
            G.py.PyGILState_Release(g);
            if (!inner) {
                logf_(inst, fmi2Error, "fmi2Instantiate: pythonfmu could not create the instance%s%s",
                      tls_exception[0] ? ": " : " (see the messages above)", tls_exception);
            }
        }
    }
    if (!inner) {
        free(inst->table.names);
        inst->magic = 0;
        free(inst);
        return NULL;
    }
    inst->inner = inner;
    inst->state = FLX_INSTANTIATED;
    return inst;
}

static void free_states_of(Instance *inst)
{
    for (;;) {
        void *s = NULL;
        lock();
        for (size_t i = 0; i < G.n_states; ++i)
            if (G.states[i].owner == inst) {
                s = G.states[i].state;
                G.states[i] = G.states[--G.n_states];
                break;
            }
        unlock();
        if (!s) break;
        fmi2FMUstate st = s;
        flx_guard_free_state(G.fmu.free_state, inst->inner, &st);
    }
}

FLX_EXPORT void fmi2FreeInstance(fmi2Component c)
{
    Instance *inst = get(c);
    if (!inst) return;
    begin(inst);
    if (inst->state != FLX_BROKEN) {
        free_states_of(inst);
        flx_guard_free(G.fmu.free_instance, inst->inner);
    }
    /* a broken pythonfmu instance is left alone: its destructor would release Python objects a
     * second time */
    inst->magic = 0;
    free(inst->table.names);
    free(inst);
}

FLX_EXPORT fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn,
                                          size_t nCategories, const fmi2String categories[])
{
    INSTANCE(fmi2SetDebugLogging)
    if (nCategories && !categories) {
        logf_(inst, fmi2Error, "fmi2SetDebugLogging: categories is NULL");
        return fmi2Error;
    }
    if (nCategories > FLX_MAX_CATS) {
        logf_(inst, fmi2Error, "fmi2SetDebugLogging: at most %d categories", FLX_MAX_CATS);
        return fmi2Error;
    }
    for (size_t i = 0; i < nCategories; ++i) {
        unsigned k = 0;
        while (categories[i] && k < inst->table.n_cats && strcmp(categories[i], inst->table.cats[k])) ++k;
        if (!categories[i] || k == inst->table.n_cats) {
            logf_(inst, fmi2Error, "fmi2SetDebugLogging: unknown log category %s",
                  categories[i] ? categories[i] : "(NULL)");
            return fmi2Error;
        }
    }
    inst->logging_on = loggingOn != fmi2False;
    inst->n_filter = (unsigned)nCategories;
    for (size_t i = 0; i < nCategories; ++i) snprintf(inst->filter[i], 64, "%s", categories[i]);
    return fmi2OK;
}

FLX_EXPORT fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined,
                                          fmi2Real tolerance, fmi2Real startTime,
                                          fmi2Boolean stopTimeDefined, fmi2Real stopTime)
{
    INSTANCE(fmi2SetupExperiment)
    if (!allowed(inst, "fmi2SetupExperiment", FLX_INSTANTIATED)) return fmi2Error;
    if (!isfinite(startTime) || (toleranceDefined && !(tolerance > 0 && isfinite(tolerance))) ||
        (stopTimeDefined && !(stopTime >= startTime))) {
        logf_(inst, fmi2Error, "fmi2SetupExperiment: startTime must be finite, a defined "
              "tolerance positive and finite, a defined stopTime >= startTime (got startTime = "
              "%.17g, tolerance = %.17g, stopTime = %.17g)", startTime, tolerance, stopTime);
        return fmi2Error;
    }
    fmi2Status s = flx_guard_setup(G.fmu.setup, inst->inner, toleranceDefined, tolerance,
                                   startTime, stopTimeDefined, stopTime);
    inst->time = startTime;
    return finish(inst, "fmi2SetupExperiment", s);
}

FLX_EXPORT fmi2Status fmi2EnterInitializationMode(fmi2Component c)
{
    INSTANCE(fmi2EnterInitializationMode)
    if (!allowed(inst, "fmi2EnterInitializationMode", FLX_INSTANTIATED)) return fmi2Error;
    fmi2Status s = finish(inst, "fmi2EnterInitializationMode",
                          flx_guard_component(G.fmu.enter_init, inst->inner));
    if (s <= fmi2Warning) inst->state = FLX_INIT;
    return s;
}

FLX_EXPORT fmi2Status fmi2ExitInitializationMode(fmi2Component c)
{
    INSTANCE(fmi2ExitInitializationMode)
    if (!allowed(inst, "fmi2ExitInitializationMode", FLX_INIT)) return fmi2Error;
    fmi2Status s = finish(inst, "fmi2ExitInitializationMode",
                          flx_guard_component(G.fmu.exit_init, inst->inner));
    /* a bad parameter is an error of this call; the instance is initialised all the same and
     * refuses every step with the reason (a state restore or fmi2Reset makes it usable) */
    if (inst->state != FLX_BROKEN) inst->state = FLX_STEPPING;
    return s;
}

FLX_EXPORT fmi2Status fmi2Terminate(fmi2Component c)
{
    INSTANCE(fmi2Terminate)
    if (!allowed(inst, "fmi2Terminate", FLX_INIT | FLX_STEPPING)) return fmi2Error;
    fmi2Status s = finish(inst, "fmi2Terminate", flx_guard_component(G.fmu.terminate, inst->inner));
    if (inst->state != FLX_BROKEN) inst->state = FLX_TERMINATED;
    return s;
}

FLX_EXPORT fmi2Status fmi2Reset(fmi2Component c)
{
    INSTANCE(fmi2Reset)
    if (!allowed(inst, "fmi2Reset", FLX_INSTANTIATED | FLX_INIT | FLX_STEPPING | FLX_TERMINATED))
        return fmi2Error;
    fmi2Status s = finish(inst, "fmi2Reset", flx_guard_component(G.fmu.reset, inst->inner));
    if (inst->state != FLX_BROKEN) inst->state = FLX_INSTANTIATED;
    return s;
}

#define GETTER(fname, T, type, field, guard)                                                   \
    FLX_EXPORT fmi2Status fname(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,    \
                                T value[])                                                     \
    {                                                                                          \
        INSTANCE(fname)                                                                        \
        if (!allowed(inst, #fname, FLX_INIT | FLX_STEPPING | FLX_TERMINATED)) return fmi2Error;   \
        if (!check_vrs(inst, #fname, vr, nvr, value, type, 0)) return fmi2Error;               \
        if (!nvr) return fmi2OK;                                                               \
        return finish(inst, #fname, guard(G.fmu.field, inst->inner, vr, nvr, value));          \
    }

#define SETTER(fname, T, type, field, guard)                                                   \
    FLX_EXPORT fmi2Status fname(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,    \
                                const T value[])                                               \
    {                                                                                          \
        INSTANCE(fname)                                                                        \
        if (!allowed(inst, #fname, FLX_INSTANTIATED | FLX_INIT | FLX_STEPPING)) return fmi2Error; \
        if (!check_vrs(inst, #fname, vr, nvr, value, type, 1)) return fmi2Error;               \
        if (!nvr) return fmi2OK;                                                               \
        return finish(inst, #fname, guard(G.fmu.field, inst->inner, vr, nvr, value));          \
    }

GETTER(fmi2GetReal, fmi2Real, 'R', get_real, flx_guard_get_real)
GETTER(fmi2GetInteger, fmi2Integer, 'I', get_integer, flx_guard_get_integer)
GETTER(fmi2GetBoolean, fmi2Boolean, 'B', get_boolean, flx_guard_get_boolean)
GETTER(fmi2GetString, fmi2String, 'S', get_string, flx_guard_get_string)
SETTER(fmi2SetReal, fmi2Real, 'R', set_real, flx_guard_set_real)
SETTER(fmi2SetInteger, fmi2Integer, 'I', set_integer, flx_guard_set_integer)
SETTER(fmi2SetBoolean, fmi2Boolean, 'B', set_boolean, flx_guard_set_boolean)

FLX_EXPORT fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                    const fmi2String value[])
{
    INSTANCE(fmi2SetString)
    if (!allowed(inst, "fmi2SetString", FLX_INSTANTIATED | FLX_INIT | FLX_STEPPING)) return fmi2Error;
    if (!check_vrs(inst, "fmi2SetString", vr, nvr, value, 'S', 1)) return fmi2Error;
    for (size_t i = 0; i < nvr; ++i)
        if (!value[i]) {
            logf_(inst, fmi2Error, "fmi2SetString: the value of %s is NULL",
                  var_name(&inst->table, vr[i]));
            return fmi2Error;
        }
    if (!nvr) return fmi2OK;
    return finish(inst, "fmi2SetString",
                  flx_guard_set_string(G.fmu.set_string, inst->inner, vr, nvr, value));
}

#define ANY_STATE (FLX_INSTANTIATED | FLX_INIT | FLX_STEPPING | FLX_TERMINATED)

FLX_EXPORT fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate)
{
    INSTANCE(fmi2GetFMUstate)
    if (!allowed(inst, "fmi2GetFMUstate", ANY_STATE)) return fmi2Error;
    if (!FMUstate) {
        logf_(inst, fmi2Error, "fmi2GetFMUstate: FMUstate is NULL");
        return fmi2Error;
    }
    void *old = *FMUstate;
    if (old && !state_known(old, inst)) {
        logf_(inst, fmi2Error, "fmi2GetFMUstate: *FMUstate must be NULL or a state this instance "
              "returned and that was not freed");
        return fmi2Error;
    }
    fmi2FMUstate s = NULL;
    fmi2Status r = finish(inst, "fmi2GetFMUstate", flx_guard_get_state(G.fmu.get_state, inst->inner, &s));
    if (r >= fmi2Error || !s) return r >= fmi2Error ? r : fmi2Error;
    if (old) {  /* FMI: a non-NULL *FMUstate is overwritten */
        state_remove(old);
        flx_guard_free_state(G.fmu.free_state, inst->inner, &old);
    }
    state_add(s, inst);
    *FMUstate = s;
    return r;
}

FLX_EXPORT fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate)
{
    INSTANCE(fmi2SetFMUstate)
    if (!allowed(inst, "fmi2SetFMUstate", ANY_STATE)) return fmi2Error;
    if (!FMUstate || !state_known(FMUstate, NULL)) {
        logf_(inst, fmi2Error, "fmi2SetFMUstate: not an FMU state of this FMU (NULL, freed, or "
              "made by another FMU); the instance is unchanged");
        return fmi2Error;
    }
    fmi2Status s = finish(inst, "fmi2SetFMUstate",
                          flx_guard_set_state(G.fmu.set_state, inst->inner, FMUstate));
    if (s <= fmi2Warning) inst->discarded = 0;
    return s;
}

FLX_EXPORT fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate)
{
    INSTANCE(fmi2FreeFMUstate)
    if (!FMUstate || !*FMUstate) return fmi2OK;  /* FMI: freeing NULL is a no-op */
    if (!state_known(*FMUstate, inst)) {
        logf_(inst, fmi2Error, "fmi2FreeFMUstate: not a state of this instance (or freed already)");
        return fmi2Error;
    }
    state_remove(*FMUstate);
    fmi2Status s = finish(inst, "fmi2FreeFMUstate",
                          flx_guard_free_state(G.fmu.free_state, inst->inner, FMUstate));
    *FMUstate = NULL;
    return s;
}

FLX_EXPORT fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate,
                                                 size_t *size)
{
    INSTANCE(fmi2SerializedFMUstateSize)
    if (!size || !FMUstate || !state_known(FMUstate, NULL)) {
        logf_(inst, fmi2Error, "fmi2SerializedFMUstateSize: size is NULL or the state is not an "
              "FMU state of this FMU");
        return fmi2Error;
    }
    return finish(inst, "fmi2SerializedFMUstateSize",
                  flx_guard_state_size(G.fmu.state_size, inst->inner, FMUstate, size));
}

FLX_EXPORT fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate,
                                            fmi2Byte serializedState[], size_t size)
{
    INSTANCE(fmi2SerializeFMUstate)
    if (!serializedState || !FMUstate || !state_known(FMUstate, NULL)) {
        logf_(inst, fmi2Error, "fmi2SerializeFMUstate: the buffer is NULL or the state is not "
              "an FMU state of this FMU");
        return fmi2Error;
    }
    size_t need = 0;
    fmi2Status s = finish(inst, "fmi2SerializeFMUstate",
                          flx_guard_state_size(G.fmu.state_size, inst->inner, FMUstate, &need));
    if (s >= fmi2Error) return s;
    if (size != need) {
        logf_(inst, fmi2Error, "fmi2SerializeFMUstate: size = %zu, but the state takes %zu bytes "
              "(fmi2SerializedFMUstateSize)", size, need);
        return fmi2Error;
    }
    return finish(inst, "fmi2SerializeFMUstate",
                  flx_guard_serialize(G.fmu.serialize, inst->inner, FMUstate, serializedState, size));
}

FLX_EXPORT fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[],
                                              size_t size, fmi2FMUstate *FMUstate)
{
    INSTANCE(fmi2DeSerializeFMUstate)
    if (!FMUstate || !serializedState || size == 0 || size > ((size_t)1 << 28)) {
        logf_(inst, fmi2Error, "fmi2DeSerializeFMUstate: NULL arguments or a size (%zu) out of "
              "1..2^28", size);
        return fmi2Error;
    }
    if (*FMUstate && !state_known(*FMUstate, inst)) {
        logf_(inst, fmi2Error, "fmi2DeSerializeFMUstate: *FMUstate must be NULL or a state this "
              "instance returned");
        return fmi2Error;
    }
    fmi2FMUstate s = NULL;
    fmi2Status r = finish(inst, "fmi2DeSerializeFMUstate",
                          flx_guard_deserialize(G.fmu.deserialize, inst->inner, serializedState,
                                                size, &s));
    if (r >= fmi2Error || !s) return r >= fmi2Error ? r : fmi2Error;
    /* the model's checks of the blob (format, version, model, sizes, finiteness, parameters) */
    char why[FLX_MSG];
    PyGILState_STATE g = G.py.PyGILState_Ensure();
    int rc = helper_call("state_error", why, sizeof why, "(O)", s, NULL);
    G.py.PyGILState_Release(g);
    if (rc != 0 || why[0]) {
        logf_(inst, fmi2Error, "fmi2DeSerializeFMUstate: %s", why);
        flx_guard_free_state(G.fmu.free_state, inst->inner, &s);
        return fmi2Error;
    }
    if (*FMUstate) {
        void *old = *FMUstate;
        state_remove(old);
        flx_guard_free_state(G.fmu.free_state, inst->inner, &old);
    }
    state_add(s, inst);
    *FMUstate = s;
    return r;
}

FLX_EXPORT fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint,
                                 fmi2Real communicationStepSize,
                                 fmi2Boolean noSetFMUStatePriorToCurrentPoint)
{
    INSTANCE(fmi2DoStep)
    if (!allowed(inst, "fmi2DoStep", FLX_STEPPING)) return fmi2Error;
    if (!(communicationStepSize > 0) || !isfinite(communicationStepSize) ||
        !isfinite(currentCommunicationPoint) ||
        !isfinite(currentCommunicationPoint + communicationStepSize)) {
        logf_(inst, fmi2Error, "fmi2DoStep: the step size must be positive and finite and the "
              "communication point finite (got t = %.17g, h = %.17g); step refused, the instance "
              "is unchanged", currentCommunicationPoint, communicationStepSize);
        return fmi2Error;
    }
    fmi2Status s = flx_guard_do_step(G.fmu.do_step, inst->inner, currentCommunicationPoint,
                                     communicationStepSize, noSetFMUStatePriorToCurrentPoint);
    if (s == fmi2Discard && !tls_exception[0]) {   /* a refused step */
        inst->discarded = 1;
        return fmi2Discard;
    }
    s = finish(inst, "fmi2DoStep", s);
    if (s <= fmi2Warning) {
        inst->time = currentCommunicationPoint + communicationStepSize;
        inst->discarded = 0;
    }
    return s;
}

/* ---- answered here: what pythonfmu does not implement, and the status inquiries */
FLX_EXPORT fmi2Status fmi2CancelStep(fmi2Component c)
{
    INSTANCE(fmi2CancelStep)
    logf_(inst, fmi2Error, "fmi2CancelStep: doStep never returns fmi2Pending here");
    return fmi2Error;
}

FLX_EXPORT fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value)
{
    INSTANCE(fmi2GetStatus)
    (void)s;
    (void)value;
    logf_(inst, fmi2Discard, "fmi2GetStatus: not available (doStep is synchronous)");
    return fmi2Discard;
}

FLX_EXPORT fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value)
{
    INSTANCE(fmi2GetRealStatus)
    if (s == fmi2LastSuccessfulTime && value) {
        *value = inst->time;
        return fmi2OK;
    }
    logf_(inst, fmi2Discard, "fmi2GetRealStatus: only fmi2LastSuccessfulTime is available");
    return fmi2Discard;
}

FLX_EXPORT fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s,
                                           fmi2Integer *value)
{
    INSTANCE(fmi2GetIntegerStatus)
    (void)s;
    (void)value;
    logf_(inst, fmi2Discard, "fmi2GetIntegerStatus: no integer status is available");
    return fmi2Discard;
}

FLX_EXPORT fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s,
                                           fmi2Boolean *value)
{
    INSTANCE(fmi2GetBooleanStatus)
    if (s == fmi2Terminated && value) {
        /* after a refused step the FMU cannot go on by itself (a master that can restore a
         * saved state may still do so): a simple master such as fmpy.simulate_fmu then stops
         * instead of retrying the same step forever */
        *value = inst->discarded ? fmi2True : fmi2False;
        return fmi2OK;
    }
    logf_(inst, fmi2Discard, "fmi2GetBooleanStatus: only fmi2Terminated is available");
    return fmi2Discard;
}

FLX_EXPORT fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s,
                                          fmi2String *value)
{
    INSTANCE(fmi2GetStringStatus)
    (void)s;
    (void)value;
    logf_(inst, fmi2Discard, "fmi2GetStringStatus: no string status is available");
    return fmi2Discard;
}

FLX_EXPORT fmi2Status fmi2GetDirectionalDerivative(fmi2Component c,
                                                   const fmi2ValueReference vUnknown_ref[],
                                                   size_t nUnknown,
                                                   const fmi2ValueReference vKnown_ref[],
                                                   size_t nKnown, const fmi2Real dvKnown[],
                                                   fmi2Real dvUnknown[])
{
    INSTANCE(fmi2GetDirectionalDerivative)
    (void)vUnknown_ref, (void)nUnknown, (void)vKnown_ref, (void)nKnown, (void)dvKnown,
        (void)dvUnknown;
    logf_(inst, fmi2Error, "fmi2GetDirectionalDerivative: not provided "
          "(providesDirectionalDerivative is false)");
    return fmi2Error;
}

FLX_EXPORT fmi2Status fmi2SetRealInputDerivatives(fmi2Component c,
                                                  const fmi2ValueReference vr[], size_t nvr,
                                                  const fmi2Integer order[],
                                                  const fmi2Real value[])
{
    INSTANCE(fmi2SetRealInputDerivatives)
    (void)vr, (void)nvr, (void)order, (void)value;
    logf_(inst, fmi2Error, "fmi2SetRealInputDerivatives: not provided (canInterpolateInputs is "
          "false); set the inputs d<u> and d2<u> instead (docs/fmus.md)");
    return fmi2Error;
}

FLX_EXPORT fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c,
                                                   const fmi2ValueReference vr[], size_t nvr,
                                                   const fmi2Integer order[], fmi2Real value[])
{
    INSTANCE(fmi2GetRealOutputDerivatives)
    (void)vr, (void)nvr, (void)order, (void)value;
    logf_(inst, fmi2Error, "fmi2GetRealOutputDerivatives: not provided "
          "(maxOutputDerivativeOrder is 0)");
    return fmi2Error;
}
