/* One Python slave behind an FMU instance, for both FMI versions: its creation and variable table
   (slave.c), its log queue (slave_queue.c), calls whose exceptions become logged messages
   (slave_calls.c), typed get and set and the model-exchange vectors (slave_values.c), FMU states
   (slave_states.c).

   Messages that arise while the GIL is held (the slave's own log, a Python exception) are queued
   and handed to the importer's logger after the GIL is released, in order, on the calling thread,
   before the call returns: a logger that blocks never holds up another instance. */

#ifndef DSC_SLAVE_H
#define DSC_SLAVE_H

#include <stdarg.h>
#include <stddef.h>

#include "pyhost.h"

/* Statuses, the same numbers in FMI 2.0 and 3.0. */
enum { STATUS_OK = 0, STATUS_WARNING = 1, STATUS_DISCARD = 2, STATUS_ERROR = 3, STATUS_FATAL = 4 };

/* What the build passes (binary.py): the codes of native_bridge.py, which owns them, as DSC_<KIND>_<NAME>,
   and its names of the types for the FMI version built (DSC_TYPE_NAMES) with the slave's get and set method
   of each (DSC_GET_METHODS, DSC_SET_METHODS); the log categories of the model descriptions and of each
   status, pythonfmu's. */
#if !defined(DSC_TYPE_REAL) || !defined(DSC_TYPE_INTEGER) || !defined(DSC_TYPE_BOOLEAN) ||                  \
    !defined(DSC_TYPE_STRING) || !defined(DSC_CAUSALITY_PARAMETER) || !defined(DSC_CAUSALITY_INPUT) ||          \
    !defined(DSC_CAUSALITY_OUTPUT) || !defined(DSC_VARIABILITY_CONSTANT) || !defined(DSC_VARIABILITY_FIXED) ||  \
    !defined(DSC_VARIABILITY_TUNABLE) || !defined(DSC_TYPE_NAMES) || !defined(DSC_GET_METHODS) ||                 \
    !defined(DSC_SET_METHODS) || !defined(DSC_LOG_CATEGORIES) || !defined(DSC_STATUS_CATEGORIES)
#error the codes of native_bridge.py (DSC_TYPE_REAL, ...) and the log categories must be defined
#endif
enum { TYPE_REAL = DSC_TYPE_REAL, TYPE_INTEGER = DSC_TYPE_INTEGER, TYPE_BOOLEAN = DSC_TYPE_BOOLEAN,
       TYPE_STRING = DSC_TYPE_STRING, TYPES = 3, NO_VARIABLE = -1 };
_Static_assert(TYPE_REAL == 0 && TYPE_INTEGER == 1 && TYPE_BOOLEAN == 2 && TYPE_STRING == TYPES,
               "the type codes index the get and set methods: Real, Integer, Boolean, then String");
/* The FMI version's name of each type (Real or Float64, ...), by code. */
extern const char *const TYPE_NAMES[TYPES + 1];

/* Model exchange: the vectors of the slave's model, each read by one method of the slave. */
typedef enum { VECTOR_DERIVATIVES, VECTOR_INDICATORS, VECTOR_STATES, VECTOR_NOMINALS, VECTORS } Vector;

/* Bound methods kept for every call: get by type, set by type, do_step, the vectors, set_point. */
enum { BOUND_DO_STEP = 2 * TYPES, BOUND_VECTORS, BOUND_SET_POINT = BOUND_VECTORS + VECTORS, BOUND_METHODS };

/* What model exchange has set and the slave has not seen yet. */
enum { PENDING_TIME = 1, PENDING_STATES = 2 };
enum { CAUSALITY_PARAMETER = DSC_CAUSALITY_PARAMETER, CAUSALITY_INPUT = DSC_CAUSALITY_INPUT,
       CAUSALITY_OUTPUT = DSC_CAUSALITY_OUTPUT };
enum { VARIABILITY_CONSTANT = DSC_VARIABILITY_CONSTANT, VARIABILITY_FIXED = DSC_VARIABILITY_FIXED,
       VARIABILITY_TUNABLE = DSC_VARIABILITY_TUNABLE };

/* How values sit in the caller's array. */
typedef enum { C_DOUBLE, C_INT, C_INT32, C_BOOL_INT, C_BOOL_BYTE } CType;

typedef void (*SlaveLog)(void *context, int status, const char *category, const char *message);

