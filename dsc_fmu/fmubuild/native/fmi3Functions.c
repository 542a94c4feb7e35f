/* The FMI 3.0 API of every dsc-fmu FMU, co-simulation and model exchange: each call guarded by the
   interface and the states functions.h allows it in, then handed to instance.c; every fmi3Error moves
   the instance to Terminated. No event mode in co-simulation, no scheduled execution, no clocks: those
   functions refuse with a message. Nothing returns fmi3Fatal. The functions FMI 2.0 has alike are in
   adapter.h. */

#include <math.h>
#include <stdio.h>

#include "fmi3Functions.h"

#define FMI_VERSION 3
#define FMI(F) fmi3##F
typedef fmi3Instance Component;
typedef fmi3Float64 Float;
typedef fmi3FMUState FMUState;
#define GET_FMU_STATE fmi3GetFMUState
#define SET_FMU_STATE fmi3SetFMUState
#define FREE_FMU_STATE fmi3FreeFMUState
#define SERIALIZED_FMU_STATE_SIZE fmi3SerializedFMUStateSize
#define SERIALIZE_FMU_STATE fmi3SerializeFMUState
#define DESERIALIZE_FMU_STATE fmi3DeserializeFMUState
#define GET_DERIVATIVES fmi3GetContinuousStateDerivatives
#define NVALUES , size_t nValues
#define COUNT nValues

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

/* --- initialisation, stepping ----------------------------------------------------------------------------- */

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

/* --- values ------------------------------------------------------------------------------------------- */

GET_AND_SET(Float64, TYPE_REAL, C_DOUBLE, fmi3Float64)
GET_AND_SET(Int32, TYPE_INTEGER, C_INT32, fmi3Int32)
GET_AND_SET(Boolean, TYPE_BOOLEAN, C_BOOL_BYTE, fmi3Boolean)

/* A type these FMUs have no variables of: only an empty call succeeds. */
#define ABSENT(F, type_name, ...)                                                                              \
    fmi3Status F(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, __VA_ARGS__) {                    \
        BEGIN(F);                                                                                              \
        END(instance_no_variables_of(instance, type_name, vr, nvr));                                           \
    }

/* Getter and setter of the type T. */
#define ABSENT_VALUES(T)                                                                                       \
    ABSENT(fmi3Get##T, #T, fmi3##T values[], size_t nValues)                                                   \
    ABSENT(fmi3Set##T, #T, const fmi3##T values[], size_t nValues)

ABSENT_VALUES(Float32) ABSENT_VALUES(UInt32)
ABSENT_VALUES(Int8) ABSENT_VALUES(UInt8)
ABSENT_VALUES(Int16) ABSENT_VALUES(UInt16)
ABSENT_VALUES(Int64) ABSENT_VALUES(UInt64)
ABSENT_VALUES(String)
ABSENT(fmi3GetBinary, "Binary", size_t valueSizes[], fmi3Binary values[], size_t nValues)
ABSENT(fmi3SetBinary, "Binary", const size_t valueSizes[], const fmi3Binary values[], size_t nValues)

/* --- model exchange ------------------------------------------------------------------------------------ */

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance c, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation, fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged, fmi3Boolean *nextEventTimeDefined,
                                    fmi3Float64 *nextEventTime) {
    BEGIN(fmi3UpdateDiscreteStates);
    if (!discreteStatesNeedUpdate || !terminateSimulation || !nominalsOfContinuousStatesChanged ||
        !valuesOfContinuousStatesChanged || !nextEventTimeDefined || !nextEventTime) {
        END(instance_fail(instance, STATUS_ERROR, "an output argument is NULL"));
    }
    int status = instance_update_discrete_states(instance);
    *discreteStatesNeedUpdate = fmi3False;
    *terminateSimulation = fmi3False;
    *nominalsOfContinuousStatesChanged = fmi3False;
    *valuesOfContinuousStatesChanged = fmi3False;
    *nextEventTimeDefined = fmi3False;
    *nextEventTime = 0.0;
    END(status);
}

fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance c, size_t *nContinuousStates) {
    BEGIN(fmi3GetNumberOfContinuousStates);
    END(instance_count(instance, nContinuousStates, instance->slave.nx));
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance c, size_t *nEventIndicators) {
    BEGIN(fmi3GetNumberOfEventIndicators);
    END(instance_count(instance, nEventIndicators, instance->slave.nz));
}

/* --- what these FMUs do not offer ------------------------------------------------------------------------- */

#define NO_EVENT_MODE "hasEventMode is false"
#define NO_STRUCTURAL_PARAMETERS "these FMUs have no structural parameters"
#define NO_DEPENDENCIES "providesPerElementDependencies is false; see ModelStructure"
#define NO_CLOCKS "these FMUs have no clocks"

