/* fmi_host: a minimal FMI 2.0 co-simulation host in C, the project's own stand-in for a non-Python
 * importer (fmusim, the FMU Compliance Checker, a Simulink S-function...). Like them it dlopen()s each
 * FMU binary with RTLD_LOCAL, instantiates with a logger callback that prints every message, sets
 * parameters, runs a fixed-step loop and prints CSV of the outputs on stdout (log lines go to stderr).
 *
 * It knows nothing of modelDescription.xml: the caller (tests/test_c_host.py) reads it and passes the
 * model identifier, GUID and value references on the command line. See docs/fmu-native-hosts.md.
 *
 * Build:  gcc -std=c99 -O2 -I <fmpy>/c-code -o fmi_host fmi_host.c -ldl -lm
 *         x86_64-w64-mingw32-gcc -std=c99 -O2 -I <fmpy>/c-code -o fmi_host.exe fmi_host.c   (Windows: it loads
 *         binaries/win64/<id>.dll; tests/test_windows_host.py runs it under Wine)
 *
 * Usage:  fmi_host MODE key=value ...
 *   MODE open       the plant alone, u = OFFSET + AMP*sin(2*pi*FREQ*t);      CSV: t,u,l,p
 *   MODE closed     plant and controller, the master algorithm below;           CSV: t,l,u
 *   MODE instances  two plant instances a, b at once (load_a, load_b, constant u), both freed, the
 *                   binary dlclose()d and loaded again (unless unload=0), then c instantiated like a;
 *                                                                               CSV: name,l
 *   MODE badvr      N times (steps=N): instantiate, fmi2GetReal and fmi2SetReal with an unknown value
 *                   reference (100000), one step, free; the host must survive; CSV: i,get,set,l
 * FMU keys (P = plant, C = ctrl):
 *   P.dir=DIR P.id=MODEL_ID P.guid=GUID        extracted FMU folder, modelIdentifier, guid
 *   P.u=VR P.l=VR P.p=VR P.load=VR             value references (plant: input u, outputs l, p, input load_force)
 *   C.l=VR C.u=VR                              controller: input l, output u
 *   P.real=VR:VALUE  P.int=VR:VALUE            parameters set in initialization mode (repeatable)
 * Run keys: steps=N dt=TS sine=OFFSET,AMP,FREQ u_const=V load_a=N load_b=N
 *           unload=0 (do not dlclose the FMU binaries at the end; default 1, as hosts do)
 *
 * Closed loop, for k = 0..N-1, t = k*dt:
 *   l = plant.getReal(l); ctrl.setReal(l); ctrl.doStep(t, dt); u = ctrl.getReal(u);
 *   plant.setReal(u); plant.doStep(t, dt); print t, l, u
 *
 * The open and closed loops print their own duration to stderr, "fmi_host: stepping loop: N steps in S s"
 * (a monotonic clock around the loop alone: benchmarks/fmu_c_host.py takes the real-time factor from it,
 * since the process's start-up, Python's and the FMUs', varies by more than 2400 steps cost).
 *
 * Exit status: 0 ok, 1 usage, 2 an FMI call failed, 3 fmi2Instantiate returned NULL, 4 load failed.
 */
#define _GNU_SOURCE
#ifdef _WIN32
/* the same host for Windows (MinGW-w64; tests/test_windows_host.py runs it under Wine) */
#include <windows.h>
#include <stdio.h>
#define dlopen(path, mode) ((void *)LoadLibraryA(path))
#define dlsym(lib, name) ((void *)GetProcAddress((HMODULE)(lib), name))
#define dlclose(lib) FreeLibrary((HMODULE)(lib))
static const char *dlerror(void) {
    static char text[64];
    snprintf(text, sizeof text, "Windows error %lu", (unsigned long)GetLastError());
    return text;
}
#define FMU_BINARY "%s/binaries/win64/%s.dll"
#define RESOURCES_URI "file:///%s/resources"
#else
#include <dlfcn.h>
#define FMU_BINARY "%s/binaries/linux64/%s.so"
#define RESOURCES_URI "file://%s/resources"
#endif
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#ifndef _WIN32
#include <time.h>
#endif

#include "fmi2Functions.h"

#define MAX_PARAMS 64

