/* The FMI 2.0 co-simulation API of every dsc-fmu FMU, over the Python slave in its resources.

   Every call is guarded by the states the standard allows it in, checks its arguments (value
   references, types, causality, variability, step sizes, FMU states) before Python sees them,
   and logs every failure through the importer's logger as text. A Python exception is an
   fmi2Error (fmi2Discard in fmi2DoStep) and leaves the instance usable; nothing returns fmi2Fatal. */

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "slave.h"

#define INSTANCE_MAGIC 0x44534332u /* "DSC2" */
#define STATE_MAGIC 0x53544132u

typedef enum {
    Instantiated = 1 << 0,
    InitializationMode = 1 << 1,
    StepComplete = 1 << 2,
    StepFailed = 1 << 3,
    Terminated = 1 << 4,
    Error = 1 << 5,
} ModelState;

#define ANY_STATE (Instantiated | InitializationMode | StepComplete | StepFailed | Terminated | Error)
#define MASK_Setup Instantiated
#define MASK_EnterInitializationMode Instantiated
#define MASK_ExitInitializationMode InitializationMode
#define MASK_Terminate (StepComplete | StepFailed)
#define MASK_Get (InitializationMode | StepComplete | StepFailed | Terminated | Error)
#define MASK_Set (Instantiated | InitializationMode | StepComplete)
#define MASK_DoStep StepComplete
#define MASK_Status (StepComplete | StepFailed | Terminated)

typedef struct {
    unsigned int magic;
    Slave slave;
    ModelState state;
    fmi2CallbackFunctions functions;
    char name[256];
    fmi2Boolean loggingOn;
} Instance;

typedef struct {
    unsigned int magic;
    PyObject *object;
    ModelState state;
} State;

static const MethodNames METHODS = {
    {"get_real", "get_integer", "get_boolean"},
    {"set_real", "set_integer", "set_boolean"},
};

static const char *CATEGORIES[] = {"logStatusWarning", "logStatusDiscard", "logStatusError", "logStatusFatal", "logAll"};

static const char *state_name(ModelState state) {
    switch (state) {
    case Instantiated: return "instantiated";
    case InitializationMode: return "initialization mode";
    case StepComplete: return "step complete";
    case StepFailed: return "step failed";
    case Terminated: return "terminated";
    case Error: return "error";
    }
    return "unknown";
}

static void log_message(void *context, int status, const char *category, const char *message) {
    Instance *instance = context;
    if (!instance->functions.logger) return;
    if (status < STATUS_WARNING && !instance->loggingOn) return;
    instance->functions.logger(instance->functions.componentEnvironment, instance->name, (fmi2Status)status,
                               category, "%s", message);
}

static void log_error(Instance *instance, const char *format, ...) {
    char message[1024];
    va_list args;
    va_start(args, format);
    vsnprintf(message, sizeof message, format, args);
    va_end(args);
    log_message(instance, STATUS_ERROR, "logStatusError", message);
}

/* Whether `c` may not make the call `function` now (logged); a foreign pointer is refused silently. */
static int refused(Instance *instance, const char *function, int mask) {
    if (!instance || instance->magic != INSTANCE_MAGIC) return 1;
    if (instance->state & mask) return 0;
    log_error(instance, "%s: %s is not allowed in state %s", instance->name, function, state_name(instance->state));
    return 1;
}

#define BEGIN(function, mask)                                                                                        \
    Instance *instance = (Instance *)c;                                                                              \
    if (refused(instance, function, mask)) return fmi2Error

static fmi2Status after(Instance *instance, int status, ModelState next) {
    if (status == STATUS_OK) instance->state = next;
    else if (status >= STATUS_ERROR) instance->state = Error;
    return (fmi2Status)status;
}

