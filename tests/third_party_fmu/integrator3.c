/*
 * Integrator3: the Integrator test model as an FMI 3.0 co-simulation FMU,
 * written in plain C for the master's tests.
 *
 *   dy/dt = k * u, integrated explicitly over each communication step:
 *       y <- y + k * u * h
 *   n_steps (Int32) counts the successful fmi3DoStep calls.
 *   fail_at >= 0: fmi3DoStep at a communication point t >= fail_at logs an
 *   error ("fail_at reached ...") and returns fmi3Error.
 *   stop_at >= 0: the fmi3DoStep that reaches t >= stop_at completes and
 *   sets terminateSimulation (the FMI 3 way to end the simulation).
 *   odd (Boolean output): n_steps is odd.
 *
 * Co-simulation only: fmi3InstantiateModelExchange and
 * fmi3InstantiateScheduledExecution return NULL; event mode, clocks, FMU
 * state and derivatives are not supported (their functions return
 * fmi3Error). Like the FMI 2 version it checks the instantiation token, the
 * calling sequence and that doStep starts where the previous one ended.
 *
 * Built by tests/third_party_fmu/build.py against fmpy's FMI headers, with
 * MODEL_GUID (the instantiationToken) defined on the compiler command line.
 */
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <math.h>

#include "fmi3Functions.h"

#ifndef MODEL_GUID
#error "compile with -DMODEL_GUID=\"{...}\" (the instantiationToken of modelDescription.xml)"
#endif

/* value references (see Integrator3.modelDescription.xml) */
#define VR_TIME     0
#define VR_U        1
#define VR_K        2
#define VR_Y        3
#define VR_FAIL_AT  4
#define VR_N_STEPS  5
#define VR_STOP_AT  6
#define VR_ODD      7

typedef enum { ST_INSTANTIATED, ST_INIT, ST_STEP, ST_TERMINATED, ST_ERROR } State;

typedef struct {
    char *name;
    fmi3InstanceEnvironment env;
    fmi3LogMessageCallback log;
    fmi3Boolean logging;
    State state;
    fmi3Float64 time;
    fmi3Float64 u, k, y, fail_at, stop_at;
    fmi3Int32 n_steps;
} Instance;

static const char *state_name(State s) {
    switch (s) {
    case ST_INSTANTIATED: return "instantiated";
    case ST_INIT: return "initialization mode";
    case ST_STEP: return "step mode";
    case ST_TERMINATED: return "terminated";
    default: return "error";
    }
}

static void log_message(Instance *c, fmi3Status status, const char *category, const char *fmt, ...) {
    char text[512];
    va_list ap;
    if (c == NULL || c->log == NULL) return;
    if (status == fmi3OK && !c->logging) return;  /* errors are always reported */
    va_start(ap, fmt);
    vsnprintf(text, sizeof text, fmt, ap);
    va_end(ap);
    c->log(c->env, status, category, text);
}

static fmi3Status fail(fmi3Instance instance, const char *function, const char *detail) {
    log_message((Instance *)instance, fmi3Error, "logStatusError", "%s: %s", function, detail);
    return fmi3Error;
}

#define IN(s) (1 << (s))
#define ANY (IN(ST_INSTANTIATED) | IN(ST_INIT) | IN(ST_STEP) | IN(ST_TERMINATED) | IN(ST_ERROR))

static int allowed(Instance *c, const char *function, int mask) {
    if (c == NULL) return 0;
    if (mask & (1 << c->state)) return 1;
    log_message(c, fmi3Error, "logStatusError", "%s must not be called in state '%s'",
                function, state_name(c->state));
    return 0;
}

static void set_defaults(Instance *c) {
    c->time = 0.0;
    c->u = 1.0;
    c->k = 2.0;
    c->y = 0.0;
    c->fail_at = -1.0;
    c->stop_at = -1.0;
    c->n_steps = 0;
}

static int scalars(Instance *c, const char *function, size_t nValueReferences, size_t nValues) {
    if (nValues == nValueReferences) return 1;
    log_message(c, fmi3Error, "logStatusError", "%s: all variables are scalars, but nValues = %u != "
                "nValueReferences = %u", function, (unsigned)nValues, (unsigned)nValueReferences);
    return 0;
}

/* ---------------------------------------------------------------- common */

