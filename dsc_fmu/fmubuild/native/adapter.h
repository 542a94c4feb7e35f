/* The FMI functions that behave alike in FMI 2.0 and 3.0, written once: fmi2Functions.c and
   fmi3Functions.c each include this file, after the standard's header and these definitions:
     FMI_VERSION                           2 or 3
     FMI(F)                                the standard's name of the function or type F: fmi2##F, fmi3##F
     Component, Float, FMUState            the standard's types of these
     GET_FMU_STATE, ..., GET_DERIVATIVES   the names the two standards spell differently
     NVALUES, COUNT                        the getters' and setters' parameter for the number of values
                                           (empty if there is none) and that number
   Every function of an instance begins with BEGIN(F), which refuses with fmiError (logged) a call that
   functions.h does not allow in the instance's interface and state, and ends with END(status): an
   error moves the instance to the standard's error state. */

#ifndef DSC_ADAPTER_H
#define DSC_ADAPTER_H

#include "instance.h"

#define BEGIN(F) BEGIN_CALL(F) /* F expanded: BEGIN(FMI(Reset)) is BEGIN_CALL(fmi2Reset) */
#define BEGIN_CALL(F)                                                                                          \
    _Static_assert(VERSION_##F == FMI_VERSION, #F " is not a function of this FMI version");                \
    Instance *instance = (Instance *)c;                                                                        \
    if (instance_refused(instance, FN_##F)) return (FMI(Status))STATUS_ERROR

#define END(call) return (FMI(Status))instance_status(instance, (call))

/* A function of a capability these FMUs do not declare: fmiError with `why`, where functions.h allows it. */
#define UNSUPPORTED(F, why, ...)                                                                               \
    FMI(Status) F(Component c, __VA_ARGS__) {                                                                  \
        BEGIN(F);                                                                                              \
        END(instance_unsupported(instance, why));                                                              \
    }

/* --- inquiry, logging, creation ------------------------------------------------------------------------ */

const char *FMI(GetVersion)(void) { return FMI(Version); }

FMI(Status) FMI(SetDebugLogging)(Component c, FMI(Boolean) loggingOn, size_t nCategories,
                                 const FMI(String) categories[]) {
    BEGIN(FMI(SetDebugLogging));
    END(instance_set_logging(instance, loggingOn, nCategories, categories));
}

void FMI(FreeInstance)(Component c) { instance_free((Instance *)c); }

/* --- initialisation, termination ------------------------------------------------------------------------ */

FMI(Status) FMI(ExitInitializationMode)(Component c) {
    BEGIN(FMI(ExitInitializationMode));
    END(instance_exit_initialization(instance));
}

FMI(Status) FMI(Terminate)(Component c) {
    BEGIN(FMI(Terminate));
    END(instance_call(instance, "terminate", 0, NULL, NULL, Terminated));
}

FMI(Status) FMI(Reset)(Component c) {
    BEGIN(FMI(Reset));
    END(instance_reset(instance));
}

/* --- model exchange: the switches change only at state events, which the event indicators show; no
   integrator step asks for an event ------------------------------------------------------------------- */

FMI(Status) FMI(EnterEventMode)(Component c) {
    BEGIN(FMI(EnterEventMode));
    END(instance_enter(instance, EventMode));
}

FMI(Status) FMI(EnterContinuousTimeMode)(Component c) {
    BEGIN(FMI(EnterContinuousTimeMode));
    END(instance_enter(instance, ContinuousTimeMode));
}

FMI(Status) FMI(CompletedIntegratorStep)(Component c, FMI(Boolean) noSetFMUStatePriorToCurrentPoint,
                                         FMI(Boolean) *enterEventMode, FMI(Boolean) *terminateSimulation) {
    BEGIN(FMI(CompletedIntegratorStep));
    if (!instance_given(instance, enterEventMode, "place for enterEventMode") ||
        !instance_given(instance, terminateSimulation, "place for terminateSimulation")) {
        END(STATUS_ERROR);
    }
    *enterEventMode = 0;
    *terminateSimulation = 0;
    END(STATUS_OK);
}

FMI(Status) FMI(SetTime)(Component c, Float time) {
    BEGIN(FMI(SetTime));
    END(instance_set_time(instance, time));
}

FMI(Status) FMI(SetContinuousStates)(Component c, const Float x[], size_t nx) {
    BEGIN(FMI(SetContinuousStates));
    END(instance_set_states(instance, x, nx));
}

/* The model-exchange vector `which`. */
#define VECTOR_FUNCTION(F, which)                                                                              \
    FMI(Status) F(Component c, Float values[], size_t n) {                                                     \
        BEGIN(F);                                                                                              \
        END(instance_get_vector(instance, which, values, n));                                                  \
    }

VECTOR_FUNCTION(GET_DERIVATIVES, VECTOR_DERIVATIVES)
VECTOR_FUNCTION(FMI(GetEventIndicators), VECTOR_INDICATORS)
VECTOR_FUNCTION(FMI(GetContinuousStates), VECTOR_STATES)
VECTOR_FUNCTION(FMI(GetNominalsOfContinuousStates), VECTOR_NOMINALS)

/* --- values: the getter and setter of the type T, whose code is `type` and whose values sit in the
   caller's array as `ctype`, the standard's C type `cvalue` ------------------------------------------------ */

#define GET_AND_SET(T, type, ctype, cvalue)                                                                    \
    FMI(Status) FMI(Get##T)(Component c, const FMI(ValueReference) vr[], size_t nvr, cvalue values[] NVALUES) { \
        BEGIN(FMI(Get##T));                                                                                    \
        END(instance_get(instance, type, vr, nvr, values, COUNT, ctype));                                      \
    }                                                                                                          \
    FMI(Status) FMI(Set##T)(Component c, const FMI(ValueReference) vr[], size_t nvr, const cvalue values[]     \
                            NVALUES) {                                                                         \
        BEGIN(FMI(Set##T));                                                                                    \
        END(instance_set(instance, type, vr, nvr, values, COUNT, ctype));                                      \
    }

/* --- FMU states ------------------------------------------------------------------------------------------- */

FMI(Status) GET_FMU_STATE(Component c, FMUState *state) {
    BEGIN(GET_FMU_STATE);
    END(instance_get_state(instance, state));
}

FMI(Status) SET_FMU_STATE(Component c, FMUState state) {
    BEGIN(SET_FMU_STATE);
    END(instance_set_state(instance, state));
}

FMI(Status) FREE_FMU_STATE(Component c, FMUState *state) {
    BEGIN(FREE_FMU_STATE);
    END(instance_free_state(instance, state));
}

FMI(Status) SERIALIZED_FMU_STATE_SIZE(Component c, FMUState state, size_t *size) {
    BEGIN(SERIALIZED_FMU_STATE_SIZE);
    END(instance_serialized_size(instance, state, size));
}

FMI(Status) SERIALIZE_FMU_STATE(Component c, FMUState state, FMI(Byte) serialized[], size_t size) {
    BEGIN(SERIALIZE_FMU_STATE);
    END(instance_serialize(instance, state, (char *)serialized, size));
}

FMI(Status) DESERIALIZE_FMU_STATE(Component c, const FMI(Byte) serialized[], size_t size, FMUState *state) {
    BEGIN(DESERIALIZE_FMU_STATE);
    END(instance_deserialize(instance, (const char *)serialized, size, state));
}

#endif
