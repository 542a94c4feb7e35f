/* The FMI 2.0 API of every dsc-fmu FMU, co-simulation and model exchange: each call guarded by the
   interface and the states the standard's state tables (FMI 2.0.4, sections 3.2.3 and 4.2.4) allow it
   in, then handed to instance.c; every fmi2Error moves the instance to the error state. Nothing
   returns fmi2Fatal. */

#include <math.h>

#include "fmi2Functions.h"
#include "instance.h"

/* The interface and states each function is allowed in (no stepInProgress, stepCanceled: fmi2DoStep is
   synchronous). */
#define MASK_fmi2SetDebugLogging ANY_STATE
#define MASK_fmi2SetupExperiment Instantiated
#define MASK_fmi2EnterInitializationMode Instantiated
#define MASK_fmi2ExitInitializationMode InitializationMode
#define MASK_fmi2Terminate (StepMode | StepFailed | EventMode | ContinuousTimeMode)
#define MASK_fmi2Reset ANY_STATE
#define MASK_fmi2DoStep (CS_ONLY | StepMode)
#define MASK_fmi2CancelStep CS_ONLY
#define MASK_GET (InitializationMode | StepMode | StepFailed | EventMode | ContinuousTimeMode | Terminated | Error)
#define MASK_SET (Instantiated | InitializationMode | StepMode | EventMode)
#define MASK_fmi2GetReal MASK_GET
#define MASK_fmi2GetInteger MASK_GET
#define MASK_fmi2GetBoolean MASK_GET
#define MASK_fmi2GetString MASK_GET
#define MASK_fmi2SetReal (MASK_SET | ContinuousTimeMode)
#define MASK_fmi2SetInteger MASK_SET
#define MASK_fmi2SetBoolean MASK_SET
#define MASK_fmi2SetString MASK_SET
#define MASK_fmi2GetDirectionalDerivative MASK_GET
#define MASK_fmi2SetRealInputDerivatives (CS_ONLY | Instantiated | InitializationMode | StepMode)
#define MASK_fmi2GetRealOutputDerivatives (CS_ONLY | StepMode | StepFailed | Terminated | Error)
#define MASK_STATUS (CS_ONLY | StepMode | StepFailed | Terminated)
#define MASK_fmi2GetStatus MASK_STATUS
#define MASK_fmi2GetRealStatus MASK_STATUS
#define MASK_fmi2GetIntegerStatus MASK_STATUS
#define MASK_fmi2GetBooleanStatus MASK_STATUS
#define MASK_fmi2GetStringStatus MASK_STATUS
#define MASK_fmi2GetFMUstate ANY_STATE
#define MASK_fmi2SetFMUstate ANY_STATE
#define MASK_fmi2FreeFMUstate ANY_STATE
#define MASK_fmi2SerializedFMUstateSize ANY_STATE
#define MASK_fmi2SerializeFMUstate ANY_STATE
#define MASK_fmi2DeSerializeFMUstate ANY_STATE
#define MASK_fmi2EnterEventMode (ME_ONLY | EventMode | ContinuousTimeMode)
#define MASK_fmi2NewDiscreteStates (ME_ONLY | EventMode)
#define MASK_fmi2EnterContinuousTimeMode (ME_ONLY | EventMode)
#define MASK_fmi2CompletedIntegratorStep (ME_ONLY | ContinuousTimeMode)
#define MASK_fmi2SetTime (ME_ONLY | EventMode | ContinuousTimeMode)
#define MASK_fmi2SetContinuousStates (ME_ONLY | ContinuousTimeMode)
#define MASK_ME_GET (ME_ONLY | InitializationMode | EventMode | ContinuousTimeMode | Terminated | Error)
#define MASK_fmi2GetDerivatives MASK_ME_GET
#define MASK_fmi2GetEventIndicators MASK_ME_GET
#define MASK_fmi2GetContinuousStates MASK_ME_GET
#define MASK_fmi2GetNominalsOfContinuousStates (MASK_ME_GET | Instantiated)

