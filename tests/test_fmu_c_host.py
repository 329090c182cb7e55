"""A host with no Python in it: a minimal FMI 2.0 co-simulation master in C (compiled here with
the system's C compiler, skipped without one) loads each FMU's linux64 binary with dlopen.

It checks what docs/fmus.md says a non-Python host needs: without libpython in the process the
binary does not load ("undefined symbol: _Py_NoneStruct"); with libpython preloaded
(LD_PRELOAD) the FMU starts its own interpreter, finds numpy and scipy in that interpreter's
site-packages, and gives the same numbers as fmpy, digit for digit.
"""
import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile

import pytest

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux") or not shutil.which("gcc"),
                                reason="needs Linux and gcc")

H = 1e-3
STEPS = 20

HOST_C = r"""/* A minimal FMI 2.0 co-simulation host in C: no Python anywhere in it. */
#include <dlfcn.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

typedef void *fmi2Component;
typedef unsigned int fmi2ValueReference;
typedef double fmi2Real;
typedef int fmi2Boolean;
typedef const char *fmi2String;
typedef enum { fmi2OK, fmi2Warning, fmi2Discard, fmi2Error, fmi2Fatal, fmi2Pending } fmi2Status;
typedef enum { fmi2ModelExchange, fmi2CoSimulation } fmi2Type;
typedef struct {
    void (*logger)(void *, fmi2String, fmi2Status, fmi2String, fmi2String, ...);
    void *(*allocateMemory)(size_t, size_t);
    void (*freeMemory)(void *);
    void (*stepFinished)(void *, fmi2Status);
    void *componentEnvironment;
} fmi2CallbackFunctions;

typedef fmi2Component (*fmi2Instantiate_t)(fmi2String, fmi2Type, fmi2String, fmi2String, const fmi2CallbackFunctions *, fmi2Boolean, fmi2Boolean);
typedef fmi2Status (*fmi2SetupExperiment_t)(fmi2Component, fmi2Boolean, fmi2Real, fmi2Real, fmi2Boolean, fmi2Real);
typedef fmi2Status (*fmi2EnterInitializationMode_t)(fmi2Component);
typedef fmi2Status (*fmi2ExitInitializationMode_t)(fmi2Component);
typedef fmi2Status (*fmi2SetReal_t)(fmi2Component, const fmi2ValueReference *, size_t, const fmi2Real *);
typedef fmi2Status (*fmi2GetReal_t)(fmi2Component, const fmi2ValueReference *, size_t, fmi2Real *);
typedef fmi2Status (*fmi2DoStep_t)(fmi2Component, fmi2Real, fmi2Real, fmi2Boolean);
typedef fmi2Status (*fmi2Terminate_t)(fmi2Component);
typedef void (*fmi2FreeInstance_t)(fmi2Component);

static void logger(void *env, fmi2String name, fmi2Status s, fmi2String cat, fmi2String msg, ...) {
    fprintf(stderr, "log [%d] %s\n", (int)s, msg);
}

#define LOAD(name) name##_t name = (name##_t)dlsym(lib, #name); if (!name) { fprintf(stderr, "no %s\n", #name); return 3; }

int main(int argc, char **argv) {
    /* host <binary.so> <resource uri> <guid> <steps> <h> <output vr> [<vr>=<real> ...] */
    if (argc < 7) return 2;
    void *lib = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
    if (!lib) { fprintf(stderr, "dlopen: %s\n", dlerror()); return 4; }
    LOAD(fmi2Instantiate)
    LOAD(fmi2SetupExperiment)
    LOAD(fmi2EnterInitializationMode)
    LOAD(fmi2ExitInitializationMode)
    LOAD(fmi2SetReal)
    LOAD(fmi2GetReal)
    LOAD(fmi2DoStep)
    LOAD(fmi2Terminate)
    LOAD(fmi2FreeInstance)
    static fmi2CallbackFunctions cb = {logger, calloc, free, NULL, NULL};
    fmi2Component c = fmi2Instantiate("c_host", fmi2CoSimulation, argv[3], argv[2], &cb, 0, 1);
    if (!c) { fprintf(stderr, "fmi2Instantiate failed\n"); return 5; }
    int steps = atoi(argv[4]);
    double h = atof(argv[5]);
    fmi2ValueReference out = (fmi2ValueReference)atoi(argv[6]);
    if (fmi2SetupExperiment(c, 0, 0.0, 0.0, 0, 0.0) != fmi2OK) return 6;
    for (int i = 7; i < argc; ++i) {
        fmi2ValueReference vr = (fmi2ValueReference)atoi(argv[i]);
        double v = atof(strchr(argv[i], '=') + 1);
        if (fmi2SetReal(c, &vr, 1, &v) != fmi2OK) return 7;
    }
    if (fmi2EnterInitializationMode(c) != fmi2OK || fmi2ExitInitializationMode(c) != fmi2OK) return 8;
    for (int k = 0; k < steps; ++k) {
        if (fmi2DoStep(c, k * h, h, 1) != fmi2OK) return 9;
        double y;
        if (fmi2GetReal(c, &out, 1, &y) != fmi2OK) return 10;
        printf("%.17g\n", y);
    }
    fmi2Terminate(c);
    fmi2FreeInstance(c);
    return 0;
}
"""


