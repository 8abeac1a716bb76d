/*
 * Integrator: a small FMI 2.0 co-simulation FMU written in plain C for the
 * master's tests ("a third-party FMU", not a pythonfmu one).
 *
 *   dy/dt = k * u, integrated explicitly over each communication step:
 *       y <- y + k * u * h
 *   n_steps counts the successful fmi2DoStep calls.
 *   fail_at >= 0: fmi2DoStep at a communication point t >= fail_at logs an
 *   error ("fail_at reached ...") and returns fmi2Error.
 *   stop_at >= 0: the fmi2DoStep that reaches t >= stop_at completes, then
 *   ends the simulation the FMI 2 way: it returns fmi2Discard and
 *   fmi2GetBooleanStatus(fmi2Terminated) turns true.
 *   discard_at >= 0: fmi2DoStep at a communication point t >= discard_at
 *   returns fmi2Discard without terminating (a step the FMU rejects).
 *   odd (Boolean output): n_steps is odd.
 *   label (String output): "step <n_steps>"; label_in (String input) is kept
 *   as a copy and can be read back with fmi2GetString.
 *
 * The FMU is strict on purpose, so that an importer that calls it wrongly
 * fails loudly: it checks the GUID, the FMU type, the calling sequence
 * (states), that fixed parameters are only set before initialization ends,
 * and that each doStep starts where the previous one ended.
 *
 * Built by tests/third_party_fmu/build.py against fmpy's FMI headers, with
 * MODEL_GUID defined on the compiler command line.
 */
#include <stdarg.h>
#include <stdio.h>
#include <string.h>
#include <math.h>

#include "fmi2Functions.h"

#ifndef MODEL_GUID
#error "compile with -DMODEL_GUID=\"{...}\" (the guid of modelDescription.xml)"
#endif

/* value references (see Integrator.modelDescription.xml) */
#define VR_U        0
#define VR_K        1
#define VR_Y        2
#define VR_FAIL_AT  3
#define VR_N_STEPS  4
#define VR_STOP_AT  5
#define VR_ODD      6
#define VR_LABEL    7
#define VR_LABEL_IN 8
#define VR_DISCARD_AT 9

#define LABEL_SIZE 64

typedef enum { ST_INSTANTIATED, ST_INIT, ST_STEP, ST_TERMINATED, ST_ERROR } State;

