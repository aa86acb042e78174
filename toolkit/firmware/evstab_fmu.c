/* evstab_fmu.c: an FMI 2.0 co-simulation slave around the exported ECU step.
 *
 * Part of evstab (toolkit/firmware/fmu.py packs it with evstab_firmware.c/.h and the design's
 * evstab_fmu_vars.h into an .fmu). One fmi2DoStep runs evstab_step round(h / period) times with the
 * inputs as last set (h a whole number of ECU periods; anything else is refused). Value references:
 * the inputs of evstab_input_t from 0 in the struct's order, the outputs of evstab_output_t from 100,
 * the calibration scalars from 1000 (tunable parameters; a value outside the limits the A2L declares
 * is refused). The calibration lives in the step's EVSTAB_CALIBRATION data, one copy per process:
 * the FMU can be instantiated once per process (modelDescription.xml says so).
 *
 * The FMI 2.0 types and function signatures are written out here as the standard defines them
 * (fmi2TypesPlatform.h, fmi2FunctionTypes.h), so that the FMU builds from its own sources.
 */
#include <stddef.h>
#include <stdlib.h>
#include <string.h>
#include <math.h>

#define EVSTAB_CALIBRATION static volatile
#include "evstab_firmware.c"
#include "evstab_fmu_vars.h"

typedef void *fmi2Component;
typedef void *fmi2ComponentEnvironment;
typedef void *fmi2FMUstate;
typedef unsigned int fmi2ValueReference;
typedef double fmi2Real;
typedef int fmi2Integer;
typedef int fmi2Boolean;
typedef char fmi2Char;
typedef const fmi2Char *fmi2String;
typedef char fmi2Byte;
typedef enum { fmi2OK, fmi2Warning, fmi2Discard, fmi2Error, fmi2Fatal, fmi2Pending } fmi2Status;
typedef enum { fmi2ModelExchange, fmi2CoSimulation } fmi2Type;
typedef enum { fmi2DoStepStatus, fmi2PendingStatus, fmi2LastSuccessfulTime, fmi2Terminated } fmi2StatusKind;
typedef void (*fmi2CallbackLogger)(fmi2ComponentEnvironment, fmi2String, fmi2Status, fmi2String, fmi2String, ...);
typedef void *(*fmi2CallbackAllocateMemory)(size_t, size_t);
typedef void (*fmi2CallbackFreeMemory)(void *);
typedef void (*fmi2StepFinished)(fmi2ComponentEnvironment, fmi2Status);
typedef struct {
    const fmi2CallbackLogger logger;
    const fmi2CallbackAllocateMemory allocateMemory;
    const fmi2CallbackFreeMemory freeMemory;
    const fmi2StepFinished stepFinished;
    const fmi2ComponentEnvironment componentEnvironment;
} fmi2CallbackFunctions;

#if defined(_WIN32)
#define FMI2_EXPORT __declspec(dllexport)
#else
#define FMI2_EXPORT __attribute__((visibility("default")))
#endif

#define EVSTAB_FMU_VR_OUT 100u
#define EVSTAB_FMU_VR_CAL 1000u

typedef struct {
    evstab_state_t state;
    evstab_input_t in;
    evstab_output_t out;
    double time;
    fmi2CallbackLogger logger;
    fmi2ComponentEnvironment env;
    char name[64];
} evstab_fmu_t;

static int evstab_fmu_instances = 0;

static void evstab_fmu_set_input(evstab_input_t *in, size_t k, double v)
{
    char *p = (char *)in + evstab_fmu_in_offset[k];
    if (evstab_fmu_in_is_int[k] != 0) {
        /* a count or a flag: a non-finite or absurd value reads as 0 (no fix, no satellites, no limit) */
        *(int *)(void *)p = (fabs(v) < 1e9) ? (int)v : 0;
    } else {
        *(evstab_real *)(void *)p = (evstab_real)v;
    }
}

static double evstab_fmu_get_input(const evstab_input_t *in, size_t k)
{
    const char *p = (const char *)in + evstab_fmu_in_offset[k];
    return evstab_fmu_in_is_int[k] != 0 ? (double)*(const int *)(const void *)p
                                        : (double)*(const evstab_real *)(const void *)p;
}

static void evstab_fmu_log(const evstab_fmu_t *c, fmi2Status status, const char *msg)
{
    if (c != NULL && c->logger != NULL) {
        c->logger(c->env, c->name, status, "evstab", "%s", msg);
    }
}

