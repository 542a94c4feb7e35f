/* An FMU instance, for both FMI versions (see instance.h).

   Every function checks its arguments (value references, types, causality, variability, step
   sizes, FMU states) before Python sees them and logs every failure as text. Any call that returns
   STATUS_ERROR (an illegal call, a bad argument, a Python exception) moves the instance to the
   standard's error state (FMI 2.0 error, FMI 3.0 terminated), from which fmiSetFMUstate,
   fmiReset and fmiFreeInstance lead on. A step the slave declines or fails is STATUS_DISCARD: the
   instance stays at the start of that step, in FMI 2.0 stepFailed, in FMI 3.0 step mode; nothing
   here returns STATUS_FATAL. */

#include "instance.h"

#include "uri.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define INSTANCE_MAGIC 0x44534349u
#define STATE_MAGIC 0x44535354u

typedef struct {
    unsigned int magic;
    PyObject *object;
    ModelState state;
    char *bytes; /* serialized, kept from the first fmiSerializedFMUstateSize or fmiSerializeFMUstate; or NULL */
    size_t size;
} State;

/* The log categories the model descriptions declare (pythonfmu's, passed by the build). A message of a
   category not among them is shown when the category of OK messages (logAll) is enabled. */
static const char *const CATEGORIES[] = {DSC_LOG_CATEGORIES};
enum { CATEGORY_COUNT = sizeof CATEGORIES / sizeof CATEGORIES[0], ALL_CATEGORIES = (1 << CATEGORY_COUNT) - 1 };

#define FUNCTION_ROW(name, version, interface, states) {#name, interface, states},
static const struct {
    const char *name;
    Interface interface;
    int states;
} FUNCTIONS[] = {FMI_FUNCTIONS(FUNCTION_ROW)};

static const char *state_name(ModelState state) {
#define STATE_NAME(state_, bit, name) if (state == state_) return name;
    MODEL_STATES(STATE_NAME)
    return "unknown";
}

static int category_bit(const char *category) {
    for (int k = 0; category && k < CATEGORY_COUNT; k++) {
        if (strcmp(category, CATEGORIES[k]) == 0) return 1 << k;
    }
    return -1;
}

/* To the importer's logger, if the standard and the enabled categories let the message through. */
static void forward(void *context, int status, const char *category, const char *message) {
    Instance *instance = context;
    if (status < STATUS_OK || status > STATUS_FATAL) status = STATUS_ERROR;
    int bit = category_bit(category);
    int enabled = instance->categories & (bit > 0 ? bit : category_bit(slave_category(STATUS_OK)));
    if (!enabled && !(instance->standard->always_logged & (1 << status))) return;
    instance->standard->log(instance, status, category, message);
}

/* The instance's own messages go through the slave's formatter and on at once (no GIL is held here). */
int instance_log(Instance *instance, int status, const char *format, ...) {
    va_list args;
    va_start(args, format);
    slave_vlog(&instance->slave, status, NULL, format, args);
    va_end(args);
    slave_deliver(&instance->slave);
    return status;
}

int instance_fail(Instance *instance, int status, const char *format, ...) {
    va_list args;
    va_start(args, format);
    slave_vlog(&instance->slave, status, FUNCTIONS[instance->function].name, format, args);
    va_end(args);
    slave_deliver(&instance->slave);
    return status;
}

Instance *instance_alloc(size_t size, const char *name, int logging_on, int model_exchange, const Standard *standard) {
    Instance *instance = calloc(1, size);
    char *copy = malloc(strlen(name) + 1);
    if (!instance || !copy) {
        free(instance);
        free(copy);
        return NULL;
    }
    instance->name = strcpy(copy, name);
    instance->magic = INSTANCE_MAGIC;
    instance->model_exchange = model_exchange;
    instance->state = Instantiated;
    instance->stop_time = INFINITY;
    instance->categories = logging_on ? ALL_CATEGORIES : 0;
    instance->standard = standard;
    slave_init(&instance->slave, instance->name, forward, instance);
    return instance;
}

