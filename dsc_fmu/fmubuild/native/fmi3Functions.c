/* The FMI 3.0 API of every dsc-fmu FMU, co-simulation and model exchange: each call guarded by the
   interface and the states functions.h allows it in (BEGIN, adapter.h), then handed to instance.c; every
   fmi3Error moves the instance to Terminated. No event mode in co-simulation, no scheduled execution, no
   clocks: those functions refuse with a message. Nothing returns fmi3Fatal. */

#include <math.h>
#include <stdio.h>

#include "fmi3Functions.h"

#define FMI_VERSION 3
#define FMI_STATUS fmi3Status
#include "adapter.h"

typedef struct {
    Instance base;
    fmi3InstanceEnvironment environment;
    fmi3LogMessageCallback logMessage;
} Fmi3Instance;

static void host_log(Instance *instance, int status, const char *category, const char *message) {
    Fmi3Instance *host = (Fmi3Instance *)instance;
    if (host->logMessage) host->logMessage(host->environment, (fmi3Status)status, category, message);
}

/* With loggingOn = fmi3False, or a category switched off, logMessage is never called (FMI 3.0.2, 2.3.1). */
static const Standard FMI3 = {
    Terminated, StepMode, 0, host_log,
};

/* --- creation -------------------------------------------------------------------------------------------- */

/* NULL after logging "<function>: <why>". */
static fmi3Instance refuse_instantiation(fmi3InstanceEnvironment environment, fmi3LogMessageCallback logMessage,
                                         fmi3Boolean loggingOn, const char *function, const char *why) {
    char text[256];
    snprintf(text, sizeof text, "%s: %s", function, why);
    if (logMessage && loggingOn) logMessage(environment, fmi3Error, slave_category(STATUS_ERROR), text);
    return NULL;
}

/* An instance of either interface, named `function` in messages; NULL after logging why. */
static fmi3Instance instantiate(const char *function, int model_exchange, fmi3String instanceName,
                                fmi3String instantiationToken, fmi3String resourcePath, fmi3Boolean visible,
                                fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment,
                                fmi3LogMessageCallback logMessage) {
    if (!instanceName || !*instanceName) {
        return refuse_instantiation(instanceEnvironment, logMessage, loggingOn, function,
                                    "the instance name is missing or empty");
    }
    Fmi3Instance *instance = (Fmi3Instance *)instance_alloc(sizeof(Fmi3Instance), instanceName, loggingOn,
                                                            model_exchange, &FMI3);
    if (!instance) return refuse_instantiation(instanceEnvironment, logMessage, loggingOn, function, "out of memory");
    instance->environment = instanceEnvironment;
    instance->logMessage = logMessage;
    if (instance_start(&instance->base, function, resourcePath, instantiationToken, visible) != 0) {
        instance_free(&instance->base);
        return NULL;
    }
    return instance;
}

fmi3Instance fmi3InstantiateCoSimulation(fmi3String instanceName, fmi3String instantiationToken,
                                         fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                         fmi3Boolean eventModeUsed, fmi3Boolean earlyReturnAllowed,
                                         const fmi3ValueReference requiredIntermediateVariables[],
                                         size_t nRequiredIntermediateVariables,
                                         fmi3InstanceEnvironment instanceEnvironment,
                                         fmi3LogMessageCallback logMessage,
                                         fmi3IntermediateUpdateCallback intermediateUpdate) {
    if (eventModeUsed) {
        return refuse_instantiation(instanceEnvironment, logMessage, loggingOn, __func__,
                                    "eventModeUsed is not supported (hasEventMode is false)");
    }
    if (nRequiredIntermediateVariables > 0) {
        return refuse_instantiation(instanceEnvironment, logMessage, loggingOn, __func__,
                                    "these FMUs provide no intermediate variables");
    }
    return instantiate(__func__, 0, instanceName, instantiationToken, resourcePath, visible,
                       loggingOn, instanceEnvironment, logMessage);
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage) {
    return instantiate(__func__, 1, instanceName, instantiationToken, resourcePath, visible,
                       loggingOn, instanceEnvironment, logMessage);
}

