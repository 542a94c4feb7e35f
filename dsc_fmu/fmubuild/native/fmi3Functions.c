/* The FMI 3.0 API of every dsc-fmu FMU, co-simulation and model exchange: each call guarded by the
   interface and the states FMI 3.0.2 (sections 2.3, 3.2 and 4.2) allows it in, then handed to
   instance.c; every fmi3Error moves the instance to Terminated. No event mode in co-simulation, no
   scheduled execution, no clocks: those functions refuse with a message. Nothing returns fmi3Fatal. */

#include <math.h>
#include <stdio.h>

#include "fmi3Functions.h"
#include "instance.h"

/* The states each function is allowed in (FMI 3.0 has no error state: an error leads to Terminated). */
#define MASK_fmi3SetDebugLogging ANY_STATE
#define MASK_fmi3Reset ANY_STATE
#define MASK_fmi3EnterInitializationMode Instantiated
#define MASK_fmi3ExitInitializationMode InitializationMode
#define MASK_fmi3Terminate (StepMode | EventMode | ContinuousTimeMode)
#define MASK_fmi3DoStep (CS_ONLY | StepMode)
#define MASK_GET (Instantiated | InitializationMode | StepMode | EventMode | ContinuousTimeMode | Terminated)
#define MASK_SET (Instantiated | InitializationMode | StepMode | EventMode)
#define MASK_SET_FLOAT (MASK_SET | ContinuousTimeMode)
#define CLOCKS 0 /* clocks are read and set in event mode, which these FMUs do not have */
#define MASK_fmi3GetFMUState ANY_STATE
#define MASK_fmi3SetFMUState ANY_STATE
#define MASK_fmi3FreeFMUState ANY_STATE
#define MASK_fmi3SerializedFMUStateSize ANY_STATE
#define MASK_fmi3SerializeFMUState ANY_STATE
#define MASK_fmi3DeserializeFMUState ANY_STATE
#define MASK_fmi3EnterEventMode (ME_ONLY | ContinuousTimeMode)
#define MASK_fmi3UpdateDiscreteStates (ME_ONLY | EventMode)
#define MASK_fmi3EnterContinuousTimeMode (ME_ONLY | EventMode)
#define MASK_fmi3CompletedIntegratorStep (ME_ONLY | ContinuousTimeMode)
#define MASK_fmi3SetTime (ME_ONLY | ContinuousTimeMode)
#define MASK_fmi3SetContinuousStates (ME_ONLY | ContinuousTimeMode)
#define MASK_ME_GET (ME_ONLY | InitializationMode | EventMode | ContinuousTimeMode | Terminated)
#define MASK_fmi3GetContinuousStateDerivatives MASK_ME_GET
#define MASK_fmi3GetEventIndicators MASK_ME_GET
#define MASK_fmi3GetContinuousStates MASK_ME_GET
#define MASK_fmi3GetNominalsOfContinuousStates MASK_ME_GET
#define MASK_fmi3GetNumberOfContinuousStates (ME_ONLY | ANY_STATE)
#define MASK_fmi3GetNumberOfEventIndicators (ME_ONLY | ANY_STATE)

typedef struct {
    Instance base;
    fmi3InstanceEnvironment environment;
    fmi3LogMessageCallback logMessage;
} Fmi3Instance;