/* --- inquiry, logging, creation ------------------------------------------------------------------------ */

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories, const fmi2String categories[]) {
    BEGIN("fmi2SetDebugLogging", ANY_STATE);
    if (nCategories > 0 && !categories) {
        log_error(instance, "%s: fmi2SetDebugLogging: %zu categories but no array", instance->name, nCategories);
        return fmi2Error;
    }
    for (size_t i = 0; i < nCategories; i++) {
        int known = 0;
        for (size_t k = 0; categories[i] && k < sizeof CATEGORIES / sizeof CATEGORIES[0]; k++) {
            known |= strcmp(categories[i], CATEGORIES[k]) == 0;
        }
        if (!known) {
            log_error(instance, "%s: fmi2SetDebugLogging: unknown log category %s; allowed: logStatusWarning, "
                      "logStatusDiscard, logStatusError, logStatusFatal, logAll", instance->name,
                      categories[i] ? categories[i] : "(null)");
            return fmi2Error;
        }
    }
    instance->loggingOn = loggingOn;
    return fmi2OK;
}

static void early_error(const fmi2CallbackFunctions *functions, fmi2String name, const char *message) {
    if (functions && functions->logger) {
        functions->logger(functions->componentEnvironment, name ? name : "?", fmi2Error, "logStatusError", "%s", message);
    }
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn) {
    char message[4352];
    if (!instanceName || !*instanceName) {
        early_error(functions, instanceName, "fmi2Instantiate: the instance name is missing or empty");
        return NULL;
    }
    if (fmuType != fmi2CoSimulation) {
        early_error(functions, instanceName, "fmi2Instantiate: only co-simulation (fmi2CoSimulation) is supported");
        return NULL;
    }
    char resources[4096];
    if (slave_uri_to_path(fmuResourceLocation, resources, sizeof resources) != 0) {
        snprintf(message, sizeof message, "fmi2Instantiate: fmuResourceLocation %s is not a file URI of the "
                 "FMU's resources folder", fmuResourceLocation ? fmuResourceLocation : "(null)");
        early_error(functions, instanceName, message);
        return NULL;
    }
    Instance *instance = calloc(1, sizeof *instance);
    if (!instance) return NULL;
    instance->magic = INSTANCE_MAGIC;
    instance->state = Instantiated;
    instance->loggingOn = loggingOn;
    if (functions) instance->functions = *functions;
    snprintf(instance->name, sizeof instance->name, "%s", instanceName);
    if (slave_create(&instance->slave, resources, instanceName, visible, &METHODS, log_message, instance) != 0) {
        free(instance);
        return NULL;
    }
    if (!fmuGUID || strcmp(fmuGUID, instance->slave.token) != 0) {
        log_error(instance, "%s: fmi2Instantiate: GUID %s does not match this FMU's %s", instance->name,
                  fmuGUID ? fmuGUID : "(null)", instance->slave.token);
        slave_free(&instance->slave);
        free(instance);
        return NULL;
    }
    return instance;
}

void fmi2FreeInstance(fmi2Component c) {
    Instance *instance = (Instance *)c;
    if (!instance || instance->magic != INSTANCE_MAGIC) return;
    slave_free(&instance->slave);
    instance->magic = 0;
    free(instance);
}

/* --- initialisation, stepping, termination --------------------------------------------------------------- */

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    BEGIN("fmi2SetupExperiment", MASK_Setup);
    if (!isfinite(startTime) || (stopTimeDefined && !(stopTime >= startTime)) ||
        (toleranceDefined && !(tolerance > 0 && isfinite(tolerance)))) {
        log_error(instance, "%s: fmi2SetupExperiment: startTime = %g, stopTime = %g, tolerance = %g; allowed: a finite "
                  "start, a stop time not before it, a positive finite tolerance", instance->name, startTime, stopTime,
                  tolerance);
        return fmi2Error;
    }
    double values[] = {startTime, stopTime, tolerance};
    int defined[] = {1, stopTimeDefined, toleranceDefined};
    return (fmi2Status)slave_call(&instance->slave, "setup_experiment", 3, values, defined, STATUS_ERROR, NULL);
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    BEGIN("fmi2EnterInitializationMode", MASK_EnterInitializationMode);
    return after(instance, slave_call(&instance->slave, "enter_initialization_mode", 0, NULL, NULL, STATUS_ERROR, NULL),
                 InitializationMode);
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    BEGIN("fmi2ExitInitializationMode", MASK_ExitInitializationMode);
    return after(instance, slave_call(&instance->slave, "exit_initialization_mode", 0, NULL, NULL, STATUS_ERROR, NULL),
                 StepComplete);
}