const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[]) {
    Instance *c = (Instance *)instance;
    (void)nCategories; (void)categories;
    if (!allowed(c, "fmi3SetDebugLogging", ANY)) return fmi3Error;
    c->logging = loggingOn;
    return fmi3OK;
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage) {
    (void)instanceName; (void)instantiationToken; (void)resourcePath; (void)visible; (void)loggingOn;
    if (logMessage != NULL)
        logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                   "fmi3InstantiateModelExchange: Integrator3 supports co-simulation only");
    return NULL;
}

fmi3Instance fmi3InstantiateCoSimulation(fmi3String instanceName, fmi3String instantiationToken,
                                         fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                         fmi3Boolean eventModeUsed, fmi3Boolean earlyReturnAllowed,
                                         const fmi3ValueReference requiredIntermediateVariables[],
                                         size_t nRequiredIntermediateVariables,
                                         fmi3InstanceEnvironment instanceEnvironment,
                                         fmi3LogMessageCallback logMessage,
                                         fmi3IntermediateUpdateCallback intermediateUpdate) {
    Instance *c;
    (void)resourcePath; (void)visible; (void)earlyReturnAllowed; (void)requiredIntermediateVariables;
    (void)intermediateUpdate;
    if (instanceName == NULL || instanceName[0] == '\0') {
        if (logMessage) logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                                   "fmi3InstantiateCoSimulation: missing instance name");
        return NULL;
    }
    if (instantiationToken == NULL || strcmp(instantiationToken, MODEL_GUID) != 0) {
        if (logMessage) logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                                   "fmi3InstantiateCoSimulation: wrong instantiationToken");
        return NULL;
    }
    if (eventModeUsed || nRequiredIntermediateVariables > 0) {
        if (logMessage) logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                                   "fmi3InstantiateCoSimulation: event mode and intermediate variables "
                                   "are not supported");
        return NULL;
    }
    c = (Instance *)calloc(1, sizeof(Instance));
    if (c == NULL) return NULL;
    c->name = (char *)malloc(strlen(instanceName) + 1);
    if (c->name == NULL) {
        free(c);
        return NULL;
    }
    strcpy(c->name, instanceName);
    c->env = instanceEnvironment;
    c->log = logMessage;
    c->logging = loggingOn;
    c->state = ST_INSTANTIATED;
    set_defaults(c);
    log_message(c, fmi3OK, "logEvents", "fmi3InstantiateCoSimulation: instance %s created", instanceName);
    return c;
}

fmi3Instance fmi3InstantiateScheduledExecution(fmi3String instanceName, fmi3String instantiationToken,
                                               fmi3String resourcePath, fmi3Boolean visible,
                                               fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment,
                                               fmi3LogMessageCallback logMessage,
                                               fmi3ClockUpdateCallback clockUpdate,
                                               fmi3LockPreemptionCallback lockPreemption,
                                               fmi3UnlockPreemptionCallback unlockPreemption) {
    (void)instanceName; (void)instantiationToken; (void)resourcePath; (void)visible; (void)loggingOn;
    (void)clockUpdate; (void)lockPreemption; (void)unlockPreemption;
    if (logMessage != NULL)
        logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                   "fmi3InstantiateScheduledExecution: Integrator3 supports co-simulation only");
    return NULL;
}

void fmi3FreeInstance(fmi3Instance instance) {
    Instance *c = (Instance *)instance;
    if (c == NULL) return;
    free(c->name);
    free(c);
}

fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined, fmi3Float64 tolerance,
                                       fmi3Float64 startTime, fmi3Boolean stopTimeDefined, fmi3Float64 stopTime) {
    Instance *c = (Instance *)instance;
    (void)toleranceDefined; (void)tolerance;
    if (!allowed(c, "fmi3EnterInitializationMode", IN(ST_INSTANTIATED))) return fmi3Error;
    if (stopTimeDefined && stopTime < startTime) return fail(c, "fmi3EnterInitializationMode", "stopTime < startTime");
    c->time = startTime;
    c->state = ST_INIT;
    return fmi3OK;
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance instance) {
    Instance *c = (Instance *)instance;
    if (!allowed(c, "fmi3ExitInitializationMode", IN(ST_INIT))) return fmi3Error;
    c->state = ST_STEP;  /* no event mode: straight to step mode */
    return fmi3OK;
}

