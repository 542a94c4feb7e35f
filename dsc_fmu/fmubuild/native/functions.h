/* Every FMI function that checks its instance: name, FMI version, interface (CS co-simulation, ME model
   exchange, CS_ME both) and the states it is allowed in, from the standards' state tables (FMI 2.0.4,
   sections 3.2.3 and 4.2.4; FMI 3.0.2, sections 2.3, 3.2 and 4.2). A function of the other interface is
   refused whatever the state; fmi2CancelStep is allowed in none (fmi2DoStep is synchronous).

   BEGIN(F) (adapter.h) looks F up here (FN_<name>); its name is the one in every message of the call.
   Not here: the functions that take no instance (fmiGetVersion, the instantiation functions) or accept
   any (fmiFreeInstance). */

#ifndef DSC_FUNCTIONS_H
#define DSC_FUNCTIONS_H

/* FMI 2.0: no stepInProgress, stepCanceled (fmi2DoStep is synchronous). */
#define FMI2_GET (InitializationMode | StepMode | StepFailed | EventMode | ContinuousTimeMode | Terminated | Error)
#define FMI2_SET (Instantiated | InitializationMode | StepMode | EventMode)
#define FMI2_STATUS (StepMode | StepFailed | Terminated)
#define FMI2_VECTOR (InitializationMode | EventMode | ContinuousTimeMode | Terminated | Error)
/* fmi2GetDirectionalDerivative: the getters' states (FMI 2.0.4, 3.2.3: initialization, event, continuous-time
   mode, terminated, and error "always, but retrieved values are usable for debugging only"; 4.2.4:
   initialization mode, stepComplete, terminated, stepFailed "always, but if status is other than
   fmi2Terminated, retrieved values are useable for debugging only", error as above). */
#define FMI2_DERIVATIVE FMI2_GET
/* FMI 3.0: no error state (an error leads to Terminated), no event mode in co-simulation, no clocks. */
#define FMI3_GET (Instantiated | InitializationMode | StepMode | EventMode | ContinuousTimeMode | Terminated)
#define FMI3_SET (Instantiated | InitializationMode | StepMode | EventMode)
#define FMI3_SET_FLOAT (FMI3_SET | ContinuousTimeMode)
/* fmi2SetReal and fmi3SetFloat64 also set continuous states in model exchange's event and continuous-time
   mode: which variables a set may change is checked per value reference (instance.c, not_settable). */
#define FMI3_VECTOR (InitializationMode | EventMode | ContinuousTimeMode | Terminated)
/* fmi3GetDirectionalDerivative, fmi3GetAdjointDerivative: among the allowed calls of Initialization Mode, Event
   Mode and Terminated (FMI 3.0.2, 2.3), Continuous-Time Mode (3.2) and Step Mode (4.2); not of Instantiated. */
#define FMI3_DERIVATIVES (InitializationMode | StepMode | EventMode | ContinuousTimeMode | Terminated)

/* The getter and setter of the FMI 3.0 type T. */
#define FMI3_VALUES(FUNCTION, T, set) FUNCTION(fmi3Get##T, 3, CS_ME, FMI3_GET) FUNCTION(fmi3Set##T, 3, CS_ME, set)