int instance_start(Instance *instance, const char *function, const char *resources, const char *token, int visible) {
    char *folder = resources ? malloc(strlen(resources) + 1) : NULL; /* a path is never longer than its URI */
    if (resources && !folder) {
        instance_log(instance, STATUS_ERROR, "%s: out of memory for the resource location", function);
        return -1;
    }
    if (uri_to_path(resources, folder, resources ? strlen(resources) + 1 : 0) != 0) {
        instance_log(instance, STATUS_ERROR, "%s: the resource location %s is not a file URI or an absolute path",
                     function, resources ? resources : "(null)");
        free(folder);
        return -1;
    }
    int result = slave_create(&instance->slave, folder, token, visible);
    free(folder);
    return result;
}

void instance_free(Instance *instance) {
    if (!instance || instance->magic != INSTANCE_MAGIC) return;
    slave_free(&instance->slave);
    instance->magic = 0;
    free(instance->name);
    free(instance);
}

int instance_status(Instance *instance, int status) {
    if (status >= STATUS_ERROR) instance->state = instance->standard->after_error;
    return status;
}

static const char *interface_name(int model_exchange) {
    return model_exchange ? "model exchange" : "co-simulation";
}

int instance_refused(Instance *instance, Function function) {
    if (!instance || instance->magic != INSTANCE_MAGIC) return 1;
    instance->function = function;
    Interface interface = FUNCTIONS[function].interface;
    int wrong_interface = interface == (instance->model_exchange ? CS : ME);
    if (!wrong_interface && instance->state & FUNCTIONS[function].states) return 0;
    if (wrong_interface) {
        instance_log(instance, STATUS_ERROR, "%s is a function of %s; this instance was instantiated for %s",
                     FUNCTIONS[function].name, interface_name(!instance->model_exchange),
                     interface_name(instance->model_exchange));
    } else {
        instance_log(instance, STATUS_ERROR, "%s is not allowed in state %s", FUNCTIONS[function].name,
                     state_name(instance->state));
    }
    instance_status(instance, STATUS_ERROR);
    return 1;
}

static int settle(Instance *instance, int status, int next) {
    if (status == STATUS_OK) instance->state = (ModelState)next;
    return status;
}

int instance_call(Instance *instance, const char *method, int n, const double *values, const int *defined, int next) {
    return settle(instance, slave_call(&instance->slave, method, n, values, defined), next);
}

int instance_terminate(Instance *instance) {
    if (!pyhost_alive()) { /* the host's CPython finalizes or has: nothing to run */
        instance->state = Terminated;
        return STATUS_OK;
    }
    return instance_call(instance, "terminate", 0, NULL, NULL, Terminated);
}

int instance_reset(Instance *instance) {
    return settle(instance, slave_reset(&instance->slave), Instantiated);
}

int instance_exit_initialization(Instance *instance) {
    if (!instance->model_exchange) return instance_call(instance, "exit_initialization_mode", 0, NULL, NULL, StepMode);
    int status = slave_call(&instance->slave, "exit_initialization_mode", 0, NULL, NULL);
    if (status == STATUS_OK) status = slave_call(&instance->slave, "start_continuous_time", 0, NULL, NULL);
    return settle(instance, status, EventMode);
}

int instance_do_step(Instance *instance, double time, double step) {
    if (!isfinite(time) || !isfinite(step) || !(step > 0)) {
        return instance_fail(instance, STATUS_ERROR, "current time %g, step size %g; allowed: a finite time and a "
                             "finite step size > 0", time, step);
    }
    if (time + step > instance->stop_time + 1e-9 * fmax(1.0, fabs(instance->stop_time))) {
        return instance_fail(instance, STATUS_ERROR, "the step from t = %.17g s by %g s ends after the stop time "
                             "%.17g s of the experiment", time, step, instance->stop_time);
    }
    int accepted = 0;
    int status = slave_step(&instance->slave, time, step, &accepted);
    if (status == STATUS_OK && !accepted) status = STATUS_DISCARD; /* the slave logged why */
    if (status == STATUS_DISCARD) instance->state = instance->standard->after_discard;
    return status;
}

