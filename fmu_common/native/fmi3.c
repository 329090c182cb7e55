/*
 * fmi3.c - the FMI 3.0 interfaces, co-simulation and Model Exchange: signatures, status codes
 * and the modes each call is allowed in (FMI 3.0, sections 3.2 and 4.2), over the
 * version-neutral core (fpm.h). A call of the other interface is refused with a message.
 *
 * Smooth inputs. FMI 3.0 has no fmi2SetRealInputDerivatives: its replacement is the
 * intermediate update mode, in which the FMU calls the importer back at its internal times and
 * the importer sets intermediate input values (the importer evaluates its polynomial, the FMU
 * does not). These FMUs do not offer it (providesIntermediateUpdate = false): the controller's
 * filter is discretised exactly for a polynomial over the whole step, which samples cannot give
 * it without refitting, and a callback per Runge-Kutta stage would cost a host call every few
 * hundred nanoseconds of work. Inputs are held over each doStep (zero-order hold); a master that
 * wants the higher-order coupling uses the FMI 2.0 FMUs (docs/fmus.md).
 *
 * Clocks (issue 38). A model with clocks (fpm.h, "Clocks": the sampled controller) runs them in
 * co-simulation with event mode: an instance created with eventModeUsed = true takes its clocked
 * partitions at fmi3SetClock + fmi3UpdateDiscreteStates, one created with eventModeUsed = false
 * inside doStep, as before (docs/fmus.md, PDLowPassSampled). Every other FMU refuses every clock
 * call with a message, as it did.
 */
#include <stdlib.h>

#include "fmi3Functions.h"
#include "fpm.h"

#define S_FMI3 (FPM_INSTANTIATED | FPM_INIT | FPM_EVENT | FPM_STEP | FPM_TERMINATED | FPM_ERROR_MODE)
#define S_FMI3_ME (FPM_INSTANTIATED | FPM_INIT | FPM_EVENT | FPM_CONTINUOUS | FPM_TERMINATED | \
                   FPM_ERROR_MODE)
#define M_ANY FPM_ANY
#define M_SET (FPM_INSTANTIATED | FPM_INIT | FPM_EVENT | FPM_STEP | FPM_CONTINUOUS)
#define ME FPM_MODEL_EXCHANGE
#define C ((fpm_instance *)inst)

static const char *const TYPES[4] = {"Float64", "Int32", "Boolean", "String"};

/* What the adapter keeps of the host: its logger, and whether it uses event mode. */
typedef struct host3 {
    fmi3InstanceEnvironment env;
    fmi3LogMessageCallback log;
    int event_mode_used;
} host3;

/* Tell the model whether this instance uses its clocks (fpm_model_use_clocks): before every call
 * that depends on it (a reset or a restored state does not keep it). */
static void sync(fmi3Instance inst)
{
    const fpm_instance *c = (const fpm_instance *)inst;
    if (c == NULL || c->m == NULL) return;
    fpm_model_use_clocks(c->m, c->interface == FPM_COSIMULATION &&
                                   ((const host3 *)c->host)->event_mode_used);
}

static void emit(fpm_instance *c, int status, const char *category, const char *message)
{
    const host3 *h = (const host3 *)c->host;
    if (h->log == NULL) return;
    if (!fpm_log_wanted(c, status)) return;            /* its category is disabled */
    h->log(h->env, (fmi3Status)status, category, message);
}

/* ------------------------------------------------------------------ life cycle */
const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance inst, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[])
{
    return (fmi3Status)fpm_set_debug_logging(C, "fmi3SetDebugLogging", M_ANY, loggingOn,
                                             nCategories, categories);
}

static fmi3Instance instantiate(const char *fn, fmi3String name, fmi3String token, int interface,
                                fmi3Boolean loggingOn, fmi3Boolean eventModeUsed,
                                fmi3InstanceEnvironment env, fmi3LogMessageCallback log)
{
    host3 h;
    h.env = env;
    h.log = log;
    h.event_mode_used = eventModeUsed ? 1 : 0;
    fpm_instance *c = fpm_instantiate(fn, name, token, interface,
                                      interface == FPM_MODEL_EXCHANGE ? S_FMI3_ME
                                      : eventModeUsed ? S_FMI3 : (S_FMI3 & ~FPM_EVENT), &h,
                                      sizeof h, emit, loggingOn ? 1 : 0);
    if (c != NULL) c->time_vr = fpm_time_vr;   /* FMI 3.0 declares `time` (fpm_get, fpm_set) */
    return c;
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible,
                                          fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage)
{
    (void)resourcePath; (void)visible;
    return instantiate("fmi3InstantiateModelExchange", instanceName, instantiationToken,
                       FPM_MODEL_EXCHANGE, loggingOn, 1, instanceEnvironment, logMessage);
}