typedef struct {
    fmi2CallbackFunctions cb;
    char *name;
    fmi2Boolean logging;
    State state;
    fmi2Real time;
    fmi2Real u, k, y, fail_at, stop_at, discard_at;
    fmi2Integer n_steps;
    fmi2Boolean terminated;  /* a doStep ended the simulation (fmi2Terminated) */
    char label[LABEL_SIZE];
    char label_in[LABEL_SIZE];
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

static void log_message(Instance *c, fmi2Status status, const char *category, const char *fmt, ...) {
    char text[512];
    va_list ap;
    if (c == NULL || c->cb.logger == NULL) return;
    if (status == fmi2OK && !c->logging) return;   /* errors are always reported */
    va_start(ap, fmt);
    vsnprintf(text, sizeof text, fmt, ap);
    va_end(ap);
    /* the message is a format string for the importer: pass ours through "%s" */
    c->cb.logger(c->cb.componentEnvironment, c->name, status, category, "%s", text);
}

static fmi2Status fail(Instance *c, const char *function, const char *detail) {
    log_message(c, fmi2Error, "logStatusError", "%s: %s", function, detail);
    return fmi2Error;
}

static int allowed(Instance *c, const char *function, int mask) {
    if (c == NULL) return 0;
    if (mask & (1 << c->state)) return 1;
    log_message(c, fmi2Error, "logStatusError", "%s must not be called in state '%s'",
                function, state_name(c->state));
    return 0;
}

#define IN(s) (1 << (s))
#define ANY_BUT_ERROR (IN(ST_INSTANTIATED) | IN(ST_INIT) | IN(ST_STEP) | IN(ST_TERMINATED))
#define ANY (ANY_BUT_ERROR | IN(ST_ERROR))

static void set_defaults(Instance *c) {
    c->time = 0.0;
    c->u = 1.0;
    c->k = 2.0;
    c->y = 0.0;
    c->fail_at = -1.0;
    c->stop_at = -1.0;
    c->discard_at = -1.0;
    c->n_steps = 0;
    c->terminated = fmi2False;
    snprintf(c->label, LABEL_SIZE, "step %d", (int)c->n_steps);
    c->label_in[0] = '\0';
}

/* ---------------------------------------------------------------- common */

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component comp, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    Instance *c = (Instance *)comp;
    (void)nCategories; (void)categories;
    if (!allowed(c, "fmi2SetDebugLogging", ANY)) return fmi2Error;
    c->logging = loggingOn;
    return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn) {
    Instance *c;
    (void)fmuResourceLocation; (void)visible;
    if (functions == NULL || functions->logger == NULL || functions->allocateMemory == NULL ||
        functions->freeMemory == NULL)
        return NULL;
    if (instanceName == NULL || instanceName[0] == '\0') {
        functions->logger(functions->componentEnvironment, "?", fmi2Error, "logStatusError",
                          "fmi2Instantiate: missing instance name");
        return NULL;
    }
    if (fmuType != fmi2CoSimulation) {
        functions->logger(functions->componentEnvironment, instanceName, fmi2Error, "logStatusError",
                          "fmi2Instantiate: Integrator supports co-simulation only");
        return NULL;
    }
    if (fmuGUID == NULL || strcmp(fmuGUID, MODEL_GUID) != 0) {
        functions->logger(functions->componentEnvironment, instanceName, fmi2Error, "logStatusError",
                          "fmi2Instantiate: wrong GUID %s (expected %s)", fmuGUID ? fmuGUID : "(null)",
                          MODEL_GUID);
        return NULL;
    }
    c = (Instance *)functions->allocateMemory(1, sizeof(Instance));
    if (c == NULL) return NULL;
    c->name = (char *)functions->allocateMemory(strlen(instanceName) + 1, 1);
    if (c->name == NULL) {
        functions->freeMemory(c);
        return NULL;
    }
    strcpy(c->name, instanceName);
    c->cb = *functions;
    c->logging = loggingOn;
    c->state = ST_INSTANTIATED;
    set_defaults(c);
    log_message(c, fmi2OK, "logEvents", "fmi2Instantiate: instance %s created", instanceName);
    return c;
}

void fmi2FreeInstance(fmi2Component comp) {
    Instance *c = (Instance *)comp;
    fmi2CallbackFreeMemory release;
    if (c == NULL) return;
    release = c->cb.freeMemory;
    release(c->name);
    release(c);
}

fmi2Status fmi2SetupExperiment(fmi2Component comp, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    Instance *c = (Instance *)comp;
    (void)toleranceDefined; (void)tolerance;
    if (!allowed(c, "fmi2SetupExperiment", IN(ST_INSTANTIATED))) return fmi2Error;
    if (stopTimeDefined && stopTime < startTime)
        return fail(c, "fmi2SetupExperiment", "stopTime < startTime");
    c->time = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component comp) {
    Instance *c = (Instance *)comp;
    if (!allowed(c, "fmi2EnterInitializationMode", IN(ST_INSTANTIATED))) return fmi2Error;
    c->state = ST_INIT;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component comp) {
    Instance *c = (Instance *)comp;
    if (!allowed(c, "fmi2ExitInitializationMode", IN(ST_INIT))) return fmi2Error;
    c->state = ST_STEP;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component comp) {
    Instance *c = (Instance *)comp;
    if (!allowed(c, "fmi2Terminate", IN(ST_INIT) | IN(ST_STEP) | IN(ST_ERROR))) return fmi2Error;
    c->state = ST_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component comp) {
    Instance *c = (Instance *)comp;
    if (!allowed(c, "fmi2Reset", ANY)) return fmi2Error;
    set_defaults(c);
    c->state = ST_INSTANTIATED;
    return fmi2OK;
}

/* ------------------------------------------------------- get and set values */

fmi2Status fmi2GetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]) {
    Instance *c = (Instance *)comp;
    size_t i;
    if (!allowed(c, "fmi2GetReal", ANY)) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        switch (vr[i]) {
        case VR_U: value[i] = c->u; break;
        case VR_K: value[i] = c->k; break;
        case VR_Y: value[i] = c->y; break;
        case VR_FAIL_AT: value[i] = c->fail_at; break;
        case VR_STOP_AT: value[i] = c->stop_at; break;
        case VR_DISCARD_AT: value[i] = c->discard_at; break;
        default:
            log_message(c, fmi2Error, "logStatusError", "fmi2GetReal: unknown value reference %u", vr[i]);
            return fmi2Error;
        }
    }
    return fmi2OK;
}

