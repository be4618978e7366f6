/* DcMotor: an FMI 2.0 FMU of a DC motor with Coulomb friction, written by hand in C; co-simulation
 * and model exchange from one binary (the model description says which interfaces are offered).
 *
 * It is a "foreign" plant for `tapmuscle diagnose`: nothing here comes from tapmuscle's FMU build.
 * tapmuscle/diagnosis/foreign_fmus/dc_motor.py compiles this file and writes modelDescription.xml;
 * the value references below must match the ones listed there.
 *
 * Model (states i [A], omega [rad/s], theta [rad]; input V [V]):
 *     L di/dt      = V - R i - K omega
 *     J domega/dt  = K i - b omega - Tc tanh(omega / omega_s)
 *     dtheta/dt    = omega
 * The Coulomb friction Tc sign(omega) is smoothed by tanh so the right-hand side stays Lipschitz
 * and the fixed-step RK4 below keeps its order.
 *
 * fmi2DoStep integrates with classic RK4 on at most 0.5 ms substeps: the electrical time constant
 * L/R is 5 ms with the default parameters, so the substep stays well inside RK4's stability region.
 * In model exchange the host integrates: the states are (i, omega, theta), their derivatives are
 * the variables der(i), der(omega), der(theta), and there are no events (no event indicators, no
 * time events).
 * Errors are always reported through the host's logger, whatever fmi2SetDebugLogging said.
 */

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

/* Also in modelDescription.xml: dc_motor.py reads it from this line. */
#define DC_MOTOR_GUID "{5f0c2d1e-8a47-4b6e-9d3a-2c1b7e4f6a90}"

#define MAX_SUBSTEP_S 0.0005
/* A communication step needing more substeps than this (about 5.8 simulated days) is refused
 * rather than left running for minutes inside one fmi2DoStep. */
#define MAX_SUBSTEPS 1.0e9
#define SNAPSHOT_MAGIC 0x44434d53u /* "DCMS": tells a DcMotor FMU state from a stray pointer */

/* Value references: the order of the variables in modelDescription.xml. */
enum {
    VR_V = 0,
    VR_OMEGA,
    VR_I,
    VR_THETA,
    VR_R,
    VR_L,
    VR_K,
    VR_J,
    VR_B,
    VR_TC,
    VR_OMEGA_S,
    VR_DER_I,
    VR_DER_OMEGA,
    VR_DER_THETA,
    N_VARIABLES
};

static const char *const VARIABLE_NAMES[N_VARIABLES] = {
    "V", "omega", "i", "theta", "R", "L", "K", "J", "b", "Tc", "omega_s", "der(i)", "der(omega)", "der(theta)"};

enum { X_I = 0, X_OMEGA, X_THETA, N_STATES };

typedef enum {
    MODE_INSTANTIATED,
    MODE_INITIALIZATION,
    MODE_STEP_COMPLETE, /* co-simulation: between fmi2DoStep calls */
    MODE_EVENT,         /* model exchange: event mode */
    MODE_CONTINUOUS,    /* model exchange: continuous-time mode */
    MODE_TERMINATED,
    MODE_ERROR
} Mode;

/* Log categories, as declared in modelDescription.xml. */
enum { CAT_ERROR = 0, CAT_WARNING, CAT_ALL, N_CATEGORIES };
static const char *const CATEGORY_NAMES[N_CATEGORIES] = {"logStatusError", "logStatusWarning", "logAll"};

/* Everything that defines the simulation: fmi2GetFMUstate copies exactly this. */
typedef struct {
    Mode mode;
    double time;
    double V;
    double x[N_STATES];
    /* parameters, indexed by value reference (VR_R .. VR_OMEGA_S); the other slots are unused */
    double p[N_VARIABLES];
} ModelData;

typedef struct {
    unsigned magic;
    ModelData data;
} Snapshot;

/* The instance: the model plus what the host gave at instantiation. */
typedef struct {
    ModelData m;
    char *instanceName;
    fmi2CallbackLogger logger;
    fmi2ComponentEnvironment environment;
    fmi2Type type;
    int categoryOn[N_CATEGORIES];
} Instance;

/* ---------------------------------------------------------------------------------------------- */
/* Logging                                                                                         */