fmi3Instance fmi3InstantiateScheduledExecution(fmi3String instanceName, fmi3String instantiationToken,
                                               fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                               fmi3InstanceEnvironment instanceEnvironment,
                                               fmi3LogMessageCallback logMessage, fmi3ClockUpdateCallback clockUpdate,
                                               fmi3LockPreemptionCallback lockPreemption,
                                               fmi3UnlockPreemptionCallback unlockPreemption) {
    return refuse_instantiation(instanceEnvironment, logMessage, loggingOn, __func__,
                                "these FMUs offer co-simulation and model exchange only");
}

/* --- inquiry, logging ------------------------------------------------------------------------------------ */

const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance c, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[]) {
    BEGIN(fmi3SetDebugLogging);
    END(instance_set_logging(instance, loggingOn, nCategories, categories));
}

void fmi3FreeInstance(fmi3Instance c) { instance_free((Instance *)c); }

/* --- initialisation, stepping, termination --------------------------------------------------------------- */

fmi3Status fmi3EnterInitializationMode(fmi3Instance c, fmi3Boolean toleranceDefined, fmi3Float64 tolerance,
                                       fmi3Float64 startTime, fmi3Boolean stopTimeDefined, fmi3Float64 stopTime) {
    BEGIN(fmi3EnterInitializationMode);
    instance->stop_time = stopTimeDefined ? stopTime : INFINITY;
    double start[] = {startTime};
    int status = instance_call(instance, "setup_experiment", 1, start, NULL, Instantiated);
    if (status == fmi3OK) {
        status = instance_call(instance, "enter_initialization_mode", 0, NULL, NULL, InitializationMode);
    }
    END(status);
}

fmi3Status fmi3DoStep(fmi3Instance c, fmi3Float64 currentCommunicationPoint, fmi3Float64 communicationStepSize,
                      fmi3Boolean noSetFMUStatePriorToCurrentPoint, fmi3Boolean *eventHandlingNeeded,
                      fmi3Boolean *terminateSimulation, fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime) {
    BEGIN(fmi3DoStep);
    if (!eventHandlingNeeded || !terminateSimulation || !earlyReturn || !lastSuccessfulTime) {
        END(instance_fail(instance, STATUS_ERROR, "an output argument is NULL"));
    }
    int status = instance_do_step(instance, currentCommunicationPoint, communicationStepSize);
    *eventHandlingNeeded = fmi3False;
    *terminateSimulation = fmi3False;
    *earlyReturn = fmi3False;
    *lastSuccessfulTime = currentCommunicationPoint + (status == fmi3OK ? communicationStepSize : 0.0);
    END(status);
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance c) {
    BEGIN(fmi3ExitInitializationMode);
    END(instance_exit_initialization(instance));
}

fmi3Status fmi3Terminate(fmi3Instance c) {
    BEGIN(fmi3Terminate);
    END(instance_terminate(instance));
}

fmi3Status fmi3Reset(fmi3Instance c) {
    BEGIN(fmi3Reset);
    END(instance_reset(instance));
}

/* --- values: these FMUs have Float64, Int32 and Boolean variables, none of the other types --------------- */

fmi3Status fmi3GetFloat64(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3Float64 values[],
                          size_t nValues) {
    BEGIN(fmi3GetFloat64);
    END(instance_get(instance, TYPE_REAL, vr, nvr, values, nValues, C_DOUBLE));
}

fmi3Status fmi3GetInt32(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3Int32 values[],
                        size_t nValues) {
    BEGIN(fmi3GetInt32);
    END(instance_get(instance, TYPE_INTEGER, vr, nvr, values, nValues, C_INT32));
}

