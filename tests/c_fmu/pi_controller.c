/* CPIController: the PI law of scenarios/examples/pi_controller.py as an FMI 2.0 co-simulation FMU
 * written in C, as a C export (OpenModelica, Dymola, Simulink) is: no Python, its messages handed to
 * the host's logger as printf formats with their arguments. tests/test_scenario_own_controller.py
 * builds it (gcc -ffp-contract=off: the same bits as Python's arithmetic) and runs it as a controller
 * of one's own.
 *
 * Value references (Real): 0 y (input, mm), 1 r (input, mm), 2 u (output, V), 3 Kp, 4 Ki, 5 u_bias,
 * 6 u_min, 7 u_max (parameters); (Boolean) 0 anti_windup. A step with a non-finite input is discarded
 * with a logged message; Kp < 0 is refused at fmi2ExitInitializationMode.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

#define GUID "{7c1f0a52-6c1e-4c55-9d7e-0c0ffee00001}"
enum { Y, R, U, KP, KI, U_BIAS, U_MIN, U_MAX, NR };

typedef struct {
    double r[NR], integral, time;
    int anti_windup;
    char name[128];
    const fmi2CallbackFunctions *cb;
} Pi;

#define LOG(p, status, category, ...)                                                                  \
    do {                                                                                               \
        if ((p)->cb && (p)->cb->logger)                                                                \
            (p)->cb->logger((p)->cb->componentEnvironment, (p)->name, status, category, __VA_ARGS__); \
    } while (0)

static void defaults(Pi *p) {
    double start[NR] = {0.0, 0.0, 5.0, 0.15, 0.6, 5.0, 0.0, 10.0};
    memcpy(p->r, start, sizeof start);
    p->anti_windup = 1;
    p->integral = 0.0;
}

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }
fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cats[]) {
    (void)c, (void)on, (void)n, (void)cats;
    return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String location,
                              const fmi2CallbackFunctions *cb, fmi2Boolean visible, fmi2Boolean logging) {
    (void)location, (void)visible, (void)logging;
    if (type != fmi2CoSimulation || !guid || strcmp(guid, GUID)) return NULL;
    Pi *p = calloc(1, sizeof *p);
    if (!p) return NULL;
    snprintf(p->name, sizeof p->name, "%s", name ? name : "");
    p->cb = cb;
    defaults(p);
    return p;
}
void fmi2FreeInstance(fmi2Component c) { free(c); }
fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean td, fmi2Real tol, fmi2Real t0, fmi2Boolean sd,
                               fmi2Real t1) {
    (void)td, (void)tol, (void)sd, (void)t1;
    ((Pi *)c)->time = t0;
    return fmi2OK;
}
fmi2Status fmi2EnterInitializationMode(fmi2Component c) { (void)c; return fmi2OK; }
fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    Pi *p = c;
    if (p->r[KP] < 0.0) {
        LOG(p, fmi2Error, "logStatusError", "Kp = %g must be >= 0 (%d of %d parameters checked)", p->r[KP], 1, 5);
        return fmi2Error;
    }
    if (p->r[KI] > 1.0) LOG(p, fmi2Warning, "logStatusWarning", "Ki = %g is %.0f%% of a 1 V/(mm s) ceiling", p->r[KI],
                            100.0 * p->r[KI]);
    return fmi2OK;
}
fmi2Status fmi2Terminate(fmi2Component c) { (void)c; return fmi2OK; }
fmi2Status fmi2Reset(fmi2Component c) { defaults(c); return fmi2OK; }

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real v[]) {
    for (size_t k = 0; k < n; k++) {
        if (vr[k] >= NR) return fmi2Error;
        v[k] = ((Pi *)c)->r[vr[k]];
    }
    return fmi2OK;
}
fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real v[]) {
    for (size_t k = 0; k < n; k++) {
        if (vr[k] >= NR) return fmi2Error;
        ((Pi *)c)->r[vr[k]] = v[k];
    }
    return fmi2OK;
}
fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean v[]) {
    for (size_t k = 0; k < n; k++) {
        if (vr[k] != 0) return fmi2Error;
        v[k] = ((Pi *)c)->anti_windup;
    }
    return fmi2OK;
}
fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Boolean v[]) {
    for (size_t k = 0; k < n; k++) {
        if (vr[k] != 0) return fmi2Error;
        ((Pi *)c)->anti_windup = v[k] != 0;
    }
    return fmi2OK;
}
fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer v[]) {
    (void)c, (void)vr, (void)v;
    return n ? fmi2Error : fmi2OK;
}
fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer v[]) {
    (void)c, (void)vr, (void)v;
    return n ? fmi2Error : fmi2OK;
}
fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String v[]) {
    (void)c, (void)vr, (void)v;
    return n ? fmi2Error : fmi2OK;
}
fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2String v[]) {
    (void)c, (void)vr, (void)v;
    return n ? fmi2Error : fmi2OK;
}

/* The law of pi_controller.py, operation for operation: fmin/fmax are Python's min/max here, since
 * v is finite (its inputs are checked, its parameters finite) and a -0.0 command drives the valve as 0. */
fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noset) {
    Pi *p = c;
    (void)noset;
    if (!isfinite(p->r[Y]) || !isfinite(p->r[R])) {
        LOG(p, fmi2Discard, "logStatusDiscard", "input y = %g or r = %g is not finite at t = %g s; the command is held",
            p->r[Y], p->r[R], t);
        return fmi2Discard;
    }
    double e = p->r[R] - p->r[Y];
    double v = p->r[U_BIAS] + p->r[KP] * e + p->integral;
    double u = fmin(fmax(v, p->r[U_MIN]), p->r[U_MAX]);
    int pushed = (v > p->r[U_MAX] && e > 0.0) || (v < p->r[U_MIN] && e < 0.0);
    if (!(p->anti_windup && pushed)) p->integral += p->r[KI] * h * e;
    p->r[U] = u;
    p->time = t + h;
    return fmi2OK;
}
fmi2Status fmi2CancelStep(fmi2Component c) { (void)c; return fmi2Error; }

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *s) { (void)c, (void)s; return fmi2Error; }
fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate s) { (void)c, (void)s; return fmi2Error; }
fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *s) { (void)c, (void)s; return fmi2Error; }
fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate s, size_t *n) {
    (void)c, (void)s, (void)n;
    return fmi2Error;
}
fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate s, fmi2Byte b[], size_t n) {
    (void)c, (void)s, (void)b, (void)n;
    return fmi2Error;
}
fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte b[], size_t n, fmi2FMUstate *s) {
    (void)c, (void)b, (void)n, (void)s;
    return fmi2Error;
}
fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference a[], size_t na,
                                        const fmi2ValueReference b[], size_t nb, const fmi2Real dv[], fmi2Real d[]) {
    (void)c, (void)a, (void)na, (void)b, (void)nb, (void)dv, (void)d;
    return fmi2Error;
}
fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                       const fmi2Integer o[], const fmi2Real v[]) {
    (void)c, (void)vr, (void)n, (void)o, (void)v;
    return fmi2Error;
}
fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                        const fmi2Integer o[], fmi2Real v[]) {
    (void)c, (void)vr, (void)n, (void)o, (void)v;
    return fmi2Error;
}
fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *v) {
    (void)c, (void)s, (void)v;
    return fmi2Discard;
}
fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *v) {
    (void)s;
    *v = ((Pi *)c)->time;
    return fmi2OK;
}
fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *v) {
    (void)c, (void)s, (void)v;
    return fmi2Discard;
}
fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *v) {
    (void)c, (void)s, (void)v;
    return fmi2Discard;
}
fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *v) {
    (void)c, (void)s, (void)v;
    return fmi2Discard;
}