fmi3Status fmi3EnterEventMode(fmi3Instance instance) {
    return fail(instance, "fmi3EnterEventMode", "not supported (hasEventMode=false)");
}

fmi3Status fmi3Terminate(fmi3Instance instance) {
    Instance *c = (Instance *)instance;
    if (!allowed(c, "fmi3Terminate", IN(ST_INIT) | IN(ST_STEP) | IN(ST_ERROR))) return fmi3Error;
    c->state = ST_TERMINATED;
    return fmi3OK;
}

fmi3Status fmi3Reset(fmi3Instance instance) {
    Instance *c = (Instance *)instance;
    if (!allowed(c, "fmi3Reset", ANY)) return fmi3Error;
    set_defaults(c);
    c->state = ST_INSTANTIATED;
    return fmi3OK;
}

/* ------------------------------------------------------- get and set values */

fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, fmi3Float64 values[], size_t nValues) {
    Instance *c = (Instance *)instance;
    size_t i;
    if (!allowed(c, "fmi3GetFloat64", ANY)) return fmi3Error;
    if (!scalars(c, "fmi3GetFloat64", nValueReferences, nValues)) return fmi3Error;
    for (i = 0; i < nValueReferences; i++) {
        switch (valueReferences[i]) {
        case VR_TIME: values[i] = c->time; break;
        case VR_U: values[i] = c->u; break;
        case VR_K: values[i] = c->k; break;
        case VR_Y: values[i] = c->y; break;
        case VR_FAIL_AT: values[i] = c->fail_at; break;
        case VR_STOP_AT: values[i] = c->stop_at; break;
        default:
            log_message(c, fmi3Error, "logStatusError", "fmi3GetFloat64: unknown value reference %u",
                        (unsigned)valueReferences[i]);
            return fmi3Error;
        }
    }
    return fmi3OK;
}

fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, const fmi3Float64 values[], size_t nValues) {
    Instance *c = (Instance *)instance;
    size_t i;
    int before_init_end;
    if (!allowed(c, "fmi3SetFloat64", IN(ST_INSTANTIATED) | IN(ST_INIT) | IN(ST_STEP))) return fmi3Error;
    if (!scalars(c, "fmi3SetFloat64", nValueReferences, nValues)) return fmi3Error;
    before_init_end = c->state == ST_INSTANTIATED || c->state == ST_INIT;
    for (i = 0; i < nValueReferences; i++) {
        const fmi3ValueReference vr = valueReferences[i];
        switch (vr) {
        case VR_U:
            c->u = values[i];
            break;
        case VR_K:
        case VR_Y:
        case VR_FAIL_AT:
        case VR_STOP_AT:
            /* fixed parameters and the exact start value of y: only until initialization ends */
            if (!before_init_end) {
                log_message(c, fmi3Error, "logStatusError",
                            "fmi3SetFloat64: value reference %u can only be set before "
                            "fmi3ExitInitializationMode", (unsigned)vr);
                return fmi3Error;
            }
            if (vr == VR_K) c->k = values[i];
            else if (vr == VR_Y) c->y = values[i];
            else if (vr == VR_FAIL_AT) c->fail_at = values[i];
            else c->stop_at = values[i];
            break;
        case VR_TIME:
            return fail(c, "fmi3SetFloat64", "the independent variable time cannot be set");
        default:
            log_message(c, fmi3Error, "logStatusError", "fmi3SetFloat64: unknown value reference %u",
                        (unsigned)vr);
            return fmi3Error;
        }
    }
    return fmi3OK;
}

fmi3Status fmi3GetInt32(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                        size_t nValueReferences, fmi3Int32 values[], size_t nValues) {
    Instance *c = (Instance *)instance;
    size_t i;
    if (!allowed(c, "fmi3GetInt32", ANY)) return fmi3Error;
    if (!scalars(c, "fmi3GetInt32", nValueReferences, nValues)) return fmi3Error;
    for (i = 0; i < nValueReferences; i++) {
        if (valueReferences[i] != VR_N_STEPS) {
            log_message(c, fmi3Error, "logStatusError", "fmi3GetInt32: unknown value reference %u",
                        (unsigned)valueReferences[i]);
            return fmi3Error;
        }
        values[i] = c->n_steps;
    }
    return fmi3OK;
}