fmi2Status fmi2Terminate(fmi2Component c) {
    BEGIN("fmi2Terminate", MASK_Terminate);
    return after(instance, slave_call(&instance->slave, "terminate", 0, NULL, NULL, STATUS_ERROR, NULL), Terminated);
}

fmi2Status fmi2Reset(fmi2Component c) {
    BEGIN("fmi2Reset", ANY_STATE);
    return after(instance, slave_reset(&instance->slave), Instantiated);
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    BEGIN("fmi2DoStep", MASK_DoStep);
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!isfinite(currentCommunicationPoint) || !isfinite(communicationStepSize) || !(communicationStepSize > 0)) {
        log_error(instance, "%s: fmi2DoStep: currentCommunicationPoint = %g, communicationStepSize = %g; allowed: a "
                  "finite time and a finite step size > 0", instance->name, currentCommunicationPoint,
                  communicationStepSize);
        return fmi2Error;
    }
    int accepted = 0;
    double values[] = {currentCommunicationPoint, communicationStepSize};
    int status = slave_call(&instance->slave, "do_step", 2, values, NULL, STATUS_DISCARD, &accepted);
    return status == STATUS_OK && !accepted ? fmi2Discard : (fmi2Status)status;
}

fmi2Status fmi2CancelStep(fmi2Component c) {
    BEGIN("fmi2CancelStep", ANY_STATE);
    log_error(instance, "%s: fmi2CancelStep: no step is in progress (fmi2DoStep returns when the step is done)",
              instance->name);
    return fmi2Error;
}

/* --- values ------------------------------------------------------------------------------------------- */

static int arrays_given(Instance *instance, const char *function, size_t nvr, const void *vr, const void *value) {
    if (nvr == 0 || (vr && value)) return 1;
    log_error(instance, "%s: %s: %zu value references but no %s array", instance->name, function, nvr,
              vr ? "value" : "value reference");
    return 0;
}

static fmi2Status get(fmi2Component c, const char *function, int type, const fmi2ValueReference vr[], size_t nvr,
                      void *value, CType ctype) {
    BEGIN(function, MASK_Get);
    if (!arrays_given(instance, function, nvr, vr, value)) return fmi2Error;
    for (size_t i = 0; i < nvr; i++) {
        const char *wrong = slave_check_type(&instance->slave, vr[i], type);
        if (wrong) {
            log_error(instance, "%s: %s: value reference %u %s", instance->name, function, vr[i], wrong);
            return fmi2Error;
        }
    }
    if (nvr && type == TYPE_STRING) {
        log_error(instance, "%s: %s: String variables are not supported", instance->name, function);
        return fmi2Error;
    }
    return nvr ? (fmi2Status)slave_get(&instance->slave, type, vr, nvr, value, ctype) : fmi2OK;
}

/* Why the variable `vr` may not be set now, or NULL. */
static const char *not_settable(const Instance *instance, fmi2ValueReference vr) {
    const Slave *s = &instance->slave;
    if (s->causality[vr] == CAUSALITY_OUTPUT) return "is an output: it cannot be set";
    if (s->causality[vr] != CAUSALITY_PARAMETER && s->causality[vr] != CAUSALITY_INPUT) return "cannot be set";
    if (s->variability[vr] == VARIABILITY_CONSTANT) return "is a constant: it cannot be set";
    if (instance->state == StepComplete && s->causality[vr] == CAUSALITY_PARAMETER &&
        s->variability[vr] != VARIABILITY_TUNABLE) {
        return "is a fixed parameter: it can be set only before fmi2ExitInitializationMode";
    }
    return NULL;
}