int instance_set_logging(Instance *instance, int logging_on, size_t n, const char *const categories[]) {
    if (n > 0 && !categories) return instance_fail(instance, STATUS_ERROR, "%zu categories but no array", n);
    int chosen = n ? 0 : ALL_CATEGORIES;
    for (size_t i = 0; i < n; i++) {
        int bit = category_bit(categories[i]);
        if (bit < 0) {
            char allowed[256] = "";
            for (int k = 0, used = 0; k < CATEGORY_COUNT && used < (int)sizeof allowed; k++) {
                used += snprintf(allowed + used, sizeof allowed - used, "%s%s", k ? ", " : "", CATEGORIES[k]);
            }
            return instance_fail(instance, STATUS_ERROR, "unknown log category %s; allowed: %s",
                                 categories[i] ? categories[i] : "(null)", allowed);
        }
        chosen |= bit;
    }
    instance->categories = logging_on ? instance->categories | chosen : instance->categories & ~chosen;
    return STATUS_OK;
}

/* --- values ------------------------------------------------------------------------------------------- */

static int arrays_given(Instance *instance, size_t nvr, const void *vr, const void *values, size_t nvalues) {
    if (nvr == 0) return 1;
    if (!vr || !values) {
        instance_fail(instance, STATUS_ERROR, "%zu value references but no %s array", nvr,
                      vr ? "value" : "value reference");
        return 0;
    }
    if (nvalues != nvr) {
        instance_fail(instance, STATUS_ERROR, "%zu value references but %zu values (every variable is a scalar)", nvr,
                      nvalues);
        return 0;
    }
    return 1;
}

/* Whether `vr` is a continuous state that a set by value reference changes now: in model exchange's event
   and continuous-time mode, as fmiSetContinuousStates would (FMI 3.0.2, sections 2.3.5 and 3.2.1, for
   states with reinit = false, which all these are; FMI 2.0 leaves it open, fmi-standard #392, and importers
   such as PyFMI rely on it). */
static int settable_state(const Instance *instance, unsigned int vr) {
    return instance->model_exchange && (instance->state & (EventMode | ContinuousTimeMode)) &&
           instance->slave.is_state[vr];
}

/* Why the variable `vr` may not be set now, or NULL. */
static const char *not_settable(const Instance *instance, unsigned int vr) {
    const Slave *s = &instance->slave;
    if (settable_state(instance, vr)) return NULL;
    if (s->causality[vr] == CAUSALITY_OUTPUT) return "is an output: it cannot be set";
    if (s->causality[vr] != CAUSALITY_PARAMETER && s->causality[vr] != CAUSALITY_INPUT) return "cannot be set";
    if (s->variability[vr] == VARIABILITY_CONSTANT) return "is a constant: it cannot be set";
    if (s->causality[vr] == CAUSALITY_PARAMETER && instance->state == ContinuousTimeMode) {
        return "is a parameter: in continuous-time mode only inputs and continuous states can be set (tunable "
               "parameters in event mode)";
    }
    if ((instance->state == StepMode || instance->state == EventMode) && s->causality[vr] == CAUSALITY_PARAMETER &&
        s->variability[vr] != VARIABILITY_TUNABLE) {
        return "is a fixed parameter: it can be set only before initialization mode ends";
    }
    return NULL;
}

/* Whether every `vr` is a variable of `type` (named `type_name`) that may be set now if `setting`; logs the
   first that is not. */
static int check(Instance *instance, int type, const char *type_name, const unsigned int vr[], size_t nvr,
                 int setting) {
    for (size_t i = 0; i < nvr; i++) {
        int actual = slave_type_of(&instance->slave, vr[i]);
        const char *wrong = NULL;
        if (actual == NO_VARIABLE || actual > TYPES) wrong = "is not a variable of this FMU";
        else if (actual != type) {
            instance_fail(instance, STATUS_ERROR, "value reference %u is a %s variable, not %s", vr[i], TYPE_NAMES[actual],
                          type_name);
            return -1;
        } else if (setting) wrong = not_settable(instance, vr[i]);
        if (wrong) {
            instance_fail(instance, STATUS_ERROR, "value reference %u %s", vr[i], wrong);
            return -1;
        }
    }
    return 0;
}

int instance_get(Instance *instance, int type, const unsigned int vr[], size_t nvr, void *values, size_t nvalues,
                 CType ctype) {
    if (!arrays_given(instance, nvr, vr, values, nvalues) || check(instance, type, TYPE_NAMES[type], vr, nvr, 0)) {
        return STATUS_ERROR;
    }
    return nvr ? slave_get(&instance->slave, type, vr, nvr, values, ctype) : STATUS_OK;
}