typedef struct {
    char key[8];
    const char *dir, *id, *guid;
    long vr_u, vr_l, vr_p, vr_load;
    int n_real, n_int;
    fmi2ValueReference real_vr[MAX_PARAMS], int_vr[MAX_PARAMS];
    fmi2Real real_val[MAX_PARAMS];
    fmi2Integer int_val[MAX_PARAMS];
    void *lib;
    char uri[4096];
    fmi2InstantiateTYPE *instantiate;
    fmi2FreeInstanceTYPE *freeInstance;
    fmi2SetupExperimentTYPE *setupExperiment;
    fmi2EnterInitializationModeTYPE *enterInit;
    fmi2ExitInitializationModeTYPE *exitInit;
    fmi2TerminateTYPE *terminate;
    fmi2GetRealTYPE *getReal;
    fmi2SetRealTYPE *setReal;
    fmi2SetIntegerTYPE *setInteger;
    fmi2DoStepTYPE *doStep;
} Fmu;

static const char *status_name(fmi2Status s) {
    switch (s) {
    case fmi2OK: return "OK";
    case fmi2Warning: return "Warning";
    case fmi2Discard: return "Discard";
    case fmi2Error: return "Error";
    case fmi2Fatal: return "Fatal";
    case fmi2Pending: return "Pending";
    }
    return "?";
}

static void logger(fmi2ComponentEnvironment env, fmi2String instance, fmi2Status status, fmi2String category,
                   fmi2String message, ...) {
    char buf[8192];
    va_list ap;
    (void)env;
    va_start(ap, message);
    vsnprintf(buf, sizeof buf, message ? message : "", ap);
    va_end(ap);
    fprintf(stderr, "[%s] %s %s: %s\n", status_name(status), instance ? instance : "?",
            category ? category : "-", buf);
    fflush(stderr);
}

static fmi2CallbackFunctions callbacks = {logger, calloc, free, NULL, NULL};

static void die(int code, const char *fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    fprintf(stderr, "fmi_host: ");
    vfprintf(stderr, fmt, ap);
    fprintf(stderr, "\n");
    va_end(ap);
    exit(code);
}

static void check(fmi2Status s, const char *what) {
    if (s != fmi2OK && s != fmi2Warning) die(2, "%s returned %s", what, status_name(s));
}

static void *sym(Fmu *f, const char *name) {
    void *p = dlsym(f->lib, name);
    if (!p) die(4, "%s: symbol %s not found: %s", f->id, name, dlerror());
    return p;
}

static void load(Fmu *f) {
    char path[4096];
    if (!f->dir || !f->id || !f->guid) die(1, "%s.dir, %s.id and %s.guid are required", f->key, f->key, f->key);
    snprintf(path, sizeof path, FMU_BINARY, f->dir, f->id);
    f->lib = dlopen(path, RTLD_NOW | RTLD_LOCAL); /* as fmusim and the FMI Library do */
    if (!f->lib) die(4, "cannot load %s: %s", path, dlerror());
    snprintf(f->uri, sizeof f->uri, RESOURCES_URI, f->dir);
    f->instantiate = (fmi2InstantiateTYPE *)sym(f, "fmi2Instantiate");
    f->freeInstance = (fmi2FreeInstanceTYPE *)sym(f, "fmi2FreeInstance");
    f->setupExperiment = (fmi2SetupExperimentTYPE *)sym(f, "fmi2SetupExperiment");
    f->enterInit = (fmi2EnterInitializationModeTYPE *)sym(f, "fmi2EnterInitializationMode");
    f->exitInit = (fmi2ExitInitializationModeTYPE *)sym(f, "fmi2ExitInitializationMode");
    f->terminate = (fmi2TerminateTYPE *)sym(f, "fmi2Terminate");
    f->getReal = (fmi2GetRealTYPE *)sym(f, "fmi2GetReal");
    f->setReal = (fmi2SetRealTYPE *)sym(f, "fmi2SetReal");
    f->setInteger = (fmi2SetIntegerTYPE *)sym(f, "fmi2SetInteger");
    f->doStep = (fmi2DoStepTYPE *)sym(f, "fmi2DoStep");
}

/* Instantiate and initialise; extra_vr/extra_val (may be -1) is one more Real set after the parameters. */
static fmi2Component start(Fmu *f, const char *name, long extra_vr, double extra_val) {
    fmi2Component c = f->instantiate(name, fmi2CoSimulation, f->guid, f->uri, &callbacks, fmi2False, fmi2True);
    if (!c) die(3, "fmi2Instantiate(%s) returned NULL", name);
    check(f->setupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0), "fmi2SetupExperiment");
    check(f->enterInit(c), "fmi2EnterInitializationMode");
    if (f->n_real) check(f->setReal(c, f->real_vr, (size_t)f->n_real, f->real_val), "fmi2SetReal (parameters)");
    if (f->n_int) check(f->setInteger(c, f->int_vr, (size_t)f->n_int, f->int_val), "fmi2SetInteger (parameters)");
    if (extra_vr >= 0) {
        fmi2ValueReference vr = (fmi2ValueReference)extra_vr;
        check(f->setReal(c, &vr, 1, &extra_val), "fmi2SetReal");
    }
    check(f->exitInit(c), "fmi2ExitInitializationMode");
    return c;
}