static fmi2Status set(fmi2Component c, const char *function, int type, const fmi2ValueReference vr[], size_t nvr,
                      const void *value, CType ctype) {
    BEGIN(function, MASK_Set);
    if (!arrays_given(instance, function, nvr, vr, value)) return fmi2Error;
    for (size_t i = 0; i < nvr; i++) {
        const char *wrong = slave_check_type(&instance->slave, vr[i], type);
        if (!wrong) wrong = not_settable(instance, vr[i]);
        if (wrong) {
            log_error(instance, "%s: %s: value reference %u %s", instance->name, function, vr[i], wrong);
            return fmi2Error;
        }
    }
    if (nvr && type == TYPE_STRING) {
        log_error(instance, "%s: %s: String variables are not supported", instance->name, function);
        return fmi2Error;
    }
    return nvr ? (fmi2Status)slave_set(&instance->slave, type, vr, nvr, value, ctype) : fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]) {
    return get(c, "fmi2GetReal", TYPE_REAL, vr, nvr, value, C_DOUBLE);
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[]) {
    return get(c, "fmi2GetInteger", TYPE_INTEGER, vr, nvr, value, C_INT);
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[]) {
    return get(c, "fmi2GetBoolean", TYPE_BOOLEAN, vr, nvr, value, C_BOOL_INT);
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2String value[]) {
    return get(c, "fmi2GetString", TYPE_STRING, vr, nvr, value, C_DOUBLE);
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[]) {
    return set(c, "fmi2SetReal", TYPE_REAL, vr, nvr, value, C_DOUBLE);
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Integer value[]) {
    return set(c, "fmi2SetInteger", TYPE_INTEGER, vr, nvr, value, C_INT);
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Boolean value[]) {
    return set(c, "fmi2SetBoolean", TYPE_BOOLEAN, vr, nvr, value, C_BOOL_INT);
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2String value[]) {
    return set(c, "fmi2SetString", TYPE_STRING, vr, nvr, value, C_DOUBLE);
}

/* --- what these FMUs do not offer ------------------------------------------------------------------------- */

static fmi2Status unsupported(fmi2Component c, const char *function, int mask, const char *why) {
    BEGIN(function, mask);
    log_error(instance, "%s: %s is not supported: %s", instance->name, function, why);
    return fmi2Error;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[], size_t nUnknown,
                                        const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[]) {
    (void)vUnknown_ref, (void)nUnknown, (void)vKnown_ref, (void)nKnown, (void)dvKnown, (void)dvUnknown;
    return unsupported(c, "fmi2GetDirectionalDerivative", ANY_STATE, "providesDirectionalDerivative is false");
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    (void)vr, (void)nvr, (void)order, (void)value;
    return unsupported(c, "fmi2SetRealInputDerivatives", ANY_STATE, "canInterpolateInputs is false");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    (void)vr, (void)nvr, (void)order, (void)value;
    return unsupported(c, "fmi2GetRealOutputDerivatives", ANY_STATE, "maxOutputDerivativeOrder is 0");
}

/* --- status ----------------------------------------------------------------------------------------------- */

static fmi2Status no_status(fmi2Component c, const char *function) {
    BEGIN(function, MASK_Status);
    log_message(instance, STATUS_WARNING, "logStatusDiscard", "this status is not available: fmi2DoStep never "
                "returns fmi2Pending");
    return fmi2Discard;
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    (void)s, (void)value;
    return no_status(c, "fmi2GetStatus");
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    (void)s, (void)value;
    return no_status(c, "fmi2GetIntegerStatus");
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    (void)s, (void)value;
    return no_status(c, "fmi2GetStringStatus");
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    if (s != fmi2LastSuccessfulTime || !value) return no_status(c, "fmi2GetRealStatus");
    BEGIN("fmi2GetRealStatus", MASK_Status);
    return (fmi2Status)slave_get_double(&instance->slave, "time", value);
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    if (s != fmi2Terminated || !value) return no_status(c, "fmi2GetBooleanStatus");
    BEGIN("fmi2GetBooleanStatus", MASK_Status);
    *value = fmi2False;
    return fmi2OK;
}

/* --- FMU states ------------------------------------------------------------------------------------------- */

