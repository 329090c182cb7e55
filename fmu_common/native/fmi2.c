/*
 * fmi2.c - the FMI 2.0 interfaces, co-simulation and Model Exchange: signatures, status codes and
 * the modes each call is allowed in (FPM2_MASK_*, FMI 2.0 section 4.2.4; FPM_ME_MASK_*, section
 * 3.2.3), over the version-neutral core (fpm.h). A call of the other interface is refused with a
 * message (the core checks each instance's interface).
 *
 * Input derivatives (canInterpolateInputs): fmi2SetRealInputDerivatives hands the first and
 * second time derivatives of an input to the model, which integrates the input polynomial over
 * the following steps.
 */
#include <stdlib.h>

#include "fmi2Functions.h"
#include "fpm.h"

#define S_FMI2 (FPM_INSTANTIATED | FPM_INIT | FPM_STEP | FPM_TERMINATED | FPM_ERROR_MODE)
#define S_FMI2_ME (FPM_INSTANTIATED | FPM_INIT | FPM_EVENT | FPM_CONTINUOUS | FPM_TERMINATED | \
                   FPM_ERROR_MODE)
/* both interfaces (an instance only reaches the modes of its own) */
#define M_TERMINATE (FPM2_MASK_TERMINATE | FPM_ME_MASK_TERMINATE)
#define M_SET (FPM2_MASK_SET | FPM_ME_MASK_SET)
#define M_DIRECTIONAL (FPM_INIT | FPM_EVENT | FPM_CONTINUOUS | FPM_STEP | FPM_TERMINATED | \
                       FPM_ERROR_MODE)
#define C ((fpm_instance *)comp)

static const char *const TYPES[4] = {"Real", "Integer", "Boolean", "String"};

static void emit(fpm_instance *c, int status, const char *category, const char *message)
{
    const fmi2CallbackFunctions *cb = (const fmi2CallbackFunctions *)c->host;
    if (cb->logger == NULL) return;
    if (!fpm_log_wanted(c, status)) return;            /* its category is disabled */
    cb->logger(cb->componentEnvironment, c->name, (fmi2Status)status, category, message);
}

/* ------------------------------------------------------------------ common functions */
const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component comp, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[])
{
    return (fmi2Status)fpm_set_debug_logging(C, "fmi2SetDebugLogging", FPM2_MASK_ANY,
                                             loggingOn, nCategories, categories);
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                              fmi2Boolean loggingOn)
{
    fmi2CallbackFunctions cb = {0, 0, 0, 0, 0};
    (void)fmuResourceLocation;
    (void)visible;
    if (functions != NULL) cb = *functions;
    if (fmuType != fmi2CoSimulation && fmuType != fmi2ModelExchange) {
        if (cb.logger != NULL)
            cb.logger(cb.componentEnvironment, instanceName ? instanceName : "?", fmi2Error,
                      "logStatusError", "fmi2Instantiate: fmuType is neither fmi2ModelExchange "
                      "nor fmi2CoSimulation");
        return NULL;
    }
    return fpm_instantiate("fmi2Instantiate", instanceName, fmuGUID,
                           fmuType == fmi2CoSimulation ? FPM_COSIMULATION : FPM_MODEL_EXCHANGE,
                           fmuType == fmi2CoSimulation ? S_FMI2 : S_FMI2_ME, &cb, sizeof cb, emit,
                           loggingOn ? 1 : 0);
}

void fmi2FreeInstance(fmi2Component comp) { fpm_free_instance(C); }

fmi2Status fmi2SetupExperiment(fmi2Component comp, fmi2Boolean toleranceDefined,
                               fmi2Real tolerance, fmi2Real startTime, fmi2Boolean stopTimeDefined,
                               fmi2Real stopTime)
{
    (void)toleranceDefined;
    (void)tolerance;
    return (fmi2Status)fpm_enter_init(C, "fmi2SetupExperiment", FPM2_MASK_SETUP, startTime,
                                      stopTimeDefined, stopTime, 0);
}

