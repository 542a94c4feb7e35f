/* The FMI 2.0 API of every dsc-fmu FMU, co-simulation and model exchange: each call guarded by the
   interface and the states functions.h allows it in (BEGIN, adapter.h), then handed to instance.c; every
   fmi2Error moves the instance to the error state. Nothing returns fmi2Fatal. */

#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#include "fmi2Functions.h"

#define FMI_VERSION 2
#define FMI_STATUS fmi2Status
#include "adapter.h"

typedef struct {
    Instance base;
    fmi2CallbackFunctions functions;
} Fmi2Instance;

/* The logger takes a printf format: the message goes as a format with every '%' doubled (in a copy, if it has
   any) and no arguments, so loggers that format and loggers that do not both show the text. */
static void host_log(Instance *instance, int status, const char *category, const char *message) {
    const fmi2CallbackFunctions *functions = &((Fmi2Instance *)instance)->functions;
    if (!functions->logger) return;
    size_t length = 0, signs = 0;
    for (; message[length]; length++) signs += message[length] == '%';
    char *doubled = signs ? malloc(length + signs + 1) : NULL;
    for (size_t i = 0, k = 0; doubled && i <= length; i++) {
        if (message[i] == '%') doubled[k++] = '%';
        doubled[k++] = message[i];
    }
    const char *format = !signs ? message : doubled ? doubled : "(a message was lost: no memory to copy it)";
    functions->logger(functions->componentEnvironment, instance->name, (fmi2Status)status, category, format);
    free(doubled);
}

/* Warnings, errors and fatal errors are shown whatever the debug logging (section 2.1.3); OK and
   discard messages only in the categories enabled. */
static const Standard FMI2 = {
    Error, StepFailed, 1 << STATUS_WARNING | 1 << STATUS_ERROR | 1 << STATUS_FATAL, host_log,
};

/* NULL after logging "<function>: <why>". */
static fmi2Component refuse_instantiation(const fmi2CallbackFunctions *functions, fmi2String name,
                                          const char *function, const char *why) {
    if (functions && functions->logger) {
        char text[256];
        snprintf(text, sizeof text, "%s: %s", function, why); /* no '%': the logger's format */
        functions->logger(functions->componentEnvironment, name ? name : "", fmi2Error, slave_category(STATUS_ERROR), text);
    }
    return NULL;
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn) {
    if (!instanceName || !*instanceName) {
        return refuse_instantiation(functions, instanceName, __func__, "the instance name is missing or empty");
    }
    if (fmuType != fmi2CoSimulation && fmuType != fmi2ModelExchange) {
        return refuse_instantiation(functions, instanceName, __func__,
                                    "the FMU type is neither fmi2ModelExchange nor fmi2CoSimulation");
    }
    Fmi2Instance *instance = (Fmi2Instance *)instance_alloc(sizeof(Fmi2Instance), instanceName, loggingOn,
                                                            fmuType == fmi2ModelExchange, &FMI2);
    if (!instance) return refuse_instantiation(functions, instanceName, __func__, "out of memory");
    if (functions) instance->functions = *functions;
    if (instance_start(&instance->base, __func__, fmuResourceLocation, fmuGUID, visible) != 0) {
        instance_free(&instance->base);
        return NULL;
    }
    return instance;
}

/* --- inquiry, logging ------------------------------------------------------------------------------------ */

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    BEGIN(fmi2SetDebugLogging);
    END(instance_set_logging(instance, loggingOn, nCategories, categories));
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

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    BEGIN(fmi2DoStep);
    END(instance_do_step(instance, currentCommunicationPoint, communicationStepSize));
}

/* Allowed in no state (BEGIN refuses every call): fmi2DoStep returns when the step is done. */
fmi2Status fmi2CancelStep(fmi2Component c) {
    BEGIN(fmi2CancelStep);
    END(STATUS_ERROR);
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    BEGIN(fmi2SetRealInputDerivatives);
    END(instance_set_input_derivatives(instance, vr, nvr, order, value));
}

fmi2Status fmi2Terminate(fmi2Component c) {
    BEGIN(fmi2Terminate);
    END(instance_terminate(instance));
}

fmi2Status fmi2Reset(fmi2Component c) {
    BEGIN(fmi2Reset);
    END(instance_reset(instance));
}

/* --- values: these FMUs have Real, Integer and Boolean variables, no String ones ------------------------ */

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]) {
    BEGIN(fmi2GetReal);
    END(instance_get(instance, TYPE_REAL, vr, nvr, value, nvr, C_DOUBLE));
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[]) {
    BEGIN(fmi2GetInteger);
    END(instance_get(instance, TYPE_INTEGER, vr, nvr, value, nvr, C_INT));
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[]) {
    BEGIN(fmi2GetBoolean);
    END(instance_get(instance, TYPE_BOOLEAN, vr, nvr, value, nvr, C_BOOL_INT));
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2String value[]) {
    NO_VARIABLES_OF(fmi2GetString, "String");
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[]) {
    BEGIN(fmi2SetReal);
    END(instance_set(instance, TYPE_REAL, vr, nvr, value, nvr, C_DOUBLE));
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Integer value[]) {
    BEGIN(fmi2SetInteger);
    END(instance_set(instance, TYPE_INTEGER, vr, nvr, value, nvr, C_INT));
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Boolean value[]) {
    BEGIN(fmi2SetBoolean);
    END(instance_set(instance, TYPE_BOOLEAN, vr, nvr, value, nvr, C_BOOL_INT));
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2String value[]) {
    NO_VARIABLES_OF(fmi2SetString, "String");
}