static State *valid_state(Instance *instance, const char *function, fmi2FMUstate FMUstate) {
    State *state = (State *)FMUstate;
    if (state && state->magic == STATE_MAGIC) return state;
    log_error(instance, "%s: %s: the FMU state is not one that fmi2GetFMUstate or fmi2DeSerializeFMUstate returned",
              instance->name, function);
    return NULL;
}

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    BEGIN("fmi2GetFMUstate", ANY_STATE);
    if (!FMUstate) {
        log_error(instance, "%s: fmi2GetFMUstate: no place for the FMU state (NULL)", instance->name);
        return fmi2Error;
    }
    State *state = *FMUstate ? valid_state(instance, "fmi2GetFMUstate", *FMUstate) : calloc(1, sizeof *state);
    if (!state) return fmi2Error;
    PyObject *object = NULL;
    if (slave_get_state(&instance->slave, &object) != STATUS_OK) {
        if (!*FMUstate) free(state);
        return fmi2Error;
    }
    slave_release(state->object);
    state->magic = STATE_MAGIC;
    state->object = object;
    state->state = instance->state;
    *FMUstate = state;
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    BEGIN("fmi2SetFMUstate", ANY_STATE);
    State *state = valid_state(instance, "fmi2SetFMUstate", FMUstate);
    if (!state) return fmi2Error;
    int status = slave_set_state(&instance->slave, state->object);
    if (status == STATUS_OK) instance->state = state->state;
    return (fmi2Status)status;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    BEGIN("fmi2FreeFMUstate", ANY_STATE);
    if (!FMUstate || !*FMUstate) return fmi2OK;
    State *state = valid_state(instance, "fmi2FreeFMUstate", *FMUstate);
    if (!state) return fmi2Error;
    slave_release(state->object);
    state->magic = 0;
    free(state);
    *FMUstate = NULL;
    return fmi2OK;
}

/* Serialized: one byte with the FMI state, then native_bridge.state_to_bytes. */
static int serialize(Instance *instance, State *state, char **bytes, size_t *size) {
    char *body = NULL;
    size_t length = 0;
    if (slave_serialize(&instance->slave, state->object, &body, &length) != STATUS_OK) return -1;
    *bytes = malloc(length + 1);
    if (!*bytes) {
        free(body);
        return -1;
    }
    (*bytes)[0] = (char)state->state;
    memcpy(*bytes + 1, body, length);
    *size = length + 1;
    free(body);
    return 0;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    BEGIN("fmi2SerializedFMUstateSize", ANY_STATE);
    State *state = valid_state(instance, "fmi2SerializedFMUstateSize", FMUstate);
    char *bytes = NULL;
    if (!state || !size || serialize(instance, state, &bytes, size) != 0) return fmi2Error;
    free(bytes);
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[], size_t size) {
    BEGIN("fmi2SerializeFMUstate", ANY_STATE);
    State *state = valid_state(instance, "fmi2SerializeFMUstate", FMUstate);
    char *bytes = NULL;
    size_t needed = 0;
    if (!state || !serializedState || serialize(instance, state, &bytes, &needed) != 0) return fmi2Error;
    if (size < needed) {
        log_error(instance, "%s: fmi2SerializeFMUstate: the buffer holds %zu bytes, the state needs %zu", instance->name,
                  size, needed);
        free(bytes);
        return fmi2Error;
    }
    memcpy(serializedState, bytes, needed);
    free(bytes);
    return fmi2OK;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate) {
    BEGIN("fmi2DeSerializeFMUstate", ANY_STATE);
    if (!serializedState || !FMUstate || size < 1) {
        log_error(instance, "%s: fmi2DeSerializeFMUstate: no serialized state or no place for the FMU state",
                  instance->name);
        return fmi2Error;
    }
    int fmi_state = (unsigned char)serializedState[0];
    if (fmi_state == 0 || (fmi_state & ~ANY_STATE) || (fmi_state & (fmi_state - 1))) {
        log_error(instance, "%s: fmi2DeSerializeFMUstate: not a serialized FMU state of dsc-fmu", instance->name);
        return fmi2Error;
    }
    PyObject *object = NULL;
    if (slave_deserialize(&instance->slave, serializedState + 1, size - 1, &object) != STATUS_OK) return fmi2Error;
    State *state = calloc(1, sizeof *state);
    if (!state) {
        slave_release(object);
        return fmi2Error;
    }
    state->magic = STATE_MAGIC;
    state->object = object;
    state->state = (ModelState)fmi_state;
    *FMUstate = state;
    return fmi2OK;
}
