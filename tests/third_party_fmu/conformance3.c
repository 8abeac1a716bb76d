/*
 * Conformance3: an FMI 3.0 co-simulation FMU written in plain C for the
 * master's conformance tests (tests/test_fmi_conformance.py).
 *
 *   y         = gain * x                       (direct feedthrough)
 *   x_int    += x * h in each fmi3DoStep       (no feedthrough; starts at its start value)
 *   count_out = count, on_out = on             (direct feedthrough, Int32 and Boolean)
 *   v_out[j]  = gain * v_in[j] + offsets[j]    (Float64[3] arrays, direct feedthrough)
 *   v_sum     = v_in[1] + v_in[2] + v_in[3]
 *
 * Outputs are computed from the current inputs whenever they are read, also
 * in initialization mode, as a real feedthrough model's are. Besides these it
 * has inputs and parameters of the narrow types (Int8 with min/max, UInt8,
 * UInt64, Float32), a parameter with a declared type bounding it to [0, 1]
 * (ratio), a discrete Real input (level) and a second array input of another
 * size (w_in); the model only stores them, so they read back as set.
 *
 * Every variable lives in one table (value reference -> type, kind, size,
 * offset into the instance's cells); the getters and setters of each type walk
 * it, with arrays passed flat as FMI 3 does (nValues counts elements). Event
 * mode, clocks, FMU state, derivatives, model exchange and scheduled execution
 * are not supported (their functions return fmi3Error). The instantiation
 * token, the calling sequence and that doStep starts where the previous one
 * ended are checked.
 *
 * Built by tests/third_party_fmu/build.py against fmpy's FMI headers, with
 * MODEL_GUID (the instantiationToken) defined on the compiler command line.
 */
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <math.h>

#include "fmi3Functions.h"

#ifndef MODEL_GUID
#error "compile with -DMODEL_GUID=\"{...}\" (the instantiationToken of modelDescription.xml)"
#endif

typedef enum { T_FLOAT64, T_FLOAT32, T_INT8, T_UINT8, T_INT32, T_UINT64, T_BOOLEAN } Type;
/* input: settable until terminated; parameter and exact-start output: until initialization ends;
   independent and calculated: never */
typedef enum { K_INDEPENDENT, K_INPUT, K_PARAMETER, K_STATE, K_CALCULATED } Kind;

typedef struct {
    const char *name;
    Type type;
    Kind kind;
    size_t size;   /* elements (1 for a scalar) */
    size_t offset; /* first cell */
} VarInfo;

/* indexed by value reference (see Conformance3.modelDescription.xml) */
static const VarInfo VARS[] = {
    {"time", T_FLOAT64, K_INDEPENDENT, 1, 0},
    {"x", T_FLOAT64, K_INPUT, 1, 1},
    {"gain", T_FLOAT64, K_PARAMETER, 1, 2},
    {"y", T_FLOAT64, K_CALCULATED, 1, 3},
    {"x_int", T_FLOAT64, K_STATE, 1, 4},
    {"level", T_FLOAT64, K_INPUT, 1, 5},
    {"count", T_INT32, K_INPUT, 1, 6},
    {"count_out", T_INT32, K_CALCULATED, 1, 7},
    {"on", T_BOOLEAN, K_INPUT, 1, 8},
    {"on_out", T_BOOLEAN, K_CALCULATED, 1, 9},
    {"i8", T_INT8, K_INPUT, 1, 10},
    {"u8", T_UINT8, K_INPUT, 1, 11},
    {"u64", T_UINT64, K_PARAMETER, 1, 12},
    {"f32", T_FLOAT32, K_INPUT, 1, 13},
    {"ratio", T_FLOAT64, K_PARAMETER, 1, 14},
    {"v_in", T_FLOAT64, K_INPUT, 3, 15},
    {"offsets", T_FLOAT64, K_PARAMETER, 3, 18},
    {"v_out", T_FLOAT64, K_CALCULATED, 3, 21},
    {"v_sum", T_FLOAT64, K_CALCULATED, 1, 24},
    {"w_in", T_FLOAT64, K_INPUT, 2, 25},
};
#define N_VARS (sizeof VARS / sizeof VARS[0])
#define N_CELLS 27

enum { VR_TIME = 0, VR_X = 1, VR_GAIN = 2, VR_Y = 3, VR_X_INT = 4, VR_COUNT = 6, VR_COUNT_OUT = 7, VR_ON = 8,
       VR_ON_OUT = 9, VR_RATIO = 14, VR_V_IN = 15, VR_OFFSETS = 16, VR_V_OUT = 17, VR_V_SUM = 18 };

typedef union {
    double f;   /* Float64, Float32 */
    int64_t i;  /* Int8, Int32, Boolean */
    uint64_t u; /* UInt8, UInt64 */
} Cell;

typedef enum { ST_INSTANTIATED, ST_INIT, ST_STEP, ST_TERMINATED, ST_ERROR } State;