/* Whether every continuous state among `vr` (checked, Real) is given a finite value; if not, logged with
   fmiDiscard as fmiSetContinuousStates refuses such a state. */
static int states_finite(Instance *instance, const unsigned int vr[], size_t nvr, const double values[]) {
    for (size_t i = 0; i < nvr; i++) {
        if (settable_state(instance, vr[i]) && !isfinite(values[i])) {
            instance_fail(instance, STATUS_DISCARD, "value reference %u, a continuous state, is %g; allowed: finite; "
                          "nothing of the call is set", vr[i], values[i]);
            return 0;
        }
    }
    return 1;
}

int instance_set(Instance *instance, int type, const unsigned int vr[], size_t nvr, const void *values,
                 size_t nvalues, CType ctype) {
    if (!arrays_given(instance, nvr, vr, values, nvalues) || check(instance, type, TYPE_NAMES[type], vr, nvr, 1)) {
        return STATUS_ERROR;
    }
    if (type == TYPE_REAL && ctype == C_DOUBLE && !states_finite(instance, vr, nvr, values)) return STATUS_DISCARD;
    return nvr ? slave_set(&instance->slave, type, vr, nvr, values, ctype) : STATUS_OK;
}

int instance_set_input_derivatives(Instance *instance, const unsigned int vr[], size_t nvr, const int order[],
                                   const double value[]) {
    if (nvr == 0) return STATUS_OK;
    if (!vr || !order || !value) {
        return instance_fail(instance, STATUS_ERROR, "%zu value references but no %s array", nvr,
                             !vr ? "value reference" : !order ? "order" : "value");
    }
    for (size_t i = 0; i < nvr; i++) {
        if (slave_type_of(&instance->slave, vr[i]) != TYPE_REAL || instance->slave.causality[vr[i]] != CAUSALITY_INPUT) {
            return instance_fail(instance, STATUS_ERROR, "value reference %u is not a Real input; allowed: the value "
                                 "references of Real inputs", vr[i]);
        }
    }
    return slave_set_input_derivatives(&instance->slave, vr, nvr, order, value);
}

/* --- partial derivatives ------------------------------------------------------------------------------- */

/* Whether the array named `what`, `n` long, is given where n > 0 (if not, logged). */
static int partials_array(Instance *instance, const void *array, size_t n, const char *what) {
    if (n == 0 || array) return 1;
    instance_fail(instance, STATUS_ERROR, "%zu %s but no array of them (NULL)", n, what);
    return 0;
}

/* Whether the length `n` of the argument `name` equals `count`, that of `counted` (if not, logged). */
static int partials_length(Instance *instance, const char *name, size_t n, const char *counted, size_t count) {
    if (n == count) return 1;
    instance_fail(instance, STATUS_ERROR, "%s is %zu but %s is %zu; allowed: %s = %s (every variable is a scalar)",
                  name, n, counted, count, name, counted);
    return 0;
}

int instance_partials(Instance *instance, const Partials *p, int adjoint) {
    const char *seeded = adjoint ? "nUnknowns" : "nKnowns", *sensed = adjoint ? "nKnowns" : "nUnknowns";
    size_t seeds = adjoint ? p->n_unknowns : p->n_knowns, sensitivities = adjoint ? p->n_knowns : p->n_unknowns;
    if (!partials_length(instance, "nSeed", p->n_seed, seeded, seeds) ||
        !partials_length(instance, "nSensitivity", p->n_sensitivity, sensed, sensitivities) ||
        !partials_array(instance, p->unknowns, p->n_unknowns, "unknowns") ||
        !partials_array(instance, p->knowns, p->n_knowns, "knowns") ||
        !partials_array(instance, p->seed, p->n_seed, "seed values") ||
        !partials_array(instance, p->sensitivity, p->n_sensitivity, "sensitivity values") ||
        check(instance, TYPE_REAL, TYPE_NAMES[TYPE_REAL], p->unknowns, p->n_unknowns, 0) ||
        check(instance, TYPE_REAL, TYPE_NAMES[TYPE_REAL], p->knowns, p->n_knowns, 0)) {
        return STATUS_ERROR;
    }
    if (p->n_unknowns == 0 && p->n_knowns == 0) return STATUS_OK;
    return slave_partials(&instance->slave, p, adjoint, instance->model_exchange);
}

