/* The FMI 2.0 API of every dsc-fmu FMU, co-simulation and model exchange: each call guarded by the
   interface and the states functions.h allows it in, then handed to instance.c; every fmi2Error moves
   the instance to the error state. Nothing returns fmi2Fatal. The functions FMI 3.0 has alike are in
   adapter.h. */

#include <math.h>
#include <stdio.h>

#include "fmi2Functions.h"

#define FMI_VERSION 2
#define FMI(F) fmi2##F
typedef fmi2Component Component;
typedef fmi2Real Float;
typedef fmi2FMUstate FMUState;
#define GET_FMU_STATE fmi2GetFMUstate
#define SET_FMU_STATE fmi2SetFMUstate
#define FREE_FMU_STATE fmi2FreeFMUstate
#define SERIALIZED_FMU_STATE_SIZE fmi2SerializedFMUstateSize
#define SERIALIZE_FMU_STATE fmi2SerializeFMUstate
#define DESERIALIZE_FMU_STATE fmi2DeSerializeFMUstate
#define GET_DERIVATIVES fmi2GetDerivatives
#define NVALUES            /* one value per value reference */
#define COUNT nvr

#include "adapter.h"

typedef struct {
    Instance base;
    fmi2CallbackFunctions functions;
} Fmi2Instance;

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
    Error, StepFailed, 1 << STATUS_WARNING | 1 << STATUS_ERROR | 1 << STATUS_FATAL, host_log,
};

/* --- inquiry, creation ------------------------------------------------------------------------------------ */

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

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

/* --- initialisation, stepping ----------------------------------------------------------------------------- */

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

/* --- model exchange ------------------------------------------------------------------------------------ */

fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *eventInfo) {
    BEGIN(fmi2NewDiscreteStates);
    if (!instance_given(instance, eventInfo, "event info")) END(STATUS_ERROR);
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

GET_AND_SET(Real, TYPE_REAL, C_DOUBLE, fmi2Real)
GET_AND_SET(Integer, TYPE_INTEGER, C_INT, fmi2Integer)
GET_AND_SET(Boolean, TYPE_BOOLEAN, C_BOOL_INT, fmi2Boolean)
GET_AND_SET(String, TYPE_STRING, C_DOUBLE, fmi2String)

/* --- status: fmi2DoStep never returns fmi2Pending ------------------------------------------------------ */

#define NOT_AVAILABLE "this status is not available (fmi2DoStep never returns fmi2Pending)"

#define NO_STATUS(F, type)                                                                                     \
    fmi2Status F(fmi2Component c, const fmi2StatusKind s, type *value) {                                      \
        BEGIN(F);                                                                                              \
        END(instance_fail(instance, STATUS_DISCARD, NOT_AVAILABLE));                                           \
    }

NO_STATUS(fmi2GetStatus, fmi2Status)
NO_STATUS(fmi2GetIntegerStatus, fmi2Integer)
NO_STATUS(fmi2GetStringStatus, fmi2String)

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    BEGIN(fmi2GetRealStatus);
    if (s != fmi2LastSuccessfulTime) END(instance_fail(instance, STATUS_DISCARD, NOT_AVAILABLE));
    if (!instance_given(instance, value, "place for the value")) END(STATUS_ERROR);
    END(slave_get_double(&instance->slave, "time", value));
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    BEGIN(fmi2GetBooleanStatus);
    if (s != fmi2Terminated) END(instance_fail(instance, STATUS_DISCARD, NOT_AVAILABLE));
    if (!instance_given(instance, value, "place for the value")) END(STATUS_ERROR);
    *value = fmi2False; /* these FMUs never ask to end the simulation */
    END(STATUS_OK);
}

/* --- what these FMUs do not offer ------------------------------------------------------------------------- */

UNSUPPORTED(fmi2GetDirectionalDerivative, "providesDirectionalDerivative is false",
            const fmi2ValueReference vUnknown_ref[], size_t nUnknown, const fmi2ValueReference vKnown_ref[],
            size_t nKnown, const fmi2Real dvKnown[], fmi2Real dvUnknown[])
UNSUPPORTED(fmi2GetRealOutputDerivatives, "maxOutputDerivativeOrder is 0", const fmi2ValueReference vr[],
            size_t nvr, const fmi2Integer order[], fmi2Real value[])