typedef struct {
    char *name;
    fmi3InstanceEnvironment env;
    fmi3LogMessageCallback log;
    fmi3Boolean logging;
    State state;
    fmi3Float64 time;
    Cell cells[N_CELLS];
} Instance;

#define CELL(c, vr, j) ((c)->cells[VARS[vr].offset + (j)])

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
    memset(c->cells, 0, sizeof c->cells);
    c->time = 0.0;
    CELL(c, VR_GAIN, 0).f = 1.0;
    CELL(c, VR_RATIO, 0).f = 0.5;
}

/* the outputs from the current inputs: called before every read */
static void update(Instance *c) {
    size_t j;
    const double gain = CELL(c, VR_GAIN, 0).f;
    double sum = 0.0;
    CELL(c, VR_TIME, 0).f = c->time;
    CELL(c, VR_Y, 0).f = gain * CELL(c, VR_X, 0).f;
    CELL(c, VR_COUNT_OUT, 0).i = CELL(c, VR_COUNT, 0).i;
    CELL(c, VR_ON_OUT, 0).i = CELL(c, VR_ON, 0).i;
    for (j = 0; j < VARS[VR_V_IN].size; j++) {
        CELL(c, VR_V_OUT, j).f = gain * CELL(c, VR_V_IN, j).f + CELL(c, VR_OFFSETS, j).f;
        sum += CELL(c, VR_V_IN, j).f;
    }
    CELL(c, VR_V_SUM, 0).f = sum;
}

/* the variable of a value reference, checked to be of the getter's/setter's type */
static const VarInfo *variable(Instance *c, const char *function, fmi3ValueReference vr, Type type) {
    if (vr >= N_VARS || VARS[vr].type != type) {
        log_message(c, fmi3Error, "logStatusError", "%s: no variable of this type has value reference %u",
                    function, (unsigned)vr);
        return NULL;
    }
    return &VARS[vr];
}

static int settable(Instance *c, const char *function, const VarInfo *v) {
    int mask;
    switch (v->kind) {
    case K_INPUT: mask = IN(ST_INSTANTIATED) | IN(ST_INIT) | IN(ST_STEP); break;
    case K_PARAMETER:
    case K_STATE: mask = IN(ST_INSTANTIATED) | IN(ST_INIT); break;
    default:
        log_message(c, fmi3Error, "logStatusError", "%s: %s cannot be set", function, v->name);
        return 0;
    }
    if (mask & (1 << c->state)) return 1;
    log_message(c, fmi3Error, "logStatusError", "%s: %s cannot be set in state '%s'", function, v->name,
                state_name(c->state));
    return 0;
}

static fmi3Status count_mismatch(Instance *c, const char *function, size_t elements, size_t nValues) {
    log_message(c, fmi3Error, "logStatusError", "%s: the variables have %u elements, but nValues = %u",
                function, (unsigned)elements, (unsigned)nValues);
    return fmi3Error;
}

static size_t elements(const fmi3ValueReference valueReferences[], size_t nValueReferences) {
    size_t i, n = 0;
    for (i = 0; i < nValueReferences; i++)
        n += valueReferences[i] < N_VARS ? VARS[valueReferences[i]].size : 1;
    return n;
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
                   "fmi3InstantiateModelExchange: Conformance3 supports co-simulation only");
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
                   "fmi3InstantiateScheduledExecution: Conformance3 supports co-simulation only");
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