/* A refused call returns fmi3Error; `mask`: the states the function is allowed in. */
#define BEGIN_MASK(F, mask)                                                                                          \
    Instance *instance = (Instance *)c;                                                                              \
    if (instance_refused(instance, #F, mask)) return fmi3Error

/* The function's name and mask from one token. */
#define BEGIN(F) BEGIN_MASK(F, MASK_##F)

/* The call's status; fmi3Error moves the instance to Terminated. */
#define END(call) return (fmi3Status)instance_status(instance, (call))

static void host_log(Instance *instance, int status, const char *category, const char *message) {
    Fmi3Instance *host = (Fmi3Instance *)instance;
    if (host->logMessage) host->logMessage(host->environment, (fmi3Status)status, category, message);
}

/* With loggingOn = fmi3False, or a category switched off, logMessage is never called (FMI 3.0.2, 2.3.1). */
static const Standard FMI3 = {
    {{"get_float64", "get_int32", "get_boolean"}, {"set_float64", "set_int32", "set_boolean"},
     {"Float64", "Int32", "Boolean", "String"}},
    Terminated, StepMode, 0, host_log,
};

/* --- inquiry, logging, creation ------------------------------------------------------------------------ */

const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance c, fmi3Boolean loggingOn, size_t nCategories, const fmi3String categories[]) {
    BEGIN(fmi3SetDebugLogging);
    END(instance_set_logging(instance, "fmi3SetDebugLogging", loggingOn, nCategories, categories));
}

static fmi3Instance refuse_instantiation(fmi3InstanceEnvironment environment, fmi3LogMessageCallback logMessage,
                                         fmi3Boolean loggingOn, const char *why) {
    if (logMessage && loggingOn) logMessage(environment, fmi3Error, "logStatusError", why);
    return NULL;
}

/* An instance of either interface, named `function` in messages; NULL after logging why. */
static fmi3Instance instantiate(const char *function, int model_exchange, fmi3String instanceName,
                                fmi3String instantiationToken, fmi3String resourcePath, fmi3Boolean visible,
                                fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment,
                                fmi3LogMessageCallback logMessage) {
    char why[256];
    if (!instanceName || !*instanceName) {
        snprintf(why, sizeof why, "%s: the instance name is missing or empty", function);
        return refuse_instantiation(instanceEnvironment, logMessage, loggingOn, why);
    }
    Fmi3Instance *instance = (Fmi3Instance *)instance_alloc(sizeof(Fmi3Instance), instanceName, loggingOn,
                                                            model_exchange, &FMI3);
    if (!instance) {
        snprintf(why, sizeof why, "%s: out of memory", function);
        return refuse_instantiation(instanceEnvironment, logMessage, loggingOn, why);
    }
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
        return refuse_instantiation(instanceEnvironment, logMessage, loggingOn,
                                    "fmi3InstantiateCoSimulation: eventModeUsed is not supported (hasEventMode is false)");
    }
    if (nRequiredIntermediateVariables > 0) {
        return refuse_instantiation(instanceEnvironment, logMessage, loggingOn,
                                    "fmi3InstantiateCoSimulation: these FMUs provide no intermediate variables");
    }
    return instantiate("fmi3InstantiateCoSimulation", 0, instanceName, instantiationToken, resourcePath, visible,
                       loggingOn, instanceEnvironment, logMessage);
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage) {
    return instantiate("fmi3InstantiateModelExchange", 1, instanceName, instantiationToken, resourcePath, visible,
                       loggingOn, instanceEnvironment, logMessage);
}