/* The FMI logger's message is a printf format: format here, then double every '%' so that a host
 * that formats again (fmpy's logger proxy) and one that does not (a bare ctypes callback) both show
 * the same text. */
static void log_raw(fmi2CallbackLogger logger, fmi2ComponentEnvironment env, const char *name,
                    fmi2Status status, const char *category, const char *format, va_list args) {
    char text[512];
    char escaped[2 * sizeof text];
    size_t k = 0;
    if (logger == NULL) return;
    vsnprintf(text, sizeof text, format, args);
    for (const char *c = text; *c != '\0' && k + 2 < sizeof escaped; c++) {
        if (*c == '%') escaped[k++] = '%';
        escaped[k++] = *c;
    }
    escaped[k] = '\0';
    logger(env, name != NULL ? name : "", status, category, escaped);
}

/* Errors and warnings are always logged; informational messages only when "logAll" is on. */
static void log_message(const Instance *inst, fmi2Status status, const char *format, ...) {
    int category = status >= fmi2Error ? CAT_ERROR : status == fmi2OK ? CAT_ALL : CAT_WARNING;
    va_list args;
    if (category == CAT_ALL && !inst->categoryOn[CAT_ALL]) return;
    va_start(args, format);
    log_raw(inst->logger, inst->environment, inst->instanceName, status, CATEGORY_NAMES[category], format,
            args);
    va_end(args);
}

/* For fmi2Instantiate's errors, before there is an instance. */
static void log_instantiate_error(const fmi2CallbackFunctions *functions, const char *name, const char *format,
                                  ...) {
    va_list args;
    va_start(args, format);
    log_raw(functions->logger, functions->componentEnvironment, name, fmi2Error, CATEGORY_NAMES[CAT_ERROR],
            format, args);
    va_end(args);
}

/* ---------------------------------------------------------------------------------------------- */
/* Model                                                                                           */

static void set_defaults(ModelData *m) {
    memset(m, 0, sizeof *m);
    m->mode = MODE_INSTANTIATED;
    m->p[VR_R] = 2.0;        /* ohm */
    m->p[VR_L] = 0.01;       /* H */
    m->p[VR_K] = 0.1;        /* N m/A = V s/rad */
    m->p[VR_J] = 0.01;       /* kg m^2 */
    m->p[VR_B] = 0.002;      /* N m s/rad */
    m->p[VR_TC] = 0.02;      /* N m */
    m->p[VR_OMEGA_S] = 0.5;  /* rad/s */
}

static void derivatives(const ModelData *m, const double x[N_STATES], double dx[N_STATES]) {
    const double *p = m->p;
    double friction = p[VR_TC] * tanh(x[X_OMEGA] / p[VR_OMEGA_S]);
    dx[X_I] = (m->V - p[VR_R] * x[X_I] - p[VR_K] * x[X_OMEGA]) / p[VR_L];
    dx[X_OMEGA] = (p[VR_K] * x[X_I] - p[VR_B] * x[X_OMEGA] - friction) / p[VR_J];
    dx[X_THETA] = x[X_OMEGA];
}

/* One classic RK4 step of length dt from x, in place. */
static void rk4_step(const ModelData *m, double x[N_STATES], double dt) {
    double k1[N_STATES], k2[N_STATES], k3[N_STATES], k4[N_STATES], y[N_STATES];
    int j;
    derivatives(m, x, k1);
    for (j = 0; j < N_STATES; j++) y[j] = x[j] + 0.5 * dt * k1[j];
    derivatives(m, y, k2);
    for (j = 0; j < N_STATES; j++) y[j] = x[j] + 0.5 * dt * k2[j];
    derivatives(m, y, k3);
    for (j = 0; j < N_STATES; j++) y[j] = x[j] + dt * k3[j];
    derivatives(m, y, k4);
    for (j = 0; j < N_STATES; j++) x[j] += dt / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j]);
}

static double get_value(const ModelData *m, fmi2ValueReference vr) {
    double dx[N_STATES];
    if (vr >= VR_DER_I) {
        derivatives(m, m->x, dx);
        return dx[vr - VR_DER_I];
    }
    switch (vr) {
        case VR_V: return m->V;
        case VR_OMEGA: return m->x[X_OMEGA];
        case VR_I: return m->x[X_I];
        case VR_THETA: return m->x[X_THETA];
        default: return m->p[vr];
    }
}

