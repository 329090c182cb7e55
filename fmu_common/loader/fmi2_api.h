/* The FMI 2.0 co-simulation interface as the loader needs it: platform types, callback struct and
 * the function types it forwards (written from the FMI 2.0.x standard, section 2.1). */
#ifndef FLEXPEND_FMI2_API_H
#define FLEXPEND_FMI2_API_H

#include <stddef.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef void *fmi2Component;
typedef void *fmi2ComponentEnvironment;
typedef void *fmi2FMUstate;
typedef unsigned int fmi2ValueReference;
typedef double fmi2Real;
typedef int fmi2Integer;
typedef int fmi2Boolean;
typedef char fmi2Char;
typedef const fmi2Char *fmi2String;
typedef char fmi2Byte;

#define fmi2True 1
#define fmi2False 0

typedef enum { fmi2OK, fmi2Warning, fmi2Discard, fmi2Error, fmi2Fatal, fmi2Pending } fmi2Status;
typedef enum { fmi2ModelExchange, fmi2CoSimulation } fmi2Type;
typedef enum {
    fmi2DoStepStatus, fmi2PendingStatus, fmi2LastSuccessfulTime, fmi2Terminated
} fmi2StatusKind;

typedef void (*fmi2CallbackLogger)(fmi2ComponentEnvironment, fmi2String, fmi2Status, fmi2String,
                                   fmi2String, ...);
typedef void *(*fmi2CallbackAllocateMemory)(size_t, size_t);
typedef void (*fmi2CallbackFreeMemory)(void *);
typedef void (*fmi2StepFinished)(fmi2ComponentEnvironment, fmi2Status);

typedef struct {
    fmi2CallbackLogger logger;
    fmi2CallbackAllocateMemory allocateMemory;
    fmi2CallbackFreeMemory freeMemory;
    fmi2StepFinished stepFinished;
    fmi2ComponentEnvironment componentEnvironment;
} fmi2CallbackFunctions;

/* The functions of pythonfmu's library that the loader calls (the others it answers itself). */
typedef fmi2Component (*fmi2InstantiateTYPE)(fmi2String, fmi2Type, fmi2String, fmi2String,
                                             const fmi2CallbackFunctions *, fmi2Boolean,
                                             fmi2Boolean);
typedef void (*fmi2FreeInstanceTYPE)(fmi2Component);
typedef fmi2Status (*fmi2SetupExperimentTYPE)(fmi2Component, fmi2Boolean, fmi2Real, fmi2Real,
                                              fmi2Boolean, fmi2Real);
typedef fmi2Status (*fmi2ComponentTYPE)(fmi2Component);  /* enter/exit init, terminate, reset */
typedef fmi2Status (*fmi2GetRealTYPE)(fmi2Component, const fmi2ValueReference *, size_t,
                                      fmi2Real *);
typedef fmi2Status (*fmi2GetIntegerTYPE)(fmi2Component, const fmi2ValueReference *, size_t,
                                         fmi2Integer *);
typedef fmi2Status (*fmi2GetBooleanTYPE)(fmi2Component, const fmi2ValueReference *, size_t,
                                         fmi2Boolean *);
typedef fmi2Status (*fmi2GetStringTYPE)(fmi2Component, const fmi2ValueReference *, size_t,
                                        fmi2String *);
typedef fmi2Status (*fmi2SetRealTYPE)(fmi2Component, const fmi2ValueReference *, size_t,
                                      const fmi2Real *);
typedef fmi2Status (*fmi2SetIntegerTYPE)(fmi2Component, const fmi2ValueReference *, size_t,
                                         const fmi2Integer *);
typedef fmi2Status (*fmi2SetBooleanTYPE)(fmi2Component, const fmi2ValueReference *, size_t,
                                         const fmi2Boolean *);
typedef fmi2Status (*fmi2SetStringTYPE)(fmi2Component, const fmi2ValueReference *, size_t,
                                        const fmi2String *);