#define FMI_FUNCTIONS(FUNCTION)                                                                                 \
    FUNCTION(fmi2SetDebugLogging, 2, CS_ME, ANY_STATE)                                                          \
    FUNCTION(fmi2SetupExperiment, 2, CS_ME, Instantiated)                                                      \
    FUNCTION(fmi2EnterInitializationMode, 2, CS_ME, Instantiated)                                              \
    FUNCTION(fmi2ExitInitializationMode, 2, CS_ME, InitializationMode)                                         \
    FUNCTION(fmi2Terminate, 2, CS_ME, StepMode | StepFailed | EventMode | ContinuousTimeMode)                  \
    FUNCTION(fmi2Reset, 2, CS_ME, ANY_STATE)                                                                   \
    FUNCTION(fmi2GetReal, 2, CS_ME, FMI2_GET) FUNCTION(fmi2SetReal, 2, CS_ME, FMI2_SET | ContinuousTimeMode)   \
    FUNCTION(fmi2GetInteger, 2, CS_ME, FMI2_GET) FUNCTION(fmi2SetInteger, 2, CS_ME, FMI2_SET)                  \
    FUNCTION(fmi2GetBoolean, 2, CS_ME, FMI2_GET) FUNCTION(fmi2SetBoolean, 2, CS_ME, FMI2_SET)                  \
    FUNCTION(fmi2GetString, 2, CS_ME, FMI2_GET) FUNCTION(fmi2SetString, 2, CS_ME, FMI2_SET)                    \
    FUNCTION(fmi2GetFMUstate, 2, CS_ME, ANY_STATE) FUNCTION(fmi2SetFMUstate, 2, CS_ME, ANY_STATE)              \
    FUNCTION(fmi2FreeFMUstate, 2, CS_ME, ANY_STATE) FUNCTION(fmi2SerializedFMUstateSize, 2, CS_ME, ANY_STATE)  \
    FUNCTION(fmi2SerializeFMUstate, 2, CS_ME, ANY_STATE) FUNCTION(fmi2DeSerializeFMUstate, 2, CS_ME, ANY_STATE) \
    FUNCTION(fmi2GetDirectionalDerivative, 2, CS_ME, FMI2_DERIVATIVE)                                          \
    FUNCTION(fmi2EnterEventMode, 2, ME, EventMode | ContinuousTimeMode)                                        \
    FUNCTION(fmi2NewDiscreteStates, 2, ME, EventMode)                                                          \
    FUNCTION(fmi2EnterContinuousTimeMode, 2, ME, EventMode)                                                    \
    FUNCTION(fmi2CompletedIntegratorStep, 2, ME, ContinuousTimeMode)                                           \
    FUNCTION(fmi2SetTime, 2, ME, EventMode | ContinuousTimeMode)                                               \
    FUNCTION(fmi2SetContinuousStates, 2, ME, ContinuousTimeMode)                                               \
    FUNCTION(fmi2GetDerivatives, 2, ME, FMI2_VECTOR) FUNCTION(fmi2GetEventIndicators, 2, ME, FMI2_VECTOR)      \
    FUNCTION(fmi2GetContinuousStates, 2, ME, FMI2_VECTOR)                                                      \
    FUNCTION(fmi2GetNominalsOfContinuousStates, 2, ME, FMI2_VECTOR | Instantiated)                             \
    FUNCTION(fmi2SetRealInputDerivatives, 2, CS, Instantiated | InitializationMode | StepMode)                 \
    FUNCTION(fmi2GetRealOutputDerivatives, 2, CS, StepMode | StepFailed | Terminated | Error)                  \
    FUNCTION(fmi2DoStep, 2, CS, StepMode) FUNCTION(fmi2CancelStep, 2, CS, 0)                                   \
    FUNCTION(fmi2GetStatus, 2, CS, FMI2_STATUS) FUNCTION(fmi2GetRealStatus, 2, CS, FMI2_STATUS)                \
    FUNCTION(fmi2GetIntegerStatus, 2, CS, FMI2_STATUS) FUNCTION(fmi2GetBooleanStatus, 2, CS, FMI2_STATUS)      \
    FUNCTION(fmi2GetStringStatus, 2, CS, FMI2_STATUS)                                                          \
    FUNCTION(fmi3SetDebugLogging, 3, CS_ME, ANY_STATE)                                                          \
    FUNCTION(fmi3EnterInitializationMode, 3, CS_ME, Instantiated)                                              \
    FUNCTION(fmi3ExitInitializationMode, 3, CS_ME, InitializationMode)                                         \
    FUNCTION(fmi3Terminate, 3, CS_ME, StepMode | EventMode | ContinuousTimeMode)                               \
    FUNCTION(fmi3Reset, 3, CS_ME, ANY_STATE)                                                                   \
    FMI3_VALUES(FUNCTION, Float32, FMI3_SET_FLOAT) FMI3_VALUES(FUNCTION, Float64, FMI3_SET_FLOAT)              \
    FMI3_VALUES(FUNCTION, Int8, FMI3_SET) FMI3_VALUES(FUNCTION, UInt8, FMI3_SET)                               \
    FMI3_VALUES(FUNCTION, Int16, FMI3_SET) FMI3_VALUES(FUNCTION, UInt16, FMI3_SET)                             \
    FMI3_VALUES(FUNCTION, Int32, FMI3_SET) FMI3_VALUES(FUNCTION, UInt32, FMI3_SET)                             \
    FMI3_VALUES(FUNCTION, Int64, FMI3_SET) FMI3_VALUES(FUNCTION, UInt64, FMI3_SET)                             \
    FMI3_VALUES(FUNCTION, Boolean, FMI3_SET) FMI3_VALUES(FUNCTION, String, FMI3_SET)                           \
    FMI3_VALUES(FUNCTION, Binary, FMI3_SET)                                                                    \
    FUNCTION(fmi3GetFMUState, 3, CS_ME, ANY_STATE) FUNCTION(fmi3SetFMUState, 3, CS_ME, ANY_STATE)              \
    FUNCTION(fmi3FreeFMUState, 3, CS_ME, ANY_STATE) FUNCTION(fmi3SerializedFMUStateSize, 3, CS_ME, ANY_STATE)  \
    FUNCTION(fmi3SerializeFMUState, 3, CS_ME, ANY_STATE) FUNCTION(fmi3DeserializeFMUState, 3, CS_ME, ANY_STATE) \
    FUNCTION(fmi3EnterEventMode, 3, ME, ContinuousTimeMode)                                                    \
    FUNCTION(fmi3UpdateDiscreteStates, 3, ME, EventMode)                                                       \
    FUNCTION(fmi3EnterContinuousTimeMode, 3, ME, EventMode)                                                    \
    FUNCTION(fmi3CompletedIntegratorStep, 3, ME, ContinuousTimeMode)                                           \
    FUNCTION(fmi3SetTime, 3, ME, ContinuousTimeMode) FUNCTION(fmi3SetContinuousStates, 3, ME, ContinuousTimeMode) \
    FUNCTION(fmi3GetContinuousStateDerivatives, 3, ME, FMI3_VECTOR)                                            \
    FUNCTION(fmi3GetEventIndicators, 3, ME, FMI3_VECTOR) FUNCTION(fmi3GetContinuousStates, 3, ME, FMI3_VECTOR) \
    FUNCTION(fmi3GetNominalsOfContinuousStates, 3, ME, FMI3_VECTOR)                                            \
    FUNCTION(fmi3GetNumberOfContinuousStates, 3, ME, ANY_STATE)                                                \
    FUNCTION(fmi3GetNumberOfEventIndicators, 3, ME, ANY_STATE)                                                 \
    FUNCTION(fmi3DoStep, 3, CS, StepMode)                                                                      \
    FUNCTION(fmi3GetDirectionalDerivative, 3, CS_ME, FMI3_DERIVATIVES)                                         \
    FUNCTION(fmi3GetAdjointDerivative, 3, CS_ME, FMI3_DERIVATIVES)                                             \
    FMI3_UNSUPPORTED(FUNCTION)