/* NULL if the value is acceptable for the variable, else why not (for the log). */
static const char *value_problem(const Instance *inst, fmi2ValueReference vr, double value) {
    if (vr >= N_VARIABLES) return "is not a value reference of DcMotor";
    if (vr >= VR_OMEGA && vr <= VR_THETA) return "is an output and cannot be set";
    if (vr >= VR_DER_I) return "is a state derivative and cannot be set";
    if (!isfinite(value)) return "must be finite";
    if (vr == VR_V) {
        if (inst->m.mode == MODE_TERMINATED || inst->m.mode == MODE_ERROR)
            return "cannot be set after fmi2Terminate or an error";
        return NULL;
    }
    if (inst->m.mode != MODE_INSTANTIATED && inst->m.mode != MODE_INITIALIZATION)
        return "is a fixed parameter: set it before fmi2ExitInitializationMode (or after fmi2Reset)";
    if ((vr == VR_B || vr == VR_TC) && value < 0.0) return "must be >= 0";
    if (vr != VR_B && vr != VR_TC && value <= 0.0) return "must be > 0";
    return NULL;
}

/* ---------------------------------------------------------------------------------------------- */
/* Checks shared by the FMI functions                                                              */

static int null_arrays(Instance *inst, const char *function, size_t nvr, const void *vr, const void *value) {
    if (nvr > 0 && (vr == NULL || value == NULL)) {
        log_message(inst, fmi2Error, "%s: vr or value is NULL with nvr = %lu", function, (unsigned long)nvr);
        return 1;
    }
    return 0;
}

static int wrong_mode(Instance *inst, const char *function, int allowed) {
    if (allowed) return 0;
    log_message(inst, fmi2Error, "%s: not allowed in the current state of the FMU", function);
    return 1;
}

/* ---------------------------------------------------------------------------------------------- */
/* Inquire version numbers and set debug logging                                                   */

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    Instance *inst = (Instance *)c;
    size_t n;
    int j;
    if (inst == NULL) return fmi2Error;
    if (nCategories == 0) { /* all categories */
        for (j = 0; j < N_CATEGORIES; j++) inst->categoryOn[j] = loggingOn ? 1 : 0;
        return fmi2OK;
    }
    if (categories == NULL) {
        log_message(inst, fmi2Error, "fmi2SetDebugLogging: categories is NULL with nCategories = %lu",
                    (unsigned long)nCategories);
        return fmi2Error;
    }
    for (n = 0; n < nCategories; n++) {
        int found = -1;
        for (j = 0; j < N_CATEGORIES; j++)
            if (categories[n] != NULL && strcmp(categories[n], CATEGORY_NAMES[j]) == 0) found = j;
        if (found < 0) {
            log_message(inst, fmi2Error, "fmi2SetDebugLogging: unknown log category \"%s\"",
                        categories[n] != NULL ? categories[n] : "(null)");
            return fmi2Error;
        }
        inst->categoryOn[found] = loggingOn ? 1 : 0;
    }
    return fmi2OK;
}

/* ---------------------------------------------------------------------------------------------- */
/* Creation and destruction                                                                        */

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn) {
    Instance *inst;
    int j;
    (void)fmuResourceLocation; /* no resources */
    (void)visible;             /* no user interface */
    if (functions == NULL || functions->logger == NULL) return NULL; /* no way to report anything */
    if (instanceName == NULL || instanceName[0] == '\0') {
        log_instantiate_error(functions, instanceName, "fmi2Instantiate: missing instanceName");
        return NULL;
    }
    if (fmuType != fmi2CoSimulation && fmuType != fmi2ModelExchange) {
        log_instantiate_error(functions, instanceName, "fmi2Instantiate: unknown fmuType %d", (int)fmuType);
        return NULL;
    }
    if (fmuGUID == NULL || strcmp(fmuGUID, DC_MOTOR_GUID) != 0) {
        log_instantiate_error(functions, instanceName, "fmi2Instantiate: GUID %s does not match DcMotor's %s",
                              fmuGUID != NULL ? fmuGUID : "(null)", DC_MOTOR_GUID);
        return NULL;
    }
    /* calloc, not functions->allocateMemory: modelDescription.xml says
     * canNotUseMemoryManagementFunctions="true", so the host may leave those NULL. */
    inst = (Instance *)calloc(1, sizeof *inst);
    if (inst != NULL) inst->instanceName = (char *)malloc(strlen(instanceName) + 1);
    if (inst == NULL || inst->instanceName == NULL) {
        free(inst);
        log_instantiate_error(functions, instanceName, "fmi2Instantiate: out of memory");
        return NULL;
    }
    strcpy(inst->instanceName, instanceName);
    inst->logger = functions->logger;
    inst->environment = functions->componentEnvironment;
    inst->type = fmuType;
    for (j = 0; j < N_CATEGORIES; j++) inst->categoryOn[j] = loggingOn ? 1 : 0;
    set_defaults(&inst->m);
    return inst;
}