fmi2Status fmi2EnterInitializationMode(fmi2Component comp)
{
    return (fmi2Status)fpm_set_mode(C, "fmi2EnterInitializationMode", FPM2_MASK_ENTER_INIT,
                                    FPM_INIT);
}

fmi2Status fmi2ExitInitializationMode(fmi2Component comp)
{
    return (fmi2Status)fpm_exit_init(C, "fmi2ExitInitializationMode", FPM2_MASK_EXIT_INIT,
                                     comp != NULL && C->interface == FPM_MODEL_EXCHANGE
                                         ? FPM_EVENT : FPM_STEP);
}

fmi2Status fmi2Terminate(fmi2Component comp)
{
    return (fmi2Status)fpm_set_mode(C, "fmi2Terminate", M_TERMINATE, FPM_TERMINATED);
}

fmi2Status fmi2Reset(fmi2Component comp)
{
    return (fmi2Status)fpm_reset(C, "fmi2Reset", FPM2_MASK_RESET);
}

/* ------------------------------------------------------------------ get and set */
#define GET(Fn, T, type, layout)                                                             \
    fmi2Status fmi2##Fn(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,       \
                        T value[])                                                           \
    {                                                                                        \
        return (fmi2Status)fpm_get(C, "fmi2" #Fn, FPM2_MASK_GET, vr, nvr, value, type,       \
                                   layout, TYPES);                                           \
    }
#define SET(Fn, T, type, layout)                                                             \
    fmi2Status fmi2##Fn(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,       \
                        const T value[])                                                     \
    {                                                                                        \
        return (fmi2Status)fpm_set(C, "fmi2" #Fn, M_SET, vr, nvr, value, type,               \
                                   layout, TYPES);                                           \
    }
GET(GetReal, fmi2Real, FPM_REAL, FPM_C_DOUBLE)
GET(GetInteger, fmi2Integer, FPM_INTEGER, FPM_C_INT)
GET(GetBoolean, fmi2Boolean, FPM_BOOLEAN, FPM_C_INT)
GET(GetString, fmi2String, FPM_STRING, FPM_C_STRING)
SET(SetReal, fmi2Real, FPM_REAL, FPM_C_DOUBLE)
SET(SetInteger, fmi2Integer, FPM_INTEGER, FPM_C_INT)
SET(SetBoolean, fmi2Boolean, FPM_BOOLEAN, FPM_C_INT)
SET(SetString, fmi2String, FPM_STRING, FPM_C_STRING)

/* ------------------------------------------------------------------ FMU states */
fmi2Status fmi2GetFMUstate(fmi2Component comp, fmi2FMUstate *state)
{
    return (fmi2Status)fpm_get_state(C, "fmi2GetFMUstate", FPM2_MASK_STATE, state);
}

fmi2Status fmi2SetFMUstate(fmi2Component comp, fmi2FMUstate state)
{
    return (fmi2Status)fpm_set_state(C, "fmi2SetFMUstate", FPM2_MASK_STATE, state);
}

fmi2Status fmi2FreeFMUstate(fmi2Component comp, fmi2FMUstate *state)
{
    return (fmi2Status)fpm_free_state(C, "fmi2FreeFMUstate", FPM2_MASK_STATE, state);
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component comp, fmi2FMUstate state, size_t *size)
{
    return (fmi2Status)fpm_state_size(C, "fmi2SerializedFMUstateSize", FPM2_MASK_STATE, state,
                                      size);
}

