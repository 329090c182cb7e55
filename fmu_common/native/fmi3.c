/*
 * fmi3.c - the FMI 3.0 co-simulation interface, written once for every model (see fpm.h).
 *
 * Every function checks its instance and the state machine first (FMI 3.0, section 4.2) and logs
 * the reason for any status other than fmi3OK.
 *
 * Smooth inputs. FMI 3.0 has no fmi2SetRealInputDerivatives: its replacement is the
 * intermediate update mode, in which the FMU calls the importer back at its internal times and
 * the importer sets intermediate input values (the importer evaluates its polynomial, the FMU
 * does not). These FMUs do not offer it (providesIntermediateUpdate = false): the controller's
 * filter is discretised exactly for a polynomial over the whole step, which samples cannot give
 * it without refitting, and a callback per Runge-Kutta stage would cost a host call every few
 * hundred nanoseconds of work. Inputs are held over each doStep (zero-order hold); a master that
 * wants the higher-order coupling uses the FMI 2.0 FMUs (docs/fmus.md).
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "fmi3Functions.h"
#include "fpm.h"

#define S_INSTANTIATED 1
#define S_INIT 2
#define S_EVENT 4
#define S_STEP 8
#define S_TERMINATED 16
#define S_ERROR 32
#define S_ANY (S_INSTANTIATED | S_INIT | S_EVENT | S_STEP | S_TERMINATED | S_ERROR)

typedef struct saved_head {
    int mode;
    int discarded;             /* the model refused the last doStep (the master should stop) */
    double align;
} saved_head;

typedef struct instance {
    fmi3InstanceEnvironment env;
    fmi3LogMessageCallback log;
    int logging_on, event_mode_used;
    char name[128];
    fpm_logger lg;
    saved_head *head;
    fpm_model *m;
    size_t saved_size;
} instance;

static const char *mode_name(int mode)
{
    switch (mode) {
    case S_INSTANTIATED: return "Instantiated";
    case S_INIT: return "InitializationMode";
    case S_EVENT: return "EventMode";
    case S_STEP: return "StepMode";
    case S_TERMINATED: return "Terminated";
    default: return "Error";
    }
}

static void emit(void *env, int status, const char *category, const char *message)
{
    instance *c = (instance *)env;
    if (c->log == NULL) return;
    if (status == FPM_OK && !c->logging_on) return;
    c->log(c->env, (fmi3Status)status, category, message);
}

static int allowed(instance *c, const char *fn, int states)
{
    if (c->head->mode & states) return 1;
    fpm_log(&c->lg, FPM_ERROR, "%s is not allowed in state %s", fn, mode_name(c->head->mode));
    return 0;
}

#define CHECK(fn, states)                                                                    \
    instance *c = (instance *)inst;                                                          \
    if (c == NULL) return fmi3Error;                                                         \
    if (!allowed(c, fn, states)) return fmi3Error

#define SET_STATES (S_INSTANTIATED | S_INIT | S_EVENT | S_STEP)

/* ------------------------------------------------------------------ life cycle */
const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance inst, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[])
{
    CHECK("fmi3SetDebugLogging", S_ANY);
    (void)nCategories;
    (void)categories;
    c->logging_on = loggingOn ? 1 : 0;
    return fmi3OK;
}

static fmi3Instance not_cs(fmi3InstanceEnvironment env, fmi3LogMessageCallback log,
                           const char *what)
{
    if (log != NULL) {
        char msg[256];
        strcpy(msg, fpm_model_name);
        strcat(msg, " is a co-simulation FMU: ");
        strcat(msg, what);
        strcat(msg, " is not supported");
        log(env, fmi3Error, "logStatusError", msg);
    }
    return NULL;
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible,
                                          fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage)
{
    (void)instanceName; (void)instantiationToken; (void)resourcePath; (void)visible;
    (void)loggingOn;
    return not_cs(instanceEnvironment, logMessage, "model exchange");
}

fmi3Instance fmi3InstantiateScheduledExecution(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage, fmi3ClockUpdateCallback clockUpdate,
    fmi3LockPreemptionCallback lockPreemption, fmi3UnlockPreemptionCallback unlockPreemption)
{
    (void)instanceName; (void)instantiationToken; (void)resourcePath; (void)visible;
    (void)loggingOn; (void)clockUpdate; (void)lockPreemption; (void)unlockPreemption;
    return not_cs(instanceEnvironment, logMessage, "scheduled execution");
}