fmi3Status fmi3SetInt32(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                        size_t nValueReferences, const fmi3Int32 values[], size_t nValues) {
    Instance *c = (Instance *)instance;
    size_t i;
    if (!allowed(c, "fmi3SetInt32", IN(ST_INSTANTIATED) | IN(ST_INIT))) return fmi3Error;
    if (!scalars(c, "fmi3SetInt32", nValueReferences, nValues)) return fmi3Error;
    for (i = 0; i < nValueReferences; i++) {
        if (valueReferences[i] != VR_N_STEPS) {
            log_message(c, fmi3Error, "logStatusError", "fmi3SetInt32: unknown value reference %u",
                        (unsigned)valueReferences[i]);
            return fmi3Error;
        }
        c->n_steps = values[i];
    }
    return fmi3OK;
}

/* The model has no variables of the other types: any non-empty request is an error. */
#define NO_VARIABLES_OF_TYPE(FUNCTION, VALUE_TYPE)                                              \
    fmi3Status FUNCTION(fmi3Instance instance, const fmi3ValueReference valueReferences[],      \
                        size_t nValueReferences, VALUE_TYPE values[], size_t nValues) {        \
        (void)valueReferences; (void)values; (void)nValues;                                     \
        if (!allowed((Instance *)instance, #FUNCTION, ANY)) return fmi3Error;                   \
        if (nValueReferences == 0) return fmi3OK;                                               \
        return fail(instance, #FUNCTION, "the model has no variables of this type");            \
    }

NO_VARIABLES_OF_TYPE(fmi3GetFloat32, fmi3Float32)
NO_VARIABLES_OF_TYPE(fmi3GetInt8, fmi3Int8)
NO_VARIABLES_OF_TYPE(fmi3GetUInt8, fmi3UInt8)
NO_VARIABLES_OF_TYPE(fmi3GetInt16, fmi3Int16)
NO_VARIABLES_OF_TYPE(fmi3GetUInt16, fmi3UInt16)
NO_VARIABLES_OF_TYPE(fmi3GetUInt32, fmi3UInt32)
NO_VARIABLES_OF_TYPE(fmi3GetInt64, fmi3Int64)
NO_VARIABLES_OF_TYPE(fmi3GetUInt64, fmi3UInt64)
NO_VARIABLES_OF_TYPE(fmi3GetString, fmi3String)
NO_VARIABLES_OF_TYPE(fmi3SetFloat32, const fmi3Float32)
NO_VARIABLES_OF_TYPE(fmi3SetInt8, const fmi3Int8)
NO_VARIABLES_OF_TYPE(fmi3SetUInt8, const fmi3UInt8)
NO_VARIABLES_OF_TYPE(fmi3SetInt16, const fmi3Int16)
NO_VARIABLES_OF_TYPE(fmi3SetUInt16, const fmi3UInt16)
NO_VARIABLES_OF_TYPE(fmi3SetUInt32, const fmi3UInt32)
NO_VARIABLES_OF_TYPE(fmi3SetInt64, const fmi3Int64)
NO_VARIABLES_OF_TYPE(fmi3SetUInt64, const fmi3UInt64)
NO_VARIABLES_OF_TYPE(fmi3SetBoolean, const fmi3Boolean)
NO_VARIABLES_OF_TYPE(fmi3SetString, const fmi3String)

fmi3Status fmi3GetBoolean(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, fmi3Boolean values[], size_t nValues) {
    Instance *c = (Instance *)instance;
    size_t i;
    if (!allowed(c, "fmi3GetBoolean", ANY)) return fmi3Error;
    if (!scalars(c, "fmi3GetBoolean", nValueReferences, nValues)) return fmi3Error;
    for (i = 0; i < nValueReferences; i++) {
        if (valueReferences[i] != VR_ODD) {
            log_message(c, fmi3Error, "logStatusError", "fmi3GetBoolean: unknown value reference %u",
                        (unsigned)valueReferences[i]);
            return fmi3Error;
        }
        values[i] = (c->n_steps % 2) ? fmi3True : fmi3False;
    }
    return fmi3OK;
}

fmi3Status fmi3GetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                         size_t nValueReferences, size_t valueSizes[], fmi3Binary values[], size_t nValues) {
    (void)valueReferences; (void)valueSizes; (void)values; (void)nValues;
    return nValueReferences == 0 ? fmi3OK : fail(instance, "fmi3GetBinary", "the model has no Binary variables");
}

fmi3Status fmi3SetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                         size_t nValueReferences, const size_t valueSizes[], const fmi3Binary values[],
                         size_t nValues) {
    (void)valueReferences; (void)valueSizes; (void)values; (void)nValues;
    return nValueReferences == 0 ? fmi3OK : fail(instance, "fmi3SetBinary", "the model has no Binary variables");
}

fmi3Status fmi3GetClock(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                        size_t nValueReferences, fmi3Clock values[]) {
    (void)valueReferences; (void)values;
    return nValueReferences == 0 ? fmi3OK : fail(instance, "fmi3GetClock", "the model has no clocks");
}

fmi3Status fmi3SetClock(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                        size_t nValueReferences, const fmi3Clock values[]) {
    (void)valueReferences; (void)values;
    return nValueReferences == 0 ? fmi3OK : fail(instance, "fmi3SetClock", "the model has no clocks");
}

/* ------------------------------------------------ dependencies, FMU state */

fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance instance, fmi3ValueReference valueReference,
                                               size_t *nDependencies) {
    (void)valueReference; (void)nDependencies;
    return fail(instance, "fmi3GetNumberOfVariableDependencies", "not supported");
}