void fmi2FreeInstance(fmi2Component c) {
    Instance *inst = (Instance *)c;
    if (inst == NULL) return;
    free(inst->instanceName);
    free(inst);
}

/* ---------------------------------------------------------------------------------------------- */
/* Initialization, termination and reset                                                          */

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    Instance *inst = (Instance *)c;
    (void)toleranceDefined; /* fixed-step RK4: the tolerance does not apply */
    (void)tolerance;
    (void)stopTimeDefined; /* the model is defined for all times */
    (void)stopTime;
    if (inst == NULL) return fmi2Error;
    if (wrong_mode(inst, "fmi2SetupExperiment", inst->m.mode == MODE_INSTANTIATED)) return fmi2Error;
    if (!isfinite(startTime)) {
        log_message(inst, fmi2Error, "fmi2SetupExperiment: startTime = %g is not finite", startTime);
        return fmi2Error;
    }
    inst->m.time = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    Instance *inst = (Instance *)c;
    if (inst == NULL) return fmi2Error;
    if (wrong_mode(inst, "fmi2EnterInitializationMode", inst->m.mode == MODE_INSTANTIATED)) return fmi2Error;
    inst->m.mode = MODE_INITIALIZATION;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    Instance *inst = (Instance *)c;
    if (inst == NULL) return fmi2Error;
    if (wrong_mode(inst, "fmi2ExitInitializationMode", inst->m.mode == MODE_INITIALIZATION)) return fmi2Error;
    /* the states start at rest: i = omega = theta = 0 */
    inst->m.mode = inst->type == fmi2CoSimulation ? MODE_STEP_COMPLETE : MODE_EVENT;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c) {
    Instance *inst = (Instance *)c;
    if (inst == NULL) return fmi2Error;
    if (wrong_mode(inst, "fmi2Terminate", inst->m.mode == MODE_STEP_COMPLETE || inst->m.mode == MODE_EVENT ||
                                              inst->m.mode == MODE_CONTINUOUS))
        return fmi2Error;
    inst->m.mode = MODE_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c) {
    Instance *inst = (Instance *)c;
    if (inst == NULL) return fmi2Error;
    set_defaults(&inst->m); /* as after fmi2Instantiate; the logging settings stay */
    return fmi2OK;
}

/* ---------------------------------------------------------------------------------------------- */
/* Getting and setting variable values                                                            */

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]) {
    Instance *inst = (Instance *)c;
    size_t n;
    if (inst == NULL) return fmi2Error;
    if (null_arrays(inst, "fmi2GetReal", nvr, vr, value)) return fmi2Error;
    for (n = 0; n < nvr; n++) {
        if (vr[n] >= N_VARIABLES) {
            log_message(inst, fmi2Error, "fmi2GetReal: %u is not a value reference of DcMotor", vr[n]);
            return fmi2Error;
        }
        value[n] = get_value(&inst->m, vr[n]);
    }
    return fmi2OK;
}