fmi3Instance fmi3InstantiateScheduledExecution(fmi3String instanceName, fmi3String instantiationToken,
                                               fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                               fmi3InstanceEnvironment instanceEnvironment,
                                               fmi3LogMessageCallback logMessage, fmi3ClockUpdateCallback clockUpdate,
                                               fmi3LockPreemptionCallback lockPreemption,
                                               fmi3UnlockPreemptionCallback unlockPreemption) {
    return refuse_instantiation(instanceEnvironment, logMessage, loggingOn,
                                "fmi3InstantiateScheduledExecution: these FMUs are co-simulation FMUs only");
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

fmi3Status fmi3ExitInitializationMode(fmi3Instance c) {
    BEGIN(fmi3ExitInitializationMode);
    END(instance_exit_initialization(instance));
}

fmi3Status fmi3Terminate(fmi3Instance c) {
    BEGIN(fmi3Terminate);
    END(instance_call(instance, "terminate", 0, NULL, NULL, Terminated));
}

fmi3Status fmi3Reset(fmi3Instance c) {
    BEGIN(fmi3Reset);
    END(instance_reset(instance));
}

fmi3Status fmi3DoStep(fmi3Instance c, fmi3Float64 currentCommunicationPoint, fmi3Float64 communicationStepSize,
                      fmi3Boolean noSetFMUStatePriorToCurrentPoint, fmi3Boolean *eventHandlingNeeded,
                      fmi3Boolean *terminateSimulation, fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime) {
    BEGIN(fmi3DoStep);
    if (!eventHandlingNeeded || !terminateSimulation || !earlyReturn || !lastSuccessfulTime) {
        instance_log(instance, STATUS_ERROR, "%s: fmi3DoStep: an output argument is NULL", instance->name);
        END(STATUS_ERROR);
    }
    int status = instance_do_step(instance, "fmi3DoStep", currentCommunicationPoint, communicationStepSize);
    *eventHandlingNeeded = fmi3False;
    *terminateSimulation = fmi3False;
    *earlyReturn = fmi3False;
    *lastSuccessfulTime = currentCommunicationPoint + (status == fmi3OK ? communicationStepSize : 0.0);
    END(status);
}

/* --- values ------------------------------------------------------------------------------------------- */

#define GETTER(function, type, ctype, cvalue)                                                                          \
    fmi3Status function(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, cvalue values[], size_t nValues) { \
        BEGIN_MASK(function, MASK_GET);                                                                              \
        END(instance_get(instance, #function, type, vr, nvr, values, nValues, ctype));                               \
    }

#define SETTER(function, type, ctype, cvalue, mask)                                                                    \
    fmi3Status function(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const cvalue values[],            \
                        size_t nValues) {                                                                            \
        BEGIN_MASK(function, mask);                                                                                  \
        END(instance_set(instance, #function, type, vr, nvr, values, nValues, ctype));                               \
    }

/* A type these FMUs have no variables of: only an empty call succeeds. */
#define ABSENT(function, mask, type_name, ...)                                                                         \
    fmi3Status function(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, __VA_ARGS__) {                    \
        BEGIN_MASK(function, mask);                                                                                  \
        END(instance_no_variables_of(instance, #function, type_name, vr, nvr));                                      \
    }

GETTER(fmi3GetFloat64, TYPE_REAL, C_DOUBLE, fmi3Float64)
GETTER(fmi3GetInt32, TYPE_INTEGER, C_INT32, fmi3Int32)
GETTER(fmi3GetBoolean, TYPE_BOOLEAN, C_BOOL_BYTE, fmi3Boolean)
SETTER(fmi3SetFloat64, TYPE_REAL, C_DOUBLE, fmi3Float64, MASK_SET_FLOAT)
SETTER(fmi3SetInt32, TYPE_INTEGER, C_INT32, fmi3Int32, MASK_SET)
SETTER(fmi3SetBoolean, TYPE_BOOLEAN, C_BOOL_BYTE, fmi3Boolean, MASK_SET)

ABSENT(fmi3GetFloat32, MASK_GET, "Float32", fmi3Float32 values[], size_t nValues)
ABSENT(fmi3GetInt8, MASK_GET, "Int8", fmi3Int8 values[], size_t nValues)
ABSENT(fmi3GetUInt8, MASK_GET, "UInt8", fmi3UInt8 values[], size_t nValues)
ABSENT(fmi3GetInt16, MASK_GET, "Int16", fmi3Int16 values[], size_t nValues)
ABSENT(fmi3GetUInt16, MASK_GET, "UInt16", fmi3UInt16 values[], size_t nValues)
ABSENT(fmi3GetUInt32, MASK_GET, "UInt32", fmi3UInt32 values[], size_t nValues)
ABSENT(fmi3GetInt64, MASK_GET, "Int64", fmi3Int64 values[], size_t nValues)
ABSENT(fmi3GetUInt64, MASK_GET, "UInt64", fmi3UInt64 values[], size_t nValues)
ABSENT(fmi3GetString, MASK_GET, "String", fmi3String values[], size_t nValues)
ABSENT(fmi3GetBinary, MASK_GET, "Binary", size_t valueSizes[], fmi3Binary values[], size_t nValues)
ABSENT(fmi3GetClock, CLOCKS, "Clock", fmi3Clock values[])
ABSENT(fmi3SetFloat32, MASK_SET_FLOAT, "Float32", const fmi3Float32 values[], size_t nValues)
ABSENT(fmi3SetInt8, MASK_SET, "Int8", const fmi3Int8 values[], size_t nValues)
ABSENT(fmi3SetUInt8, MASK_SET, "UInt8", const fmi3UInt8 values[], size_t nValues)
ABSENT(fmi3SetInt16, MASK_SET, "Int16", const fmi3Int16 values[], size_t nValues)
ABSENT(fmi3SetUInt16, MASK_SET, "UInt16", const fmi3UInt16 values[], size_t nValues)
ABSENT(fmi3SetUInt32, MASK_SET, "UInt32", const fmi3UInt32 values[], size_t nValues)
ABSENT(fmi3SetInt64, MASK_SET, "Int64", const fmi3Int64 values[], size_t nValues)
ABSENT(fmi3SetUInt64, MASK_SET, "UInt64", const fmi3UInt64 values[], size_t nValues)
ABSENT(fmi3SetString, MASK_SET, "String", const fmi3String values[], size_t nValues)
ABSENT(fmi3SetBinary, MASK_SET, "Binary", const size_t valueSizes[], const fmi3Binary values[], size_t nValues)
ABSENT(fmi3SetClock, CLOCKS, "Clock", const fmi3Clock values[])

/* --- FMU states ------------------------------------------------------------------------------------------- */

FMU_STATE_FUNCTIONS(fmi3Status, fmi3Instance, fmi3FMUState, fmi3Byte, fmi3GetFMUState, fmi3SetFMUState,
                    fmi3FreeFMUState, fmi3SerializedFMUStateSize, fmi3SerializeFMUState, fmi3DeserializeFMUState)

/* --- what these FMUs do not offer ------------------------------------------------------------------------- */

/* A function of a capability these FMUs do not declare: fmi3Error with `why`, in any state. */
#define UNSUPPORTED(function, why, ...)                                                                               \
    fmi3Status function(fmi3Instance c, __VA_ARGS__) {                                                               \
        BEGIN_MASK(function, ANY_STATE);                                                                             \
        END(instance_unsupported(instance, #function, why));                                                         \
    }

#define NO_EVENT_MODE "hasEventMode is false"
#define NO_CLOCKS "these FMUs have no clocks"

/* --- model exchange ------------------------------------------------------------------------------------ */

MODEL_EXCHANGE_FUNCTIONS(fmi3Status, fmi3Instance, fmi3Boolean, fmi3Float64, fmi3EnterEventMode,
                         fmi3EnterContinuousTimeMode, fmi3CompletedIntegratorStep, fmi3SetTime, fmi3SetContinuousStates,
                         fmi3GetContinuousStateDerivatives, fmi3GetEventIndicators, fmi3GetContinuousStates,
                         fmi3GetNominalsOfContinuousStates)

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance c, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation, fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged, fmi3Boolean *nextEventTimeDefined,
                                    fmi3Float64 *nextEventTime) {
    BEGIN(fmi3UpdateDiscreteStates);
    if (!discreteStatesNeedUpdate || !terminateSimulation || !nominalsOfContinuousStatesChanged ||
        !valuesOfContinuousStatesChanged || !nextEventTimeDefined || !nextEventTime) {
        instance_log(instance, STATUS_ERROR, "%s: fmi3UpdateDiscreteStates: an output argument is NULL", instance->name);
        END(STATUS_ERROR);
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
    END(instance_count(instance, "fmi3GetNumberOfContinuousStates", nContinuousStates, instance->slave.nx));
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance c, size_t *nEventIndicators) {
    BEGIN(fmi3GetNumberOfEventIndicators);
    END(instance_count(instance, "fmi3GetNumberOfEventIndicators", nEventIndicators, instance->slave.nz));
}

/* --- co-simulation with event mode, configuration ------------------------------------------------------------ */

fmi3Status fmi3EnterStepMode(fmi3Instance c) {
    BEGIN_MASK(fmi3EnterStepMode, ANY_STATE);
    END(instance_unsupported(instance, "fmi3EnterStepMode", NO_EVENT_MODE));
}

fmi3Status fmi3EnterConfigurationMode(fmi3Instance c) {
    BEGIN_MASK(fmi3EnterConfigurationMode, ANY_STATE);
    END(instance_unsupported(instance, "fmi3EnterConfigurationMode", "these FMUs have no structural parameters"));
}

fmi3Status fmi3ExitConfigurationMode(fmi3Instance c) {
    BEGIN_MASK(fmi3ExitConfigurationMode, ANY_STATE);
    END(instance_unsupported(instance, "fmi3ExitConfigurationMode", "these FMUs have no structural parameters"));
}

fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance c) {
    BEGIN_MASK(fmi3EvaluateDiscreteStates, ANY_STATE);
    END(instance_unsupported(instance, "fmi3EvaluateDiscreteStates", NO_EVENT_MODE));
}


UNSUPPORTED(fmi3GetNumberOfVariableDependencies, "providesPerElementDependencies is false; see ModelStructure",
            fmi3ValueReference valueReference, size_t *nDependencies)
UNSUPPORTED(fmi3GetVariableDependencies, "providesPerElementDependencies is false; see ModelStructure",
            fmi3ValueReference dependent, size_t elementIndicesOfDependent[], fmi3ValueReference independents[],
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