fmi3Instance fmi3InstantiateScheduledExecution(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage, fmi3ClockUpdateCallback clockUpdate,
    fmi3LockPreemptionCallback lockPreemption, fmi3UnlockPreemptionCallback unlockPreemption)
{
    (void)instanceName; (void)instantiationToken; (void)resourcePath; (void)visible;
    (void)loggingOn; (void)clockUpdate; (void)lockPreemption; (void)unlockPreemption;
    if (logMessage != NULL)
        logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                   "fmi3InstantiateScheduledExecution: this is a co-simulation FMU: scheduled "
                   "execution is not supported");
    return NULL;
}

fmi3Instance fmi3InstantiateCoSimulation(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3Boolean eventModeUsed,
    fmi3Boolean earlyReturnAllowed, const fmi3ValueReference requiredIntermediateVariables[],
    size_t nRequiredIntermediateVariables, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage, fmi3IntermediateUpdateCallback intermediateUpdate)
{
    (void)resourcePath; (void)visible; (void)earlyReturnAllowed;
    (void)requiredIntermediateVariables; (void)intermediateUpdate;
    if (nRequiredIntermediateVariables > 0) {
        if (logMessage != NULL)
            logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                       "fmi3InstantiateCoSimulation: this FMU has no intermediate update "
                       "(providesIntermediateUpdate = false)");
        return NULL;
    }
    return instantiate("fmi3InstantiateCoSimulation", instanceName, instantiationToken,
                       FPM_COSIMULATION, loggingOn, eventModeUsed, instanceEnvironment,
                       logMessage);
}

void fmi3FreeInstance(fmi3Instance inst) { fpm_free_instance(C); }

fmi3Status fmi3EnterInitializationMode(fmi3Instance inst, fmi3Boolean toleranceDefined,
                                       fmi3Float64 tolerance, fmi3Float64 startTime,
                                       fmi3Boolean stopTimeDefined, fmi3Float64 stopTime)
{
    (void)toleranceDefined;
    (void)tolerance;
    return (fmi3Status)fpm_enter_init(C, "fmi3EnterInitializationMode", FPM_INSTANTIATED,
                                      startTime, stopTimeDefined, stopTime, 1);
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance inst)
{
    int event = inst != NULL && ((const host3 *)C->host)->event_mode_used;
    return (fmi3Status)fpm_exit_init(C, "fmi3ExitInitializationMode", FPM_INIT,
                                     event ? FPM_EVENT : FPM_STEP);
}

fmi3Status fmi3EnterEventMode(fmi3Instance inst)
{
    if (inst != NULL && !((const host3 *)C->host)->event_mode_used)
        return (fmi3Status)fpm_refuse(C, FPM_ERROR, "fmi3EnterEventMode", "the instance was "
                                      "created with eventModeUsed = false (hasEventMode = false)");
    return (fmi3Status)fpm_set_mode(C, "fmi3EnterEventMode",
                                    FPM_STEP | FPM_EVENT | FPM_CONTINUOUS, FPM_EVENT);
}

fmi3Status fmi3EnterStepMode(fmi3Instance inst)
{
    /* a clock still active ends its super-dense instant here (its partition runs) */
    if (inst != NULL && C->interface == FPM_COSIMULATION && C->mode == FPM_EVENT) {
        int rc;
        sync(inst);
        rc = fpm_model_clock_update(C->m, &C->lg);
        if (rc > FPM_WARNING) return (fmi3Status)rc;
    }
    return (fmi3Status)fpm_set_mode_of(C, "fmi3EnterStepMode", FPM_COSIMULATION, FPM_EVENT,
                                       FPM_STEP);
}

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance inst, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation,
                                    fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged,
                                    fmi3Boolean *nextEventTimeDefined, fmi3Float64 *nextEventTime)
{
    int terminate = 0, rc;
    if (inst != NULL && C->interface == FPM_MODEL_EXCHANGE)
        rc = fpm_me_update_discrete(C, "fmi3UpdateDiscreteStates", FPM_ME_MASK_NEW_DISCRETE,
                                    &terminate);
    else {
        rc = fpm_set_mode(C, "fmi3UpdateDiscreteStates", FPM_EVENT, FPM_EVENT);
        if (rc <= FPM_WARNING) {              /* the active clocks' partitions, then none active */
            int rc2;
            sync(inst);
            rc2 = fpm_model_clock_update(C->m, &C->lg);
            if (rc2 > rc) rc = rc2;
        }
    }
    if (rc > FPM_WARNING) return (fmi3Status)rc;
    if (discreteStatesNeedUpdate) *discreteStatesNeedUpdate = fmi3False;
    if (terminateSimulation) *terminateSimulation = terminate ? fmi3True : fmi3False;
    if (nominalsOfContinuousStatesChanged) *nominalsOfContinuousStatesChanged = fmi3False;
    if (valuesOfContinuousStatesChanged) *valuesOfContinuousStatesChanged = fmi3False;
    if (nextEventTimeDefined) *nextEventTimeDefined = fmi3False;
    if (nextEventTime) *nextEventTime = 0.0;
    return (fmi3Status)rc;
}