static void stop(Fmu *f, fmi2Component c) {
    check(f->terminate(c), "fmi2Terminate");
    f->freeInstance(c);
}

static double get1(Fmu *f, fmi2Component c, long vr) {
    fmi2ValueReference r = (fmi2ValueReference)vr;
    fmi2Real v;
    if (vr < 0) die(1, "%s: a value reference is missing", f->key);
    check(f->getReal(c, &r, 1, &v), "fmi2GetReal");
    return v;
}

static void set1(Fmu *f, fmi2Component c, long vr, double v) {
    fmi2ValueReference r = (fmi2ValueReference)vr;
    if (vr < 0) die(1, "%s: a value reference is missing", f->key);
    check(f->setReal(c, &r, 1, &v), "fmi2SetReal");
}

static void step(Fmu *f, fmi2Component c, double t, double dt) {
    check(f->doStep(c, t, dt, fmi2True), "fmi2DoStep");
}

static int fmu_option(Fmu *f, const char *key, const char *value) {
    char *end;
    if (!strcmp(key, "dir")) f->dir = value;
    else if (!strcmp(key, "id")) f->id = value;
    else if (!strcmp(key, "guid")) f->guid = value;
    else if (!strcmp(key, "u")) f->vr_u = atol(value);
    else if (!strcmp(key, "l")) f->vr_l = atol(value);
    else if (!strcmp(key, "p")) f->vr_p = atol(value);
    else if (!strcmp(key, "load")) f->vr_load = atol(value);
    else if (!strcmp(key, "real") || !strcmp(key, "int")) {
        long vr = strtol(value, &end, 10);
        if (*end != ':') return 0;
        if (key[0] == 'r') {
            if (f->n_real == MAX_PARAMS) return 0;
            f->real_vr[f->n_real] = (fmi2ValueReference)vr;
            f->real_val[f->n_real++] = strtod(end + 1, NULL);
        } else {
            if (f->n_int == MAX_PARAMS) return 0;
            f->int_vr[f->n_int] = (fmi2ValueReference)vr;
            f->int_val[f->n_int++] = (fmi2Integer)strtol(end + 1, NULL, 10);
        }
    } else return 0;
    return 1;
}

/* Seconds on a monotonic clock (differences only). */
static double now_s(void) {
#ifdef _WIN32
    LARGE_INTEGER count, frequency;
    QueryPerformanceCounter(&count);
    QueryPerformanceFrequency(&frequency);
    return (double)count.QuadPart / (double)frequency.QuadPart;
#else
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
#endif
}

static void report_loop(long steps, double started) {
    fprintf(stderr, "fmi_host: stepping loop: %ld steps in %.6f s\n", steps, now_s() - started);
}