fmi3Status fmi3GetBoolean(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3Boolean values[],
                          size_t nValues) {
    BEGIN(fmi3GetBoolean);
    END(instance_get(instance, TYPE_BOOLEAN, vr, nvr, values, nValues, C_BOOL_BYTE));
}

fmi3Status fmi3SetFloat64(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3Float64 values[],
                          size_t nValues) {
    BEGIN(fmi3SetFloat64);
    END(instance_set(instance, TYPE_REAL, vr, nvr, values, nValues, C_DOUBLE));
}

fmi3Status fmi3SetInt32(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3Int32 values[],
                        size_t nValues) {
    BEGIN(fmi3SetInt32);
    END(instance_set(instance, TYPE_INTEGER, vr, nvr, values, nValues, C_INT32));
}

fmi3Status fmi3SetBoolean(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3Boolean values[],
                          size_t nValues) {
    BEGIN(fmi3SetBoolean);
    END(instance_set(instance, TYPE_BOOLEAN, vr, nvr, values, nValues, C_BOOL_BYTE));
}

fmi3Status fmi3GetFloat32(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3Float32 values[],
                          size_t nValues) {
    NO_VARIABLES_OF(fmi3GetFloat32, "Float32");
}

fmi3Status fmi3SetFloat32(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3Float32 values[],
                          size_t nValues) {
    NO_VARIABLES_OF(fmi3SetFloat32, "Float32");
}

fmi3Status fmi3GetInt8(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3Int8 values[], size_t nValues) {
    NO_VARIABLES_OF(fmi3GetInt8, "Int8");
}

fmi3Status fmi3SetInt8(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3Int8 values[],
                       size_t nValues) {
    NO_VARIABLES_OF(fmi3SetInt8, "Int8");
}

fmi3Status fmi3GetUInt8(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3UInt8 values[], size_t nValues) {
    NO_VARIABLES_OF(fmi3GetUInt8, "UInt8");
}

fmi3Status fmi3SetUInt8(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3UInt8 values[],
                        size_t nValues) {
    NO_VARIABLES_OF(fmi3SetUInt8, "UInt8");
}

fmi3Status fmi3GetInt16(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3Int16 values[], size_t nValues) {
    NO_VARIABLES_OF(fmi3GetInt16, "Int16");
}

fmi3Status fmi3SetInt16(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3Int16 values[],
                        size_t nValues) {
    NO_VARIABLES_OF(fmi3SetInt16, "Int16");
}

fmi3Status fmi3GetUInt16(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3UInt16 values[],
                         size_t nValues) {
    NO_VARIABLES_OF(fmi3GetUInt16, "UInt16");
}

fmi3Status fmi3SetUInt16(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3UInt16 values[],
                         size_t nValues) {
    NO_VARIABLES_OF(fmi3SetUInt16, "UInt16");
}

fmi3Status fmi3GetUInt32(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3UInt32 values[],
                         size_t nValues) {
    NO_VARIABLES_OF(fmi3GetUInt32, "UInt32");
}

fmi3Status fmi3SetUInt32(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3UInt32 values[],
                         size_t nValues) {
    NO_VARIABLES_OF(fmi3SetUInt32, "UInt32");
}

fmi3Status fmi3GetInt64(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3Int64 values[], size_t nValues) {
    NO_VARIABLES_OF(fmi3GetInt64, "Int64");
}

fmi3Status fmi3SetInt64(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3Int64 values[],
                        size_t nValues) {
    NO_VARIABLES_OF(fmi3SetInt64, "Int64");
}

fmi3Status fmi3GetUInt64(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3UInt64 values[],
                         size_t nValues) {
    NO_VARIABLES_OF(fmi3GetUInt64, "UInt64");
}

fmi3Status fmi3SetUInt64(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3UInt64 values[],
                         size_t nValues) {
    NO_VARIABLES_OF(fmi3SetUInt64, "UInt64");
}