static void evstab_fmu_start(evstab_fmu_t *c)
{
    size_t k;
    evstab_init(&c->state);
    memset(&c->in, 0, sizeof c->in);
    memset(&c->out, 0, sizeof c->out);
    for (k = 0; k < EVSTAB_FMU_N_IN; k++) {
        evstab_fmu_set_input(&c->in, k, evstab_fmu_in_start[k]);
    }
    for (k = 0; k < EVSTAB_FMU_N_CAL; k++) {
        *evstab_fmu_cal[k] = (evstab_real)evstab_fmu_cal_start[k];
    }
    c->time = 0.0;
}

FMI2_EXPORT const char *fmi2GetTypesPlatform(void) { return "default"; }
FMI2_EXPORT const char *fmi2GetVersion(void) { return "2.0"; }

FMI2_EXPORT fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cat[])
{
    (void)c; (void)on; (void)n; (void)cat;
    return fmi2OK;
}

FMI2_EXPORT fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String resources,
                                          const fmi2CallbackFunctions *cb, fmi2Boolean visible, fmi2Boolean logging)
{
    evstab_fmu_t *c;
    (void)resources; (void)visible; (void)logging;
    if (type != fmi2CoSimulation || guid == NULL || strcmp(guid, EVSTAB_FMU_GUID) != 0 || evstab_fmu_instances > 0) {
        if (cb != NULL && cb->logger != NULL) {
            cb->logger(cb->componentEnvironment, name, fmi2Error, "evstab",
                       "fmi2Instantiate: co-simulation only, GUID " EVSTAB_FMU_GUID ", one instance per process");
        }
        return NULL;
    }
    c = (evstab_fmu_t *)calloc(1, sizeof *c);
    if (c == NULL) {
        return NULL;
    }
    c->logger = cb != NULL ? cb->logger : NULL;
    c->env = cb != NULL ? cb->componentEnvironment : NULL;
    strncpy(c->name, name != NULL ? name : "evstab", sizeof c->name - 1);
    evstab_fmu_start(c);
    evstab_fmu_instances++;
    return c;
}

FMI2_EXPORT void fmi2FreeInstance(fmi2Component c)
{
    if (c != NULL) {
        free(c);
        evstab_fmu_instances--;
    }
}

FMI2_EXPORT fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean tolDefined, fmi2Real tol, fmi2Real start,
                                           fmi2Boolean stopDefined, fmi2Real stop)
{
    (void)tolDefined; (void)tol; (void)stopDefined; (void)stop;
    ((evstab_fmu_t *)c)->time = start;
    return fmi2OK;
}

FMI2_EXPORT fmi2Status fmi2EnterInitializationMode(fmi2Component c) { (void)c; return fmi2OK; }
FMI2_EXPORT fmi2Status fmi2ExitInitializationMode(fmi2Component c) { (void)c; return fmi2OK; }
FMI2_EXPORT fmi2Status fmi2Terminate(fmi2Component c) { (void)c; return fmi2OK; }

FMI2_EXPORT fmi2Status fmi2Reset(fmi2Component c)
{
    evstab_fmu_start((evstab_fmu_t *)c);
    return fmi2OK;
}

FMI2_EXPORT fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real value[])
{
    evstab_fmu_t *m = (evstab_fmu_t *)c;
    size_t k;
    for (k = 0; k < n; k++) {
        if (vr[k] < EVSTAB_FMU_N_IN) {
            value[k] = evstab_fmu_get_input(&m->in, vr[k]);
        } else if (vr[k] >= EVSTAB_FMU_VR_OUT && vr[k] < EVSTAB_FMU_VR_OUT + EVSTAB_FMU_N_OUT) {
            value[k] = (fmi2Real)((const evstab_real *)&m->out)[vr[k] - EVSTAB_FMU_VR_OUT];
        } else if (vr[k] >= EVSTAB_FMU_VR_CAL && vr[k] < EVSTAB_FMU_VR_CAL + EVSTAB_FMU_N_CAL) {
            value[k] = (fmi2Real)*evstab_fmu_cal[vr[k] - EVSTAB_FMU_VR_CAL];
        } else {
            evstab_fmu_log(m, fmi2Error, "fmi2GetReal: unknown value reference");
            return fmi2Error;
        }
    }
    return fmi2OK;
}