typedef struct {
    Instance base;
    fmi2CallbackFunctions functions;
} Fmi2Instance;

/* The function's name and mask from one token; a refused call returns fmi2Error. */
#define BEGIN(F)                                                                                                     \
    Instance *instance = (Instance *)c;                                                                              \
    if (instance_refused(instance, #F, MASK_##F)) return fmi2Error

/* The call's status; fmi2Error moves the instance to the error state. */
#define END(call) return (fmi2Status)instance_status(instance, (call))

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

/* Warnings, errors and fatal errors are shown whatever the debug logging (section 2.1.3); OK and
   discard messages only in the categories enabled. */
static const Standard FMI2 = {
    {{"get_real", "get_integer", "get_boolean"}, {"set_real", "set_integer", "set_boolean"},
     {"Real", "Integer", "Boolean", "String"}},
    Error, StepFailed, 1 << STATUS_WARNING | 1 << STATUS_ERROR | 1 << STATUS_FATAL, host_log,
};

/* --- inquiry, logging, creation ------------------------------------------------------------------------ */

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories, const fmi2String categories[]) {
    BEGIN(fmi2SetDebugLogging);
    END(instance_set_logging(instance, "fmi2SetDebugLogging", loggingOn, nCategories, categories));
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
    if (fmuType != fmi2CoSimulation && fmuType != fmi2ModelExchange) {
        return refuse_instantiation(functions, instanceName, "fmi2Instantiate: the FMU type is neither fmi2ModelExchange "
                                    "nor fmi2CoSimulation");
    }
    Fmi2Instance *instance = (Fmi2Instance *)instance_alloc(sizeof(Fmi2Instance), instanceName, loggingOn,
                                                            fmuType == fmi2ModelExchange, &FMI2);
    if (!instance) return refuse_instantiation(functions, instanceName, "fmi2Instantiate: out of memory");
    if (functions) instance->functions = *functions;
    if (instance_start(&instance->base, "fmi2Instantiate", fmuResourceLocation, fmuGUID, visible) != 0) {
        instance_free(&instance->base);
        return NULL;
    }
    return instance;
}

void fmi2FreeInstance(fmi2Component c) { instance_free((Instance *)c); }

/* --- initialisation, stepping, termination --------------------------------------------------------------- */

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    BEGIN(fmi2SetupExperiment);
    instance->stop_time = stopTimeDefined ? stopTime : INFINITY;
    double values[] = {startTime, stopTime, tolerance};
    int defined[] = {1, stopTimeDefined, toleranceDefined};
    END(instance_call(instance, "setup_experiment", 3, values, defined, Instantiated));
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    BEGIN(fmi2EnterInitializationMode);
    END(instance_call(instance, "enter_initialization_mode", 0, NULL, NULL, InitializationMode));
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    BEGIN(fmi2ExitInitializationMode);
    END(instance_exit_initialization(instance));
}

fmi2Status fmi2Terminate(fmi2Component c) {
    BEGIN(fmi2Terminate);
    END(instance_call(instance, "terminate", 0, NULL, NULL, Terminated));
}

fmi2Status fmi2Reset(fmi2Component c) {
    BEGIN(fmi2Reset);
    END(instance_reset(instance));
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    BEGIN(fmi2DoStep);
    END(instance_do_step(instance, "fmi2DoStep", currentCommunicationPoint, communicationStepSize));
}

/* Allowed only while a step is pending, which never happens: fmi2DoStep returns when the step is done. */
fmi2Status fmi2CancelStep(fmi2Component c) {
    instance_refused((Instance *)c, "fmi2CancelStep", MASK_fmi2CancelStep);
    return fmi2Error;
}

/* --- model exchange ------------------------------------------------------------------------------------ */

