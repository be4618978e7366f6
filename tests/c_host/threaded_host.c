/* threaded_host: what a parallel co-simulation master (libcosim, Ecos with TBB, OMSimulator) does to
 * the FMUs with threads, in a C process with no Python of its own. tests/test_c_host.py runs it.
 *
 * Build:  gcc -std=gnu11 -O2 -pthread -I <fmpy>/c-code -o threaded_host threaded_host.c -ldl
 *         x86_64-w64-mingw32-gcc -std=gnu11 -O2 -I <fmpy>/c-code -o threaded_host.exe threaded_host.c -static
 *         (Windows: the FMU's binaries/win64 DLL, POSIX threads from MinGW-w64's winpthreads; run with the
 *         Python folder holding python3.dll on PATH; P.dir=C:/... with forward slashes)
 *
 * Usage:  threaded_host MODE key=value ...
 *   MODE loops    two closed loops (plant + controller each; plant load 44 N and 68 N), instantiated
 *                 with one thread per instance all at once (the process's first fmi2Instantiate of
 *                 both FMUs at the same moment), then stepped as a parallel (Jacobi) master steps
 *                 them: every fmi2DoStep of a communication step in its own thread, on the previous
 *                 step's outputs. threads=1 does the same one instance at a time in one thread.
 *                 CSV: k,l44,u44,l68,u68 (hex floats, so a comparison is bit for bit)
 *   MODE states   the plant's FMU states by FMI 2.0 (2.1.8), N times (steps=N) each:
 *                 fmi2GetFMUstate into the state already held, fmi2DeSerializeFMUstate into it;
 *                 then fmi2FreeFMUstate (must set it to NULL) and a second free (must be ignored).
 *                 Prints: key=value lines (RSS growth in kB, the pointer after the free, statuses)
 *   MODE threads  N short-lived host threads (steps=N), each one fmi2GetReal on one plant instance.
 *                 Prints: rss_growth_kb=... (Linux: resident set; Windows: commit charge)
 * Keys: P.dir= P.id= P.guid= P.u= P.l= P.load=  (plant: folder, model identifier, GUID, value refs)
 *       C.dir= C.id= C.guid= C.l= C.u=          (controller)   steps=N threads=1|4
 * Exit status: 0 ok, 1 usage, 2 an FMI call failed, 3 fmi2Instantiate returned NULL, 4 load failed.
 */
#define _GNU_SOURCE
#ifdef _WIN32
#define WIN32_LEAN_AND_MEAN
#include <windows.h>
#include <psapi.h>
#else
#include <dlfcn.h>
#endif
#include <pthread.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "fmi2Functions.h"

#define TS 0.1

typedef struct {
    const char *dir, *id, *guid;
    long vr_u, vr_l, vr_load;
    void *lib;
    char uri[4096];
#define F(n) fmi2##n##TYPE *n;
    F(Instantiate) F(FreeInstance) F(SetupExperiment) F(EnterInitializationMode) F(ExitInitializationMode)
    F(Terminate) F(GetReal) F(SetReal) F(DoStep) F(GetFMUstate) F(FreeFMUstate) F(SerializedFMUstateSize)
    F(SerializeFMUstate) F(DeSerializeFMUstate)
#undef F
} Fmu;

static Fmu PL = {.vr_u = -1, .vr_l = -1, .vr_load = -1}, CT = {.vr_u = -1, .vr_l = -1, .vr_load = -1};

static void die(int code, const char *fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    fprintf(stderr, "threaded_host: ");
    vfprintf(stderr, fmt, ap);
    fprintf(stderr, "\n");
    va_end(ap);
    fflush(stdout);
    _exit(code);
}

static void log_message(fmi2ComponentEnvironment env, fmi2String instance, fmi2Status status, fmi2String category,
                        fmi2String message, ...) {
    char buf[8192];
    va_list ap;
    (void)env;
    va_start(ap, message);
    vsnprintf(buf, sizeof buf, message ? message : "(NULL message)", ap);
    va_end(ap);
    fprintf(stderr, "[%d] %s %s: %s\n", (int)status, instance ? instance : "(NULL instance)",
            category ? category : "(NULL category)", buf);
}