/* All values are checked before any is set, so a refused call changes nothing. */
fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[]) {
    Instance *inst = (Instance *)c;
    size_t n;
    if (inst == NULL) return fmi2Error;
    if (null_arrays(inst, "fmi2SetReal", nvr, vr, value)) return fmi2Error;
    for (n = 0; n < nvr; n++) {
        const char *problem = value_problem(inst, vr[n], value[n]);
        if (problem != NULL) {
            if (vr[n] < N_VARIABLES)
                log_message(inst, fmi2Error, "fmi2SetReal: %s = %g refused: %s", VARIABLE_NAMES[vr[n]], value[n],
                            problem);
            else
                log_message(inst, fmi2Error, "fmi2SetReal: %u %s", vr[n], problem);
            return fmi2Error;
        }
    }
    for (n = 0; n < nvr; n++) {
        if (vr[n] == VR_V)
            inst->m.V = value[n];
        else
            inst->m.p[vr[n]] = value[n];
    }
    return fmi2OK;
}

/* DcMotor has Real variables only: any other type's value reference is an error. */
static fmi2Status no_variables_of_type(fmi2Component c, const char *function, size_t nvr) {
    Instance *inst = (Instance *)c;
    if (inst == NULL) return fmi2Error;
    if (nvr == 0) return fmi2OK;
    log_message(inst, fmi2Error, "%s: DcMotor has no variables of this type", function);
    return fmi2Error;
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[]) {
    (void)vr;
    (void)value;
    return no_variables_of_type(c, "fmi2GetInteger", nvr);
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[]) {
    (void)vr;
    (void)value;
    return no_variables_of_type(c, "fmi2GetBoolean", nvr);
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2String value[]) {
    (void)vr;
    (void)value;
    return no_variables_of_type(c, "fmi2GetString", nvr);
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Integer value[]) {
    (void)vr;
    (void)value;
    return no_variables_of_type(c, "fmi2SetInteger", nvr);
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Boolean value[]) {
    (void)vr;
    (void)value;
    return no_variables_of_type(c, "fmi2SetBoolean", nvr);
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2String value[]) {
    (void)vr;
    (void)value;
    return no_variables_of_type(c, "fmi2SetString", nvr);
}

/* ---------------------------------------------------------------------------------------------- */
/* FMU state: a copy of ModelData (the host's logger and the instance name are not part of it)     */

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    Instance *inst = (Instance *)c;
    Snapshot *snapshot;
    if (inst == NULL) return fmi2Error;
    if (FMUstate == NULL) {
        log_message(inst, fmi2Error, "fmi2GetFMUstate: FMUstate is NULL");
        return fmi2Error;
    }
    snapshot = (Snapshot *)*FMUstate; /* non-NULL: a state to overwrite */
    if (snapshot != NULL && snapshot->magic != SNAPSHOT_MAGIC) {
        log_message(inst, fmi2Error, "fmi2GetFMUstate: *FMUstate is not a DcMotor FMU state");
        return fmi2Error;
    }
    if (snapshot == NULL) snapshot = (Snapshot *)calloc(1, sizeof *snapshot);
    if (snapshot == NULL) {
        log_message(inst, fmi2Error, "fmi2GetFMUstate: out of memory");
        return fmi2Error;
    }
    snapshot->magic = SNAPSHOT_MAGIC;
    snapshot->data = inst->m;
    *FMUstate = snapshot;
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    Instance *inst = (Instance *)c;
    const Snapshot *snapshot = (const Snapshot *)FMUstate;
    if (inst == NULL) return fmi2Error;
    if (snapshot == NULL || snapshot->magic != SNAPSHOT_MAGIC) {
        log_message(inst, fmi2Error, "fmi2SetFMUstate: not a DcMotor FMU state");
        return fmi2Error;
    }
    inst->m = snapshot->data;
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    Instance *inst = (Instance *)c;
    Snapshot *snapshot;
    if (inst == NULL) return fmi2Error;
    if (FMUstate == NULL || *FMUstate == NULL) return fmi2OK; /* nothing to free */
    snapshot = (Snapshot *)*FMUstate;
    if (snapshot->magic != SNAPSHOT_MAGIC) {
        log_message(inst, fmi2Error, "fmi2FreeFMUstate: not a DcMotor FMU state");
        return fmi2Error;
    }
    snapshot->magic = 0; /* a second free of the same pointer is then caught above, if still mapped */
    free(snapshot);
    *FMUstate = NULL;
    return fmi2OK;
}

