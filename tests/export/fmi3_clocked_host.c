/*
 * fmi3_clocked_host.c - a plain FMI 3.0 co-simulation host in C that honours clocks, written to
 * the standard (sections 2.2.9 and 4.2): it instantiates the FMU with eventModeUsed = true,
 * reads the periodic clocks' intervals and shifts in initialization mode
 * (fmi3GetIntervalDecimal, fmi3GetShiftDecimal), then runs from event to event: doStep to the
 * next clock tick, fmi3EnterEventMode, fmi3SetClock of the clocks ticking there, the clocked
 * inputs of the first clock, F_c while the second clock is active, fmi3UpdateDiscreteStates,
 * fmi3EnterStepMode. The inputs are a deterministic sequence of rationals (tick k):
 *   x_o = ((37 k) % 101 - 50) / 500, phi_o = ((53 k) % 89 - 44) / 300,
 *   omega_o = ((71 k) % 97 - 48) / 40.
 * Prints "interval shift" of each clock, then one line per tick of the second clock:
 * "j t F_c" (%.17g). Used by tests/export/test_sampled_clocks.py.
 *
 * usage: fmi3_clocked_host LIB TOKEN N VR_x_o VR_phi_o VR_omega_o VR_F_c VR_CLOCK_IN VR_CLOCK_OUT
 *                          VR_filter_order FILTER_ORDER VR_sample_period SAMPLE_PERIOD
 *                          VR_delay DELAY VR_discretization DISCRETIZATION
 */
#include <stdio.h>
#include <stdlib.h>

#include "fmi3FunctionTypes.h"

#include <dlfcn.h>

