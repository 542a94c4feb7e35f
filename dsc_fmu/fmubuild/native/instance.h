/* An FMU instance, for both FMI versions: its state machine, guarded calls, values and FMU states.

   fmi2Functions.c and fmi3Functions.c embed an Instance first in their own struct (with the
   importer's callbacks) and map each FMI call onto the functions here. */

#ifndef DSC_INSTANCE_H
#define DSC_INSTANCE_H

#include <stddef.h>

#include "slave.h"

/* The states of the standards' state machines that these FMUs reach (no asynchronous step, no
   configuration mode, no event mode in co-simulation): STATE(state, bit, name in messages). */
#define MODEL_STATES(STATE)                                                                                    \
    STATE(Instantiated, 0, "instantiated")                                                                     \
    STATE(InitializationMode, 1, "initialization mode")                                                        \
    STATE(StepMode, 2, "step mode")      /* co-simulation: FMI 2.0 stepComplete; FMI 3.0 Step Mode */          \
    STATE(StepFailed, 3, "step failed")  /* co-simulation: FMI 2.0 stepFailed, fmi2DoStep returned fmi2Discard */ \
    STATE(EventMode, 4, "event mode")    /* model exchange */                                                  \
    STATE(ContinuousTimeMode, 5, "continuous-time mode") /* model exchange */                                  \
    STATE(Terminated, 6, "terminated")                                                                         \
    STATE(Error, 7, "error") /* FMI 2.0 error: a call returned fmi2Error (FMI 3.0 enters Terminated instead) */

#define STATE_BIT(state, bit, name) state = 1 << bit,
typedef enum { MODEL_STATES(STATE_BIT) } ModelState;
#define STATE_OR(state, bit, name) | state
#define ANY_STATE (0 MODEL_STATES(STATE_OR))

/* The interface a function belongs to (functions.h); an instance of the other refuses it. */
typedef enum { CS_ME, CS, ME } Interface;

#include "functions.h"

typedef struct Instance Instance;

/* Hand `message` to the importer's logger as text. */
typedef void (*HostLog)(Instance *instance, int status, const char *category, const char *message);

/* What the two standards do differently beyond their names and types. */
typedef struct {
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
    Function function; /* the call in progress (set by instance_refused): its name is in the call's messages */
    char *name;
    int categories; /* the log categories enabled, bit i for the i-th of DSC_LOG_CATEGORIES */
    double stop_time; /* of the experiment (INFINITY: none); no step may end after it */
    int model_exchange; /* instantiated for model exchange, else co-simulation */
    const Standard *standard;
};

/* A zeroed instance of `size` bytes (at least sizeof(Instance)) named `name`, or NULL. */
Instance *instance_alloc(size_t size, const char *name, int logging_on, int model_exchange, const Standard *standard);

/* Create the slave (resources: a path or file URI; token: the GUID or instantiation token the
   importer passed), for the instantiation function `function`. 0, or -1 after logging why; the caller
   then frees the instance. */
int instance_start(Instance *instance, const char *function, const char *resources, const char *token, int visible);
void instance_free(Instance *instance);

/* Log "<instance name>: <message>" (printf's `format`) now; returns `status`. */
int instance_log(Instance *instance, int status, const char *format, ...);
/* The same for the call in progress, the one BEGIN admitted last (instance_refused):
   "<instance name>: <function>: <message>". Only for use after BEGIN. */
int instance_fail(Instance *instance, int status, const char *format, ...);

/* Whether `pointer`, an argument of the call in progress that must not be NULL, is given (if not, logged
   as `what`). Only for use after BEGIN. */
int instance_given(Instance *instance, const void *pointer, const char *what);

/* Whether the call of `function` is refused: a foreign pointer (silently), a function of the other
   interface or one not allowed in the instance's state (functions.h; logged, and the instance enters its
   error state). Else `function` becomes the call in progress. */
int instance_refused(Instance *instance, Function function);

/* `status`, the result of the call that the functions below made; STATUS_ERROR moves the instance to
   its error state. END (adapter.h) ends every call with it. */
int instance_status(Instance *instance, int status);

/* The functions below serve the call in progress, whose state BEGIN has checked. */

/* setup, enter, exit, terminate: call `method` with `n` floats; on success the state becomes `next`. */
int instance_call(Instance *instance, const char *method, int n, const double *values, const int *defined, int next);
/* Terminate: the slave's terminate, or, while the host's CPython finalizes or once it has (pyhost_alive),
   only the state Terminated (no Python object is touched). */
int instance_terminate(Instance *instance);
int instance_reset(Instance *instance);
/* exit_initialization_mode; in model exchange the state then stops following the inputs and the
   instance enters event mode, in co-simulation step mode. */
int instance_exit_initialization(Instance *instance);
int instance_do_step(Instance *instance, double time, double step);
int instance_set_logging(Instance *instance, int logging_on, size_t n, const char *const categories[]);

int instance_get(Instance *instance, int type, const unsigned int vr[], size_t nvr, void *values, size_t nvalues,
                 CType ctype);
int instance_set(Instance *instance, int type, const unsigned int vr[], size_t nvr, const void *values,
                 size_t nvalues, CType ctype);

/* fmi2SetRealInputDerivatives: first derivatives of Real inputs for the next step (the slave's
   set_input_derivatives). */
int instance_set_input_derivatives(Instance *instance, const unsigned int vr[], size_t nvr, const int order[],
                                   const double value[]);

/* J·seed (fmiGetDirectionalDerivative) or, if `adjoint`, seedᵀ·J (fmi3GetAdjointDerivative), by the slave
   (slave_partials) for the instance's interface. Refused with STATUS_ERROR before Python sees them: a seed or
   sensitivity whose length is not the knowns' or unknowns' count (every variable is a scalar), a NULL array
   with a nonzero count, a value reference that is not a Real variable. With no unknowns and no knowns,
   STATUS_OK and nothing called. */
int instance_partials(Instance *instance, const Partials *p, int adjoint);

/* Model exchange. */
int instance_set_time(Instance *instance, double time);
int instance_set_states(Instance *instance, const double x[], size_t nx);
/* The vector `which` into `values` (`n` must be its length). Derivatives and event indicators that fail
   or are not finite are STATUS_DISCARD (the model's trouble); anything else STATUS_ERROR. */
int instance_get_vector(Instance *instance, Vector which, double values[], size_t n);
/* Event mode: the slave's update_discrete_states; `changed`: whether it changed a continuous state's value. */
int instance_update_discrete_states(Instance *instance, int *changed);
/* Move to `next` (EventMode, ContinuousTimeMode). */
int instance_enter(Instance *instance, ModelState next);
/* A size the importer asks for (NULL: an error). */
int instance_count(Instance *instance, size_t *count, size_t value);

/* For the types these FMUs have no variables of: STATUS_OK for no value references, else STATUS_ERROR
   naming the type of the first. */
int instance_no_variables_of(Instance *instance, const char *type_name, const unsigned int vr[], size_t nvr);

/* For a function these FMUs do not support: always STATUS_ERROR, logged with `why`. */
int instance_unsupported(Instance *instance, const char *why);

int instance_get_state(Instance *instance, void **state);
int instance_set_state(Instance *instance, void *state);
int instance_free_state(Instance *instance, void **state);
int instance_serialized_size(Instance *instance, void *state, size_t *size);
int instance_serialize(Instance *instance, void *state, char *buffer, size_t size);
int instance_deserialize(Instance *instance, const char *buffer, size_t size, void **state);

#endif