MODEL_EXCHANGE_FUNCTIONS(fmi2Status, fmi2Component, fmi2Boolean, fmi2Real, fmi2EnterEventMode,
                         fmi2EnterContinuousTimeMode, fmi2CompletedIntegratorStep, fmi2SetTime, fmi2SetContinuousStates,
                         fmi2GetDerivatives, fmi2GetEventIndicators, fmi2GetContinuousStates,
                         fmi2GetNominalsOfContinuousStates)

fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *eventInfo) {
    BEGIN(fmi2NewDiscreteStates);
    if (!instance_given(instance, "fmi2NewDiscreteStates", eventInfo, "event info")) END(STATUS_ERROR);
    int status = instance_update_discrete_states(instance);
    eventInfo->newDiscreteStatesNeeded = fmi2False;
    eventInfo->terminateSimulation = fmi2False;
    eventInfo->nominalsOfContinuousStatesChanged = fmi2False;
    eventInfo->valuesOfContinuousStatesChanged = fmi2False;
    eventInfo->nextEventTimeDefined = fmi2False;
    eventInfo->nextEventTime = 0.0;
    END(status);
}

/* --- values ------------------------------------------------------------------------------------------- */

#define GETTER(function, type, ctype, cvalue)                                                                          \
    fmi2Status function(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, cvalue value[]) {                \
        BEGIN(function);                                                                                             \
        END(instance_get(instance, #function, type, vr, nvr, value, nvr, ctype));                                    \
    }

#define SETTER(function, type, ctype, cvalue)                                                                          \
    fmi2Status function(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const cvalue value[]) {          \
        BEGIN(function);                                                                                             \
        END(instance_set(instance, #function, type, vr, nvr, value, nvr, ctype));                                    \
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
    BEGIN(fmi2GetDirectionalDerivative);
    END(instance_unsupported(instance, "fmi2GetDirectionalDerivative", "providesDirectionalDerivative is false"));
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    BEGIN(fmi2SetRealInputDerivatives);
    END(instance_set_input_derivatives(instance, "fmi2SetRealInputDerivatives", vr, nvr, order, value));
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    BEGIN(fmi2GetRealOutputDerivatives);
    END(instance_unsupported(instance, "fmi2GetRealOutputDerivatives", "maxOutputDerivativeOrder is 0"));
}

/* --- status: fmi2DoStep never returns fmi2Pending ------------------------------------------------------ */

static fmi2Status no_status(Instance *instance, const char *function) {
    instance_log(instance, STATUS_DISCARD, "%s: %s: this status is not available (fmi2DoStep never returns "
                 "fmi2Pending)", instance->name, function);
    return fmi2Discard;
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    BEGIN(fmi2GetStatus);
    return no_status(instance, "fmi2GetStatus");
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    BEGIN(fmi2GetIntegerStatus);
    return no_status(instance, "fmi2GetIntegerStatus");
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    BEGIN(fmi2GetStringStatus);
    return no_status(instance, "fmi2GetStringStatus");
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    BEGIN(fmi2GetRealStatus);
    if (s != fmi2LastSuccessfulTime) return no_status(instance, "fmi2GetRealStatus");
    if (!instance_given(instance, "fmi2GetRealStatus", value, "place for the value")) END(STATUS_ERROR);
    END(slave_get_double(&instance->slave, "time", value));
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    BEGIN(fmi2GetBooleanStatus);
    if (s != fmi2Terminated) return no_status(instance, "fmi2GetBooleanStatus");
    if (!instance_given(instance, "fmi2GetBooleanStatus", value, "place for the value")) END(STATUS_ERROR);
    *value = fmi2False; /* these FMUs never ask to end the simulation */
    return fmi2OK;
}

/* --- FMU states ------------------------------------------------------------------------------------------- */

FMU_STATE_FUNCTIONS(fmi2Status, fmi2Component, fmi2FMUstate, fmi2Byte, fmi2GetFMUstate, fmi2SetFMUstate,
                    fmi2FreeFMUstate, fmi2SerializedFMUstateSize, fmi2SerializeFMUstate, fmi2DeSerializeFMUstate)