fmi2Status fmi2GetInteger(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[]) {
    Instance *c = (Instance *)comp;
    size_t i;
    if (!allowed(c, "fmi2GetInteger", ANY)) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        if (vr[i] != VR_N_STEPS) {
            log_message(c, fmi2Error, "logStatusError", "fmi2GetInteger: unknown value reference %u", vr[i]);
            return fmi2Error;
        }
        value[i] = c->n_steps;
    }
    return fmi2OK;
}

fmi2Status fmi2GetBoolean(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[]) {
    Instance *c = (Instance *)comp;
    size_t i;
    if (!allowed(c, "fmi2GetBoolean", ANY)) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        if (vr[i] != VR_ODD) {
            log_message(c, fmi2Error, "logStatusError", "fmi2GetBoolean: unknown value reference %u", vr[i]);
            return fmi2Error;
        }
        value[i] = (c->n_steps % 2) ? fmi2True : fmi2False;
    }
    return fmi2OK;
}

fmi2Status fmi2GetString(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, fmi2String value[]) {
    Instance *c = (Instance *)comp;
    size_t i;
    if (!allowed(c, "fmi2GetString", ANY)) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        switch (vr[i]) {
        case VR_LABEL: value[i] = c->label; break;  /* valid until the next call into the FMU */
        case VR_LABEL_IN: value[i] = c->label_in; break;
        default:
            log_message(c, fmi2Error, "logStatusError", "fmi2GetString: unknown value reference %u", vr[i]);
            return fmi2Error;
        }
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[]) {
    Instance *c = (Instance *)comp;
    size_t i;
    int before_init_end;
    if (!allowed(c, "fmi2SetReal", IN(ST_INSTANTIATED) | IN(ST_INIT) | IN(ST_STEP))) return fmi2Error;
    before_init_end = c->state == ST_INSTANTIATED || c->state == ST_INIT;
    for (i = 0; i < nvr; i++) {
        switch (vr[i]) {
        case VR_U:
            c->u = value[i];
            break;
        case VR_K:
        case VR_Y:
        case VR_FAIL_AT:
        case VR_STOP_AT:
        case VR_DISCARD_AT:
            /* fixed parameters and the exact start value of y: only until initialization ends */
            if (!before_init_end) {
                log_message(c, fmi2Error, "logStatusError",
                            "fmi2SetReal: value reference %u can only be set before fmi2ExitInitializationMode",
                            vr[i]);
                return fmi2Error;
            }
            if (vr[i] == VR_K) c->k = value[i];
            else if (vr[i] == VR_Y) c->y = value[i];
            else if (vr[i] == VR_FAIL_AT) c->fail_at = value[i];
            else if (vr[i] == VR_STOP_AT) c->stop_at = value[i];
            else c->discard_at = value[i];
            break;
        default:
            log_message(c, fmi2Error, "logStatusError", "fmi2SetReal: unknown value reference %u", vr[i]);
            return fmi2Error;
        }
    }
    return fmi2OK;
}

fmi2Status fmi2SetInteger(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Integer value[]) {
    Instance *c = (Instance *)comp;
    size_t i;
    if (!allowed(c, "fmi2SetInteger", IN(ST_INSTANTIATED) | IN(ST_INIT))) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        if (vr[i] != VR_N_STEPS) {
            log_message(c, fmi2Error, "logStatusError", "fmi2SetInteger: unknown value reference %u", vr[i]);
            return fmi2Error;
        }
        c->n_steps = value[i];
    }
    return fmi2OK;
}

fmi2Status fmi2SetBoolean(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Boolean value[]) {
    Instance *c = (Instance *)comp;
    (void)vr; (void)value;
    if (!allowed(c, "fmi2SetBoolean", ANY_BUT_ERROR)) return fmi2Error;
    return nvr == 0 ? fmi2OK : fail(c, "fmi2SetBoolean", "the model has no Boolean variables");
}