/* --- FMU states ------------------------------------------------------------------------------------------- */

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    BEGIN(fmi2GetFMUstate);
    END(instance_get_state(instance, FMUstate));
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    BEGIN(fmi2SetFMUstate);
    END(instance_set_state(instance, FMUstate));
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    BEGIN(fmi2FreeFMUstate);
    END(instance_free_state(instance, FMUstate));
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    BEGIN(fmi2SerializedFMUstateSize);
    END(instance_serialized_size(instance, FMUstate, size));
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[], size_t size) {
    BEGIN(fmi2SerializeFMUstate);
    END(instance_serialize(instance, FMUstate, serializedState, size));
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate) {
    BEGIN(fmi2DeSerializeFMUstate);
    END(instance_deserialize(instance, serializedState, size, FMUstate));
}

/* --- model exchange ------------------------------------------------------------------------------------ */

fmi2Status fmi2EnterEventMode(fmi2Component c) {
    BEGIN(fmi2EnterEventMode);
    END(instance_enter(instance, EventMode));
}

fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *eventInfo) {
    BEGIN(fmi2NewDiscreteStates);
    if (!instance_given(instance, eventInfo, "event info")) END(STATUS_ERROR);
    int changed = 0;
    int status = instance_update_discrete_states(instance, &changed);
    eventInfo->newDiscreteStatesNeeded = fmi2False;
    eventInfo->terminateSimulation = fmi2False;
    eventInfo->nominalsOfContinuousStatesChanged = fmi2False;
    eventInfo->valuesOfContinuousStatesChanged = changed ? fmi2True : fmi2False;
    eventInfo->nextEventTimeDefined = fmi2False;
    eventInfo->nextEventTime = 0.0;
    END(status);
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) {
    BEGIN(fmi2EnterContinuousTimeMode);
    END(instance_enter(instance, ContinuousTimeMode));
}

fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean *enterEventMode, fmi2Boolean *terminateSimulation) {
    NO_EVENT_AFTER_INTEGRATOR_STEP(fmi2CompletedIntegratorStep);
}

fmi2Status fmi2SetTime(fmi2Component c, fmi2Real time) {
    BEGIN(fmi2SetTime);
    END(instance_set_time(instance, time));
}

fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx) {
    BEGIN(fmi2SetContinuousStates);
    END(instance_set_states(instance, x, nx));
}

fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real derivatives[], size_t nx) {
    BEGIN(fmi2GetDerivatives);
    END(instance_get_vector(instance, VECTOR_DERIVATIVES, derivatives, nx));
}

fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real eventIndicators[], size_t ni) {
    BEGIN(fmi2GetEventIndicators);
    END(instance_get_vector(instance, VECTOR_INDICATORS, eventIndicators, ni));
}

fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx) {
    BEGIN(fmi2GetContinuousStates);
    END(instance_get_vector(instance, VECTOR_STATES, x, nx));
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x_nominal[], size_t nx) {
    BEGIN(fmi2GetNominalsOfContinuousStates);
    END(instance_get_vector(instance, VECTOR_NOMINALS, x_nominal, nx));
}

/* --- status: fmi2DoStep never returns fmi2Pending ------------------------------------------------------ */

#define NOT_AVAILABLE "this status is not available (fmi2DoStep never returns fmi2Pending)"

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    BEGIN(fmi2GetStatus);
    END(instance_fail(instance, STATUS_DISCARD, NOT_AVAILABLE));
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    BEGIN(fmi2GetRealStatus);
    if (s != fmi2LastSuccessfulTime) END(instance_fail(instance, STATUS_DISCARD, NOT_AVAILABLE));
    if (!instance_given(instance, value, "place for the value")) END(STATUS_ERROR);
    END(slave_get_double(&instance->slave, "time", value));
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    BEGIN(fmi2GetIntegerStatus);
    END(instance_fail(instance, STATUS_DISCARD, NOT_AVAILABLE));
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    BEGIN(fmi2GetBooleanStatus);
    if (s != fmi2Terminated) END(instance_fail(instance, STATUS_DISCARD, NOT_AVAILABLE));
    if (!instance_given(instance, value, "place for the value")) END(STATUS_ERROR);
    *value = fmi2False; /* these FMUs never ask to end the simulation */
    END(STATUS_OK);
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    BEGIN(fmi2GetStringStatus);
    END(instance_fail(instance, STATUS_DISCARD, NOT_AVAILABLE));
}

/* --- partial derivatives: exact, the model code differentiated in Python ---------------------------------- */

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[], size_t nUnknown,
                                        const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[]) {
    BEGIN(fmi2GetDirectionalDerivative);
    Partials partials = {vUnknown_ref, nUnknown, vKnown_ref, nKnown, dvKnown, nKnown, dvUnknown, nUnknown};
    END(instance_partials(instance, &partials, 0));
}

/* --- what these FMUs do not offer ------------------------------------------------------------------------- */

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    UNSUPPORTED(fmi2GetRealOutputDerivatives, "maxOutputDerivativeOrder is 0");
}