fmi3Status fmi3GetVariableDependencies(fmi3Instance instance, fmi3ValueReference dependent,
                                       size_t elementIndicesOfDependent[], fmi3ValueReference independents[],
                                       size_t elementIndicesOfIndependents[],
                                       fmi3DependencyKind dependencyKinds[], size_t nDependencies) {
    (void)dependent; (void)elementIndicesOfDependent; (void)independents; (void)elementIndicesOfIndependents;
    (void)dependencyKinds; (void)nDependencies;
    return fail(instance, "fmi3GetVariableDependencies", "not supported");
}

fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    (void)FMUState;
    return fail(instance, "fmi3GetFMUState", "not supported (canGetAndSetFMUState=false)");
}

fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState FMUState) {
    (void)FMUState;
    return fail(instance, "fmi3SetFMUState", "not supported (canGetAndSetFMUState=false)");
}

fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    (void)FMUState;
    return fail(instance, "fmi3FreeFMUState", "not supported (canGetAndSetFMUState=false)");
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState FMUState, size_t *size) {
    (void)FMUState; (void)size;
    return fail(instance, "fmi3SerializedFMUStateSize", "not supported (canSerializeFMUState=false)");
}

fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState FMUState, fmi3Byte serializedState[],
                                 size_t size) {
    (void)FMUState; (void)serializedState; (void)size;
    return fail(instance, "fmi3SerializeFMUState", "not supported (canSerializeFMUState=false)");
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serializedState[], size_t size,
                                   fmi3FMUState *FMUState) {
    (void)serializedState; (void)size; (void)FMUState;
    return fail(instance, "fmi3DeserializeFMUState", "not supported (canSerializeFMUState=false)");
}

fmi3Status fmi3GetDirectionalDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[],
                                        size_t nUnknowns, const fmi3ValueReference knowns[], size_t nKnowns,
                                        const fmi3Float64 seed[], size_t nSeed, fmi3Float64 sensitivity[],
                                        size_t nSensitivity) {
    (void)unknowns; (void)nUnknowns; (void)knowns; (void)nKnowns; (void)seed; (void)nSeed; (void)sensitivity;
    (void)nSensitivity;
    return fail(instance, "fmi3GetDirectionalDerivative", "not supported (providesDirectionalDerivatives=false)");
}

fmi3Status fmi3GetAdjointDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[],
                                    size_t nUnknowns, const fmi3ValueReference knowns[], size_t nKnowns,
                                    const fmi3Float64 seed[], size_t nSeed, fmi3Float64 sensitivity[],
                                    size_t nSensitivity) {
    (void)unknowns; (void)nUnknowns; (void)knowns; (void)nKnowns; (void)seed; (void)nSeed; (void)sensitivity;
    (void)nSensitivity;
    return fail(instance, "fmi3GetAdjointDerivative", "not supported (providesAdjointDerivatives=false)");
}

/* ------------------------------------------- configuration mode, clocks */

fmi3Status fmi3EnterConfigurationMode(fmi3Instance instance) {
    return fail(instance, "fmi3EnterConfigurationMode", "the model has no structural parameters");
}