/* canSerializeFMUstate="false" */
fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    Instance *inst = (Instance *)c;
    (void)FMUstate;
    (void)size;
    if (inst != NULL) log_message(inst, fmi2Error, "fmi2SerializedFMUstateSize: DcMotor cannot serialize its state");
    return fmi2Error;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[], size_t size) {
    Instance *inst = (Instance *)c;
    (void)FMUstate;
    (void)serializedState;
    (void)size;
    if (inst != NULL) log_message(inst, fmi2Error, "fmi2SerializeFMUstate: DcMotor cannot serialize its state");
    return fmi2Error;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate) {
    Instance *inst = (Instance *)c;
    (void)serializedState;
    (void)size;
    (void)FMUstate;
    if (inst != NULL) log_message(inst, fmi2Error, "fmi2DeSerializeFMUstate: DcMotor cannot serialize its state");
    return fmi2Error;
}

/* ---------------------------------------------------------------------------------------------- */
/* Unsupported capabilities (providesDirectionalDerivative, canInterpolateInputs and                */
/* maxOutputDerivativeOrder are left at their defaults false / false / 0)                           */

static fmi2Status unsupported(fmi2Component c, const char *function) {
    Instance *inst = (Instance *)c;
    if (inst != NULL) log_message(inst, fmi2Error, "%s: not supported by DcMotor", function);
    return fmi2Error;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[], size_t nUnknown,
                                        const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[]) {
    (void)vUnknown_ref;
    (void)nUnknown;
    (void)vKnown_ref;
    (void)nKnown;
    (void)dvKnown;
    (void)dvUnknown;
    return unsupported(c, "fmi2GetDirectionalDerivative");
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    (void)vr;
    (void)nvr;
    (void)order;
    (void)value;
    return unsupported(c, "fmi2SetRealInputDerivatives");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    (void)vr;
    (void)nvr;
    (void)order;
    (void)value;
    return unsupported(c, "fmi2GetRealOutputDerivatives");
}

/* ---------------------------------------------------------------------------------------------- */
/* Co-simulation: stepping                                                                         */

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    Instance *inst = (Instance *)c;
    double x[N_STATES], substeps, dt;
    long n, count;
    int j;
    (void)noSetFMUStatePriorToCurrentPoint; /* nothing to discard: a state is one small struct */
    if (inst == NULL) return fmi2Error;
    if (wrong_mode(inst, "fmi2DoStep", inst->m.mode == MODE_STEP_COMPLETE)) return fmi2Error;
    if (!(communicationStepSize > 0.0) || !isfinite(communicationStepSize) || !isfinite(currentCommunicationPoint)) {
        log_message(inst, fmi2Error, "fmi2DoStep: communication step %g from t = %g refused: the step must be "
                    "finite and > 0", communicationStepSize, currentCommunicationPoint);
        return fmi2Error;
    }
    /* ceil(h / 0.5 ms) equal substeps; the relative 1e-12 keeps h = 0.05 at 100 substeps, not 101,
     * when the division rounds up by an ulp. */
    substeps = ceil(communicationStepSize / MAX_SUBSTEP_S * (1.0 - 1e-12));
    if (substeps < 1.0) substeps = 1.0;
    if (substeps > MAX_SUBSTEPS) {
        log_message(inst, fmi2Error, "fmi2DoStep: communication step %g s refused: it would need %g RK4 substeps "
                    "of 0.5 ms (at most %g)", communicationStepSize, substeps, MAX_SUBSTEPS);
        return fmi2Error;
    }
    count = (long)substeps;
    dt = communicationStepSize / substeps;
    /* integrate a copy: a step that diverges leaves the last good state (and outputs) in place */
    memcpy(x, inst->m.x, sizeof x);
    for (n = 0; n < count; n++) rk4_step(&inst->m, x, dt);
    for (j = 0; j < N_STATES; j++) {
        if (!isfinite(x[j])) {
            log_message(inst, fmi2Error, "fmi2DoStep: the state became non-finite between t = %g and t = %g "
                        "(i = %g A, omega = %g rad/s, theta = %g rad at the start of the step, V = %g V)",
                        currentCommunicationPoint, currentCommunicationPoint + communicationStepSize,
                        inst->m.x[X_I], inst->m.x[X_OMEGA], inst->m.x[X_THETA], inst->m.V);
            inst->m.mode = MODE_ERROR;
            return fmi2Error;
        }
    }
    memcpy(inst->m.x, x, sizeof x);
    inst->m.time = currentCommunicationPoint + communicationStepSize;
    return fmi2OK;
}

