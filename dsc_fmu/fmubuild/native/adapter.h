/* What the bodies of the FMI functions are made of. fmi2Functions.c and fmi3Functions.c write out every
   function's signature under the standard's name (grep finds fmi2GetReal where it is defined) and build
   its body from these macros; they include this file after the standard's header and
     FMI_VERSION   2 or 3
     FMI_STATUS    the standard's status type: fmi2Status, fmi3Status.
   Every function of an instance, named `c`, begins with BEGIN(F), which refuses with fmiError (logged) a
   call that functions.h does not allow in the instance's interface and state, and ends with END(status):
   an error moves the instance to the standard's error state. */

#ifndef DSC_ADAPTER_H
#define DSC_ADAPTER_H

#include "instance.h"

#define BEGIN(F)                                                                                               \
    _Static_assert(VERSION_##F == FMI_VERSION, #F " is not a function of this FMI version");                \
    Instance *instance = (Instance *)c;                                                                        \
    if (instance_refused(instance, FN_##F)) return (FMI_STATUS)STATUS_ERROR

#define END(call) return (FMI_STATUS)instance_status(instance, (call))

/* The body of F, a function of a capability these FMUs do not declare: fmiError with `why`. */
#define UNSUPPORTED(F, why)                                                                                    \
    BEGIN(F);                                                                                                  \
    END(instance_unsupported(instance, why))

/* The body of F, the getter or setter of a type these FMUs have no variables of (named `type_name`): only
   a call without value references succeeds. */
#define NO_VARIABLES_OF(F, type_name)                                                                          \
    BEGIN(F);                                                                                                  \
    END(instance_no_variables_of(instance, type_name, vr, nvr))

/* The body of fmiCompletedIntegratorStep: the switches change only at state events, which the event
   indicators show; no integrator step asks for an event or for the end. */
#define NO_EVENT_AFTER_INTEGRATOR_STEP(F)                                                                      \
    BEGIN(F);                                                                                                  \
    if (!instance_given(instance, enterEventMode, "place for enterEventMode") ||                               \
        !instance_given(instance, terminateSimulation, "place for terminateSimulation")) {                     \
        END(STATUS_ERROR);                                                                                     \
    }                                                                                                          \
    *enterEventMode = 0;                                                                                       \
    *terminateSimulation = 0;                                                                                  \
    END(STATUS_OK)

#endif