/* --- model exchange --------------------------------------------------------------------------------------- */

int instance_set_time(Instance *instance, double time) {
    if (!isfinite(time)) return instance_fail(instance, STATUS_ERROR, "time %g; allowed: a finite time", time);
    return slave_set_time(&instance->slave, time);
}

/* Whether `values` is given with `n` entries, the length of the vector (if not, logged). */
static int vector_given(Instance *instance, const void *values, size_t n, size_t length) {
    if (n != length) {
        instance_fail(instance, STATUS_ERROR, "%zu values; allowed: %zu, this model's number", n, length);
        return 0;
    }
    return n == 0 || instance_given(instance, values, "array");
}

/* The index of the first value of `values` that is not finite, or -1. */
static long first_not_finite(const double values[], size_t n) {
    for (size_t i = 0; i < n; i++) {
        if (!isfinite(values[i])) return (long)i;
    }
    return -1;
}

int instance_set_states(Instance *instance, const double x[], size_t nx) {
    if (!vector_given(instance, x, nx, instance->slave.nx)) return STATUS_ERROR;
    long bad = first_not_finite(x, nx);
    if (bad >= 0) {
        return instance_fail(instance, STATUS_DISCARD, "state %ld is %g; allowed: finite; the states are refused", bad,
                             x[bad]);
    }
    return nx ? slave_set_states(&instance->slave, x, nx) : STATUS_OK;
}

int instance_get_vector(Instance *instance, Vector which, double values[], size_t n) {
    size_t length = which == VECTOR_INDICATORS ? instance->slave.nz : instance->slave.nx;
    if (!vector_given(instance, values, n, length)) return STATUS_ERROR;
    if (n == 0) return STATUS_OK;
    int model = which == VECTOR_DERIVATIVES || which == VECTOR_INDICATORS;
    int status = slave_get_vector(&instance->slave, which, values, n, model ? STATUS_DISCARD : STATUS_ERROR);
    long bad = status == STATUS_OK && model ? first_not_finite(values, n) : -1;
    if (bad >= 0) {
        status = instance_fail(instance, STATUS_DISCARD, "value %ld is %g; the model is not defined at this time, "
                               "state and inputs", bad, values[bad]);
    }
    return status;
}

int instance_update_discrete_states(Instance *instance, int *changed) {
    return slave_update_discrete_states(&instance->slave, changed);
}

int instance_enter(Instance *instance, ModelState next) {
    instance->state = next;
    return STATUS_OK;
}

int instance_count(Instance *instance, size_t *count, size_t value) {
    if (!instance_given(instance, count, "place for the number")) return STATUS_ERROR;
    *count = value;
    return STATUS_OK;
}

int instance_no_variables_of(Instance *instance, const char *type_name, const unsigned int vr[], size_t nvr) {
    if (nvr && !vr) return instance_fail(instance, STATUS_ERROR, "%zu value references but no array", nvr);
    return check(instance, TYPES + 1, type_name, vr, nvr, 0) ? STATUS_ERROR : STATUS_OK;
}

int instance_unsupported(Instance *instance, const char *why) {
    return instance_log(instance, STATUS_ERROR, "%s is not supported: %s", FUNCTIONS[instance->function].name, why);
}

/* --- FMU states ------------------------------------------------------------------------------------------- */

static State *valid_state(Instance *instance, void *pointer) {
    State *state = pointer;
    if (state && state->magic == STATE_MAGIC) return state;
    instance_fail(instance, STATUS_ERROR, "not an FMU state that this FMU returned (or one already freed)");
    return NULL;
}