fmi2Status fmi2CancelStep(fmi2Component c) {
    Instance *inst = (Instance *)c;
    /* fmi2DoStep never returns fmi2Pending, so there is never a step to cancel */
    if (inst != NULL) log_message(inst, fmi2Error, "fmi2CancelStep: no asynchronous step is running");
    return fmi2Error;
}

/* The status functions: fmi2DoStep is synchronous and never discards, so only the last successful
 * time is known; the other kinds answer fmi2Discard (FMI 2.0: "status not available"). */
static fmi2Status status_query(fmi2Component c, const char *function, fmi2StatusKind s, const void *value) {
    Instance *inst = (Instance *)c;
    if (inst == NULL) return fmi2Error;
    if (value == NULL) {
        log_message(inst, fmi2Error, "%s: value is NULL", function);
        return fmi2Error;
    }
    if (s != fmi2DoStepStatus && s != fmi2PendingStatus && s != fmi2LastSuccessfulTime && s != fmi2Terminated) {
        log_message(inst, fmi2Error, "%s: unknown status kind %d", function, (int)s);
        return fmi2Error;
    }
    return fmi2Discard;
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    return status_query(c, "fmi2GetStatus", s, value);
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    fmi2Status status = status_query(c, "fmi2GetRealStatus", s, value);
    if (status == fmi2Discard && s == fmi2LastSuccessfulTime) {
        *value = ((Instance *)c)->m.time;
        return fmi2OK;
    }
    return status;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    return status_query(c, "fmi2GetIntegerStatus", s, value);
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    return status_query(c, "fmi2GetBooleanStatus", s, value);
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    return status_query(c, "fmi2GetStringStatus", s, value);
}

/* ---------------------------------------------------------------------------------------------- */
/* Model exchange: the host integrates the states; the model has no events.                        */

static int me_call(Instance *inst, const char *function, int allowed_modes) {
    if (inst->type != fmi2ModelExchange) {
        log_message(inst, fmi2Error, "%s: this instance was created for co-simulation", function);
        return 1;
    }
    return wrong_mode(inst, function, allowed_modes);
}

static int wrong_size(Instance *inst, const char *function, size_t n, size_t expected, const void *array) {
    if (n != expected) {
        log_message(inst, fmi2Error, "%s: called with %lu values; DcMotor has %lu", function, (unsigned long)n,
                    (unsigned long)expected);
        return 1;
    }
    if (n > 0 && array == NULL) {
        log_message(inst, fmi2Error, "%s: the array is NULL", function);
        return 1;
    }
    return 0;
}

fmi2Status fmi2EnterEventMode(fmi2Component c) {
    Instance *inst = (Instance *)c;
    if (inst == NULL) return fmi2Error;
    if (me_call(inst, "fmi2EnterEventMode", inst->m.mode == MODE_CONTINUOUS || inst->m.mode == MODE_EVENT))
        return fmi2Error;
    inst->m.mode = MODE_EVENT;
    return fmi2OK;
}

fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *fmi2eventInfo) {
    Instance *inst = (Instance *)c;
    if (inst == NULL) return fmi2Error;
    if (me_call(inst, "fmi2NewDiscreteStates", inst->m.mode == MODE_EVENT)) return fmi2Error;
    if (fmi2eventInfo == NULL) {
        log_message(inst, fmi2Error, "fmi2NewDiscreteStates: eventInfo is NULL");
        return fmi2Error;
    }
    fmi2eventInfo->newDiscreteStatesNeeded = fmi2False;
    fmi2eventInfo->terminateSimulation = fmi2False;
    fmi2eventInfo->nominalsOfContinuousStatesChanged = fmi2False;
    fmi2eventInfo->valuesOfContinuousStatesChanged = fmi2False;
    fmi2eventInfo->nextEventTimeDefined = fmi2False;
    fmi2eventInfo->nextEventTime = 0.0;
    return fmi2OK;
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) {
    Instance *inst = (Instance *)c;
    if (inst == NULL) return fmi2Error;
    if (me_call(inst, "fmi2EnterContinuousTimeMode", inst->m.mode == MODE_EVENT)) return fmi2Error;
    inst->m.mode = MODE_CONTINUOUS;
    return fmi2OK;
}

fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean *enterEventMode, fmi2Boolean *terminateSimulation) {
    Instance *inst = (Instance *)c;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (inst == NULL) return fmi2Error;
    if (me_call(inst, "fmi2CompletedIntegratorStep", inst->m.mode == MODE_CONTINUOUS)) return fmi2Error;
    if (enterEventMode == NULL || terminateSimulation == NULL) {
        log_message(inst, fmi2Error, "fmi2CompletedIntegratorStep: an output argument is NULL");
        return fmi2Error;
    }
    *enterEventMode = fmi2False;
    *terminateSimulation = fmi2False;
    return fmi2OK;
}

fmi2Status fmi2SetTime(fmi2Component c, fmi2Real time) {
    Instance *inst = (Instance *)c;
    if (inst == NULL) return fmi2Error;
    if (me_call(inst, "fmi2SetTime", inst->m.mode == MODE_EVENT || inst->m.mode == MODE_CONTINUOUS))
        return fmi2Error;
    if (!isfinite(time)) {
        log_message(inst, fmi2Error, "fmi2SetTime: time = %g is not finite", time);
        return fmi2Error;
    }
    inst->m.time = time;
    return fmi2OK;
}

fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx) {
    Instance *inst = (Instance *)c;
    size_t j;
    if (inst == NULL) return fmi2Error;
    if (me_call(inst, "fmi2SetContinuousStates", inst->m.mode == MODE_CONTINUOUS)) return fmi2Error;
    if (wrong_size(inst, "fmi2SetContinuousStates", nx, N_STATES, x)) return fmi2Error;
    for (j = 0; j < nx; j++) {
        if (!isfinite(x[j])) {
            log_message(inst, fmi2Error, "fmi2SetContinuousStates: %s = %g is not finite at t = %g",
                        VARIABLE_NAMES[j == X_I ? VR_I : j == X_OMEGA ? VR_OMEGA : VR_THETA], x[j], inst->m.time);
            return fmi2Error;
        }
    }
    memcpy(inst->m.x, x, sizeof inst->m.x);
    return fmi2OK;
}

static int me_query_mode(const Instance *inst) {
    return inst->m.mode == MODE_INITIALIZATION || inst->m.mode == MODE_EVENT || inst->m.mode == MODE_CONTINUOUS ||
           inst->m.mode == MODE_TERMINATED;
}

fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real derivatives_[], size_t nx) {
    Instance *inst = (Instance *)c;
    if (inst == NULL) return fmi2Error;
    if (me_call(inst, "fmi2GetDerivatives", me_query_mode(inst))) return fmi2Error;
    if (wrong_size(inst, "fmi2GetDerivatives", nx, N_STATES, derivatives_)) return fmi2Error;
    derivatives(&inst->m, inst->m.x, derivatives_);
    return fmi2OK;
}

fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real eventIndicators[], size_t ni) {
    Instance *inst = (Instance *)c;
    if (inst == NULL) return fmi2Error;
    if (me_call(inst, "fmi2GetEventIndicators", me_query_mode(inst))) return fmi2Error;
    return wrong_size(inst, "fmi2GetEventIndicators", ni, 0, eventIndicators) ? fmi2Error : fmi2OK;
}

fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx) {
    Instance *inst = (Instance *)c;
    if (inst == NULL) return fmi2Error;
    if (me_call(inst, "fmi2GetContinuousStates", me_query_mode(inst))) return fmi2Error;
    if (wrong_size(inst, "fmi2GetContinuousStates", nx, N_STATES, x)) return fmi2Error;
    memcpy(x, inst->m.x, sizeof inst->m.x);
    return fmi2OK;
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x_nominal[], size_t nx) {
    Instance *inst = (Instance *)c;
    size_t j;
    if (inst == NULL) return fmi2Error;
    if (me_call(inst, "fmi2GetNominalsOfContinuousStates", inst->m.mode != MODE_ERROR)) return fmi2Error;
    if (wrong_size(inst, "fmi2GetNominalsOfContinuousStates", nx, N_STATES, x_nominal)) return fmi2Error;
    for (j = 0; j < nx; j++) x_nominal[j] = 1.0;
    return fmi2OK;
}