/* A getter walks the value references, each variable giving all its elements (arrays flat). */
#define GETTER(FUNCTION, VALUE_TYPE, TYPE, READ)                                                  \
    fmi3Status FUNCTION(fmi3Instance instance, const fmi3ValueReference valueReferences[],       \
                        size_t nValueReferences, VALUE_TYPE values[], size_t nValues) {         \
        Instance *c = (Instance *)instance;                                                      \
        size_t i, j, k = 0;                                                                      \
        if (!allowed(c, #FUNCTION, ANY)) return fmi3Error;                                       \
        for (i = 0; i < nValueReferences; i++)                                                   \
            if (variable(c, #FUNCTION, valueReferences[i], TYPE) == NULL) return fmi3Error;       \
        if (elements(valueReferences, nValueReferences) != nValues)                              \
            return count_mismatch(c, #FUNCTION, elements(valueReferences, nValueReferences), nValues); \
        update(c);                                                                               \
        for (i = 0; i < nValueReferences; i++) {                                                 \
            const VarInfo *v = &VARS[valueReferences[i]];                                        \
            for (j = 0; j < v->size; j++, k++) {                                                 \
                const Cell cell = c->cells[v->offset + j];                                       \
                values[k] = READ;                                                                \
            }                                                                                    \
        }                                                                                        \
        return fmi3OK;                                                                           \
    }

/* A setter checks every variable first, so that a refused call changes nothing. */
#define SETTER(FUNCTION, VALUE_TYPE, TYPE, WRITE)                                                 \
    fmi3Status FUNCTION(fmi3Instance instance, const fmi3ValueReference valueReferences[],       \
                        size_t nValueReferences, const VALUE_TYPE values[], size_t nValues) {   \
        Instance *c = (Instance *)instance;                                                      \
        size_t i, j, k = 0;                                                                      \
        if (!allowed(c, #FUNCTION, IN(ST_INSTANTIATED) | IN(ST_INIT) | IN(ST_STEP))) return fmi3Error; \
        for (i = 0; i < nValueReferences; i++) {                                                 \
            const VarInfo *v = variable(c, #FUNCTION, valueReferences[i], TYPE);                 \
            if (v == NULL || !settable(c, #FUNCTION, v)) return fmi3Error;                        \
        }                                                                                        \
        if (elements(valueReferences, nValueReferences) != nValues)                              \
            return count_mismatch(c, #FUNCTION, elements(valueReferences, nValueReferences), nValues); \
        for (i = 0; i < nValueReferences; i++) {                                                 \
            const VarInfo *v = &VARS[valueReferences[i]];                                        \
            for (j = 0; j < v->size; j++, k++) {                                                 \
                Cell *cell = &c->cells[v->offset + j];                                           \
                WRITE;                                                                           \
            }                                                                                    \
        }                                                                                        \
        return fmi3OK;                                                                           \
    }

GETTER(fmi3GetFloat64, fmi3Float64, T_FLOAT64, cell.f)
GETTER(fmi3GetFloat32, fmi3Float32, T_FLOAT32, (fmi3Float32)cell.f)
GETTER(fmi3GetInt8, fmi3Int8, T_INT8, (fmi3Int8)cell.i)
GETTER(fmi3GetUInt8, fmi3UInt8, T_UINT8, (fmi3UInt8)cell.u)
GETTER(fmi3GetInt32, fmi3Int32, T_INT32, (fmi3Int32)cell.i)
GETTER(fmi3GetUInt64, fmi3UInt64, T_UINT64, (fmi3UInt64)cell.u)
GETTER(fmi3GetBoolean, fmi3Boolean, T_BOOLEAN, cell.i != 0)

SETTER(fmi3SetFloat64, fmi3Float64, T_FLOAT64, cell->f = values[k])
SETTER(fmi3SetFloat32, fmi3Float32, T_FLOAT32, cell->f = (double)values[k])
SETTER(fmi3SetInt8, fmi3Int8, T_INT8, cell->i = values[k])
SETTER(fmi3SetUInt8, fmi3UInt8, T_UINT8, cell->u = values[k])
SETTER(fmi3SetInt32, fmi3Int32, T_INT32, cell->i = values[k])
SETTER(fmi3SetUInt64, fmi3UInt64, T_UINT64, cell->u = values[k])
SETTER(fmi3SetBoolean, fmi3Boolean, T_BOOLEAN, cell->i = values[k] ? 1 : 0)

/* The model has no variables of the other types: any non-empty request is an error. */
#define NO_VARIABLES_OF_TYPE(FUNCTION, VALUE_TYPE)                                              \
    fmi3Status FUNCTION(fmi3Instance instance, const fmi3ValueReference valueReferences[],      \
                        size_t nValueReferences, VALUE_TYPE values[], size_t nValues) {        \
        (void)valueReferences; (void)values; (void)nValues;                                     \
        if (!allowed((Instance *)instance, #FUNCTION, ANY)) return fmi3Error;                   \
        if (nValueReferences == 0) return fmi3OK;                                               \
        return fail(instance, #FUNCTION, "the model has no variables of this type");            \
    }

NO_VARIABLES_OF_TYPE(fmi3GetInt16, fmi3Int16)
NO_VARIABLES_OF_TYPE(fmi3GetUInt16, fmi3UInt16)
NO_VARIABLES_OF_TYPE(fmi3GetUInt32, fmi3UInt32)
NO_VARIABLES_OF_TYPE(fmi3GetInt64, fmi3Int64)
NO_VARIABLES_OF_TYPE(fmi3GetString, fmi3String)
NO_VARIABLES_OF_TYPE(fmi3SetInt16, const fmi3Int16)
NO_VARIABLES_OF_TYPE(fmi3SetUInt16, const fmi3UInt16)
NO_VARIABLES_OF_TYPE(fmi3SetUInt32, const fmi3UInt32)
NO_VARIABLES_OF_TYPE(fmi3SetInt64, const fmi3Int64)
NO_VARIABLES_OF_TYPE(fmi3SetString, const fmi3String)

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

#define ME_ONLY "Conformance3 is a co-simulation FMU (no model exchange)"

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
    CELL(c, VR_X_INT, 0).f += CELL(c, VR_X, 0).f * h;
    c->time = t + h;
    *lastSuccessfulTime = c->time;
    return fmi3OK;
}

/* ------------------------------------------------- scheduled execution */

fmi3Status fmi3ActivateModelPartition(fmi3Instance instance, fmi3ValueReference clockReference,
                                      fmi3Float64 activationTime) {
    (void)clockReference; (void)activationTime;
    return fail(instance, "fmi3ActivateModelPartition", "Conformance3 supports co-simulation only");
}