fmi3Instance fmi3InstantiateCoSimulation(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3Boolean eventModeUsed,
    fmi3Boolean earlyReturnAllowed, const fmi3ValueReference requiredIntermediateVariables[],
    size_t nRequiredIntermediateVariables, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage, fmi3IntermediateUpdateCallback intermediateUpdate)
{
    instance tmp, *c;
    (void)resourcePath; (void)visible; (void)earlyReturnAllowed;
    (void)requiredIntermediateVariables; (void)intermediateUpdate;
    memset(&tmp, 0, sizeof tmp);
    tmp.env = instanceEnvironment;
    tmp.log = logMessage;
    tmp.logging_on = loggingOn ? 1 : 0;
    tmp.event_mode_used = eventModeUsed ? 1 : 0;
    tmp.lg.emit = emit;
    tmp.lg.env = &tmp;
    strncpy(tmp.name, instanceName ? instanceName : "?", sizeof tmp.name - 1);
    if (instantiationToken == NULL || strcmp(instantiationToken, fpm_token) != 0) {
        fpm_log(&tmp.lg, FPM_ERROR, "fmi3InstantiateCoSimulation: the instantiation token %s is "
                "not this FMU's (%s): the modelDescription.xml and the binary come from "
                "different builds", instantiationToken ? instantiationToken : "(null)", fpm_token);
        return NULL;
    }
    if (nRequiredIntermediateVariables > 0) {
        fpm_log(&tmp.lg, FPM_ERROR, "fmi3InstantiateCoSimulation: this FMU has no intermediate "
                "update (providesIntermediateUpdate = false)");
        return NULL;
    }
    c = (instance *)calloc(1, sizeof *c);
    if (c == NULL) return NULL;
    *c = tmp;
    c->lg.env = c;
    c->saved_size = sizeof(saved_head) + fpm_model_size();
    c->head = (saved_head *)calloc(1, c->saved_size);
    if (c->head == NULL) {
        fpm_log(&c->lg, FPM_ERROR, "fmi3InstantiateCoSimulation: out of memory");
        free(c);
        return NULL;
    }
    c->m = (fpm_model *)(c->head + 1);
    fpm_model_reset(c->m, 0.0);
    c->head->mode = S_INSTANTIATED;
    return c;
}

void fmi3FreeInstance(fmi3Instance inst)
{
    instance *c = (instance *)inst;
    if (c == NULL) return;
    free(c->head);
    free(c);
}

fmi3Status fmi3EnterInitializationMode(fmi3Instance inst, fmi3Boolean toleranceDefined,
                                       fmi3Float64 tolerance, fmi3Float64 startTime,
                                       fmi3Boolean stopTimeDefined, fmi3Float64 stopTime)
{
    fpm_values v;
    CHECK("fmi3EnterInitializationMode", S_INSTANTIATED);
    (void)toleranceDefined;
    (void)tolerance;
    if (!isfinite(startTime) || (stopTimeDefined && !(stopTime >= startTime))) {
        fpm_log(&c->lg, FPM_ERROR, "fmi3EnterInitializationMode: startTime = %.17g, stopTime = "
                "%.17g: the start must be finite and not after the stop", startTime, stopTime);
        return fmi3Error;
    }
    v = *fpm_model_values(c->m);
    fpm_model_reset(c->m, startTime);
    *fpm_model_values(c->m) = v;
    c->head->mode = S_INIT;
    return fmi3OK;
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance inst)
{
    int rc;
    CHECK("fmi3ExitInitializationMode", S_INIT);
    rc = fpm_model_init(c->m, &c->lg);
    if (rc > FPM_WARNING) {
        c->head->mode = S_ERROR;
        return fmi3Error;
    }
    c->head->mode = c->event_mode_used ? S_EVENT : S_STEP;
    return (fmi3Status)rc;
}