static fmi2CallbackFunctions callbacks = {log_message, calloc, free, NULL, NULL};

static void check(fmi2Status s, const char *what) {
    if (s != fmi2OK && s != fmi2Warning) die(2, "%s returned status %d", what, (int)s);
}

#ifdef _WIN32
#define BINARY "binaries/win64/%s.dll"
#define URI "file:///%s/resources"
#define OPEN(path) (void *)LoadLibraryA(path)
#define OPEN_ERROR() "LoadLibrary failed"
#define SYMBOL(lib, name) (void *)GetProcAddress((HMODULE)(lib), name)
#else
#define BINARY "binaries/linux64/%s.so"
#define URI "file://%s/resources"
#define OPEN(path) dlopen(path, RTLD_NOW | RTLD_LOCAL)
#define OPEN_ERROR() dlerror()
#define SYMBOL(lib, name) dlsym(lib, name)
#endif

static void load(Fmu *f, const char *key) {
    char path[4096];
    if (!f->dir || !f->id || !f->guid) die(1, "%s.dir, %s.id and %s.guid are required", key, key, key);
    snprintf(path, sizeof path, "%s/" BINARY, f->dir, f->id);
    if (!(f->lib = OPEN(path))) die(4, "cannot load %s: %s", path, OPEN_ERROR());
    snprintf(f->uri, sizeof f->uri, URI, f->dir);
#define F(n) if (!(f->n = (fmi2##n##TYPE *)SYMBOL(f->lib, "fmi2" #n))) die(4, "%s: no fmi2" #n, f->id);
    F(Instantiate) F(FreeInstance) F(SetupExperiment) F(EnterInitializationMode) F(ExitInitializationMode)
    F(Terminate) F(GetReal) F(SetReal) F(DoStep) F(GetFMUstate) F(FreeFMUstate) F(SerializedFMUstateSize)
    F(SerializeFMUstate) F(DeSerializeFMUstate)
#undef F
}

#ifdef _WIN32
static long rss_kb(void) {   /* the commit charge: the private memory the process allocated (Wine: its
                               PrivateUsage stays 0, its PagefileUsage counts) */
    PROCESS_MEMORY_COUNTERS m = {.cb = sizeof m};
    if (!GetProcessMemoryInfo(GetCurrentProcess(), &m, sizeof m)) die(1, "GetProcessMemoryInfo failed");
    return (long)(m.PagefileUsage / 1024);
}
#else
static long rss_kb(void) {
    long pages = 0, resident = 0;
    FILE *f = fopen("/proc/self/statm", "r");
    if (!f || fscanf(f, "%ld %ld", &pages, &resident) != 2) die(1, "cannot read /proc/self/statm");
    fclose(f);
    return resident * 4;   /* 4 kB pages (x86-64 Linux) */
}
#endif

/* ---- closed loops ---- */
typedef struct {
    Fmu *f;
    const char *name;
    double load_n;        /* plant only */
    fmi2Component c;
    double in, out;       /* this step's input (the other FMU's previous output) and output */
} Instance;

static Instance INST[4];  /* plant44, ctrl44, plant68, ctrl68 */
static int N_THREADS = 1, STEPS = 600, STEP_K;
static pthread_barrier_t BARRIER;

static void instantiate(Instance *I) {
    fmi2ValueReference vr;
    I->c = I->f->Instantiate(I->name, fmi2CoSimulation, I->f->guid, I->f->uri, &callbacks, fmi2False, fmi2False);
    if (!I->c) die(3, "fmi2Instantiate(%s) returned NULL", I->name);
    check(I->f->SetupExperiment(I->c, fmi2False, 0.0, 0.0, fmi2False, 0.0), "fmi2SetupExperiment");
    check(I->f->EnterInitializationMode(I->c), "fmi2EnterInitializationMode");
    if (I->f == &PL) {
        vr = (fmi2ValueReference)PL.vr_load;
        check(PL.SetReal(I->c, &vr, 1, &I->load_n), "fmi2SetReal(load)");
    }
    check(I->f->ExitInitializationMode(I->c), "fmi2ExitInitializationMode");
    vr = (fmi2ValueReference)(I->f == &PL ? PL.vr_l : CT.vr_u);   /* the output the other FMU starts from */
    check(I->f->GetReal(I->c, &vr, 1, &I->out), "fmi2GetReal");
}

