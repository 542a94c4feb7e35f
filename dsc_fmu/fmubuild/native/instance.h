/* An FMU instance, for both FMI versions: its state machine, guarded calls, values and FMU states.

   fmi2Functions.c and fmi3Functions.c embed an Instance first in their own struct (with the
   importer's callbacks) and map each FMI call onto the functions here. */

#ifndef DSC_INSTANCE_H
#define DSC_INSTANCE_H

#include <stddef.h>

#include "slave.h"

/* The states of the standards' state machines that these FMUs reach (no asynchronous step, no
   configuration mode, no event mode in co-simulation). */
typedef enum {
    Instantiated = 1 << 0,
    InitializationMode = 1 << 1,
    StepMode = 1 << 2,           /* co-simulation: FMI 2.0 stepComplete; FMI 3.0 Step Mode */
    StepFailed = 1 << 3,         /* co-simulation: FMI 2.0 stepFailed, fmi2DoStep returned fmi2Discard */
    EventMode = 1 << 4,          /* model exchange */
    ContinuousTimeMode = 1 << 5, /* model exchange */
    Terminated = 1 << 6,
    Error = 1 << 7,              /* FMI 2.0 error: a call returned fmi2Error (FMI 3.0 enters Terminated instead) */
} ModelState;

#define ANY_STATE (Instantiated | InitializationMode | StepMode | StepFailed | EventMode | ContinuousTimeMode | \
                   Terminated | Error)

/* In a mask: the function belongs to one interface only, and an instance of the other refuses it. */
#define CS_ONLY (1 << 8)
#define ME_ONLY (1 << 9)

typedef struct Instance Instance;

/* Hand `message` to the importer's logger as text. */
typedef void (*HostLog)(Instance *instance, int status, const char *category, const char *message);

/* What the two standards do differently beyond their names. */
typedef struct {
    MethodNames names;
    ModelState after_error;   /* FMI 2.0 Error, FMI 3.0 Terminated */
    ModelState after_discard; /* FMI 2.0 StepFailed, FMI 3.0 StepMode (the state before the call) */
    int always_logged;        /* statuses (bit 1 << status) logged whatever the categories: FMI 2.0 warnings,
                                 errors and fatal errors; FMI 3.0 none (loggingOn = false silences all) */
    HostLog log;
} Standard;

struct Instance {
    unsigned int magic;
    Slave slave;
    ModelState state;
    char name[256];
    int categories; /* the log categories enabled, bit i for CATEGORIES[i] of instance.c */
    double stop_time; /* of the experiment (INFINITY: none); no step may end after it */
    int model_exchange; /* instantiated for model exchange, else co-simulation */
    const Standard *standard;
};

/* A zeroed instance of `size` bytes (at least sizeof(Instance)) named `name`, or NULL. */
Instance *instance_alloc(size_t size, const char *name, int logging_on, int model_exchange, const Standard *standard);

/* Create the slave (resources: a path or file URI; token: the GUID or instantiation token the
   importer passed). 0, or -1 after logging why; the caller then frees the instance. */
int instance_start(Instance *instance, const char *function, const char *resources, const char *token, int visible);
void instance_free(Instance *instance);

void instance_log(Instance *instance, int status, const char *format, ...);

/* Whether `pointer`, an argument of `function` that must not be NULL, is given (if not, logged as `what`). */
int instance_given(Instance *instance, const char *function, const void *pointer, const char *what);

/* Whether the call `function` is refused: a foreign pointer (silently) or a state outside `mask` (logged,
   and the instance enters its error state). */
int instance_refused(Instance *instance, const char *function, int mask);

/* `status`, the result of the call that the functions below made; STATUS_ERROR moves the instance to
   its error state. The adapters end every call with it. */
int instance_status(Instance *instance, int status);

/* setup, enter, exit, terminate: call `method` with `n` floats; on success the state becomes `next`. */
int instance_call(Instance *instance, const char *method, int n, const double *values, const int *defined, int next);
int instance_reset(Instance *instance);
/* exit_initialization_mode; in model exchange the state then stops following the inputs and the
   instance enters event mode, in co-simulation step mode. */
int instance_exit_initialization(Instance *instance);
int instance_do_step(Instance *instance, const char *function, double time, double step);
int instance_set_logging(Instance *instance, const char *function, int logging_on, size_t n, const char *const categories[]);

int instance_get(Instance *instance, const char *function, int type, const unsigned int vr[], size_t nvr, void *values,
                 size_t nvalues, CType ctype);
int instance_set(Instance *instance, const char *function, int type, const unsigned int vr[], size_t nvr,
                 const void *values, size_t nvalues, CType ctype);

/* fmi2SetRealInputDerivatives: first derivatives of Real inputs for the next step (the slave's
   set_input_derivatives). The caller checks the state. */
int instance_set_input_derivatives(Instance *instance, const char *function, const unsigned int vr[], size_t nvr,
                                   const int order[], const double value[]);

/* Model exchange. The caller checks the state. */
int instance_set_time(Instance *instance, const char *function, double time);
int instance_set_states(Instance *instance, const char *function, const double x[], size_t nx);
/* The vector `which` into `values` (`n` must be its length). Derivatives and event indicators that fail
   or are not finite are STATUS_DISCARD (the model's trouble); anything else STATUS_ERROR. */
int instance_get_vector(Instance *instance, const char *function, Vector which, double values[], size_t n);
/* Event mode: the slave's update_discrete_states. */
int instance_update_discrete_states(Instance *instance);
/* Move to `next` (EventMode, ContinuousTimeMode). */
int instance_enter(Instance *instance, ModelState next);
/* A size the importer asks for (NULL: an error). */
int instance_count(Instance *instance, const char *function, size_t *count, size_t value);