int instance_get_state(Instance *instance, void **pointer) {
    if (!instance_given(instance, pointer, "place for the FMU state")) return STATUS_ERROR;
    State *state = *pointer ? valid_state(instance, *pointer) : calloc(1, sizeof(State));
    if (!state) return STATUS_ERROR;
    PyObject *object = NULL;
    if (slave_get_state(&instance->slave, &object) != STATUS_OK) {
        if (!*pointer) free(state);
        return STATUS_ERROR;
    }
    slave_release(state->object);
    free(state->bytes);
    state->magic = STATE_MAGIC;
    state->object = object;
    state->state = instance->state;
    state->bytes = NULL;
    state->size = 0;
    *pointer = state;
    return STATUS_OK;
}

int instance_set_state(Instance *instance, void *pointer) {
    State *state = valid_state(instance, pointer);
    if (!state) return STATUS_ERROR;
    if (state->state & (instance->model_exchange ? (StepMode | StepFailed) : (EventMode | ContinuousTimeMode))) {
        return instance_fail(instance, STATUS_ERROR, "the FMU state is one of %s, in state %s; this instance is for %s",
                             interface_name(!instance->model_exchange), state_name(state->state),
                             interface_name(instance->model_exchange));
    }
    int status = slave_set_state(&instance->slave, state->object);
    if (status == STATUS_OK) instance->state = state->state;
    return status;
}

int instance_free_state(Instance *instance, void **pointer) {
    if (!pointer || !*pointer) return STATUS_OK;
    State *state = valid_state(instance, *pointer);
    if (!state) return STATUS_ERROR;
    slave_release(state->object);
    free(state->bytes);
    state->magic = 0;
    free(state);
    *pointer = NULL;
    return STATUS_OK;
}

/* Serialize `state` into its `bytes`, once (fmiSerializedFMUstateSize, then fmiSerializeFMUstate of the same
   state, run Python once; the state object does not change until it is freed or taken anew): one byte
   with the instance's state, then native_bridge.state_to_bytes. 0, or -1 after logging why. */
static int serialize(Instance *instance, State *state) {
    if (state->bytes) return 0;
    char *body = NULL;
    size_t length = 0;
    if (slave_serialize(&instance->slave, state->object, &body, &length) != STATUS_OK) return -1;
    state->bytes = malloc(length + 1);
    if (state->bytes) {
        state->bytes[0] = (char)state->state;
        memcpy(state->bytes + 1, body, length);
        state->size = length + 1;
    } else {
        instance_fail(instance, STATUS_ERROR, "out of memory for the serialized FMU state");
    }
    free(body);
    return state->bytes ? 0 : -1;
}

int instance_given(Instance *instance, const void *pointer, const char *what) {
    if (!pointer) instance_fail(instance, STATUS_ERROR, "no %s (NULL)", what);
    return pointer != NULL;
}

int instance_serialized_size(Instance *instance, void *pointer, size_t *size) {
    State *state = valid_state(instance, pointer);
    if (!state || !instance_given(instance, size, "place for the size") || serialize(instance, state) != 0) {
        return STATUS_ERROR;
    }
    *size = state->size;
    return STATUS_OK;
}

int instance_serialize(Instance *instance, void *pointer, char *buffer, size_t size) {
    State *state = valid_state(instance, pointer);
    if (!state || !instance_given(instance, buffer, "buffer") || serialize(instance, state) != 0) {
        return STATUS_ERROR;
    }
    if (size < state->size) {
        return instance_fail(instance, STATUS_ERROR, "the buffer holds %zu bytes, the state needs %zu", size,
                             state->size);
    }
    memcpy(buffer, state->bytes, state->size);
    return STATUS_OK;
}

int instance_deserialize(Instance *instance, const char *buffer, size_t size, void **pointer) {
    int saved = buffer && size > 0 ? (unsigned char)buffer[0] : 0;
    if (!pointer || saved == 0 || (saved & ~ANY_STATE) || (saved & (saved - 1))) {
        return instance_fail(instance, STATUS_ERROR, "not a serialized FMU state of dsc-fmu (or no place for it)");
    }
    PyObject *object = NULL;
    if (slave_deserialize(&instance->slave, buffer + 1, size - 1, &object) != STATUS_OK) return STATUS_ERROR;
    State *state = calloc(1, sizeof *state);
    if (!state) {
        slave_release(object);
        return STATUS_ERROR;
    }
    state->magic = STATE_MAGIC;
    state->object = object;
    state->state = (ModelState)saved;
    *pointer = state;
    return STATUS_OK;
}