/* What the steps, gets and sets taken in C have done that the slave has not seen yet (Traced.ahead). */
enum { AHEAD_INPUTS = 1, AHEAD_STEP = 2 };

/* The values the model traced to C reads (slave_traced.c, traced.h; docs/traced-c.md), copied from the slave at
   the end of each of its calls (its traced_snapshot) and handed back at the start of the next (traced_sync):
   between two calls into Python, sets of inputs, gets of outputs, co-simulation steps and model exchange's
   derivatives and event indicators run here, without Python, where the slave allows it (`ready`). */
typedef struct {
    int usable;                 /* the FMU carries a traced model whose sizes agree with the slave's (its layout) */
    int ready;                  /* the values below are the slave's, as of its last call, but for what is `ahead` */
    int ahead;                  /* AHEAD_INPUTS, AHEAD_STEP */
    int outputs_valid;          /* `outputs` are those of the current values */
    int has_history;            /* a step was taken: `stamp`, `stamped` hold its inputs */
    int has_held;               /* model exchange: `held` are the switches held since the last event */
    size_t np, nu, ny, nb;      /* parameters, inputs, traced outputs, outputs of the model's bookkeeping */
    int max_step, coupling;     /* their indices in p; -1: none */
    long max_substeps, hold, interpolate;
    double time, stamp;
    double *p, *x, *u, *stamped, *slope, *next, *outputs, *bookkeeping, *held;
    double *dx, *du, *values, *drates, *doutputs; /* directional derivatives' seeds, values, tangents */
    double *checks;             /* each input's bound code, minimum, maximum (the slave's traced_layout) */
    signed char *role;          /* by value reference: the role in the layout, or NO_VARIABLE */
    int *index;                 /* by value reference: the index in its role's values */
    int *state_of;              /* by value reference: the index of the continuous state it is, or -1 */
    int *derivative_of;         /* by value reference: the index of the state whose derivative it is, or -1 */
} Traced;

/* A message waiting for the GIL to be released: one block, the category after the text. */
typedef struct Message {
    struct Message *next;
    int status;
    const char *category;
    char text[];
} Message;

typedef struct {
    PyObject *bridge;
    PyObject *slave;
    PyObject *log_queue;
    PyObject *bound[BOUND_METHODS];
    char *entry;                /* the entry file's text, its words ended in place: */
    const char *module;         /*   the slave's module, */
    const char *class_name;     /*   its class */
    const char *token;          /*   and the GUID (FMI 2.0) or instantiation token (FMI 3.0) */
    char *resources;            /* the resources folder's path */
    const char *instance_name;  /* the instance's, which outlives the slave */
    int visible;
    size_t nx;                  /* continuous states (model exchange) */
    size_t nz;                  /* event indicators */
    int pending;                /* PENDING_TIME, PENDING_STATES: set here, handed to the slave at its next call */
    double time;
    double *x;                  /* nx states */
    unsigned int size;          /* largest value reference + 1 */
    signed char *type;          /* by value reference; NO_VARIABLE where there is none */
    signed char *causality;
    signed char *variability;
    signed char *is_state;      /* 1 for a continuous state of model exchange, else 0 */
    SlaveLog log;
    void *context;
    Message *messages;          /* queued while the GIL is held */
    Message **last;
    int lost;                   /* messages that found no memory since the last delivery: counted, then reported */
    int interrupted;            /* a KeyboardInterrupt to raise again in the host once the GIL is released */
    Traced traced;
} Slave;

/* An empty slave of the instance `instance_name` (which must outlive it) whose messages go to `log`. */
void slave_init(Slave *s, const char *instance_name, SlaveLog log, void *context);

/* Check `token` against the FMU's, then start Python if needed and create the slave of the FMU
   whose resources folder is `resources` (a path). 0, or -1 after logging why (the Slave is then
   empty). */
int slave_create(Slave *s, const char *resources, const char *token, int visible);
/* Release the slave's Python objects, then its C memory. While the host's Python finalizes, or once it
   has (pyhost_alive), only the C memory: nothing is logged and no Python object is touched. */
void slave_free(Slave *s);

/* A new Python slave in place of the current one (fmiReset). */
int slave_reset(Slave *s);

/* The type of the variable `vr`, or NO_VARIABLE. */
int slave_type_of(const Slave *s, unsigned int vr);