fmi3Status fmi3EnterEventMode(fmi3Instance inst)
{
    CHECK("fmi3EnterEventMode", S_STEP | S_EVENT);
    if (!c->event_mode_used) {
        fpm_log(&c->lg, FPM_ERROR, "fmi3EnterEventMode: the instance was created with "
                "eventModeUsed = false (hasEventMode = false)");
        return fmi3Error;
    }
    c->head->mode = S_EVENT;
    return fmi3OK;
}

fmi3Status fmi3EnterStepMode(fmi3Instance inst)
{
    CHECK("fmi3EnterStepMode", S_EVENT);
    c->head->mode = S_STEP;
    return fmi3OK;
}

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance inst, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation,
                                    fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged,
                                    fmi3Boolean *nextEventTimeDefined, fmi3Float64 *nextEventTime)
{
    CHECK("fmi3UpdateDiscreteStates", S_EVENT);
    if (discreteStatesNeedUpdate) *discreteStatesNeedUpdate = fmi3False;
    if (terminateSimulation) *terminateSimulation = fmi3False;
    if (nominalsOfContinuousStatesChanged) *nominalsOfContinuousStatesChanged = fmi3False;
    if (valuesOfContinuousStatesChanged) *valuesOfContinuousStatesChanged = fmi3False;
    if (nextEventTimeDefined) *nextEventTimeDefined = fmi3False;
    if (nextEventTime) *nextEventTime = 0.0;
    return fmi3OK;
}

fmi3Status fmi3Terminate(fmi3Instance inst)
{
    CHECK("fmi3Terminate", S_STEP | S_EVENT | S_ERROR);
    c->head->mode = S_TERMINATED;
    return fmi3OK;
}

fmi3Status fmi3Reset(fmi3Instance inst)
{
    CHECK("fmi3Reset", S_ANY);
    memset(c->head, 0, c->saved_size);
    fpm_model_reset(c->m, 0.0);
    c->head->mode = S_INSTANTIATED;
    return fmi3OK;
}

/* ------------------------------------------------------------------ get and set */
static const fpm_var *variable(instance *c, const char *fn, fmi3ValueReference vr, int type)
{
    static const char *TYPE[] = {"Float64", "Int32", "Boolean", "String"};
    int i = fpm_lookup(vr);
    if (i < 0) {
        fpm_log(&c->lg, FPM_ERROR, "%s: %s has no variable with value reference %u", fn,
                fpm_model_name, (unsigned)vr);
        return NULL;
    }
    if (fpm_vars[i].type != type) {
        fpm_log(&c->lg, FPM_ERROR, "%s: variable %s (value reference %u) is of type %s", fn,
                fpm_vars[i].name, (unsigned)vr, TYPE[fpm_vars[i].type]);
        return NULL;
    }
    return &fpm_vars[i];
}

static int settable(instance *c, const char *fn, const fpm_var *v)
{
    if (v->causality == FPM_OUTPUT) {
        fpm_log(&c->lg, FPM_ERROR, "%s: %s is an output; it cannot be set", fn, v->name);
        return 0;
    }
    if (v->causality == FPM_PARAMETER && !(c->head->mode & (S_INSTANTIATED | S_INIT))) {
        fpm_log(&c->lg, FPM_ERROR, "%s: parameter %s is fixed: it can only be set before "
                "fmi3ExitInitializationMode (state: %s)", fn, v->name, mode_name(c->head->mode));
        return 0;
    }
    return 1;
}

static int counts(instance *c, const char *fn, size_t nvr, size_t nvalues)
{
    if (nvr == nvalues) return 1;
    fpm_log(&c->lg, FPM_ERROR, "%s: %lu value references but %lu values (scalar variables "
            "only)", fn, (unsigned long)nvr, (unsigned long)nvalues);
    return 0;
}

fmi3Status fmi3GetFloat64(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr,
                          fmi3Float64 values[], size_t nValues)
{
    size_t i;
    int worst = FPM_OK;
    CHECK("fmi3GetFloat64", S_ANY);
    if (!counts(c, "fmi3GetFloat64", nvr, nValues)) return fmi3Error;
    for (i = 0; i < nvr; i++) {
        const fpm_var *v = variable(c, "fmi3GetFloat64", vr[i], FPM_REAL);
        if (v == NULL) return fmi3Error;
        if (v->causality == FPM_OUTPUT) {
            int rc = fpm_model_get_output(c->m, &c->lg, vr[i], &values[i]);
            if (rc > FPM_WARNING) return (fmi3Status)rc;
            if (rc > worst) worst = rc;
        } else {
            values[i] = fpm_model_values(c->m)->real[vr[i]];
        }
    }
    return (fmi3Status)worst;
}