fmi2Status fmi2SetString(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                         const fmi2String value[]) {
    Instance *c = (Instance *)comp;
    size_t i;
    if (!allowed(c, "fmi2SetString", ANY_BUT_ERROR)) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        if (vr[i] != VR_LABEL_IN) {
            log_message(c, fmi2Error, "logStatusError", "fmi2SetString: value reference %u is not an input",
                        vr[i]);
            return fmi2Error;
        }
        if (value[i] == NULL) return fail(c, "fmi2SetString", "NULL string for label_in");
        /* the importer's string is only valid during this call: copy it */
        snprintf(c->label_in, LABEL_SIZE, "%s", value[i]);
    }
    return fmi2OK;
}

/* ------------------------------------ FMU state, derivatives: not supported */

fmi2Status fmi2GetFMUstate(fmi2Component comp, fmi2FMUstate *FMUstate) {
    (void)FMUstate;
    return fail((Instance *)comp, "fmi2GetFMUstate", "not supported (canGetAndSetFMUstate=false)");
}

fmi2Status fmi2SetFMUstate(fmi2Component comp, fmi2FMUstate FMUstate) {
    (void)FMUstate;
    return fail((Instance *)comp, "fmi2SetFMUstate", "not supported (canGetAndSetFMUstate=false)");
}

fmi2Status fmi2FreeFMUstate(fmi2Component comp, fmi2FMUstate *FMUstate) {
    (void)FMUstate;
    return fail((Instance *)comp, "fmi2FreeFMUstate", "not supported (canGetAndSetFMUstate=false)");
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component comp, fmi2FMUstate FMUstate, size_t *size) {
    (void)FMUstate; (void)size;
    return fail((Instance *)comp, "fmi2SerializedFMUstateSize", "not supported (canSerializeFMUstate=false)");
}

fmi2Status fmi2SerializeFMUstate(fmi2Component comp, fmi2FMUstate FMUstate, fmi2Byte serializedState[],
                                 size_t size) {
    (void)FMUstate; (void)serializedState; (void)size;
    return fail((Instance *)comp, "fmi2SerializeFMUstate", "not supported (canSerializeFMUstate=false)");
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component comp, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate) {
    (void)serializedState; (void)size; (void)FMUstate;
    return fail((Instance *)comp, "fmi2DeSerializeFMUstate", "not supported (canSerializeFMUstate=false)");
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component comp, const fmi2ValueReference vUnknown_ref[],
                                        size_t nUnknown, const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[]) {
    (void)vUnknown_ref; (void)nUnknown; (void)vKnown_ref; (void)nKnown; (void)dvKnown; (void)dvUnknown;
    return fail((Instance *)comp, "fmi2GetDirectionalDerivative",
                "not supported (providesDirectionalDerivative=false)");
}

/* ------------------------------------- model exchange: not implemented */

static fmi2Status no_model_exchange(fmi2Component comp, const char *function) {
    return fail((Instance *)comp, function, "Integrator is a co-simulation FMU (no model exchange)");
}

fmi2Status fmi2EnterEventMode(fmi2Component c) { return no_model_exchange(c, "fmi2EnterEventMode"); }

fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *eventInfo) {
    (void)eventInfo;
    return no_model_exchange(c, "fmi2NewDiscreteStates");
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) {
    return no_model_exchange(c, "fmi2EnterContinuousTimeMode");
}

fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean *enterEventMode, fmi2Boolean *terminateSimulation) {
    (void)noSetFMUStatePriorToCurrentPoint; (void)enterEventMode; (void)terminateSimulation;
    return no_model_exchange(c, "fmi2CompletedIntegratorStep");
}

fmi2Status fmi2SetTime(fmi2Component c, fmi2Real time) {
    (void)time;
    return no_model_exchange(c, "fmi2SetTime");
}

fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx) {
    (void)x; (void)nx;
    return no_model_exchange(c, "fmi2SetContinuousStates");
}

fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real derivatives[], size_t nx) {
    (void)derivatives; (void)nx;
    return no_model_exchange(c, "fmi2GetDerivatives");
}

fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real eventIndicators[], size_t ni) {
    (void)eventIndicators; (void)ni;
    return no_model_exchange(c, "fmi2GetEventIndicators");
}

fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx) {
    (void)x; (void)nx;
    return no_model_exchange(c, "fmi2GetContinuousStates");
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x_nominal[], size_t nx) {
    (void)x_nominal; (void)nx;
    return no_model_exchange(c, "fmi2GetNominalsOfContinuousStates");
}