fmi2Status fmi2SerializeFMUstate(fmi2Component comp, fmi2FMUstate state, fmi2Byte data[],
                                 size_t size)
{
    return (fmi2Status)fpm_serialize_state(C, "fmi2SerializeFMUstate", FPM2_MASK_STATE, state,
                                           (unsigned char *)data, size);
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component comp, const fmi2Byte data[], size_t size,
                                   fmi2FMUstate *state)
{
    return (fmi2Status)fpm_deserialize_state(C, "fmi2DeSerializeFMUstate", FPM2_MASK_STATE,
                                             (const unsigned char *)data, size, state);
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component comp, const fmi2ValueReference vUnknown[],
                                        size_t nUnknown, const fmi2ValueReference vKnown[],
                                        size_t nKnown, const fmi2Real dvKnown[],
                                        fmi2Real dvUnknown[])
{
    return (fmi2Status)fpm_directional_derivative(C, "fmi2GetDirectionalDerivative",
                                                  M_DIRECTIONAL, vUnknown, nUnknown, vKnown,
                                                  nKnown, dvKnown, dvUnknown);
}

/* ------------------------------------------------------------------ co-simulation */
fmi2Status fmi2SetRealInputDerivatives(fmi2Component comp, const fmi2ValueReference vr[],
                                       size_t nvr, const fmi2Integer order[],
                                       const fmi2Real value[])
{
    return (fmi2Status)fpm_set_input_derivatives(C, "fmi2SetRealInputDerivatives",
                                                 FPM2_MASK_SET, vr, nvr, order, value);
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component comp, const fmi2ValueReference vr[],
                                        size_t nvr, const fmi2Integer order[], fmi2Real value[])
{
    return (fmi2Status)fpm_output_derivatives(C, "fmi2GetRealOutputDerivatives",
                                              FPM_STEP | FPM_TERMINATED, vr, nvr, order, value);
}

fmi2Status fmi2DoStep(fmi2Component comp, fmi2Real currentCommunicationPoint,
                      fmi2Real communicationStepSize, fmi2Boolean noSetFMUStatePriorToCurrentPoint)
{
    (void)noSetFMUStatePriorToCurrentPoint;
    return (fmi2Status)fpm_do_step(C, "fmi2DoStep", FPM2_MASK_DO_STEP, currentCommunicationPoint,
                                   communicationStepSize);
}

fmi2Status fmi2CancelStep(fmi2Component comp)
{
    return (fmi2Status)fpm_refuse(C, FPM_ERROR, "fmi2CancelStep",
                                  "doStep is synchronous here (nothing to cancel)");
}

fmi2Status fmi2GetStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Status *value)
{
    (void)s;
    (void)value;
    return (fmi2Status)fpm_refuse(C, FPM_DISCARD, "fmi2GetStatus",
                                  "not available (doStep is synchronous)");
}

fmi2Status fmi2GetRealStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Real *value)
{
    if (comp != NULL && s == fmi2LastSuccessfulTime && value != NULL) {
        *value = fpm_time(C);
        return fmi2OK;
    }
    return (fmi2Status)fpm_refuse(C, FPM_DISCARD, "fmi2GetRealStatus",
                                  "only fmi2LastSuccessfulTime is available (value not NULL)");
}

fmi2Status fmi2GetIntegerStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Integer *value)
{
    (void)s;
    (void)value;
    return (fmi2Status)fpm_refuse(C, FPM_DISCARD, "fmi2GetIntegerStatus", "not available");
}

fmi2Status fmi2GetBooleanStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Boolean *value)
{
    if (comp != NULL && s == fmi2Terminated && value != NULL) {
        /* after the model refused a step it cannot go on by itself (a master that restores a
         * saved state still can): a simple master (fmpy.simulate_fmu) stops instead of
         * retrying the same step forever */
        *value = C->discarded ? fmi2True : fmi2False;
        return fmi2OK;
    }
    return (fmi2Status)fpm_refuse(C, FPM_DISCARD, "fmi2GetBooleanStatus",
                                  "only fmi2Terminated is available (value not NULL)");
}

fmi2Status fmi2GetStringStatus(fmi2Component comp, const fmi2StatusKind s, fmi2String *value)
{
    (void)s;
    (void)value;
    return (fmi2Status)fpm_refuse(C, FPM_DISCARD, "fmi2GetStringStatus", "not available");
}

/* ------------------------------------------------------------------ model exchange */
#define ME FPM_MODEL_EXCHANGE