fmi3Status fmi3ExitConfigurationMode(fmi3Instance instance) {
    return fail(instance, "fmi3ExitConfigurationMode", "the model has no structural parameters");
}

fmi3Status fmi3GetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                  size_t nValueReferences, fmi3Float64 intervals[],
                                  fmi3IntervalQualifier qualifiers[]) {
    (void)valueReferences; (void)nValueReferences; (void)intervals; (void)qualifiers;
    return fail(instance, "fmi3GetIntervalDecimal", "the model has no clocks");
}

fmi3Status fmi3GetIntervalFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                   size_t nValueReferences, fmi3UInt64 counters[], fmi3UInt64 resolutions[],
                                   fmi3IntervalQualifier qualifiers[]) {
    (void)valueReferences; (void)nValueReferences; (void)counters; (void)resolutions; (void)qualifiers;
    return fail(instance, "fmi3GetIntervalFraction", "the model has no clocks");
}

fmi3Status fmi3GetShiftDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                               size_t nValueReferences, fmi3Float64 shifts[]) {
    (void)valueReferences; (void)nValueReferences; (void)shifts;
    return fail(instance, "fmi3GetShiftDecimal", "the model has no clocks");
}

fmi3Status fmi3GetShiftFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                size_t nValueReferences, fmi3UInt64 counters[], fmi3UInt64 resolutions[]) {
    (void)valueReferences; (void)nValueReferences; (void)counters; (void)resolutions;
    return fail(instance, "fmi3GetShiftFraction", "the model has no clocks");
}

fmi3Status fmi3SetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                  size_t nValueReferences, const fmi3Float64 intervals[]) {
    (void)valueReferences; (void)nValueReferences; (void)intervals;
    return fail(instance, "fmi3SetIntervalDecimal", "the model has no clocks");
}

fmi3Status fmi3SetIntervalFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                   size_t nValueReferences, const fmi3UInt64 counters[],
                                   const fmi3UInt64 resolutions[]) {
    (void)valueReferences; (void)nValueReferences; (void)counters; (void)resolutions;
    return fail(instance, "fmi3SetIntervalFraction", "the model has no clocks");
}

fmi3Status fmi3SetShiftDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                               size_t nValueReferences, const fmi3Float64 shifts[]) {
    (void)valueReferences; (void)nValueReferences; (void)shifts;
    return fail(instance, "fmi3SetShiftDecimal", "the model has no clocks");
}

fmi3Status fmi3SetShiftFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                size_t nValueReferences, const fmi3UInt64 counters[],
                                const fmi3UInt64 resolutions[]) {
    (void)valueReferences; (void)nValueReferences; (void)counters; (void)resolutions;
    return fail(instance, "fmi3SetShiftFraction", "the model has no clocks");
}

fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance instance) {
    return fail(instance, "fmi3EvaluateDiscreteStates", "not supported (providesEvaluateDiscreteStates=false)");
}

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation,
                                    fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged,
                                    fmi3Boolean *nextEventTimeDefined, fmi3Float64 *nextEventTime) {
    (void)discreteStatesNeedUpdate; (void)terminateSimulation; (void)nominalsOfContinuousStatesChanged;
    (void)valuesOfContinuousStatesChanged; (void)nextEventTimeDefined; (void)nextEventTime;
    return fail(instance, "fmi3UpdateDiscreteStates", "not supported (hasEventMode=false)");
}

/* ------------------------------------------- model exchange: not implemented */

#define ME_ONLY "Integrator3 is a co-simulation FMU (no model exchange)"

fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance) {
    return fail(instance, "fmi3EnterContinuousTimeMode", ME_ONLY);
}

fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode, fmi3Boolean *terminateSimulation) {
    (void)noSetFMUStatePriorToCurrentPoint; (void)enterEventMode; (void)terminateSimulation;
    return fail(instance, "fmi3CompletedIntegratorStep", ME_ONLY);
}

fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time) {
    (void)time;
    return fail(instance, "fmi3SetTime", ME_ONLY);
}

fmi3Status fmi3SetContinuousStates(fmi3Instance instance, const fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    (void)continuousStates; (void)nContinuousStates;
    return fail(instance, "fmi3SetContinuousStates", ME_ONLY);
}

fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance instance, fmi3Float64 derivatives[],
                                             size_t nContinuousStates) {
    (void)derivatives; (void)nContinuousStates;
    return fail(instance, "fmi3GetContinuousStateDerivatives", ME_ONLY);
}

fmi3Status fmi3GetEventIndicators(fmi3Instance instance, fmi3Float64 eventIndicators[], size_t nEventIndicators) {
    (void)eventIndicators; (void)nEventIndicators;
    return fail(instance, "fmi3GetEventIndicators", ME_ONLY);
}

fmi3Status fmi3GetContinuousStates(fmi3Instance instance, fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    (void)continuousStates; (void)nContinuousStates;
    return fail(instance, "fmi3GetContinuousStates", ME_ONLY);
}

fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance instance, fmi3Float64 nominals[],
                                             size_t nContinuousStates) {
    (void)nominals; (void)nContinuousStates;
    return fail(instance, "fmi3GetNominalsOfContinuousStates", ME_ONLY);
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance, size_t *nEventIndicators) {
    Instance *c = (Instance *)instance;
    if (!allowed(c, "fmi3GetNumberOfEventIndicators", ANY)) return fmi3Error;
    *nEventIndicators = 0;
    return fmi3OK;
}

fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance, size_t *nContinuousStates) {
    Instance *c = (Instance *)instance;
    if (!allowed(c, "fmi3GetNumberOfContinuousStates", ANY)) return fmi3Error;
    *nContinuousStates = 0;
    return fmi3OK;
}

/* --------------------------------------------------------- co-simulation */

fmi3Status fmi3EnterStepMode(fmi3Instance instance) {
    return fail(instance, "fmi3EnterStepMode", "not supported (hasEventMode=false: exitInitializationMode "
                "enters step mode)");
}

fmi3Status fmi3GetOutputDerivatives(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                    size_t nValueReferences, const fmi3Int32 orders[], fmi3Float64 values[],
                                    size_t nValues) {
    (void)valueReferences; (void)nValueReferences; (void)orders; (void)values; (void)nValues;
    return fail(instance, "fmi3GetOutputDerivatives", "not supported (maxOutputDerivativeOrder=0)");
}

fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint,
                      fmi3Float64 communicationStepSize, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                      fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation,
                      fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime) {
    Instance *c = (Instance *)instance;
    const fmi3Float64 t = currentCommunicationPoint, h = communicationStepSize;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!allowed(c, "fmi3DoStep", IN(ST_STEP))) return fmi3Error;
    *eventHandlingNeeded = fmi3False;
    *terminateSimulation = fmi3False;
    *earlyReturn = fmi3False;
    *lastSuccessfulTime = c->time;
    if (!(h > 0.0)) {
        log_message(c, fmi3Error, "logStatusError", "fmi3DoStep: communicationStepSize must be > 0, got %g", h);
        return fmi3Error;
    }
    if (fabs(t - c->time) > 1e-9 * (1.0 + fabs(t))) {
        log_message(c, fmi3Error, "logStatusError",
                    "fmi3DoStep: currentCommunicationPoint %.17g is not where the last step ended (%.17g)",
                    t, c->time);
        return fmi3Error;
    }
    if (c->fail_at >= 0.0 && t >= c->fail_at) {
        log_message(c, fmi3Error, "logStatusError", "fail_at reached: t = %g >= fail_at = %g", t, c->fail_at);
        c->state = ST_ERROR;
        return fmi3Error;
    }
    c->y += c->k * c->u * h;
    c->n_steps += 1;
    c->time = t + h;
    *lastSuccessfulTime = c->time;
    if (c->stop_at >= 0.0 && c->time >= c->stop_at - 1e-9 * (1.0 + fabs(c->stop_at))) {
        log_message(c, fmi3OK, "logEvents", "stop_at reached: t = %g, ending the simulation", c->time);
        *terminateSimulation = fmi3True;
    }
    return fmi3OK;
}

/* ------------------------------------------------- scheduled execution */

fmi3Status fmi3ActivateModelPartition(fmi3Instance instance, fmi3ValueReference clockReference,
                                      fmi3Float64 activationTime) {
    (void)clockReference; (void)activationTime;
    return fail(instance, "fmi3ActivateModelPartition", "Integrator3 supports co-simulation only");
}