static void step(Instance *I) {
    fmi2ValueReference in = (fmi2ValueReference)(I->f == &PL ? PL.vr_u : CT.vr_l);
    fmi2ValueReference out = (fmi2ValueReference)(I->f == &PL ? PL.vr_l : CT.vr_u);
    check(I->f->SetReal(I->c, &in, 1, &I->in), "fmi2SetReal");
    check(I->f->DoStep(I->c, STEP_K * TS, TS, fmi2True), "fmi2DoStep");
    check(I->f->GetReal(I->c, &out, 1, &I->out), "fmi2GetReal");
}

static void exchange(void) {   /* Jacobi: every input from the other FMU's output of the step before */
    for (int j = 0; j < 4; j += 2) {
        INST[j].in = INST[j + 1].out;       /* plant u <- controller u */
        INST[j + 1].in = INST[j].out;       /* controller l <- plant l */
    }
}

static void *worker(void *arg) {   /* one instance per thread */
    Instance *I = arg;
    pthread_barrier_wait(&BARRIER);          /* all four fmi2Instantiate at the same moment */
    instantiate(I);
    pthread_barrier_wait(&BARRIER);
    for (int k = 0; k < STEPS; k++) {
        pthread_barrier_wait(&BARRIER);      /* the main thread has exchanged the values */
        step(I);
        pthread_barrier_wait(&BARRIER);
    }
    return NULL;
}

static void run_loops(void) {
    pthread_t th[4];
    INST[0] = (Instance){.f = &PL, .name = "plant44", .load_n = 44.0};
    INST[1] = (Instance){.f = &CT, .name = "ctrl44", .load_n = 0.0};
    INST[2] = (Instance){.f = &PL, .name = "plant68", .load_n = 68.0};
    INST[3] = (Instance){.f = &CT, .name = "ctrl68", .load_n = 0.0};
    printf("k,l44,u44,l68,u68\n");
    if (N_THREADS == 1) {
        for (int j = 0; j < 4; j++) instantiate(&INST[j]);
        for (STEP_K = 0; STEP_K < STEPS; STEP_K++) {
            exchange();
            for (int j = 0; j < 4; j++) step(&INST[j]);
            printf("%d,%a,%a,%a,%a\n", STEP_K, INST[0].out, INST[1].out, INST[2].out, INST[3].out);
        }
    } else {
        pthread_barrier_init(&BARRIER, NULL, 5);
        for (int j = 0; j < 4; j++) pthread_create(&th[j], NULL, worker, &INST[j]);
        pthread_barrier_wait(&BARRIER);
        pthread_barrier_wait(&BARRIER);
        for (STEP_K = 0; STEP_K < STEPS; STEP_K++) {
            exchange();
            pthread_barrier_wait(&BARRIER);
            pthread_barrier_wait(&BARRIER);
            printf("%d,%a,%a,%a,%a\n", STEP_K, INST[0].out, INST[1].out, INST[2].out, INST[3].out);
        }
        for (int j = 0; j < 4; j++) pthread_join(th[j], NULL);
    }
    for (int j = 0; j < 4; j++) {
        check(INST[j].f->Terminate(INST[j].c), "fmi2Terminate");
        INST[j].f->FreeInstance(INST[j].c);
    }
}