fmi3Status fmi3GetString(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3String values[],
                         size_t nValues) {
    NO_VARIABLES_OF(fmi3GetString, "String");
}

fmi3Status fmi3SetString(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3String values[],
                         size_t nValues) {
    NO_VARIABLES_OF(fmi3SetString, "String");
}

fmi3Status fmi3GetBinary(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, size_t valueSizes[],
                         fmi3Binary values[], size_t nValues) {
    NO_VARIABLES_OF(fmi3GetBinary, "Binary");
}

fmi3Status fmi3SetBinary(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const size_t valueSizes[],
                         const fmi3Binary values[], size_t nValues) {
    NO_VARIABLES_OF(fmi3SetBinary, "Binary");
}

/* --- FMU states ------------------------------------------------------------------------------------------- */

fmi3Status fmi3GetFMUState(fmi3Instance c, fmi3FMUState *FMUState) {
    BEGIN(fmi3GetFMUState);
    END(instance_get_state(instance, FMUState));
}

fmi3Status fmi3SetFMUState(fmi3Instance c, fmi3FMUState FMUState) {
    BEGIN(fmi3SetFMUState);
    END(instance_set_state(instance, FMUState));
}

fmi3Status fmi3FreeFMUState(fmi3Instance c, fmi3FMUState *FMUState) {
    BEGIN(fmi3FreeFMUState);
    END(instance_free_state(instance, FMUState));
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance c, fmi3FMUState FMUState, size_t *size) {
    BEGIN(fmi3SerializedFMUStateSize);
    END(instance_serialized_size(instance, FMUState, size));
}

fmi3Status fmi3SerializeFMUState(fmi3Instance c, fmi3FMUState FMUState, fmi3Byte serializedState[], size_t size) {
    BEGIN(fmi3SerializeFMUState);
    END(instance_serialize(instance, FMUState, (char *)serializedState, size));
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance c, const fmi3Byte serializedState[], size_t size,
                                   fmi3FMUState *FMUState) {
    BEGIN(fmi3DeserializeFMUState);
    END(instance_deserialize(instance, (const char *)serializedState, size, FMUState));
}

/* --- model exchange ------------------------------------------------------------------------------------ */

fmi3Status fmi3EnterEventMode(fmi3Instance c) {
    BEGIN(fmi3EnterEventMode);
    END(instance_enter(instance, EventMode));
}

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance c, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation, fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged, fmi3Boolean *nextEventTimeDefined,
                                    fmi3Float64 *nextEventTime) {
    BEGIN(fmi3UpdateDiscreteStates);
    if (!discreteStatesNeedUpdate || !terminateSimulation || !nominalsOfContinuousStatesChanged ||
        !valuesOfContinuousStatesChanged || !nextEventTimeDefined || !nextEventTime) {
        END(instance_fail(instance, STATUS_ERROR, "an output argument is NULL"));
    }
    int changed = 0;
    int status = instance_update_discrete_states(instance, &changed);
    *discreteStatesNeedUpdate = fmi3False;
    *terminateSimulation = fmi3False;
    *nominalsOfContinuousStatesChanged = fmi3False;
    *valuesOfContinuousStatesChanged = changed ? fmi3True : fmi3False;
    *nextEventTimeDefined = fmi3False;
    *nextEventTime = 0.0;
    END(status);
}

fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance c) {
    BEGIN(fmi3EnterContinuousTimeMode);
    END(instance_enter(instance, ContinuousTimeMode));
}

fmi3Status fmi3CompletedIntegratorStep(fmi3Instance c, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode, fmi3Boolean *terminateSimulation) {
    NO_EVENT_AFTER_INTEGRATOR_STEP(fmi3CompletedIntegratorStep);
}

fmi3Status fmi3SetTime(fmi3Instance c, fmi3Float64 time) {
    BEGIN(fmi3SetTime);
    END(instance_set_time(instance, time));
}