fmi3Status fmi3Terminate(fmi3Instance inst)
{
    return (fmi3Status)fpm_set_mode(C, "fmi3Terminate",
                                    FPM_STEP | FPM_EVENT | FPM_CONTINUOUS | FPM_ERROR_MODE,
                                    FPM_TERMINATED);
}

fmi3Status fmi3Reset(fmi3Instance inst) { return (fmi3Status)fpm_reset(C, "fmi3Reset", M_ANY); }

/* ------------------------------------------------------------------ get and set */
/* Scalar variables only: as many values as value references. */
static int counts(fmi3Instance inst, const char *fn, size_t nvr, size_t nvalues)
{
    if (nvr == nvalues) return 1;
    if (inst != NULL)
        fpm_log(&C->lg, FPM_ERROR, "%s: %lu value references but %lu values (scalar variables "
                "only)", fn, (unsigned long)nvr, (unsigned long)nvalues);
    return 0;
}

#define GET(Fn, T, type, layout)                                                             \
    fmi3Status fmi3##Fn(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr,        \
                        T values[], size_t nValues)                                          \
    {                                                                                        \
        if (!counts(inst, "fmi3" #Fn, nvr, nValues)) return fmi3Error;                       \
        return (fmi3Status)fpm_get(C, "fmi3" #Fn, M_ANY, vr, nvr, values, type, layout,      \
                                   TYPES);                                                   \
    }
#define SET(Fn, T, type, layout)                                                             \
    fmi3Status fmi3##Fn(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr,        \
                        const T values[], size_t nValues)                                    \
    {                                                                                        \
        if (!counts(inst, "fmi3" #Fn, nvr, nValues)) return fmi3Error;                       \
        return (fmi3Status)fpm_set(C, "fmi3" #Fn, M_SET, vr, nvr, values, type, layout,      \
                                   TYPES);                                                   \
    }
fmi3Status fmi3GetFloat64(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr,
                          fmi3Float64 values[], size_t nValues)
{
    if (!counts(inst, "fmi3GetFloat64", nvr, nValues)) return fmi3Error;
    sync(inst);
    return (fmi3Status)fpm_get(C, "fmi3GetFloat64", M_ANY, vr, nvr, values, FPM_REAL,
                               FPM_C_DOUBLE, TYPES);
}

/* A clocked input is set at its clock's activation (fpm_model_clocked_set). */
fmi3Status fmi3SetFloat64(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr,
                          const fmi3Float64 values[], size_t nValues)
{
    if (!counts(inst, "fmi3SetFloat64", nvr, nValues)) return fmi3Error;
    if (inst != NULL && (C->mode & M_SET)) {
        int rc;
        sync(inst);
        rc = fpm_model_clocked_set(C->m, &C->lg, "fmi3SetFloat64", C->mode, vr, nvr);
        if (rc > FPM_WARNING) return (fmi3Status)rc;
    }
    return (fmi3Status)fpm_set(C, "fmi3SetFloat64", M_SET, vr, nvr, values, FPM_REAL,
                               FPM_C_DOUBLE, TYPES);
}
GET(GetInt32, fmi3Int32, FPM_INTEGER, FPM_C_INT)
GET(GetBoolean, fmi3Boolean, FPM_BOOLEAN, FPM_C_BOOL)
GET(GetString, fmi3String, FPM_STRING, FPM_C_STRING)
SET(SetInt32, fmi3Int32, FPM_INTEGER, FPM_C_INT)
SET(SetBoolean, fmi3Boolean, FPM_BOOLEAN, FPM_C_BOOL)
SET(SetString, fmi3String, FPM_STRING, FPM_C_STRING)

/* The types this FMU has no variable of: the same checks, with a type no variable has. */
static fmi3Status no_such(fmi3Instance inst, const char *fn, const char *type,
                          const fmi3ValueReference vr[], size_t nvr, const void *values)
{
    size_t i;
    if (inst == NULL) return fmi3Error;
    if (!fpm_allowed(&C->lg, fn, C->mode, M_ANY)) return fmi3Error;
    if (nvr == 0) return fmi3OK;
    if (vr == NULL || values == NULL) {
        fpm_log(&C->lg, FPM_ERROR, "%s: %s is NULL but %lu values are asked for", fn,
                vr == NULL ? "the value reference array" : "the value array", (unsigned long)nvr);
        return fmi3Error;
    }
    for (i = 0; i < nvr; i++) {
        int k = fpm_lookup(vr[i]);
        if (k < 0 && (long)vr[i] == C->time_vr)
            fpm_log(&C->lg, FPM_ERROR, "%s: variable time (value reference %u) is of type "
                    "Float64, not %s", fn, (unsigned)vr[i], type);
        else if (k < 0)
            fpm_log(&C->lg, FPM_ERROR, "%s: %s has no variable with value reference %u", fn,
                    fpm_model_name, (unsigned)vr[i]);
        else
            fpm_log(&C->lg, FPM_ERROR, "%s: variable %s (value reference %u) is of type %s, not "
                    "%s", fn, fpm_vars[k].name, (unsigned)vr[i], TYPES[fpm_vars[k].type], type);
        return fmi3Error;
    }
    return fmi3OK;
}

#define NO_TYPE(Fn, T, Q, Name)                                                                  \
    fmi3Status fmi3##Fn(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr,        \
                        Q T values[], size_t nValues)                                        \
    {                                                                                        \
        if (!counts(inst, "fmi3" #Fn, nvr, nValues)) return fmi3Error;                       \
        return no_such(inst, "fmi3" #Fn, Name, vr, nvr, values);                           \
    }
#define EMPTY
NO_TYPE(GetFloat32, fmi3Float32, EMPTY, "Float32")
NO_TYPE(GetInt8, fmi3Int8, EMPTY, "Int8")
NO_TYPE(GetUInt8, fmi3UInt8, EMPTY, "UInt8")
NO_TYPE(GetInt16, fmi3Int16, EMPTY, "Int16")
NO_TYPE(GetUInt16, fmi3UInt16, EMPTY, "UInt16")
NO_TYPE(GetUInt32, fmi3UInt32, EMPTY, "UInt32")
NO_TYPE(GetInt64, fmi3Int64, EMPTY, "Int64")
NO_TYPE(GetUInt64, fmi3UInt64, EMPTY, "UInt64")
NO_TYPE(SetFloat32, fmi3Float32, const, "Float32")
NO_TYPE(SetInt8, fmi3Int8, const, "Int8")
NO_TYPE(SetUInt8, fmi3UInt8, const, "UInt8")
NO_TYPE(SetInt16, fmi3Int16, const, "Int16")
NO_TYPE(SetUInt16, fmi3UInt16, const, "UInt16")
NO_TYPE(SetUInt32, fmi3UInt32, const, "UInt32")
NO_TYPE(SetInt64, fmi3Int64, const, "Int64")
NO_TYPE(SetUInt64, fmi3UInt64, const, "UInt64")

fmi3Status fmi3GetBinary(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr,
                         size_t valueSizes[], fmi3Binary values[], size_t nValues)
{
    (void)valueSizes;
    if (!counts(inst, "fmi3GetBinary", nvr, nValues)) return fmi3Error;
    return no_such(inst, "fmi3GetBinary", "Binary", vr, nvr, values);
}

fmi3Status fmi3SetBinary(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr,
                         const size_t valueSizes[], const fmi3Binary values[], size_t nValues)
{
    (void)valueSizes;
    if (!counts(inst, "fmi3SetBinary", nvr, nValues)) return fmi3Error;
    return no_such(inst, "fmi3SetBinary", "Binary", vr, nvr, values);
}

/* A clock call's checks: an instance, the mode, the arrays, and every value reference a clock
 * (the first that is not one is refused by no_such, which names its type). 1, or 0 logged. */
static int clock_call(fmi3Instance inst, const char *fn, int mask, const fmi3ValueReference vr[],
                      size_t nvr, const void *values)
{
    size_t i;
    if (inst == NULL) return 0;
    if (!fpm_allowed(&C->lg, fn, C->mode, mask)) return 0;
    if (nvr > 0 && (vr == NULL || values == NULL)) {
        fpm_log(&C->lg, FPM_ERROR, "%s: an array is NULL but %lu clocks are named", fn,
                (unsigned long)nvr);
        return 0;
    }
    for (i = 0; i < nvr; i++)
        if (fpm_model_clock_of(vr[i]) < 0) {
            no_such(inst, fn, "Clock", &vr[i], 1, values);
            return 0;
        }
    sync(inst);
    return 1;
}

/* In event mode: clocks tick (co-simulation with eventModeUsed = true). */
fmi3Status fmi3GetClock(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr,
                        fmi3Clock values[])
{
    size_t i;
    if (fpm_model_n_clocks() == 0) return no_such(inst, "fmi3GetClock", "Clock", vr, nvr, values);
    if (!clock_call(inst, "fmi3GetClock", FPM_EVENT, vr, nvr, values)) return fmi3Error;
    for (i = 0; i < nvr; i++)
        values[i] = fpm_model_get_clock(C->m, fpm_model_clock_of(vr[i])) ? fmi3ClockActive
                                                                          : fmi3ClockInactive;
    return fmi3OK;
}

fmi3Status fmi3SetClock(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr,
                        const fmi3Clock values[])
{
    size_t i;
    if (fpm_model_n_clocks() == 0) return no_such(inst, "fmi3SetClock", "Clock", vr, nvr, values);
    if (!clock_call(inst, "fmi3SetClock", FPM_EVENT, vr, nvr, values)) return fmi3Error;
    if (C->interface != FPM_COSIMULATION)
        return (fmi3Status)fpm_refuse(C, FPM_ERROR, "fmi3SetClock", "the clocks run in "
                                      "co-simulation with event mode");
    for (i = 0; i < 2 * nvr; i++) {           /* every clock checked, then every one set */
        int rc = fpm_model_set_clock(C->m, &C->lg, "fmi3SetClock",
                                     fpm_model_clock_of(vr[i % nvr]), values[i % nvr] ? 1 : 0,
                                     i >= nvr);
        if (rc > FPM_WARNING) return (fmi3Status)rc;
    }
    return fmi3OK;
}

fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance inst, fmi3ValueReference vr,
                                               size_t *nDependencies)
{
    (void)vr; (void)nDependencies;
    return (fmi3Status)fpm_refuse(C, FPM_ERROR, "fmi3GetNumberOfVariableDependencies",
                                  "not provided (the dependencies are in modelDescription.xml)");
}

fmi3Status fmi3GetVariableDependencies(fmi3Instance inst, fmi3ValueReference dependent,
                                       size_t elementIndicesOfDependent[],
                                       fmi3ValueReference independents[],
                                       size_t elementIndicesOfIndependents[],
                                       fmi3DependencyKind dependencyKinds[], size_t nDependencies)
{
    (void)dependent; (void)elementIndicesOfDependent; (void)independents;
    (void)elementIndicesOfIndependents; (void)dependencyKinds; (void)nDependencies;
    return (fmi3Status)fpm_refuse(C, FPM_ERROR, "fmi3GetVariableDependencies",
                                  "not provided (the dependencies are in modelDescription.xml)");
}

/* ------------------------------------------------------------------ FMU states */
fmi3Status fmi3GetFMUState(fmi3Instance inst, fmi3FMUState *state)
{
    return (fmi3Status)fpm_get_state(C, "fmi3GetFMUState", M_ANY, state);
}

fmi3Status fmi3SetFMUState(fmi3Instance inst, fmi3FMUState state)
{
    return (fmi3Status)fpm_set_state(C, "fmi3SetFMUState", M_ANY, state);
}

fmi3Status fmi3FreeFMUState(fmi3Instance inst, fmi3FMUState *state)
{
    return (fmi3Status)fpm_free_state(C, "fmi3FreeFMUState", M_ANY, state);
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance inst, fmi3FMUState state, size_t *size)
{
    return (fmi3Status)fpm_state_size(C, "fmi3SerializedFMUStateSize", M_ANY, state, size);
}

fmi3Status fmi3SerializeFMUState(fmi3Instance inst, fmi3FMUState state, fmi3Byte data[],
                                 size_t size)
{
    return (fmi3Status)fpm_serialize_state(C, "fmi3SerializeFMUState", M_ANY, state, data, size);
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance inst, const fmi3Byte data[], size_t size,
                                   fmi3FMUState *state)
{
    return (fmi3Status)fpm_deserialize_state(C, "fmi3DeserializeFMUState", M_ANY, data, size,
                                             state);
}

/* ------------------------------------------------------------------ not provided */
#define NOT_PROVIDED(fn, why) return (fmi3Status)fpm_refuse(C, FPM_ERROR, fn, why)

#define NO_CLOCKS "this FMU has no clocks"
#define CLOCK_NO_FRACTION "the clocks declare supportsFraction = false: use the Decimal variant"
#define CLOCK_NOT_SET "the clocks' intervals and shifts follow from the parameters (intervalVariability = fixed, no intervalDecimal): the importer reads them (fmi3GetIntervalDecimal, fmi3GetShiftDecimal)"

fmi3Status fmi3GetDirectionalDerivative(fmi3Instance inst, const fmi3ValueReference unknowns[],
                                        size_t nUnknowns, const fmi3ValueReference knowns[],
                                        size_t nKnowns, const fmi3Float64 seed[], size_t nSeed,
                                        fmi3Float64 sensitivity[], size_t nSensitivity)
{
    if (inst != NULL && (nSeed != nKnowns || nSensitivity != nUnknowns)) {
        fpm_log(&C->lg, FPM_ERROR, "fmi3GetDirectionalDerivative: %lu knowns but %lu seeds, %lu "
                "unknowns but %lu sensitivities (scalar variables only)", (unsigned long)nKnowns,
                (unsigned long)nSeed, (unsigned long)nUnknowns, (unsigned long)nSensitivity);
        return fmi3Error;
    }
    return (fmi3Status)fpm_directional_derivative(
        C, "fmi3GetDirectionalDerivative",
        FPM_INIT | FPM_EVENT | FPM_CONTINUOUS | FPM_STEP | FPM_TERMINATED | FPM_ERROR_MODE,
        unknowns, nUnknowns, knowns, nKnowns, seed, sensitivity);
}

fmi3Status fmi3GetAdjointDerivative(fmi3Instance inst, const fmi3ValueReference unknowns[],
                                    size_t nUnknowns, const fmi3ValueReference knowns[],
                                    size_t nKnowns, const fmi3Float64 seed[], size_t nSeed,
                                    fmi3Float64 sensitivity[], size_t nSensitivity)
{
    (void)unknowns; (void)nUnknowns; (void)knowns; (void)nKnowns; (void)seed; (void)nSeed;
    (void)sensitivity; (void)nSensitivity;
    NOT_PROVIDED("fmi3GetAdjointDerivative", "not provided by this FMU");
}

fmi3Status fmi3EnterConfigurationMode(fmi3Instance inst)
{
    NOT_PROVIDED("fmi3EnterConfigurationMode", "this FMU has no structural parameters");
}

fmi3Status fmi3ExitConfigurationMode(fmi3Instance inst)
{
    NOT_PROVIDED("fmi3ExitConfigurationMode", "this FMU has no structural parameters");
}

/* The clocks are periodic with intervalVariability = "fixed" and no intervalDecimal: their
 * interval and shift follow from fixed parameters, and the importer reads them in
 * initialization mode (fmi3IntervalChanged: the value the parameters give), or later in event
 * mode (fmi3IntervalUnchanged: fixed from initialisation on). supportsFraction = false. */
#define M_TIMING (FPM_INIT | FPM_EVENT)

/* What the clocks do not offer: the clocks' description (a FMU without clocks: NO_CLOCKS). */
static fmi3Status clock_refuse(fmi3Instance inst, const char *fn, const char *why)
{
    return (fmi3Status)fpm_refuse(C, FPM_ERROR, fn, fpm_model_n_clocks() == 0 ? NO_CLOCKS : why);
}

fmi3Status fmi3GetIntervalDecimal(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr,
                                  fmi3Float64 intervals[], fmi3IntervalQualifier qualifiers[])
{
    size_t i;
    if (fpm_model_n_clocks() == 0) return clock_refuse(inst, "fmi3GetIntervalDecimal", NO_CLOCKS);
    if (!clock_call(inst, "fmi3GetIntervalDecimal", M_TIMING, vr, nvr, intervals))
        return fmi3Error;
    if (nvr > 0 && qualifiers == NULL)
        return (fmi3Status)fpm_refuse(C, FPM_ERROR, "fmi3GetIntervalDecimal",
                                      "the qualifier array is NULL");
    for (i = 0; i < nvr; i++) {
        double shift;
        int rc = fpm_model_clock_timing(C->m, &C->lg, "fmi3GetIntervalDecimal",
                                        fpm_model_clock_of(vr[i]), &intervals[i], &shift);
        if (rc > FPM_WARNING) return (fmi3Status)rc;
        qualifiers[i] = C->mode == FPM_INIT ? fmi3IntervalChanged : fmi3IntervalUnchanged;
    }
    return fmi3OK;
}

fmi3Status fmi3GetShiftDecimal(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr,
                               fmi3Float64 shifts[])
{
    size_t i;
    if (fpm_model_n_clocks() == 0) return clock_refuse(inst, "fmi3GetShiftDecimal", NO_CLOCKS);
    if (!clock_call(inst, "fmi3GetShiftDecimal", M_TIMING, vr, nvr, shifts)) return fmi3Error;
    for (i = 0; i < nvr; i++) {
        double interval;
        int rc = fpm_model_clock_timing(C->m, &C->lg, "fmi3GetShiftDecimal",
                                        fpm_model_clock_of(vr[i]), &interval, &shifts[i]);
        if (rc > FPM_WARNING) return (fmi3Status)rc;
    }
    return fmi3OK;
}

fmi3Status fmi3GetIntervalFraction(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr,
                                   fmi3UInt64 counters[], fmi3UInt64 resolutions[],
                                   fmi3IntervalQualifier qualifiers[])
{
    (void)vr; (void)nvr; (void)counters; (void)resolutions; (void)qualifiers;
    return clock_refuse(inst, "fmi3GetIntervalFraction", CLOCK_NO_FRACTION);
}

fmi3Status fmi3GetShiftFraction(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr,
                                fmi3UInt64 counters[], fmi3UInt64 resolutions[])
{
    (void)vr; (void)nvr; (void)counters; (void)resolutions;
    return clock_refuse(inst, "fmi3GetShiftFraction", CLOCK_NO_FRACTION);
}

fmi3Status fmi3SetIntervalDecimal(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr,
                                  const fmi3Float64 intervals[])
{
    (void)vr; (void)nvr; (void)intervals;
    return clock_refuse(inst, "fmi3SetIntervalDecimal", CLOCK_NOT_SET);
}

fmi3Status fmi3SetIntervalFraction(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr,
                                   const fmi3UInt64 counters[], const fmi3UInt64 resolutions[])
{
    (void)vr; (void)nvr; (void)counters; (void)resolutions;
    return clock_refuse(inst, "fmi3SetIntervalFraction", CLOCK_NOT_SET);
}

fmi3Status fmi3SetShiftDecimal(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr,
                               const fmi3Float64 shifts[])
{
    (void)vr; (void)nvr; (void)shifts;
    return clock_refuse(inst, "fmi3SetShiftDecimal", CLOCK_NOT_SET);
}

fmi3Status fmi3SetShiftFraction(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr,
                                const fmi3UInt64 counters[], const fmi3UInt64 resolutions[])
{
    (void)vr; (void)nvr; (void)counters; (void)resolutions;
    return clock_refuse(inst, "fmi3SetShiftFraction", CLOCK_NOT_SET);
}

fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance inst)
{
    NOT_PROVIDED("fmi3EvaluateDiscreteStates", "providesEvaluateDiscreteStates = false");
}

fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance inst)
{
    return (fmi3Status)fpm_set_mode_of(C, "fmi3EnterContinuousTimeMode", ME,
                                       FPM_ME_MASK_ENTER_CONTINUOUS, FPM_CONTINUOUS);
}

fmi3Status fmi3CompletedIntegratorStep(fmi3Instance inst,
                                       fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode,
                                       fmi3Boolean *terminateSimulation)
{
    int terminate = 0, rc;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (inst != NULL && (enterEventMode == NULL || terminateSimulation == NULL))
        return (fmi3Status)fpm_refuse(C, FPM_ERROR, "fmi3CompletedIntegratorStep",
                                      "enterEventMode or terminateSimulation is NULL");
    rc = fpm_me_completed_step(C, "fmi3CompletedIntegratorStep", FPM_ME_MASK_COMPLETED_STEP,
                               &terminate);
    if (rc > FPM_WARNING) return (fmi3Status)rc;
    *enterEventMode = fmi3False;
    *terminateSimulation = terminate ? fmi3True : fmi3False;
    return (fmi3Status)rc;
}

fmi3Status fmi3SetTime(fmi3Instance inst, fmi3Float64 time)
{
    return (fmi3Status)fpm_me_set_time(C, "fmi3SetTime", FPM_ME_MASK_SET_TIME, time);
}

fmi3Status fmi3SetContinuousStates(fmi3Instance inst, const fmi3Float64 x[], size_t nx)
{
    return (fmi3Status)fpm_me_set_states(C, "fmi3SetContinuousStates", FPM_ME_MASK_SET_STATES,
                                         x, nx);
}

fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance inst, fmi3Float64 d[], size_t nx)
{
    return (fmi3Status)fpm_me_get_derivatives(C, "fmi3GetContinuousStateDerivatives",
                                              FPM_ME_MASK_GET_DERIVATIVES, d, nx);
}

fmi3Status fmi3GetEventIndicators(fmi3Instance inst, fmi3Float64 ind[], size_t n)
{
    return (fmi3Status)fpm_me_get_event_indicators(C, "fmi3GetEventIndicators",
                                                   FPM_ME_MASK_GET_DERIVATIVES, ind, n);
}

fmi3Status fmi3GetContinuousStates(fmi3Instance inst, fmi3Float64 x[], size_t nx)
{
    return (fmi3Status)fpm_me_get_states(C, "fmi3GetContinuousStates", FPM_ME_MASK_GET_STATES,
                                         x, nx);
}

fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance inst, fmi3Float64 nominals[], size_t nx)
{
    return (fmi3Status)fpm_me_get_nominals(C, "fmi3GetNominalsOfContinuousStates",
                                           FPM_ME_MASK_GET_STATES | FPM_INSTANTIATED, nominals,
                                           nx);
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance inst, size_t *n)
{
    if (inst == NULL) return fmi3Error;
    if (n == NULL) return (fmi3Status)fpm_refuse(C, FPM_ERROR, "fmi3GetNumberOfEventIndicators",
                                                 "the pointer is NULL");
    *n = fpm_model_nz();
    return fmi3OK;
}

fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance inst, size_t *n)
{
    if (inst == NULL) return fmi3Error;
    if (n == NULL) return (fmi3Status)fpm_refuse(C, FPM_ERROR,
                                                 "fmi3GetNumberOfContinuousStates",
                                                 "the pointer is NULL");
    *n = fpm_model_nx();
    return fmi3OK;
}

fmi3Status fmi3ActivateModelPartition(fmi3Instance inst, fmi3ValueReference clockReference,
                                      fmi3Float64 activationTime)
{
    (void)clockReference; (void)activationTime;
    NOT_PROVIDED("fmi3ActivateModelPartition", "this is not a scheduled-execution FMU");
}

fmi3Status fmi3GetOutputDerivatives(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr,
                                    const fmi3Int32 orders[], fmi3Float64 values[],
                                    size_t nValues)
{
    if (!counts(inst, "fmi3GetOutputDerivatives", nvr, nValues)) return fmi3Error;
    return (fmi3Status)fpm_output_derivatives(C, "fmi3GetOutputDerivatives",
                                              FPM_STEP | FPM_EVENT | FPM_TERMINATED, vr, nvr,
                                              orders, values);
}

/* ------------------------------------------------------------------ co-simulation */
fmi3Status fmi3DoStep(fmi3Instance inst, fmi3Float64 currentCommunicationPoint,
                      fmi3Float64 communicationStepSize,
                      fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                      fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation,
                      fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime)
{
    int rc;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (eventHandlingNeeded) *eventHandlingNeeded = fmi3False;
    if (terminateSimulation) *terminateSimulation = fmi3False;
    if (earlyReturn) *earlyReturn = fmi3False;
    sync(inst);
    rc = fpm_do_step(C, "fmi3DoStep", FPM_STEP, currentCommunicationPoint,
                     communicationStepSize);
    if (lastSuccessfulTime && inst != NULL) *lastSuccessfulTime = fpm_time(C);
    /* the model refused the step: it cannot go on by itself (see fmi2GetBooleanStatus) */
    if (terminateSimulation && rc == FPM_DISCARD && C->discarded) *terminateSimulation = fmi3True;
    return (fmi3Status)rc;
}