/* For the types these FMUs have no variables of: STATUS_OK for no value references, else STATUS_ERROR
   naming the type of the first. */
int instance_no_variables_of(Instance *instance, const char *function, const char *type_name, const unsigned int vr[],
                              size_t nvr);

/* For a function these FMUs do not support: always STATUS_ERROR, logged with `why`. */
int instance_unsupported(Instance *instance, const char *function, const char *why);

int instance_get_state(Instance *instance, const char *function, void **state);
int instance_set_state(Instance *instance, const char *function, void *state);
int instance_free_state(Instance *instance, const char *function, void **state);
int instance_serialized_size(Instance *instance, const char *function, void *state, size_t *size);
int instance_serialize(Instance *instance, const char *function, void *state, char *buffer, size_t size);
int instance_deserialize(Instance *instance, const char *function, const char *buffer, size_t size, void **state);

/* For the adapters: the six FMU-state functions of one FMI version under its names and types, each
   guarded by the adapter's BEGIN (its mask MASK_<name>) and ended by its END. */
#define FMU_STATE_FUNCTIONS(Status, Component, FMUState, Byte, Get, Set, Free, SerializedSize, Serialize,        \
                            Deserialize)                                                                       \
    Status Get(Component c, FMUState *state) {                                                                 \
        BEGIN(Get);                                                                                            \
        END(instance_get_state(instance, #Get, state));                                                        \
    }                                                                                                          \
    Status Set(Component c, FMUState state) {                                                                  \
        BEGIN(Set);                                                                                            \
        END(instance_set_state(instance, #Set, state));                                                        \
    }                                                                                                          \
    Status Free(Component c, FMUState *state) {                                                                \
        BEGIN(Free);                                                                                           \
        END(instance_free_state(instance, #Free, state));                                                      \
    }                                                                                                          \
    Status SerializedSize(Component c, FMUState state, size_t *size) {                                         \
        BEGIN(SerializedSize);                                                                                 \
        END(instance_serialized_size(instance, #SerializedSize, state, size));                                 \
    }                                                                                                          \
    Status Serialize(Component c, FMUState state, Byte serialized[], size_t size) {                            \
        BEGIN(Serialize);                                                                                      \
        END(instance_serialize(instance, #Serialize, state, (char *)serialized, size));                        \
    }                                                                                                          \
    Status Deserialize(Component c, const Byte serialized[], size_t size, FMUState *state) {                   \
        BEGIN(Deserialize);                                                                                    \
        END(instance_deserialize(instance, #Deserialize, (const char *)serialized, size, state));              \
    }

/* For the adapters: the model-exchange functions that both FMI versions share, under each version's names
   and types, each guarded by the adapter's BEGIN (its mask MASK_<name>) and ended by its END. The
   switches change only at state events, which the event indicators show: no integrator step asks for
   an event. */
#define MODEL_EXCHANGE_FUNCTIONS(Status, Component, Boolean, Float, EnterEventMode, EnterContinuousTimeMode,     \
                                 CompletedIntegratorStep, SetTime, SetContinuousStates, GetDerivatives,          \
                                 GetEventIndicators, GetContinuousStates, GetNominals)                           \
    Status EnterEventMode(Component c) {                                                                       \
        BEGIN(EnterEventMode);                                                                                 \
        END(instance_enter(instance, EventMode));                                                              \
    }                                                                                                          \
    Status EnterContinuousTimeMode(Component c) {                                                              \
        BEGIN(EnterContinuousTimeMode);                                                                        \
        END(instance_enter(instance, ContinuousTimeMode));                                                     \
    }                                                                                                          \
    Status CompletedIntegratorStep(Component c, Boolean noSetFMUStatePriorToCurrentPoint, Boolean *enterEventMode, \
                                   Boolean *terminateSimulation) {                                             \
        BEGIN(CompletedIntegratorStep);                                                                        \
        if (!instance_given(instance, #CompletedIntegratorStep, enterEventMode, "place for enterEventMode") ||  \
            !instance_given(instance, #CompletedIntegratorStep, terminateSimulation,                           \
                            "place for terminateSimulation")) {                                                \
            END(STATUS_ERROR);                                                                                 \
        }                                                                                                      \
        *enterEventMode = 0;                                                                                   \
        *terminateSimulation = 0;                                                                              \
        END(STATUS_OK);                                                                                        \
    }                                                                                                          \
    Status SetTime(Component c, Float time) {                                                                  \
        BEGIN(SetTime);                                                                                        \
        END(instance_set_time(instance, #SetTime, time));                                                      \
    }                                                                                                          \
    Status SetContinuousStates(Component c, const Float x[], size_t nx) {                                      \
        BEGIN(SetContinuousStates);                                                                            \
        END(instance_set_states(instance, #SetContinuousStates, x, nx));                                       \
    }                                                                                                          \
    VECTOR_FUNCTION(Status, Component, Float, GetDerivatives, VECTOR_DERIVATIVES)                              \
    VECTOR_FUNCTION(Status, Component, Float, GetEventIndicators, VECTOR_INDICATORS)                           \
    VECTOR_FUNCTION(Status, Component, Float, GetContinuousStates, VECTOR_STATES)                              \
    VECTOR_FUNCTION(Status, Component, Float, GetNominals, VECTOR_NOMINALS)

/* One function reading the model-exchange vector `which` (see MODEL_EXCHANGE_FUNCTIONS). */
#define VECTOR_FUNCTION(Status, Component, Float, F, which)                                                     \
    Status F(Component c, Float values[], size_t n) {                                                          \
        BEGIN(F);                                                                                              \
        END(instance_get_vector(instance, #F, which, values, n));                                              \
    }

#endif