/* ---- FMU states ---- */
static void run_states(void) {
    Instance I = {.f = &PL, .name = "plant", .load_n = 44.0};
    fmi2FMUstate st = NULL;
    fmi2Byte *bytes;
    size_t size;
    long before;
    instantiate(&I);
    I.in = 5.0;
    for (STEP_K = 0; STEP_K < 10; STEP_K++) step(&I);
    check(PL.GetFMUstate(I.c, &st), "fmi2GetFMUstate");
    check(PL.SerializedFMUstateSize(I.c, st, &size), "fmi2SerializedFMUstateSize");
    if (!(bytes = malloc(size))) die(1, "out of memory");
    check(PL.SerializeFMUstate(I.c, st, bytes, size), "fmi2SerializeFMUstate");
    for (int i = 0; i < 50; i++) check(PL.GetFMUstate(I.c, &st), "fmi2GetFMUstate");   /* warm-up */
    before = rss_kb();
    for (int i = 0; i < STEPS; i++) check(PL.GetFMUstate(I.c, &st), "fmi2GetFMUstate");
    printf("get_into_held_state_kb=%ld\n", rss_kb() - before);
    before = rss_kb();
    for (int i = 0; i < STEPS; i++) check(PL.DeSerializeFMUstate(I.c, bytes, size, &st), "fmi2DeSerializeFMUstate");
    printf("deserialize_into_held_state_kb=%ld\n", rss_kb() - before);
    check(PL.FreeFMUstate(I.c, &st), "fmi2FreeFMUstate");
    printf("pointer_after_free=%s\n", st ? "set" : "NULL");
    printf("second_free_status=%d\n", (int)PL.FreeFMUstate(I.c, &st));
    check(PL.GetFMUstate(I.c, &st), "fmi2GetFMUstate after the frees");
    check(PL.FreeFMUstate(I.c, &st), "fmi2FreeFMUstate");
    free(bytes);
    check(PL.Terminate(I.c), "fmi2Terminate");
    PL.FreeInstance(I.c);
}

/* ---- short-lived host threads ---- */
static Instance SHARED = {.f = &PL, .name = "plant", .load_n = 44.0};

static void *one_call(void *arg) {
    fmi2ValueReference vr = (fmi2ValueReference)PL.vr_l;
    double l;
    (void)arg;
    check(PL.GetReal(SHARED.c, &vr, 1, &l), "fmi2GetReal");
    return NULL;
}

static void run_threads(void) {
    pthread_t t;
    long before = 0;
    instantiate(&SHARED);
    for (int i = 0; i < 50 + STEPS; i++) {
        if (i == 50) before = rss_kb();   /* after a warm-up */
        if (pthread_create(&t, NULL, one_call, NULL)) die(1, "pthread_create failed");
        pthread_join(t, NULL);
    }
    printf("rss_growth_kb=%ld\n", rss_kb() - before);
    check(PL.Terminate(SHARED.c), "fmi2Terminate");
    PL.FreeInstance(SHARED.c);
}

int main(int argc, char **argv) {
    const char *mode;
    if (argc < 2) die(1, "usage: threaded_host loops|states|threads key=value ... (see threaded_host.c)");
    mode = argv[1];
    for (int i = 2; i < argc; i++) {
        char *eq = strchr(argv[i], '=');
        Fmu *f;
        const char *k, *v;
        if (!eq) die(1, "not key=value: %s", argv[i]);
        *eq = 0;
        k = argv[i];
        v = eq + 1;
        if (!strcmp(k, "steps")) STEPS = atoi(v);
        else if (!strcmp(k, "threads")) N_THREADS = atoi(v);
        else if ((k[0] == 'P' || k[0] == 'C') && k[1] == '.') {
            f = k[0] == 'P' ? &PL : &CT;
            k += 2;
            if (!strcmp(k, "dir")) f->dir = v;
            else if (!strcmp(k, "id")) f->id = v;
            else if (!strcmp(k, "guid")) f->guid = v;
            else if (!strcmp(k, "u")) f->vr_u = atol(v);
            else if (!strcmp(k, "l")) f->vr_l = atol(v);
            else if (!strcmp(k, "load")) f->vr_load = atol(v);
            else die(1, "unknown key %s", argv[i]);
        } else die(1, "unknown key %s", argv[i]);
    }
    if (N_THREADS != 1 && N_THREADS != 4) die(1, "threads must be 1 or 4");
    load(&PL, "P");
    if (!strcmp(mode, "loops")) {
        load(&CT, "C");
        run_loops();
    } else if (!strcmp(mode, "states")) run_states();
    else if (!strcmp(mode, "threads")) run_threads();
    else die(1, "unknown mode %s", mode);
    fflush(stdout);
    return 0;
}