fmi3Status fmi3GetInt32(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr,
                        fmi3Int32 values[], size_t nValues)
{
    size_t i;
    CHECK("fmi3GetInt32", S_ANY);
    if (!counts(c, "fmi3GetInt32", nvr, nValues)) return fmi3Error;
    for (i = 0; i < nvr; i++) {
        if (variable(c, "fmi3GetInt32", vr[i], FPM_INTEGER) == NULL) return fmi3Error;
        values[i] = (fmi3Int32)fpm_model_values(c->m)->real[vr[i]];
    }
    return fmi3OK;
}

fmi3Status fmi3GetBoolean(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr,
                          fmi3Boolean values[], size_t nValues)
{
    size_t i;
    CHECK("fmi3GetBoolean", S_ANY);
    if (!counts(c, "fmi3GetBoolean", nvr, nValues)) return fmi3Error;
    for (i = 0; i < nvr; i++) {
        if (variable(c, "fmi3GetBoolean", vr[i], FPM_BOOLEAN) == NULL) return fmi3Error;
        values[i] = fpm_model_values(c->m)->real[vr[i]] != 0.0;
    }
    return fmi3OK;
}

fmi3Status fmi3GetString(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr,
                         fmi3String values[], size_t nValues)
{
    size_t i;
    CHECK("fmi3GetString", S_ANY);
    if (!counts(c, "fmi3GetString", nvr, nValues)) return fmi3Error;
    for (i = 0; i < nvr; i++) {
        if (variable(c, "fmi3GetString", vr[i], FPM_STRING) == NULL) return fmi3Error;
        values[i] = fpm_model_values(c->m)->string[vr[i]];
    }
    return fmi3OK;
}

fmi3Status fmi3SetFloat64(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr,
                          const fmi3Float64 values[], size_t nValues)
{
    size_t i;
    CHECK("fmi3SetFloat64", SET_STATES);
    if (!counts(c, "fmi3SetFloat64", nvr, nValues)) return fmi3Error;
    for (i = 0; i < nvr; i++) {
        const fpm_var *v = variable(c, "fmi3SetFloat64", vr[i], FPM_REAL);
        if (v == NULL || !settable(c, "fmi3SetFloat64", v)) return fmi3Error;
        fpm_model_values(c->m)->real[vr[i]] = values[i];
    }
    return fmi3OK;
}

fmi3Status fmi3SetInt32(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr,
                        const fmi3Int32 values[], size_t nValues)
{
    size_t i;
    CHECK("fmi3SetInt32", SET_STATES);
    if (!counts(c, "fmi3SetInt32", nvr, nValues)) return fmi3Error;
    for (i = 0; i < nvr; i++) {
        const fpm_var *v = variable(c, "fmi3SetInt32", vr[i], FPM_INTEGER);
        if (v == NULL || !settable(c, "fmi3SetInt32", v)) return fmi3Error;
        fpm_model_values(c->m)->real[vr[i]] = (double)values[i];
    }
    return fmi3OK;
}

fmi3Status fmi3SetBoolean(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr,
                          const fmi3Boolean values[], size_t nValues)
{
    size_t i;
    CHECK("fmi3SetBoolean", SET_STATES);
    if (!counts(c, "fmi3SetBoolean", nvr, nValues)) return fmi3Error;
    for (i = 0; i < nvr; i++) {
        const fpm_var *v = variable(c, "fmi3SetBoolean", vr[i], FPM_BOOLEAN);
        if (v == NULL || !settable(c, "fmi3SetBoolean", v)) return fmi3Error;
        fpm_model_values(c->m)->real[vr[i]] = values[i] ? 1.0 : 0.0;
    }
    return fmi3OK;
}