int main(int argc, char **argv) {
    Fmu plant = {.key = "P", .vr_u = -1, .vr_l = -1, .vr_p = -1, .vr_load = -1};
    Fmu ctrl = {.key = "C", .vr_u = -1, .vr_l = -1, .vr_p = -1, .vr_load = -1};
    long steps = 200, unload = 1;
    double dt = 0.1, offset = 5.0, amp = 3.0, freq = 0.1, u_const = 6.0, load_a = 44.0, load_b = 68.0;
    const char *mode;
    int i;

    if (argc < 2) die(1, "usage: fmi_host open|closed|instances|badvr key=value ... (see the comment in fmi_host.c)");
    mode = argv[1];
    for (i = 2; i < argc; i++) {
        char *arg = argv[i], *eq = strchr(arg, '='), *dot;
        int ok = 0;
        if (!eq) die(1, "bad argument %s (key=value expected)", arg);
        *eq = '\0';
        dot = strchr(arg, '.');
        if (dot && dot - arg == 1 && (arg[0] == 'P' || arg[0] == 'C'))
            ok = fmu_option(arg[0] == 'P' ? &plant : &ctrl, dot + 1, eq + 1);
        else if (!strcmp(arg, "steps")) ok = (steps = atol(eq + 1)) > 0;
        else if (!strcmp(arg, "dt")) ok = (dt = strtod(eq + 1, NULL)) > 0;
        else if (!strcmp(arg, "sine")) ok = sscanf(eq + 1, "%lf,%lf,%lf", &offset, &amp, &freq) == 3;
        else if (!strcmp(arg, "u_const")) { u_const = strtod(eq + 1, NULL); ok = 1; }
        else if (!strcmp(arg, "load_a")) { load_a = strtod(eq + 1, NULL); ok = 1; }
        else if (!strcmp(arg, "load_b")) { load_b = strtod(eq + 1, NULL); ok = 1; }
        else if (!strcmp(arg, "unload")) { unload = atol(eq + 1); ok = 1; }
        if (!ok) die(1, "bad argument %s=%s", arg, eq + 1);
    }

    load(&plant);
    if (!strcmp(mode, "open")) {
        fmi2Component p = start(&plant, "plant", -1, 0.0);
        long k;
        double started;
        printf("t,u,l,p\n");
        started = now_s();
        for (k = 0; k < steps; k++) {
            double t = (double)k * dt, u = offset + amp * sin(2.0 * M_PI * freq * t), l, pr;
            set1(&plant, p, plant.vr_u, u);
            step(&plant, p, t, dt);
            l = get1(&plant, p, plant.vr_l);
            pr = plant.vr_p >= 0 ? get1(&plant, p, plant.vr_p) : NAN;
            printf("%.17g,%.17g,%.17g,%.17g\n", t, u, l, pr);
        }
        report_loop(steps, started);
        stop(&plant, p);
    } else if (!strcmp(mode, "closed")) {
        fmi2Component p, c;
        long k;
        double started;
        load(&ctrl);
        p = start(&plant, "plant", -1, 0.0);
        c = start(&ctrl, "controller", -1, 0.0);
        printf("t,l,u\n");
        started = now_s();
        for (k = 0; k < steps; k++) {
            double t = (double)k * dt, l, u;
            l = get1(&plant, p, plant.vr_l);
            set1(&ctrl, c, ctrl.vr_l, l);
            step(&ctrl, c, t, dt);
            u = get1(&ctrl, c, ctrl.vr_u);
            set1(&plant, p, plant.vr_u, u);
            step(&plant, p, t, dt);
            printf("%.17g,%.17g,%.17g\n", t, l, u);
        }
        report_loop(steps, started);
        stop(&ctrl, c);
        stop(&plant, p);
        if (unload) dlclose(ctrl.lib);
    } else if (!strcmp(mode, "instances")) {
        fmi2Component a = start(&plant, "a", plant.vr_load, load_a), b = start(&plant, "b", plant.vr_load, load_b), c;
        long k;
        printf("name,l\n");
        for (k = 0; k < steps; k++) {
            set1(&plant, a, plant.vr_u, u_const);
            set1(&plant, b, plant.vr_u, u_const);
            step(&plant, a, (double)k * dt, dt);
            step(&plant, b, (double)k * dt, dt);
        }
        printf("a,%.17g\nb,%.17g\n", get1(&plant, a, plant.vr_l), get1(&plant, b, plant.vr_l));
        stop(&plant, a);
        stop(&plant, b);
        if (unload) { /* as a host that runs a new simulation does: unload, load again, instantiate */
            dlclose(plant.lib);
            load(&plant);
        }
        c = start(&plant, "c", plant.vr_load, load_a);
        for (k = 0; k < steps; k++) {
            set1(&plant, c, plant.vr_u, u_const);
            step(&plant, c, (double)k * dt, dt);
        }
        printf("c,%.17g\n", get1(&plant, c, plant.vr_l));
        stop(&plant, c);
    } else if (!strcmp(mode, "badvr")) {
        long k;
        printf("i,get,set,l\n");
        for (k = 0; k < steps; k++) {
            fmi2Component c = start(&plant, "bad", -1, 0.0);
            fmi2ValueReference bad = 100000;
            fmi2Real v = 0.0, one = 1.0;
            fmi2Status get = plant.getReal(c, &bad, 1, &v), set = plant.setReal(c, &bad, 1, &one);
            double l;
            set1(&plant, c, plant.vr_u, u_const);
            step(&plant, c, 0.0, dt);
            l = get1(&plant, c, plant.vr_l);
            printf("%ld,%s,%s,%.17g\n", k, status_name(get), status_name(set), l);
            stop(&plant, c);
        }
    } else {
        die(1, "unknown mode %s", mode);
    }
    fflush(stdout);
    if (unload) dlclose(plant.lib);
    return 0;
}