FMI2_EXPORT fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real value[])
{
    evstab_fmu_t *m = (evstab_fmu_t *)c;
    size_t k;
    for (k = 0; k < n; k++) {
        if (vr[k] < EVSTAB_FMU_N_IN) {
            evstab_fmu_set_input(&m->in, vr[k], value[k]);
        } else if (vr[k] >= EVSTAB_FMU_VR_CAL && vr[k] < EVSTAB_FMU_VR_CAL + EVSTAB_FMU_N_CAL) {
            size_t i = vr[k] - EVSTAB_FMU_VR_CAL;
            /* the limits the A2L declares; a NaN fails both comparisons */
            if (!(value[k] >= evstab_fmu_cal_lower[i] && value[k] <= evstab_fmu_cal_upper[i])) {
                evstab_fmu_log(m, fmi2Error, "fmi2SetReal: calibration value outside the limits the A2L declares");
                return fmi2Error;
            }
            *evstab_fmu_cal[i] = (evstab_real)value[k];
        } else {
            evstab_fmu_log(m, fmi2Error, "fmi2SetReal: not an input or a calibration parameter");
            return fmi2Error;
        }
    }
    return fmi2OK;
}

FMI2_EXPORT fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noSetPrior)
{
    evstab_fmu_t *m = (evstab_fmu_t *)c;
    double periods = h / EVSTAB_CONTROL_PERIOD;
    long n = (long)floor(periods + 0.5);
    long k;
    (void)noSetPrior;
    if (n < 1 || fabs(periods - (double)n) > 1e-6 * (double)n) {
        evstab_fmu_log(m, fmi2Error, "fmi2DoStep: the communication step must be a whole number of ECU periods");
        return fmi2Error;
    }
    for (k = 0; k < n; k++) {
        evstab_step(&m->state, &m->in, &m->out);
    }
    m->time = t + h;
    return fmi2OK;
}

/* not supported: integers, booleans and strings (every variable is Real), FMU states, directional
 * derivatives, input derivatives, asynchronous steps */
FMI2_EXPORT fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer v[])
{ (void)c; (void)vr; (void)v; return n == 0 ? fmi2OK : fmi2Error; }
FMI2_EXPORT fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean v[])
{ (void)c; (void)vr; (void)v; return n == 0 ? fmi2OK : fmi2Error; }
FMI2_EXPORT fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String v[])
{ (void)c; (void)vr; (void)v; return n == 0 ? fmi2OK : fmi2Error; }
FMI2_EXPORT fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer v[])
{ (void)c; (void)vr; (void)v; return n == 0 ? fmi2OK : fmi2Error; }
FMI2_EXPORT fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Boolean v[])
{ (void)c; (void)vr; (void)v; return n == 0 ? fmi2OK : fmi2Error; }
FMI2_EXPORT fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2String v[])
{ (void)c; (void)vr; (void)v; return n == 0 ? fmi2OK : fmi2Error; }
FMI2_EXPORT fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *s) { (void)c; (void)s; return fmi2Error; }
FMI2_EXPORT fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate s) { (void)c; (void)s; return fmi2Error; }
FMI2_EXPORT fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *s) { (void)c; (void)s; return fmi2Error; }
FMI2_EXPORT fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate s, size_t *n)
{ (void)c; (void)s; (void)n; return fmi2Error; }
FMI2_EXPORT fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate s, fmi2Byte b[], size_t n)
{ (void)c; (void)s; (void)b; (void)n; return fmi2Error; }
FMI2_EXPORT fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte b[], size_t n, fmi2FMUstate *s)
{ (void)c; (void)b; (void)n; (void)s; return fmi2Error; }
FMI2_EXPORT fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference u[], size_t nu,
                                                    const fmi2ValueReference z[], size_t nz, const fmi2Real dv[],
                                                    fmi2Real dz[])
{ (void)c; (void)u; (void)nu; (void)z; (void)nz; (void)dv; (void)dz; return fmi2Error; }
FMI2_EXPORT fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                                   const fmi2Integer order[], const fmi2Real v[])
{ (void)c; (void)vr; (void)n; (void)order; (void)v; return fmi2Error; }
FMI2_EXPORT fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                                    const fmi2Integer order[], fmi2Real v[])
{ (void)c; (void)vr; (void)n; (void)order; (void)v; return fmi2Error; }
FMI2_EXPORT fmi2Status fmi2CancelStep(fmi2Component c) { (void)c; return fmi2Error; }
FMI2_EXPORT fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *v)
{ (void)c; (void)s; (void)v; return fmi2Discard; }
FMI2_EXPORT fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *v)
{
    if (s == fmi2LastSuccessfulTime) {
        *v = ((evstab_fmu_t *)c)->time;
        return fmi2OK;
    }
    return fmi2Discard;
}
FMI2_EXPORT fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *v)
{ (void)c; (void)s; (void)v; return fmi2Discard; }
FMI2_EXPORT fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *v)
{ (void)c; (void)s; (void)v; return fmi2Discard; }
FMI2_EXPORT fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *v)
{ (void)c; (void)s; (void)v; return fmi2Discard; }