@pytest.fixture(scope="module")
def host(tmp_path_factory):
    d = tmp_path_factory.mktemp("c_host")
    (d / "host.c").write_text(HOST_C)
    subprocess.run(["gcc", "-O1", "-Wall", "-Werror", "-o", str(d / "host"), str(d / "host.c"),
                    "-ldl"], check=True, capture_output=True)
    return d / "host"


def libpython() -> str:
    return os.path.join(sysconfig.get_config_var("LIBDIR"), sysconfig.get_config_var("LDLIBRARY"))


def run_host(host, fmu, tmp_path, output, start, preload=True):
    from fmpy import read_model_description

    unpacked = tmp_path / "fmu"
    with zipfile.ZipFile(fmu) as zf:
        zf.extractall(unpacked)
    md = read_model_description(str(unpacked / "modelDescription.xml"))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    model = md.coSimulation.modelIdentifier
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "LD_PRELOAD")}
    if preload:
        env["LD_PRELOAD"] = libpython()
    args = [str(host), str(unpacked / "binaries" / "linux64" / f"{model}.so"),
            (unpacked / "resources").as_uri(), md.guid, str(STEPS), repr(H), str(vr[output])]
    args += [f"{vr[k]}={v!r}" for k, v in start.items()]
    return subprocess.run(args, env=env, cwd=tmp_path, capture_output=True, text=True,
                          timeout=300)


def test_without_libpython_the_binary_does_not_load(host, fmus, tmp_path):
    proc = run_host(host, fmus["PDLowPass"], tmp_path, "F_c", {}, preload=False)
    assert proc.returncode == 4
    assert "undefined symbol: _Py_NoneStruct" in proc.stderr


@pytest.mark.parametrize("name, output, start", [
    ("FlexiblePendulum", "phi_o", {"phi0": 0.1, "x_dot0": -0.2}),
    ("PDLowPass", "F_c", {"phi_o": 0.1, "omega_o": -0.3}),
])
def test_c_host_with_libpython_preloaded_matches_fmpy(host, fmus, open_fmu, tmp_path, name,
                                                     output, start):
    proc = run_host(host, fmus[name], tmp_path, output, start)
    assert proc.returncode == 0, proc.stderr[-3000:]
    values = [float(line) for line in proc.stdout.split()]
    inst = open_fmu(name, **start)
    expected = []
    for k in range(STEPS):
        assert inst.step(k * H, H) == 0
        expected.append(inst.get(output)[0])
    assert values == expected
