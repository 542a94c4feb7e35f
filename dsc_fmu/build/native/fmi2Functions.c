/* The FMI 2.0 co-simulation API of every dsc-fmu FMU: each call guarded by the states the standard
   allows it in, then handed to instance.c. Nothing returns fmi2Fatal. */

#include <stdio.h>

#include "fmi2Functions.h"
#include "instance.h"

#define MASK_Setup Instantiated
#define MASK_Get (InitializationMode | StepMode | Terminated | Error)
#define MASK_Set (Instantiated | InitializationMode | StepMode)
#define MASK_Status (StepMode | Terminated)

typedef struct {
    Instance base;
    fmi2CallbackFunctions functions;
} Fmi2Instance;

static const MethodNames METHODS = {
    {"get_real", "get_integer", "get_boolean"},
    {"set_real", "set_integer", "set_boolean"},
    {"Real", "Integer", "Boolean", "String"},
};

#define BEGIN(function, mask)                                                                                        \
    Instance *instance = (Instance *)c;                                                                              \
    if (instance_refused(instance, function, mask)) return fmi2Error

/* The logger takes a printf format: the message goes as a format with every '%' doubled and no
   arguments, so loggers that format and loggers that do not both show the text. */
static void host_log(Instance *instance, int status, const char *category, const char *message) {
    const fmi2CallbackFunctions *functions = &((Fmi2Instance *)instance)->functions;
    if (!functions->logger) return;
    char text[4096];
    size_t k = 0;
    for (const char *p = message; *p && k + 2 < sizeof text; p++) {
        if (*p == '%') text[k++] = '%';
        text[k++] = *p;
    }
    text[k] = '\0';
    functions->logger(functions->componentEnvironment, instance->name, (fmi2Status)status, category, text);
}

/* --- inquiry, logging, creation ------------------------------------------------------------------------ */

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories, const fmi2String categories[]) {
    BEGIN("fmi2SetDebugLogging", ANY_STATE);
    return (fmi2Status)instance_set_logging(instance, "fmi2SetDebugLogging", loggingOn, nCategories, categories);
}

/* `why` holds no '%'. */
static fmi2Component refuse_instantiation(const fmi2CallbackFunctions *functions, fmi2String name, const char *why) {
    if (functions && functions->logger) {
        functions->logger(functions->componentEnvironment, name ? name : "", fmi2Error, "logStatusError", why);
    }
    return NULL;
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn) {
    if (!instanceName || !*instanceName) {
        return refuse_instantiation(functions, instanceName, "fmi2Instantiate: the instance name is missing or empty");
    }
    if (fmuType != fmi2CoSimulation) {
        return refuse_instantiation(functions, instanceName, "fmi2Instantiate: only fmi2CoSimulation is supported");
    }
    Fmi2Instance *instance = (Fmi2Instance *)instance_alloc(sizeof(Fmi2Instance), instanceName, loggingOn, host_log);
    if (!instance) return refuse_instantiation(functions, instanceName, "fmi2Instantiate: out of memory");
    if (functions) instance->functions = *functions;
    if (instance_start(&instance->base, "fmi2Instantiate", fmuResourceLocation, fmuGUID, visible, &METHODS) != 0) {
        instance_free(&instance->base);
        return NULL;
    }
    return instance;
}

void fmi2FreeInstance(fmi2Component c) { instance_free((Instance *)c); }

/* --- initialisation, stepping, termination --------------------------------------------------------------- */

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    BEGIN("fmi2SetupExperiment", MASK_Setup);
    double values[] = {startTime, stopTime, tolerance};
    int defined[] = {1, stopTimeDefined, toleranceDefined};
    return (fmi2Status)instance_call(instance, "setup_experiment", 3, values, defined, Instantiated);
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    BEGIN("fmi2EnterInitializationMode", Instantiated);
    return (fmi2Status)instance_call(instance, "enter_initialization_mode", 0, NULL, NULL, InitializationMode);
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    BEGIN("fmi2ExitInitializationMode", InitializationMode);
    return (fmi2Status)instance_call(instance, "exit_initialization_mode", 0, NULL, NULL, StepMode);
}

fmi2Status fmi2Terminate(fmi2Component c) {
    BEGIN("fmi2Terminate", StepMode);
    return (fmi2Status)instance_call(instance, "terminate", 0, NULL, NULL, Terminated);
}