#define CHECK(call)                                                                          \
    do {                                                                                     \
        fmi3Status s_ = (call);                                                              \
        if (s_ != fmi3OK) {                                                                  \
            fprintf(stderr, "%s returned %d\n", #call, (int)s_);                             \
            return 2;                                                                        \
        }                                                                                    \
    } while (0)

static void logger(fmi3InstanceEnvironment env, fmi3Status status, fmi3String category,
                   fmi3String message)
{
    (void)env;
    fprintf(stderr, "log [%d] %s: %s\n", (int)status, category ? category : "", message);
}

#define API(X)                                                                               \
    X(InstantiateCoSimulation) X(EnterInitializationMode) X(ExitInitializationMode)          \
    X(SetFloat64) X(GetFloat64) X(SetInt32) X(SetString) X(GetIntervalDecimal)               \
    X(GetShiftDecimal) X(SetClock) X(EnterEventMode) X(EnterStepMode)                        \
    X(UpdateDiscreteStates) X(DoStep) X(Terminate) X(FreeInstance)
#define FIELD(name) fmi3##name##TYPE *name;
typedef struct api { API(FIELD) } api;

int main(int argc, char **argv)
{
    api a;
    void *lib;
    fmi3Instance inst;
    fmi3ValueReference in[3], vr_F, clocks[2], vr_order, vr_T, vr_tau, vr_disc;
    fmi3Float64 interval[2], shift[2], T, tau;
    fmi3IntervalQualifier q[2];
    fmi3Int32 order;
    fmi3String disc;
    long n, i_s = 0, i_f = 0;
    double t = 0.0, tol;
    int in_event;
    if (argc != 18) {
        fprintf(stderr, "usage: see the source\n");
        return 1;
    }
    lib = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
    if (!lib) {
        fprintf(stderr, "cannot load %s\n", argv[1]);
        return 1;
    }
#define LOAD(name)                                                                           \
    *(void **)(&a.name) = dlsym(lib, "fmi3" #name);                                          \
    if (!a.name) {                                                                           \
        fprintf(stderr, "no fmi3" #name "\n");                                               \
        return 1;                                                                            \
    }
    API(LOAD)
    n = atol(argv[3]);
    in[0] = (fmi3ValueReference)atol(argv[4]);
    in[1] = (fmi3ValueReference)atol(argv[5]);
    in[2] = (fmi3ValueReference)atol(argv[6]);
    vr_F = (fmi3ValueReference)atol(argv[7]);
    clocks[0] = (fmi3ValueReference)atol(argv[8]);
    clocks[1] = (fmi3ValueReference)atol(argv[9]);
    vr_order = (fmi3ValueReference)atol(argv[10]);
    order = (fmi3Int32)atol(argv[11]);
    vr_T = (fmi3ValueReference)atol(argv[12]);
    T = strtod(argv[13], NULL);
    vr_tau = (fmi3ValueReference)atol(argv[14]);
    tau = strtod(argv[15], NULL);
    vr_disc = (fmi3ValueReference)atol(argv[16]);
    disc = argv[17];

    inst = a.InstantiateCoSimulation("clocked", argv[2], NULL, fmi3False, fmi3False,
                                     fmi3True /* eventModeUsed */, fmi3False, NULL, 0, NULL,
                                     logger, NULL);
    if (!inst) return 2;
    CHECK(a.EnterInitializationMode(inst, fmi3False, 0.0, 0.0, fmi3False, 0.0));
    CHECK(a.SetInt32(inst, &vr_order, 1, &order, 1));
    CHECK(a.SetFloat64(inst, &vr_T, 1, &T, 1));
    CHECK(a.SetFloat64(inst, &vr_tau, 1, &tau, 1));
    CHECK(a.SetString(inst, &vr_disc, 1, &disc, 1));
    /* fixed periodic clocks without intervalDecimal: read in initialization mode */
    CHECK(a.GetIntervalDecimal(inst, clocks, 2, interval, q));
    CHECK(a.GetShiftDecimal(inst, clocks, 2, shift));
    if (q[0] != fmi3IntervalChanged || q[1] != fmi3IntervalChanged) {
        fprintf(stderr, "qualifiers %d %d\n", (int)q[0], (int)q[1]);
        return 2;
    }
    printf("%.17g %.17g\n%.17g %.17g\n", interval[0], shift[0], interval[1], shift[1]);
    CHECK(a.ExitInitializationMode(inst));   /* -> event mode at the start time */
    in_event = 1;
    tol = 1e-9 * (interval[0] < interval[1] ? interval[0] : interval[1]);
    while (i_f < n) {
        const double ts = shift[0] + (double)i_s * interval[0];
        const double tf = shift[1] + (double)i_f * interval[1];
        const double te = ts < tf ? ts : tf;
        const int sample = ts <= te + tol, force = tf <= te + tol;
        fmi3ValueReference active[2];
        fmi3Clock on[2] = {fmi3ClockActive, fmi3ClockActive};
        size_t na = 0;
        fmi3Boolean need, term, nominals, values, next_defined;
        fmi3Float64 next;
        if (te > t + tol) {
            fmi3Boolean event, terminate, early;
            fmi3Float64 last;
            if (in_event) CHECK(a.EnterStepMode(inst));
            CHECK(a.DoStep(inst, t, te - t, fmi3False, &event, &terminate, &early, &last));
            t = te;
            CHECK(a.EnterEventMode(inst));
            in_event = 1;
        }
        if (sample) active[na++] = clocks[0];
        if (force) active[na++] = clocks[1];
        CHECK(a.SetClock(inst, active, na, on));
        if (sample) {
            const long k = i_s;
            fmi3Float64 y[3];
            y[0] = (double)((37 * k) % 101 - 50) / 500.0;
            y[1] = (double)((53 * k) % 89 - 44) / 300.0;
            y[2] = (double)((71 * k) % 97 - 48) / 40.0;
            CHECK(a.SetFloat64(inst, in, 3, y, 3));
            i_s++;
        }
        if (force) {                          /* read while its clock is active */
            fmi3Float64 F;
            CHECK(a.GetFloat64(inst, &vr_F, 1, &F, 1));
            printf("%ld %.17g %.17g\n", i_f, t, F);
            i_f++;
        }
        CHECK(a.UpdateDiscreteStates(inst, &need, &term, &nominals, &values, &next_defined,
                                     &next));
        if (need || term) {
            fprintf(stderr, "discreteStatesNeedUpdate %d terminateSimulation %d\n", need, term);
            return 2;
        }
    }
    if (in_event) CHECK(a.EnterStepMode(inst));
    CHECK(a.Terminate(inst));
    a.FreeInstance(inst);
    return 0;
}
