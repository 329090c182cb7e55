// The C++ boundary of the loader: pythonfmu's library is C++, and an exception that escapes one of
// its FMI functions would unwind through the loader's C frames into the host (std::terminate, an
// abort of the host process). Each guard calls one function of that library and turns any
// exception into fmi2Error (NULL for fmi2Instantiate), reporting it through flx_exception.
#include <exception>

#include "fmi2_api.h"

namespace {

template <typename R, typename F, typename... A>
R guarded(const char *what, R on_error, F f, A... a) noexcept
{
    try {
        return f(a...);
    } catch (const std::exception &e) {
        flx_exception(what, e.what());
    } catch (...) {
        flx_exception(what, "an exception that is not a std::exception");
    }
    return on_error;
}

}  // namespace

extern "C" {

fmi2Component flx_guard_instantiate(fmi2InstantiateTYPE f, fmi2String n, fmi2Type t, fmi2String g,
                                    fmi2String r, const fmi2CallbackFunctions *cb, fmi2Boolean v,
                                    fmi2Boolean l)
{
    return guarded("fmi2Instantiate", static_cast<fmi2Component>(nullptr), f, n, t, g, r, cb, v, l);
}

void flx_guard_free(fmi2FreeInstanceTYPE f, fmi2Component c)
{
    try {
        f(c);
    } catch (const std::exception &e) {
        flx_exception("fmi2FreeInstance", e.what());
    } catch (...) {
        flx_exception("fmi2FreeInstance", "an exception that is not a std::exception");
    }
}

fmi2Status flx_guard_setup(fmi2SetupExperimentTYPE f, fmi2Component c, fmi2Boolean td, fmi2Real tol,
                           fmi2Real t0, fmi2Boolean sd, fmi2Real t1)
{
    return guarded("fmi2SetupExperiment", fmi2Error, f, c, td, tol, t0, sd, t1);
}

fmi2Status flx_guard_component(fmi2ComponentTYPE f, fmi2Component c)
{
    return guarded("fmi2 call", fmi2Error, f, c);
}

#define FLX_GUARD_ARRAY(name, fname, T, V)                                                       \
    fmi2Status name(T f, fmi2Component c, const fmi2ValueReference *vr, size_t n, V value)      \
    {                                                                                            \
        return guarded(fname, fmi2Error, f, c, vr, n, value);                                   \
    }

FLX_GUARD_ARRAY(flx_guard_get_real, "fmi2GetReal", fmi2GetRealTYPE, fmi2Real *)
FLX_GUARD_ARRAY(flx_guard_get_integer, "fmi2GetInteger", fmi2GetIntegerTYPE, fmi2Integer *)
FLX_GUARD_ARRAY(flx_guard_get_boolean, "fmi2GetBoolean", fmi2GetBooleanTYPE, fmi2Boolean *)
FLX_GUARD_ARRAY(flx_guard_get_string, "fmi2GetString", fmi2GetStringTYPE, fmi2String *)
FLX_GUARD_ARRAY(flx_guard_set_real, "fmi2SetReal", fmi2SetRealTYPE, const fmi2Real *)
FLX_GUARD_ARRAY(flx_guard_set_integer, "fmi2SetInteger", fmi2SetIntegerTYPE, const fmi2Integer *)
FLX_GUARD_ARRAY(flx_guard_set_boolean, "fmi2SetBoolean", fmi2SetBooleanTYPE, const fmi2Boolean *)
FLX_GUARD_ARRAY(flx_guard_set_string, "fmi2SetString", fmi2SetStringTYPE, const fmi2String *)

fmi2Status flx_guard_get_state(fmi2GetFMUstateTYPE f, fmi2Component c, fmi2FMUstate *s)
{
    return guarded("fmi2GetFMUstate", fmi2Error, f, c, s);
}

fmi2Status flx_guard_set_state(fmi2SetFMUstateTYPE f, fmi2Component c, fmi2FMUstate s)
{
    return guarded("fmi2SetFMUstate", fmi2Error, f, c, s);
}

fmi2Status flx_guard_free_state(fmi2FreeFMUstateTYPE f, fmi2Component c, fmi2FMUstate *s)
{
    return guarded("fmi2FreeFMUstate", fmi2Error, f, c, s);
}

fmi2Status flx_guard_state_size(fmi2SerializedFMUstateSizeTYPE f, fmi2Component c, fmi2FMUstate s,
                                size_t *size)
{
    return guarded("fmi2SerializedFMUstateSize", fmi2Error, f, c, s, size);
}

fmi2Status flx_guard_serialize(fmi2SerializeFMUstateTYPE f, fmi2Component c, fmi2FMUstate s,
                               fmi2Byte *bytes, size_t size)
{
    return guarded("fmi2SerializeFMUstate", fmi2Error, f, c, s, bytes, size);
}

fmi2Status flx_guard_deserialize(fmi2DeSerializeFMUstateTYPE f, fmi2Component c,
                                 const fmi2Byte *bytes, size_t size, fmi2FMUstate *s)
{
    return guarded("fmi2DeSerializeFMUstate", fmi2Error, f, c, bytes, size, s);
}

fmi2Status flx_guard_do_step(fmi2DoStepTYPE f, fmi2Component c, fmi2Real t, fmi2Real h,
                             fmi2Boolean no_set)
{
    return guarded("fmi2DoStep", fmi2Error, f, c, t, h, no_set);
}

}  // extern "C"