/* The FMI 3.0 functions of capabilities these FMUs do not declare: refused with why in any state. */
#define FMI3_UNSUPPORTED(FUNCTION)                                                                              \
    FUNCTION(fmi3EnterStepMode, 3, CS_ME, ANY_STATE) FUNCTION(fmi3EvaluateDiscreteStates, 3, CS_ME, ANY_STATE) \
    FUNCTION(fmi3EnterConfigurationMode, 3, CS_ME, ANY_STATE)                                                  \
    FUNCTION(fmi3ExitConfigurationMode, 3, CS_ME, ANY_STATE)                                                   \
    FUNCTION(fmi3GetNumberOfVariableDependencies, 3, CS_ME, ANY_STATE)                                         \
    FUNCTION(fmi3GetVariableDependencies, 3, CS_ME, ANY_STATE)                                                 \
    FUNCTION(fmi3GetOutputDerivatives, 3, CS_ME, ANY_STATE)                                                    \
    FUNCTION(fmi3GetClock, 3, CS_ME, ANY_STATE) FUNCTION(fmi3SetClock, 3, CS_ME, ANY_STATE)                    \
    FUNCTION(fmi3GetIntervalDecimal, 3, CS_ME, ANY_STATE) FUNCTION(fmi3SetIntervalDecimal, 3, CS_ME, ANY_STATE) \
    FUNCTION(fmi3GetIntervalFraction, 3, CS_ME, ANY_STATE) FUNCTION(fmi3SetIntervalFraction, 3, CS_ME, ANY_STATE) \
    FUNCTION(fmi3GetShiftDecimal, 3, CS_ME, ANY_STATE) FUNCTION(fmi3SetShiftDecimal, 3, CS_ME, ANY_STATE)      \
    FUNCTION(fmi3GetShiftFraction, 3, CS_ME, ANY_STATE) FUNCTION(fmi3SetShiftFraction, 3, CS_ME, ANY_STATE)    \
    FUNCTION(fmi3ActivateModelPartition, 3, CS_ME, ANY_STATE)

#define FUNCTION_ID(name, version, interface, states) FN_##name,
typedef enum { FMI_FUNCTIONS(FUNCTION_ID) } Function;
#undef FUNCTION_ID

/* VERSION_<name>: the FMI version of each function, which BEGIN checks at compile time. */
#define FUNCTION_VERSION(name, version, interface, states) VERSION_##name = version,
enum { FMI_FUNCTIONS(FUNCTION_VERSION) };
#undef FUNCTION_VERSION

#endif