fmi3Status fmi3SetString(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr,
                         const fmi3String values[], size_t nValues)
{
    size_t i;
    CHECK("fmi3SetString", SET_STATES);
    if (!counts(c, "fmi3SetString", nvr, nValues)) return fmi3Error;
    for (i = 0; i < nvr; i++) {
        const fpm_var *v = variable(c, "fmi3SetString", vr[i], FPM_STRING);
        if (v == NULL || !settable(c, "fmi3SetString", v)) return fmi3Error;
        if (values[i] == NULL || strlen(values[i]) >= FPM_STR_MAX) {
            fpm_log(&c->lg, FPM_ERROR, "fmi3SetString: the value of %s is %s (at most %d "
                    "characters)", v->name, values[i] ? "too long" : "NULL", FPM_STR_MAX - 1);
            return fmi3Error;
        }
        strcpy(fpm_model_values(c->m)->string[vr[i]], values[i]);
    }
    return fmi3OK;
}

/* The types this FMU has no variable of. */
static fmi3Status no_such(instance *c, const char *fn, const fmi3ValueReference vr[], size_t nvr)
{
    size_t i;
    for (i = 0; i < nvr; i++) {
        int k = fpm_lookup(vr[i]);
        if (k < 0)
            fpm_log(&c->lg, FPM_ERROR, "%s: %s has no variable with value reference %u", fn,
                    fpm_model_name, (unsigned)vr[i]);
        else
            fpm_log(&c->lg, FPM_ERROR, "%s: variable %s (value reference %u) is of another type",
                    fn, fpm_vars[k].name, (unsigned)vr[i]);
        return fmi3Error;
    }
    return fmi3OK;
}