fmi3Status fmi3SetContinuousStates(fmi3Instance c, const fmi3Float64 continuousStates[], size_t nContinuousStates) {
    BEGIN(fmi3SetContinuousStates);
    END(instance_set_states(instance, continuousStates, nContinuousStates));
}

fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance c, fmi3Float64 derivatives[], size_t nContinuousStates) {
    BEGIN(fmi3GetContinuousStateDerivatives);
    END(instance_get_vector(instance, VECTOR_DERIVATIVES, derivatives, nContinuousStates));
}

fmi3Status fmi3GetEventIndicators(fmi3Instance c, fmi3Float64 eventIndicators[], size_t nEventIndicators) {
    BEGIN(fmi3GetEventIndicators);
    END(instance_get_vector(instance, VECTOR_INDICATORS, eventIndicators, nEventIndicators));
}

fmi3Status fmi3GetContinuousStates(fmi3Instance c, fmi3Float64 continuousStates[], size_t nContinuousStates) {
    BEGIN(fmi3GetContinuousStates);
    END(instance_get_vector(instance, VECTOR_STATES, continuousStates, nContinuousStates));
}

fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance c, fmi3Float64 nominals[], size_t nContinuousStates) {
    BEGIN(fmi3GetNominalsOfContinuousStates);
    END(instance_get_vector(instance, VECTOR_NOMINALS, nominals, nContinuousStates));
}

fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance c, size_t *nContinuousStates) {
    BEGIN(fmi3GetNumberOfContinuousStates);
    END(instance_count(instance, nContinuousStates, instance->slave.nx));
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance c, size_t *nEventIndicators) {
    BEGIN(fmi3GetNumberOfEventIndicators);
    END(instance_count(instance, nEventIndicators, instance->slave.nz));
}

/* --- partial derivatives: exact, the model code differentiated in Python ---------------------------------- */

fmi3Status fmi3GetDirectionalDerivative(fmi3Instance c, const fmi3ValueReference unknowns[], size_t nUnknowns,
                                        const fmi3ValueReference knowns[], size_t nKnowns, const fmi3Float64 seed[],
                                        size_t nSeed, fmi3Float64 sensitivity[], size_t nSensitivity) {
    BEGIN(fmi3GetDirectionalDerivative);
    Partials partials = {unknowns, nUnknowns, knowns, nKnowns, seed, nSeed, sensitivity, nSensitivity};
    END(instance_partials(instance, &partials, 0));
}

fmi3Status fmi3GetAdjointDerivative(fmi3Instance c, const fmi3ValueReference unknowns[], size_t nUnknowns,
                                    const fmi3ValueReference knowns[], size_t nKnowns, const fmi3Float64 seed[],
                                    size_t nSeed, fmi3Float64 sensitivity[], size_t nSensitivity) {
    BEGIN(fmi3GetAdjointDerivative);
    Partials partials = {unknowns, nUnknowns, knowns, nKnowns, seed, nSeed, sensitivity, nSensitivity};
    END(instance_partials(instance, &partials, 1));
}

/* --- what these FMUs do not offer: functions.h admits these in every state, and each says why ------------ */

#define NO_EVENT_MODE "hasEventMode is false"
#define NO_STRUCTURAL_PARAMETERS "these FMUs have no structural parameters"
#define NO_DEPENDENCIES "providesPerElementDependencies is false; see ModelStructure"
#define NO_CLOCKS "these FMUs have no clocks"

fmi3Status fmi3EnterStepMode(fmi3Instance c) {
    UNSUPPORTED(fmi3EnterStepMode, NO_EVENT_MODE);
}

fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance c) {
    UNSUPPORTED(fmi3EvaluateDiscreteStates, NO_EVENT_MODE);
}

fmi3Status fmi3EnterConfigurationMode(fmi3Instance c) {
    UNSUPPORTED(fmi3EnterConfigurationMode, NO_STRUCTURAL_PARAMETERS);
}