/* --------------------------------------------------------- co-simulation */

fmi2Status fmi2SetRealInputDerivatives(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    (void)vr; (void)nvr; (void)order; (void)value;
    return fail((Instance *)comp, "fmi2SetRealInputDerivatives",
                "not supported (canInterpolateInputs=false)");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    (void)vr; (void)nvr; (void)order; (void)value;
    return fail((Instance *)comp, "fmi2GetRealOutputDerivatives", "not supported (maxOutputDerivativeOrder=0)");
}

fmi2Status fmi2DoStep(fmi2Component comp, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    Instance *c = (Instance *)comp;
    const fmi2Real t = currentCommunicationPoint, h = communicationStepSize;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!allowed(c, "fmi2DoStep", IN(ST_STEP))) return fmi2Error;
    if (!(h > 0.0)) {
        log_message(c, fmi2Error, "logStatusError", "fmi2DoStep: communicationStepSize must be > 0, got %g", h);
        return fmi2Error;
    }
    if (fabs(t - c->time) > 1e-9 * (1.0 + fabs(t))) {
        log_message(c, fmi2Error, "logStatusError",
                    "fmi2DoStep: currentCommunicationPoint %.17g is not where the last step ended (%.17g)",
                    t, c->time);
        return fmi2Error;
    }
    if (c->terminated)
        return fail(c, "fmi2DoStep", "the FMU has ended the simulation (fmi2Terminated)");
    if (c->fail_at >= 0.0 && t >= c->fail_at) {
        log_message(c, fmi2Error, "logStatusError", "fail_at reached: t = %g >= fail_at = %g", t, c->fail_at);
        c->state = ST_ERROR;
        return fmi2Error;
    }
    if (c->discard_at >= 0.0 && t >= c->discard_at) {
        log_message(c, fmi2Discard, "logStatusDiscard", "discard_at reached: t = %g >= discard_at = %g",
                    t, c->discard_at);
        return fmi2Discard;
    }
    c->y += c->k * c->u * h;
    c->n_steps += 1;
    c->time = t + h;
    snprintf(c->label, LABEL_SIZE, "step %d", (int)c->n_steps);
    if (c->stop_at >= 0.0 && c->time >= c->stop_at - 1e-9 * (1.0 + fabs(c->stop_at))) {
        log_message(c, fmi2OK, "logEvents", "stop_at reached: t = %g, ending the simulation", c->time);
        c->terminated = fmi2True;
        return fmi2Discard;
    }
    return fmi2OK;
}

fmi2Status fmi2CancelStep(fmi2Component comp) {
    return fail((Instance *)comp, "fmi2CancelStep", "not supported (doStep never returns fmi2Pending)");
}

fmi2Status fmi2GetStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Status *value) {
    Instance *c = (Instance *)comp;
    (void)s; (void)value;
    if (!allowed(c, "fmi2GetStatus", ANY)) return fmi2Error;
    return fmi2Discard;  /* doStep is synchronous: there is never a pending status */
}

fmi2Status fmi2GetRealStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Real *value) {
    Instance *c = (Instance *)comp;
    if (!allowed(c, "fmi2GetRealStatus", ANY)) return fmi2Error;
    if (s != fmi2LastSuccessfulTime) return fmi2Discard;
    *value = c->time;
    return fmi2OK;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Integer *value) {
    Instance *c = (Instance *)comp;
    (void)s; (void)value;
    if (!allowed(c, "fmi2GetIntegerStatus", ANY)) return fmi2Error;
    return fmi2Discard;
}

fmi2Status fmi2GetBooleanStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Boolean *value) {
    Instance *c = (Instance *)comp;
    if (!allowed(c, "fmi2GetBooleanStatus", ANY)) return fmi2Error;
    if (s != fmi2Terminated) return fmi2Discard;
    *value = c->terminated;  /* set by the doStep that reached stop_at */
    return fmi2OK;
}

fmi2Status fmi2GetStringStatus(fmi2Component comp, const fmi2StatusKind s, fmi2String *value) {
    Instance *c = (Instance *)comp;
    (void)s; (void)value;
    if (!allowed(c, "fmi2GetStringStatus", ANY)) return fmi2Error;
    return fmi2Discard;
}