/* These FMUs have no clocks: functions.h allows these two in no state, so BEGIN refuses every call. */
UNSUPPORTED(fmi3GetClock, NO_CLOCKS, const fmi3ValueReference valueReferences[], size_t nValueReferences,
            fmi3Clock values[])
UNSUPPORTED(fmi3SetClock, NO_CLOCKS, const fmi3ValueReference valueReferences[], size_t nValueReferences,
            const fmi3Clock values[])

/* The functions without arguments but the instance. */
#define UNSUPPORTED_CALL(F, why)                                                                               \
    fmi3Status F(fmi3Instance c) {                                                                             \
        BEGIN(F);                                                                                              \
        END(instance_unsupported(instance, why));                                                              \
    }

UNSUPPORTED_CALL(fmi3EnterStepMode, NO_EVENT_MODE)
UNSUPPORTED_CALL(fmi3EnterConfigurationMode, NO_STRUCTURAL_PARAMETERS)
UNSUPPORTED_CALL(fmi3ExitConfigurationMode, NO_STRUCTURAL_PARAMETERS)
UNSUPPORTED_CALL(fmi3EvaluateDiscreteStates, NO_EVENT_MODE)
UNSUPPORTED(fmi3GetNumberOfVariableDependencies, NO_DEPENDENCIES, fmi3ValueReference valueReference,
            size_t *nDependencies)
UNSUPPORTED(fmi3GetVariableDependencies, NO_DEPENDENCIES, fmi3ValueReference dependent,
            size_t elementIndicesOfDependent[], fmi3ValueReference independents[],
            size_t elementIndicesOfIndependents[], fmi3DependencyKind dependencyKinds[], size_t nDependencies)
UNSUPPORTED(fmi3GetDirectionalDerivative, "providesDirectionalDerivatives is false", const fmi3ValueReference unknowns[],
            size_t nUnknowns, const fmi3ValueReference knowns[], size_t nKnowns, const fmi3Float64 seed[], size_t nSeed,
            fmi3Float64 sensitivity[], size_t nSensitivity)
UNSUPPORTED(fmi3GetAdjointDerivative, "providesAdjointDerivatives is false", const fmi3ValueReference unknowns[],
            size_t nUnknowns, const fmi3ValueReference knowns[], size_t nKnowns, const fmi3Float64 seed[], size_t nSeed,
            fmi3Float64 sensitivity[], size_t nSensitivity)
UNSUPPORTED(fmi3GetOutputDerivatives, "maxOutputDerivativeOrder is 0", const fmi3ValueReference valueReferences[],
            size_t nValueReferences, const fmi3Int32 orders[], fmi3Float64 values[], size_t nValues)
UNSUPPORTED(fmi3GetIntervalDecimal, NO_CLOCKS, const fmi3ValueReference valueReferences[], size_t nValueReferences,
            fmi3Float64 intervals[], fmi3IntervalQualifier qualifiers[])
UNSUPPORTED(fmi3GetIntervalFraction, NO_CLOCKS, const fmi3ValueReference valueReferences[], size_t nValueReferences,
            fmi3UInt64 counters[], fmi3UInt64 resolutions[], fmi3IntervalQualifier qualifiers[])
UNSUPPORTED(fmi3GetShiftDecimal, NO_CLOCKS, const fmi3ValueReference valueReferences[], size_t nValueReferences,
            fmi3Float64 shifts[])
UNSUPPORTED(fmi3GetShiftFraction, NO_CLOCKS, const fmi3ValueReference valueReferences[], size_t nValueReferences,
            fmi3UInt64 counters[], fmi3UInt64 resolutions[])
UNSUPPORTED(fmi3SetIntervalDecimal, NO_CLOCKS, const fmi3ValueReference valueReferences[], size_t nValueReferences,
            const fmi3Float64 intervals[])
UNSUPPORTED(fmi3SetIntervalFraction, NO_CLOCKS, const fmi3ValueReference valueReferences[], size_t nValueReferences,
            const fmi3UInt64 counters[], const fmi3UInt64 resolutions[])
UNSUPPORTED(fmi3SetShiftDecimal, NO_CLOCKS, const fmi3ValueReference valueReferences[], size_t nValueReferences,
            const fmi3Float64 shifts[])
UNSUPPORTED(fmi3SetShiftFraction, NO_CLOCKS, const fmi3ValueReference valueReferences[], size_t nValueReferences,
            const fmi3UInt64 counters[], const fmi3UInt64 resolutions[])
UNSUPPORTED(fmi3ActivateModelPartition, "a function of scheduled execution; these FMUs do not offer it",
            fmi3ValueReference clockReference, fmi3Float64 activationTime)