fmi3Status fmi3ExitConfigurationMode(fmi3Instance c) {
    UNSUPPORTED(fmi3ExitConfigurationMode, NO_STRUCTURAL_PARAMETERS);
}

fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance c, fmi3ValueReference valueReference,
                                               size_t *nDependencies) {
    UNSUPPORTED(fmi3GetNumberOfVariableDependencies, NO_DEPENDENCIES);
}

fmi3Status fmi3GetVariableDependencies(fmi3Instance c, fmi3ValueReference dependent, size_t elementIndicesOfDependent[],
                                       fmi3ValueReference independents[], size_t elementIndicesOfIndependents[],
                                       fmi3DependencyKind dependencyKinds[], size_t nDependencies) {
    UNSUPPORTED(fmi3GetVariableDependencies, NO_DEPENDENCIES);
}

fmi3Status fmi3GetOutputDerivatives(fmi3Instance c, const fmi3ValueReference valueReferences[],
                                    size_t nValueReferences, const fmi3Int32 orders[], fmi3Float64 values[],
                                    size_t nValues) {
    UNSUPPORTED(fmi3GetOutputDerivatives, "maxOutputDerivativeOrder is 0");
}

fmi3Status fmi3GetClock(fmi3Instance c, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                        fmi3Clock values[]) {
    UNSUPPORTED(fmi3GetClock, NO_CLOCKS);
}

fmi3Status fmi3SetClock(fmi3Instance c, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                        const fmi3Clock values[]) {
    UNSUPPORTED(fmi3SetClock, NO_CLOCKS);
}

fmi3Status fmi3GetIntervalDecimal(fmi3Instance c, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                                  fmi3Float64 intervals[], fmi3IntervalQualifier qualifiers[]) {
    UNSUPPORTED(fmi3GetIntervalDecimal, NO_CLOCKS);
}

fmi3Status fmi3GetIntervalFraction(fmi3Instance c, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                                   fmi3UInt64 counters[], fmi3UInt64 resolutions[],
                                   fmi3IntervalQualifier qualifiers[]) {
    UNSUPPORTED(fmi3GetIntervalFraction, NO_CLOCKS);
}

fmi3Status fmi3GetShiftDecimal(fmi3Instance c, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                               fmi3Float64 shifts[]) {
    UNSUPPORTED(fmi3GetShiftDecimal, NO_CLOCKS);
}

fmi3Status fmi3GetShiftFraction(fmi3Instance c, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                                fmi3UInt64 counters[], fmi3UInt64 resolutions[]) {
    UNSUPPORTED(fmi3GetShiftFraction, NO_CLOCKS);
}

fmi3Status fmi3SetIntervalDecimal(fmi3Instance c, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                                  const fmi3Float64 intervals[]) {
    UNSUPPORTED(fmi3SetIntervalDecimal, NO_CLOCKS);
}

fmi3Status fmi3SetIntervalFraction(fmi3Instance c, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                                   const fmi3UInt64 counters[], const fmi3UInt64 resolutions[]) {
    UNSUPPORTED(fmi3SetIntervalFraction, NO_CLOCKS);
}

fmi3Status fmi3SetShiftDecimal(fmi3Instance c, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                               const fmi3Float64 shifts[]) {
    UNSUPPORTED(fmi3SetShiftDecimal, NO_CLOCKS);
}

fmi3Status fmi3SetShiftFraction(fmi3Instance c, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                                const fmi3UInt64 counters[], const fmi3UInt64 resolutions[]) {
    UNSUPPORTED(fmi3SetShiftFraction, NO_CLOCKS);
}

fmi3Status fmi3ActivateModelPartition(fmi3Instance c, fmi3ValueReference clockReference, fmi3Float64 activationTime) {
    UNSUPPORTED(fmi3ActivateModelPartition, "a function of scheduled execution; these FMUs do not offer it");
}