fmi2Status fmi2Reset(fmi2Component c) {
    BEGIN("fmi2Reset", ANY_STATE);
    return (fmi2Status)instance_reset(instance);
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    BEGIN("fmi2DoStep", StepMode);
    return (fmi2Status)instance_do_step(instance, "fmi2DoStep", currentCommunicationPoint, communicationStepSize);
}

fmi2Status fmi2CancelStep(fmi2Component c) {
    return (fmi2Status)instance_unsupported((Instance *)c, "fmi2CancelStep", "fmi2DoStep returns when the step is done");
}

/* --- values ------------------------------------------------------------------------------------------- */

#define GETTER(function, type, ctype, cvalue)                                                                          \
    fmi2Status function(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, cvalue value[]) {                \
        BEGIN(#function, MASK_Get);                                                                                  \
        return (fmi2Status)instance_get(instance, #function, type, vr, nvr, value, nvr, ctype);                      \
    }

#define SETTER(function, type, ctype, cvalue)                                                                          \
    fmi2Status function(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const cvalue value[]) {          \
        BEGIN(#function, MASK_Set);                                                                                  \
        return (fmi2Status)instance_set(instance, #function, type, vr, nvr, value, nvr, ctype);                      \
    }

GETTER(fmi2GetReal, TYPE_REAL, C_DOUBLE, fmi2Real)
GETTER(fmi2GetInteger, TYPE_INTEGER, C_INT, fmi2Integer)
GETTER(fmi2GetBoolean, TYPE_BOOLEAN, C_BOOL_INT, fmi2Boolean)
GETTER(fmi2GetString, TYPE_STRING, C_DOUBLE, fmi2String)
SETTER(fmi2SetReal, TYPE_REAL, C_DOUBLE, fmi2Real)
SETTER(fmi2SetInteger, TYPE_INTEGER, C_INT, fmi2Integer)
SETTER(fmi2SetBoolean, TYPE_BOOLEAN, C_BOOL_INT, fmi2Boolean)
SETTER(fmi2SetString, TYPE_STRING, C_DOUBLE, fmi2String)

/* --- what these FMUs do not offer ------------------------------------------------------------------------- */

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[], size_t nUnknown,
                                        const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[]) {
    return (fmi2Status)instance_unsupported((Instance *)c, "fmi2GetDirectionalDerivative",
                                            "providesDirectionalDerivative is false");
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    return (fmi2Status)instance_set_input_derivatives((Instance *)c, "fmi2SetRealInputDerivatives", vr, nvr, order,
                                                      value);
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    return (fmi2Status)instance_unsupported((Instance *)c, "fmi2GetRealOutputDerivatives",
                                            "maxOutputDerivativeOrder is 0");
}

/* --- status: fmi2DoStep never returns fmi2Pending ------------------------------------------------------ */

static fmi2Status no_status(fmi2Component c, const char *function) {
    BEGIN(function, MASK_Status);
    instance_log(instance, STATUS_DISCARD, "%s: %s: this status is not available (fmi2DoStep never returns "
                 "fmi2Pending)", instance->name, function);
    return fmi2Discard;
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    return no_status(c, "fmi2GetStatus");
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    return no_status(c, "fmi2GetIntegerStatus");
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
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

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    BEGIN("fmi2GetFMUstate", ANY_STATE);
    return (fmi2Status)instance_get_state(instance, "fmi2GetFMUstate", FMUstate);
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    BEGIN("fmi2SetFMUstate", ANY_STATE);
    return (fmi2Status)instance_set_state(instance, "fmi2SetFMUstate", FMUstate);
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    BEGIN("fmi2FreeFMUstate", ANY_STATE);
    return (fmi2Status)instance_free_state(instance, "fmi2FreeFMUstate", FMUstate);
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    BEGIN("fmi2SerializedFMUstateSize", ANY_STATE);
    return (fmi2Status)instance_serialized_size(instance, "fmi2SerializedFMUstateSize", FMUstate, size);
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[], size_t size) {
    BEGIN("fmi2SerializeFMUstate", ANY_STATE);
    return (fmi2Status)instance_serialize(instance, "fmi2SerializeFMUstate", FMUstate, serializedState, size);
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate) {
    BEGIN("fmi2DeSerializeFMUstate", ANY_STATE);
    return (fmi2Status)instance_deserialize(instance, "fmi2DeSerializeFMUstate", serializedState, size, FMUstate);
}