/* Typed get and set of `n` values; STATUS_OK or STATUS_ERROR (logged). */
int slave_get(Slave *s, int type, const unsigned int *vr, size_t n, void *values, CType ctype);
int slave_set(Slave *s, int type, const unsigned int *vr, size_t n, const void *values, CType ctype);
/* The slave's set_input_derivatives(value references, orders, values). */
int slave_set_input_derivatives(Slave *s, const unsigned int *vr, size_t n, const int *order, const double *values);

/* The arguments of a partial-derivative call (fmi2GetDirectionalDerivative, fmi3GetDirectionalDerivative,
   fmi3GetAdjointDerivative): value references of the unknowns and knowns, the seed and the place for the
   sensitivity, each with its length. */
typedef struct {
    const unsigned int *unknowns;
    size_t n_unknowns;
    const unsigned int *knowns;
    size_t n_knowns;
    const double *seed;
    size_t n_seed;
    double *sensitivity;
    size_t n_sensitivity;
} Partials;

/* J·seed (the slave's directional_derivative) or seedᵀ·J (`adjoint`: adjoint_derivative), J the Jacobian of the
   unknowns with respect to the knowns, for model exchange or co-simulation: the lists go to the method, its
   n_sensitivity floats come back. STATUS_OK, or STATUS_ERROR after logging the exception (one message) or a
   result of another length. */
int slave_partials(Slave *s, const Partials *p, int adjoint, int model_exchange);

/* Call a method of the slave with `n` float arguments (None where `defined`, if not NULL, is 0).
   STATUS_OK, or STATUS_ERROR after logging the exception. Like every call below that runs the slave, it
   first hands over what model exchange set (set_point); if that fails, STATUS_ERROR (logged) and nothing
   else runs. */
int slave_call(Slave *s, const char *method, int n, const double *values, const int *defined);

/* update_discrete_states (event mode): STATUS_OK with `changed` whether the slave changed the value of a
   continuous state, or STATUS_ERROR after logging the exception. */
int slave_update_discrete_states(Slave *s, int *changed);

/* do_step(time, step): STATUS_OK with `accepted` the slave's answer, or STATUS_DISCARD after logging
   the exception. */
int slave_step(Slave *s, double time, double step, int *accepted);

/* The `n` values of the vector `which` (n must be its length); STATUS_OK, or `failure` after logging
   the exception. */
int slave_get_vector(Slave *s, Vector which, double *values, size_t n, int failure);

/* The time and the `n` (= nx) continuous states, kept here and handed to the slave (set_point) with its
   next call, so that a solver's SetTime, SetContinuousStates, GetDerivatives enter Python once. */
int slave_set_states(Slave *s, const double *values, size_t n);
int slave_set_time(Slave *s, double time);

/* A float attribute of the slave (such as its time). */
int slave_get_double(Slave *s, const char *attribute, double *value);

/* FMU states: opaque Python objects owned by the caller. */
int slave_get_state(Slave *s, PyObject **state);
int slave_set_state(Slave *s, PyObject *state);
/* Release an FMU state; nothing while the host's Python finalizes or once it has (pyhost_alive). */
void slave_release(PyObject *object);
int slave_serialize(Slave *s, PyObject *state, char **bytes, size_t *size);
int slave_deserialize(Slave *s, const char *bytes, size_t size, PyObject **state);

/* Gets, sets, steps and vectors in C (slave_traced.c): each 1 if done there (values written, `*accepted` set),
   0 if the call is to go to Python. */
int traced_get(Slave *s, int type, const unsigned int *vr, size_t n, void *values, CType ctype);
int traced_set(Slave *s, int type, const unsigned int *vr, size_t n, const void *values, CType ctype);
int traced_step(Slave *s, double time, double step, int *accepted);
int traced_vector(Slave *s, Vector which, double *values, size_t n);
int traced_partials(Slave *s, const Partials *p, int adjoint, int model_exchange);
/* The values changed by model exchange's set time and states: the outputs are computed again. */
void traced_touched(Slave *s);

/* The log category of a message with `status` (logStatusWarning, ..., logAll for OK). */
const char *slave_category(int status);

/* The one formatter of the binary's messages: "<instance name>: ", then "<call>: " if `call` is not NULL,
   then `format` (printf's) with `args`, queued with `status` and its category. */
void slave_vlog(Slave *s, int status, const char *call, const char *format, va_list args);

/* Hand the queued messages to the logger, in order; call without the GIL. */
void slave_deliver(Slave *s);

#endif