#define NO_TYPE(Fn, T, Q)                                                                    \
    fmi3Status fmi3##Fn(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr,        \
                        Q T values[], size_t nValues)                                        \
    {                                                                                        \
        CHECK("fmi3" #Fn, S_ANY);                                                            \
        (void)values;                                                                        \
        (void)nValues;                                                                       \
        return no_such(c, "fmi3" #Fn, vr, nvr);                                              \
    }
#define EMPTY
NO_TYPE(GetFloat32, fmi3Float32, EMPTY)
NO_TYPE(GetInt8, fmi3Int8, EMPTY)
NO_TYPE(GetUInt8, fmi3UInt8, EMPTY)
NO_TYPE(GetInt16, fmi3Int16, EMPTY)
NO_TYPE(GetUInt16, fmi3UInt16, EMPTY)
NO_TYPE(GetUInt32, fmi3UInt32, EMPTY)
NO_TYPE(GetInt64, fmi3Int64, EMPTY)
NO_TYPE(GetUInt64, fmi3UInt64, EMPTY)
NO_TYPE(SetFloat32, fmi3Float32, const)
NO_TYPE(SetInt8, fmi3Int8, const)
NO_TYPE(SetUInt8, fmi3UInt8, const)
NO_TYPE(SetInt16, fmi3Int16, const)
NO_TYPE(SetUInt16, fmi3UInt16, const)
NO_TYPE(SetUInt32, fmi3UInt32, const)
NO_TYPE(SetInt64, fmi3Int64, const)
NO_TYPE(SetUInt64, fmi3UInt64, const)

fmi3Status fmi3GetBinary(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr,
                         size_t valueSizes[], fmi3Binary values[], size_t nValues)
{
    CHECK("fmi3GetBinary", S_ANY);
    (void)valueSizes; (void)values; (void)nValues;
    return no_such(c, "fmi3GetBinary", vr, nvr);
}

fmi3Status fmi3SetBinary(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr,
                         const size_t valueSizes[], const fmi3Binary values[], size_t nValues)
{
    CHECK("fmi3SetBinary", S_ANY);
    (void)valueSizes; (void)values; (void)nValues;
    return no_such(c, "fmi3SetBinary", vr, nvr);
}

fmi3Status fmi3GetClock(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr,
                        fmi3Clock values[])
{
    CHECK("fmi3GetClock", S_ANY);
    (void)values;
    return no_such(c, "fmi3GetClock", vr, nvr);
}

fmi3Status fmi3SetClock(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr,
                        const fmi3Clock values[])
{
    CHECK("fmi3SetClock", S_ANY);
    (void)values;
    return no_such(c, "fmi3SetClock", vr, nvr);
}

fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance inst, fmi3ValueReference vr,
                                               size_t *nDependencies)
{
    CHECK("fmi3GetNumberOfVariableDependencies", S_ANY);
    (void)vr; (void)nDependencies;
    fpm_log(&c->lg, FPM_ERROR, "fmi3GetNumberOfVariableDependencies: not provided (the "
            "dependencies are in modelDescription.xml)");
    return fmi3Error;
}

fmi3Status fmi3GetVariableDependencies(fmi3Instance inst, fmi3ValueReference dependent,
                                       size_t elementIndicesOfDependent[],
                                       fmi3ValueReference independents[],
                                       size_t elementIndicesOfIndependents[],
                                       fmi3DependencyKind dependencyKinds[], size_t nDependencies)
{
    CHECK("fmi3GetVariableDependencies", S_ANY);
    (void)dependent; (void)elementIndicesOfDependent; (void)independents;
    (void)elementIndicesOfIndependents; (void)dependencyKinds; (void)nDependencies;
    fpm_log(&c->lg, FPM_ERROR, "fmi3GetVariableDependencies: not provided (the dependencies are "
            "in modelDescription.xml)");
    return fmi3Error;
}

/* ------------------------------------------------------------------ FMU states */
fmi3Status fmi3GetFMUState(fmi3Instance inst, fmi3FMUState *state)
{
    CHECK("fmi3GetFMUState", S_ANY);
    if (state == NULL) return fmi3Error;
    if (*state == NULL) {
        *state = calloc(1, c->saved_size);
        if (*state == NULL) {
            fpm_log(&c->lg, FPM_ERROR, "fmi3GetFMUState: out of memory");
            return fmi3Error;
        }
    }
    memcpy(*state, c->head, c->saved_size);
    return fmi3OK;
}

fmi3Status fmi3SetFMUState(fmi3Instance inst, fmi3FMUState state)
{
    CHECK("fmi3SetFMUState", S_ANY);
    if (state == NULL) {
        fpm_log(&c->lg, FPM_ERROR, "fmi3SetFMUState: the state is NULL");
        return fmi3Error;
    }
    memcpy(c->head, state, c->saved_size);
    if (fpm_model_relink(c->m, &c->lg) != FPM_OK) {
        c->head->mode = S_ERROR;
        return fmi3Error;
    }
    return fmi3OK;
}

fmi3Status fmi3FreeFMUState(fmi3Instance inst, fmi3FMUState *state)
{
    CHECK("fmi3FreeFMUState", S_ANY);
    if (state == NULL) return fmi3OK;
    free(*state);
    *state = NULL;
    return fmi3OK;
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance inst, fmi3FMUState state, size_t *size)
{
    CHECK("fmi3SerializedFMUStateSize", S_ANY);
    (void)state;
    if (size == NULL) return fmi3Error;
    *size = fpm_serialized_size(c->saved_size);
    return fmi3OK;
}

fmi3Status fmi3SerializeFMUState(fmi3Instance inst, fmi3FMUState state, fmi3Byte data[],
                                 size_t size)
{
    CHECK("fmi3SerializeFMUState", S_ANY);
    if (state == NULL || data == NULL || size < fpm_serialized_size(c->saved_size)) {
        fpm_log(&c->lg, FPM_ERROR, "fmi3SerializeFMUState: need a state and %lu bytes, got %lu",
                (unsigned long)fpm_serialized_size(c->saved_size), (unsigned long)size);
        return fmi3Error;
    }
    fpm_serialize(state, c->saved_size, (unsigned char *)data);
    return fmi3OK;
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance inst, const fmi3Byte data[], size_t size,
                                   fmi3FMUState *state)
{
    char why[FPM_MSG_MAX];
    void *buf;
    CHECK("fmi3DeserializeFMUState", S_ANY);
    if (state == NULL) return fmi3Error;
    buf = calloc(1, c->saved_size);
    if (buf == NULL) return fmi3Error;
    if (fpm_deserialize((const unsigned char *)data, size, buf, c->saved_size, why) != FPM_OK) {
        fpm_log(&c->lg, FPM_ERROR, "fmi3DeserializeFMUState: %s", why);
        free(buf);
        return fmi3Error;
    }
    {
        saved_head *h = (saved_head *)buf;
        if (!(h->mode & S_ANY) || fpm_model_relink((fpm_model *)(h + 1), &c->lg) != FPM_OK) {
            fpm_log(&c->lg, FPM_ERROR, "fmi3DeserializeFMUState: the data are not a valid state");
            free(buf);
            return fmi3Error;
        }
    }
    if (*state != NULL) free(*state);
    *state = buf;
    return fmi3OK;
}

/* ------------------------------------------------------------------ not provided */
#define NOT_PROVIDED(fn, why)                                                                \
    do {                                                                                     \
        instance *c = (instance *)inst;                                                      \
        if (c != NULL) fpm_log(&c->lg, FPM_ERROR, "%s: %s", fn, why);                        \
        return fmi3Error;                                                                    \
    } while (0)

#define CS_ONLY "this is a co-simulation FMU"
#define NO_CLOCKS "this FMU has no clocks"

fmi3Status fmi3GetDirectionalDerivative(fmi3Instance inst, const fmi3ValueReference unknowns[],
                                        size_t nUnknowns, const fmi3ValueReference knowns[],
                                        size_t nKnowns, const fmi3Float64 seed[], size_t nSeed,
                                        fmi3Float64 sensitivity[], size_t nSensitivity)
{
    (void)unknowns; (void)nUnknowns; (void)knowns; (void)nKnowns; (void)seed; (void)nSeed;
    (void)sensitivity; (void)nSensitivity;
    NOT_PROVIDED("fmi3GetDirectionalDerivative", "not provided by this FMU");
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

fmi3Status fmi3GetIntervalDecimal(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr,
                                  fmi3Float64 intervals[], fmi3IntervalQualifier qualifiers[])
{
    (void)vr; (void)nvr; (void)intervals; (void)qualifiers;
    NOT_PROVIDED("fmi3GetIntervalDecimal", NO_CLOCKS);
}

fmi3Status fmi3GetIntervalFraction(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr,
                                   fmi3UInt64 counters[], fmi3UInt64 resolutions[],
                                   fmi3IntervalQualifier qualifiers[])
{
    (void)vr; (void)nvr; (void)counters; (void)resolutions; (void)qualifiers;
    NOT_PROVIDED("fmi3GetIntervalFraction", NO_CLOCKS);
}

fmi3Status fmi3GetShiftDecimal(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr,
                               fmi3Float64 shifts[])
{
    (void)vr; (void)nvr; (void)shifts;
    NOT_PROVIDED("fmi3GetShiftDecimal", NO_CLOCKS);
}

fmi3Status fmi3GetShiftFraction(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr,
                                fmi3UInt64 counters[], fmi3UInt64 resolutions[])
{
    (void)vr; (void)nvr; (void)counters; (void)resolutions;
    NOT_PROVIDED("fmi3GetShiftFraction", NO_CLOCKS);
}

fmi3Status fmi3SetIntervalDecimal(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr,
                                  const fmi3Float64 intervals[])
{
    (void)vr; (void)nvr; (void)intervals;
    NOT_PROVIDED("fmi3SetIntervalDecimal", NO_CLOCKS);
}

fmi3Status fmi3SetIntervalFraction(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr,
                                   const fmi3UInt64 counters[], const fmi3UInt64 resolutions[])
{
    (void)vr; (void)nvr; (void)counters; (void)resolutions;
    NOT_PROVIDED("fmi3SetIntervalFraction", NO_CLOCKS);
}

fmi3Status fmi3SetShiftDecimal(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr,
                               const fmi3Float64 shifts[])
{
    (void)vr; (void)nvr; (void)shifts;
    NOT_PROVIDED("fmi3SetShiftDecimal", NO_CLOCKS);
}

fmi3Status fmi3SetShiftFraction(fmi3Instance inst, const fmi3ValueReference vr[], size_t nvr,
                                const fmi3UInt64 counters[], const fmi3UInt64 resolutions[])
{
    (void)vr; (void)nvr; (void)counters; (void)resolutions;
    NOT_PROVIDED("fmi3SetShiftFraction", NO_CLOCKS);
}

fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance inst)
{
    NOT_PROVIDED("fmi3EvaluateDiscreteStates", "providesEvaluateDiscreteStates = false");
}

fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance inst)
{
    NOT_PROVIDED("fmi3EnterContinuousTimeMode", CS_ONLY);
}