typedef fmi2Status (*fmi2GetFMUstateTYPE)(fmi2Component, fmi2FMUstate *);
typedef fmi2Status (*fmi2SetFMUstateTYPE)(fmi2Component, fmi2FMUstate);
typedef fmi2Status (*fmi2FreeFMUstateTYPE)(fmi2Component, fmi2FMUstate *);
typedef fmi2Status (*fmi2SerializedFMUstateSizeTYPE)(fmi2Component, fmi2FMUstate, size_t *);
typedef fmi2Status (*fmi2SerializeFMUstateTYPE)(fmi2Component, fmi2FMUstate, fmi2Byte *, size_t);
typedef fmi2Status (*fmi2DeSerializeFMUstateTYPE)(fmi2Component, const fmi2Byte *, size_t,
                                                  fmi2FMUstate *);
typedef fmi2Status (*fmi2DoStepTYPE)(fmi2Component, fmi2Real, fmi2Real, fmi2Boolean);

/* The C++ boundary (guard.cpp): each calls the function and turns any C++ exception into
 * fmi2Error (NULL for instantiate), after reporting it through flx_exception(what, message). */
fmi2Component flx_guard_instantiate(fmi2InstantiateTYPE, fmi2String, fmi2Type, fmi2String,
                                    fmi2String, const fmi2CallbackFunctions *, fmi2Boolean,
                                    fmi2Boolean);
void flx_guard_free(fmi2FreeInstanceTYPE, fmi2Component);
fmi2Status flx_guard_setup(fmi2SetupExperimentTYPE, fmi2Component, fmi2Boolean, fmi2Real,
                           fmi2Real, fmi2Boolean, fmi2Real);
fmi2Status flx_guard_component(fmi2ComponentTYPE, fmi2Component);
fmi2Status flx_guard_get_real(fmi2GetRealTYPE, fmi2Component, const fmi2ValueReference *, size_t,
                              fmi2Real *);
fmi2Status flx_guard_get_integer(fmi2GetIntegerTYPE, fmi2Component, const fmi2ValueReference *,
                                 size_t, fmi2Integer *);
fmi2Status flx_guard_get_boolean(fmi2GetBooleanTYPE, fmi2Component, const fmi2ValueReference *,
                                 size_t, fmi2Boolean *);
fmi2Status flx_guard_get_string(fmi2GetStringTYPE, fmi2Component, const fmi2ValueReference *,
                                size_t, fmi2String *);
fmi2Status flx_guard_set_real(fmi2SetRealTYPE, fmi2Component, const fmi2ValueReference *, size_t,
                              const fmi2Real *);
fmi2Status flx_guard_set_integer(fmi2SetIntegerTYPE, fmi2Component, const fmi2ValueReference *,
                                 size_t, const fmi2Integer *);
fmi2Status flx_guard_set_boolean(fmi2SetBooleanTYPE, fmi2Component, const fmi2ValueReference *,
                                 size_t, const fmi2Boolean *);
fmi2Status flx_guard_set_string(fmi2SetStringTYPE, fmi2Component, const fmi2ValueReference *,
                                size_t, const fmi2String *);
fmi2Status flx_guard_get_state(fmi2GetFMUstateTYPE, fmi2Component, fmi2FMUstate *);
fmi2Status flx_guard_set_state(fmi2SetFMUstateTYPE, fmi2Component, fmi2FMUstate);
fmi2Status flx_guard_free_state(fmi2FreeFMUstateTYPE, fmi2Component, fmi2FMUstate *);
fmi2Status flx_guard_state_size(fmi2SerializedFMUstateSizeTYPE, fmi2Component, fmi2FMUstate,
                                size_t *);
fmi2Status flx_guard_serialize(fmi2SerializeFMUstateTYPE, fmi2Component, fmi2FMUstate, fmi2Byte *,
                               size_t);
fmi2Status flx_guard_deserialize(fmi2DeSerializeFMUstateTYPE, fmi2Component, const fmi2Byte *,
                                 size_t, fmi2FMUstate *);
fmi2Status flx_guard_do_step(fmi2DoStepTYPE, fmi2Component, fmi2Real, fmi2Real, fmi2Boolean);

/* Called by guard.cpp (defined in fmi2_loader.c) with the function's name and the exception's
 * message. */
void flx_exception(const char *what, const char *message);

#ifdef __cplusplus
}
#endif
#endif