fmi2Status fmi2EnterEventMode(fmi2Component comp)
{
    return (fmi2Status)fpm_set_mode_of(C, "fmi2EnterEventMode", ME, FPM_ME_MASK_ENTER_EVENT,
                                       FPM_EVENT);
}

fmi2Status fmi2NewDiscreteStates(fmi2Component comp, fmi2EventInfo *info)
{
    int terminate = 0, rc;
    if (comp != NULL && info == NULL)
        return (fmi2Status)fpm_refuse(C, FPM_ERROR, "fmi2NewDiscreteStates", "eventInfo is NULL");
    rc = fpm_me_update_discrete(C, "fmi2NewDiscreteStates", FPM_ME_MASK_NEW_DISCRETE, &terminate);
    if (rc > FPM_WARNING) return (fmi2Status)rc;
    info->newDiscreteStatesNeeded = fmi2False;
    info->terminateSimulation = terminate ? fmi2True : fmi2False;
    info->nominalsOfContinuousStatesChanged = fmi2False;
    info->valuesOfContinuousStatesChanged = fmi2False;
    info->nextEventTimeDefined = fmi2False;
    info->nextEventTime = 0.0;
    return (fmi2Status)rc;
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component comp)
{
    return (fmi2Status)fpm_set_mode_of(C, "fmi2EnterContinuousTimeMode", ME,
                                       FPM_ME_MASK_ENTER_CONTINUOUS, FPM_CONTINUOUS);
}

fmi2Status fmi2CompletedIntegratorStep(fmi2Component comp, fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean *enterEventMode, fmi2Boolean *terminateSimulation)
{
    int terminate = 0, rc;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (comp != NULL && (enterEventMode == NULL || terminateSimulation == NULL))
        return (fmi2Status)fpm_refuse(C, FPM_ERROR, "fmi2CompletedIntegratorStep",
                                      "enterEventMode or terminateSimulation is NULL");
    rc = fpm_me_completed_step(C, "fmi2CompletedIntegratorStep", FPM_ME_MASK_COMPLETED_STEP,
                               &terminate);
    if (rc > FPM_WARNING) return (fmi2Status)rc;
    *enterEventMode = fmi2False;
    *terminateSimulation = terminate ? fmi2True : fmi2False;
    return (fmi2Status)rc;
}

fmi2Status fmi2SetTime(fmi2Component comp, fmi2Real time)
{
    return (fmi2Status)fpm_me_set_time(C, "fmi2SetTime", FPM_ME_MASK_SET_TIME, time);
}

fmi2Status fmi2SetContinuousStates(fmi2Component comp, const fmi2Real x[], size_t nx)
{
    return (fmi2Status)fpm_me_set_states(C, "fmi2SetContinuousStates", FPM_ME_MASK_SET_STATES,
                                         x, nx);
}

fmi2Status fmi2GetDerivatives(fmi2Component comp, fmi2Real derivatives[], size_t nx)
{
    return (fmi2Status)fpm_me_get_derivatives(C, "fmi2GetDerivatives",
                                              FPM_ME_MASK_GET_DERIVATIVES, derivatives, nx);
}

fmi2Status fmi2GetEventIndicators(fmi2Component comp, fmi2Real eventIndicators[], size_t ni)
{
    return (fmi2Status)fpm_me_get_event_indicators(C, "fmi2GetEventIndicators",
                                                   FPM_ME_MASK_GET_DERIVATIVES, eventIndicators,
                                                   ni);
}

fmi2Status fmi2GetContinuousStates(fmi2Component comp, fmi2Real x[], size_t nx)
{
    return (fmi2Status)fpm_me_get_states(C, "fmi2GetContinuousStates", FPM_ME_MASK_GET_STATES,
                                         x, nx);
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component comp, fmi2Real x_nominal[], size_t nx)
{
    return (fmi2Status)fpm_me_get_nominals(C, "fmi2GetNominalsOfContinuousStates",
                                           FPM_ME_MASK_GET_STATES | FPM_INSTANTIATED, x_nominal,
                                           nx);
}