fmi3Status fmi3CompletedIntegratorStep(fmi3Instance inst,
                                       fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode,
                                       fmi3Boolean *terminateSimulation)
{
    (void)noSetFMUStatePriorToCurrentPoint; (void)enterEventMode; (void)terminateSimulation;
    NOT_PROVIDED("fmi3CompletedIntegratorStep", CS_ONLY);
}

fmi3Status fmi3SetTime(fmi3Instance inst, fmi3Float64 time)
{
    (void)time;
    NOT_PROVIDED("fmi3SetTime", CS_ONLY);
}

fmi3Status fmi3SetContinuousStates(fmi3Instance inst, const fmi3Float64 x[], size_t nx)
{
    (void)x; (void)nx;
    NOT_PROVIDED("fmi3SetContinuousStates", CS_ONLY);
}

fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance inst, fmi3Float64 d[], size_t nx)
{
    (void)d; (void)nx;
    NOT_PROVIDED("fmi3GetContinuousStateDerivatives", CS_ONLY);
}

fmi3Status fmi3GetEventIndicators(fmi3Instance inst, fmi3Float64 ind[], size_t n)
{
    (void)ind; (void)n;
    NOT_PROVIDED("fmi3GetEventIndicators", CS_ONLY);
}

fmi3Status fmi3GetContinuousStates(fmi3Instance inst, fmi3Float64 x[], size_t nx)
{
    (void)x; (void)nx;
    NOT_PROVIDED("fmi3GetContinuousStates", CS_ONLY);
}

fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance inst, fmi3Float64 nominals[], size_t nx)
{
    (void)nominals; (void)nx;
    NOT_PROVIDED("fmi3GetNominalsOfContinuousStates", CS_ONLY);
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance inst, size_t *n)
{
    (void)n;
    NOT_PROVIDED("fmi3GetNumberOfEventIndicators", CS_ONLY);
}

fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance inst, size_t *n)
{
    (void)n;
    NOT_PROVIDED("fmi3GetNumberOfContinuousStates", CS_ONLY);
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
    (void)vr; (void)orders; (void)values; (void)nValues;
    if (nvr == 0) return fmi3OK;
    NOT_PROVIDED("fmi3GetOutputDerivatives", "not provided (maxOutputDerivativeOrder = 0)");
}

/* ------------------------------------------------------------------ co-simulation */
fmi3Status fmi3DoStep(fmi3Instance inst, fmi3Float64 currentCommunicationPoint,
                      fmi3Float64 communicationStepSize,
                      fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                      fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation,
                      fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime)
{
    double t = currentCommunicationPoint, h = communicationStepSize, own;
    int rc;
    CHECK("fmi3DoStep", S_STEP);
    (void)noSetFMUStatePriorToCurrentPoint;
    if (eventHandlingNeeded) *eventHandlingNeeded = fmi3False;
    if (terminateSimulation) *terminateSimulation = fmi3False;
    if (earlyReturn) *earlyReturn = fmi3False;
    own = fpm_model_time(c->m);
    if (lastSuccessfulTime) *lastSuccessfulTime = own;
    if (!(h > 0.0) || !isfinite(h) || !isfinite(t)) {
        fpm_log(&c->lg, FPM_DISCARD, "fmi3DoStep: communicationStepSize = %.17g at t = %.17g: the "
                "step must be positive and finite, and the time finite; step rejected, state "
                "unchanged", h, t);
        return fmi3Discard;
    }
    if (!(fabs(t - own) <= FPM_TIME_RTOL * (fabs(own) > 1.0 ? fabs(own) : 1.0))) {
        fpm_log(&c->lg, FPM_ERROR, "fmi3DoStep called at t = %.17g but the FMU is at t = %.17g; "
                "restore a saved FMU state to step from another time", t, own);
        return fmi3Error;
    }
    rc = fpm_model_step(c->m, &c->lg, t, h);
    if (lastSuccessfulTime) *lastSuccessfulTime = fpm_model_time(c->m);
    c->head->discarded = rc == FPM_DISCARD;
    /* the model refused the step: it cannot go on by itself (see fmi2GetBooleanStatus) */
    if (terminateSimulation && rc == FPM_DISCARD) *terminateSimulation = fmi3True;
    return (fmi3Status)rc;
}
