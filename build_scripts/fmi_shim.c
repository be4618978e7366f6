/* ---- FMI shim: every FMI function of the FMU goes through here to pythonfmu's ----
   Compiled appended to a loader (native_loader_linux64.c, native_loader_win64.c), which provides
   real(symbol) (pythonfmu's function), library_error() (why pythonfmu's library is not loaded),
   python_home_hint() (what a failed instantiation adds about PYTHONHOME),
   readable(path), local_path(path, size), instantiate_lock()/instantiate_unlock() and pin_thread().
   Why: (1) some hosts do not check a NULL from fmi2Instantiate (libcosim dereferences it, Ecos crashes
   in fmi2SetupExperiment): a failed instantiation returns an instance that answers every later call
   with fmi2Error and the reason; (2) pythonfmu passes category NULL on its exception path (OMSimulator
   aborts on it): the shim names the category after the status; (3) with loggingOn = false pythonfmu
   logs nothing, so a Discard or an Error came without its reason: pythonfmu always logs to the shim,
   which passes on OK/info messages only if the host asked for logging (and, where fmi2SetDebugLogging
   listed categories, only those in them) and every other one always;
   (4) a call returns at least the worst status the FMU logged during it, so the status a host sees
   is the one in the message (pythonfmu returns OK from fmi2ExitInitializationMode after a rejected
   parameter, which the slave logs as an error). */
#include <ctype.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "fmi2Functions.h"

/* The FMUs' log categories (SafeSlave.log_categories in fmi_slave/base.py): a category that
   fmi2SetDebugLogging lists must be one of them (FMI 2.0). */
static const char *const KNOWN_CATEGORIES[] = {"logStatusWarning", "logStatusDiscard", "logStatusError",
                                               "logStatusFatal", "logAll", "logEvents"};
#define N_KNOWN (sizeof KNOWN_CATEGORIES / sizeof KNOWN_CATEGORIES[0])
#define MAX_CATEGORIES N_KNOWN
#define CATEGORY_CHARS 32

typedef struct {
    fmi2Component inner;                  /* pythonfmu's instance; NULL: instantiation failed */
    fmi2CallbackFunctions host;           /* the host's callbacks */
    fmi2CallbackFunctions mine;           /* what pythonfmu gets: our logger, our instance as environment */
    fmi2Boolean logging_on;
    char categories[MAX_CATEGORIES][CATEGORY_CHARS];   /* OK messages passed on with logging on; */
    size_t n_categories;                               /* 0: every category */
    fmi2Status worst;                     /* worst status logged during the current call */
    char name[256];
    char lead[300];                       /* the name messages lead with (numbered where a path: below) */
    char reason[1600];                    /* the first error logged (why an instantiation failed) */
    fmi2FMUstate *states;                 /* the states this instance gave out and has not freed */
    size_t n_states, cap_states;
} Shim;

static long path_named = 0;              /* instances made with a path for a name (see fmi2Instantiate) */

static const char *category_of(fmi2Status status) {
    switch (status) {
        case fmi2Warning: return "logStatusWarning";
        case fmi2Discard: return "logStatusDiscard";
        case fmi2Error: return "logStatusError";
        case fmi2Fatal: return "logStatusFatal";
        default: return "logAll";
    }
}

/* The message goes to the host as a format without arguments, '%' doubled: hosts that format it
   (vsnprintf) print the text, and hosts that cannot take C varargs (fmpy's ctypes logger) get the
   text rather than a bare "%s". The text is led by "[instance name] ": the logger gets the name apart,
   but fmpy's default logger, libcosim and Ecos print the text alone, and in a master with several
   instances of one FMU (a rig of several muscles) the name says which one spoke. */
static void to_host(Shim *s, fmi2String instance, fmi2Status status, fmi2String category, const char *text) {
    char escaped[16384];
    const char *name = instance ? instance : s->name;
    const char *parts[4] = {"[", s->lead, "] ", text};
    size_t j = 0;
    int cut = 0;
    for (int i = *s->lead ? 0 : 3; i < 4 && !cut; i++) {
        for (const char *p = parts[i]; *p; p++) {
            if (j + 3 > sizeof escaped) {
                cut = 1;
                break;
            }
            if (*p == '%') escaped[j++] = '%';
            escaped[j++] = *p;
        }
    }
    if (cut) {   /* a cut text ends on a whole UTF-8 character: a host decoding strictly would drop it */
        while (j > 0 && ((unsigned char)escaped[j - 1] & 0xC0) == 0x80) j--;
        if (j > 0 && ((unsigned char)escaped[j - 1] & 0xC0) == 0xC0) j--;
    }
    escaped[j] = 0;
    if (s->host.logger)
        s->host.logger(s->host.componentEnvironment, name, status,
                       category && *category ? category : category_of(status), escaped);
}

/* Whether a message of `category` is one the host asked for (every one if it listed none). */
static int listed(const Shim *s, fmi2String category) {
    if (!s->n_categories) return 1;
    for (size_t i = 0; i < s->n_categories; i++)
        if (category && !strcmp(s->categories[i], category)) return 1;
    return 0;
}

/* pythonfmu passes its text as the format with no arguments: it is taken literally here (formatting a
   '%' in it would read arguments that were never passed). */
static void shim_logger(fmi2ComponentEnvironment env, fmi2String instance, fmi2Status status, fmi2String category,
                        fmi2String message, ...) {
    Shim *s = (Shim *)env;
    const char *text = message ? message : "";
    if (status > s->worst) s->worst = status;
    if (status >= fmi2Error && !s->reason[0]) snprintf(s->reason, sizeof s->reason, "%s", text);
    if (status == fmi2OK && !(s->logging_on && listed(s, category))) return;
    to_host(s, instance, status, category, text);
}

/* The reason shortened for the messages that repeat it: the host logged it whole once (a message of
   several hundred characters on every later call buried the rest of a host's log). Line breaks become
   spaces; a cut ends on a whole UTF-8 character, marked "...". */
#define SUMMARY_CHARS 200
static void summary(const char *reason, char *out, size_t size) {
    size_t j = 0, limit = size - 4 < SUMMARY_CHARS ? size - 4 : SUMMARY_CHARS;
    const char *p = reason;
    for (; *p && j < limit; p++) {
        if (*p == '\r' || *p == '\n') {
            if (j && out[j - 1] != ' ') out[j++] = ' ';
        } else out[j++] = *p;
    }
    if (*p) {
        while (j > 0 && ((unsigned char)out[j - 1] & 0xC0) == 0x80) j--;
        if (j > 0 && ((unsigned char)out[j - 1] & 0xC0) == 0xC0) j--;
        memcpy(out + j, "...", 3);
        j += 3;
    }
    out[j] = 0;
}

/* A call on an instance whose instantiation failed: logged with the reason in short and answered with
   `status` (fmi2Warning before the first step, fmi2Error from fmi2DoStep on; see FORWARD). */
static fmi2Status refuse(Shim *s, const char *call, fmi2Status status) {
    char text[600], shown[SUMMARY_CHARS + 8];
    summary(s->reason, shown, sizeof shown);
    snprintf(text, sizeof text, "%s %s: the instance failed at instantiation (%s; the whole reason is in the "
             "instance's first message)", call, status >= fmi2Error ? "refused" : "ignored",
             shown[0] ? shown : "no reason was logged");
    to_host(s, s->name, status, category_of(status), text);
    return status;
}


static fmi2Status settle(Shim *s, fmi2Status returned) {
    fmi2Status worst = s->worst;
    s->worst = fmi2OK;
    return worst > returned && worst <= fmi2Fatal ? worst : returned;
}

FMI2_Export const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
FMI2_Export const char *fmi2GetVersion(void) { return fmi2Version; }

/* The resources folder's path from the host's fmuResourceLocation: a file URI (file:///p,
   file://localhost/p, file:/p), percent-decoded as RFC 3986 encodes it (fmpy, libcosim: a space as %20,
   a non-ASCII byte as %C3%BC), or, as some hosts pass it, an absolute path as it is; trailing slashes
   dropped. 0 if it is neither (NULL, another host's file://host/..., a relative path, too long).
   pythonfmu itself only strips "file://" and decodes %20, so any other encoded byte (a user folder
   "Müller") left it a path that does not exist, and its failure path then called a NULL class (a
   segfault in fmi2Instantiate): the shim hands it the decoded path. On Windows the URI's /C:/dir is C:/dir. */
#ifdef _WIN32
#define PATH_BACKSLASH 1
#else
#define PATH_BACKSLASH 0
#endif
/* The value of a hexadecimal digit. By hand, not strtol: built against glibc 2.38 or newer with
   _GNU_SOURCE, strtol binds to __isoc23_strtol@GLIBC_2.38, and the FMU would not load on an older
   Linux (Debian 12, Ubuntu 22.04). */
static int hex_digit(char c) {
    return c <= '9' ? c - '0' : (c | 0x20) - 'a' + 10;
}

static int resource_path(const char *resources, char *path, size_t size) {
    const char *p = resources;
    size_t j = 0;
    int uri;
    if (!p) return 0;
    uri = !strncmp(p, "file:", 5);
    if (uri) {
        p += 5;
        if (!strncmp(p, "//localhost/", 12)) p += 11;
        else if (!strncmp(p, "//", 2)) p += 2;
    }
#ifdef _WIN32
    /* file:///C:/dir gives /C:/dir; a host may also pass C:\dir or C:/dir */
    if (*p == '/' && isalpha((unsigned char)p[1]) && p[2] == ':') p++;
    if (*p != '/' && !(isalpha((unsigned char)p[0]) && p[1] == ':' && (p[2] == '/' || p[2] == '\\'))) return 0;
#else
    if (*p != '/') return 0;
#endif
    for (; *p; p++) {
        if (j + 1 >= size) return 0;
        if (uri && *p == '%' && isxdigit((unsigned char)p[1]) && isxdigit((unsigned char)p[2])) {
            path[j++] = (char)(hex_digit(p[1]) << 4 | hex_digit(p[2]));
            p += 2;
        } else path[j++] = *p;
    }
    while (j > 1 && (path[j - 1] == '/' || (PATH_BACKSLASH && path[j - 1] == '\\'))) j--;
    path[j] = 0;
    return 1;
}

/* The offset of the first byte of ``text`` that is not part of well-formed UTF-8, -1 if none. */
static long not_utf8_at(const char *text) {
    const unsigned char *p = (const unsigned char *)text;
    while (*p) {
        int n = *p < 0x80 ? 0 : (*p & 0xE0) == 0xC0 && *p >= 0xC2 ? 1 : (*p & 0xF0) == 0xE0 ? 2
              : (*p & 0xF8) == 0xF0 && *p <= 0xF4 ? 3 : -1;
        int i;
        if (n < 0) return (long)(p - (const unsigned char *)text);
        for (i = 1; i <= n; i++)
            if ((p[i] & 0xC0) != 0x80) return (long)(p - (const unsigned char *)text);
        p += n + 1;
    }
    return -1;
}

/* ``text`` with every byte outside printable ASCII written as \xHH (a message the host's logger can
   show whatever it decodes with). */
static void escaped(const char *text, char *out, size_t size) {
    size_t j = 0;
    const unsigned char *p = (const unsigned char *)text;
    for (; *p && j + 5 < size; p++) {
        if (*p >= 0x20 && *p < 0x7F) out[j++] = (char)*p;
        else j += (size_t)snprintf(out + j, size - j, "\\x%02X", *p);
    }
    out[j] = 0;
}

/* The GUID in the unzipped FMU's modelDescription.xml (resources/../modelDescription.xml); 0 if it
   cannot be read. */
static int model_guid(const char *resources_dir, char *guid, size_t size) {
    char path[4200], text[65536];
    size_t n;
    const char *g, *e;
    FILE *f;
    snprintf(path, sizeof path, "%s/../modelDescription.xml", resources_dir);
    if (!(f = fopen(path, "rb"))) return 0;
    n = fread(text, 1, sizeof text - 1, f);
    fclose(f);
    text[n] = 0;
    if (!(g = strstr(text, " guid=\""))) return 0;
    g += 7;
    if (!(e = strchr(g, '"')) || (size_t)(e - g) >= size) return 0;
    memcpy(guid, g, (size_t)(e - g));
    guid[e - g] = 0;
    return 1;
}

FMI2_Export fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String resources,
                                          const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                                          fmi2Boolean loggingOn) {
    fmi2InstantiateTYPE *inst = (fmi2InstantiateTYPE *)real("fmi2Instantiate");
    Shim *s = calloc(1, sizeof *s);
    if (!s) return NULL;
    if (functions) s->host = *functions;
    s->mine = s->host;
    s->mine.logger = shim_logger;
    s->mine.componentEnvironment = s;
    s->logging_on = loggingOn;
    snprintf(s->name, sizeof s->name, "%s", name ? name : "");
    /* Ecos names every instance by its FMU's path, so the instances of one FMU share their name: a name
       that is a path is numbered in the order this library made them ("[/x/AMPCController.fmu #2]"),
       and a message still says which instance spoke. */
    if (strchr(s->name, '/') || strchr(s->name, '\\'))
        snprintf(s->lead, sizeof s->lead, "%s #%ld", s->name, __atomic_add_fetch(&path_named, 1, __ATOMIC_SEQ_CST));
    else
        snprintf(s->lead, sizeof s->lead, "%s", s->name);
    if (!name || !*name || type != fmi2CoSimulation) {
        snprintf(s->reason, sizeof s->reason, !name || !*name
                 ? "instanceName is NULL or empty: FMI 2.0 asks for a name that identifies the instance"
                 : "fmuType %d: this FMU is for co-simulation only (fmi2CoSimulation = 1)", (int)type);
        to_host(s, s->name, fmi2Error, "logStatusError", s->reason);
        return s;
    }
    if (!inst) {
        snprintf(s->reason, sizeof s->reason, "the FMU's pythonfmu library %s could not be loaded: %s", PYTHONFMU_LIBRARY,
                 library_error());
        to_host(s, s->name, fmi2Error, "logStatusError", s->reason);
        return s;
    }
    {
        char dir[4096], expected[128], module[4200];
        if (!resource_path(resources, dir, sizeof dir)) {
            snprintf(s->reason, sizeof s->reason, "fmuResourceLocation %.900s is not a file URI of a local folder "
                     "(file:///path/to/the/extracted/fmu/resources)", resources ? resources : "(NULL)");
            to_host(s, s->name, fmi2Error, "logStatusError", s->reason);
            return s;
        }
        if (!local_path(dir, sizeof dir)) {
            snprintf(s->reason, sizeof s->reason, "the FMU's folder %.900s has a non-ASCII character and no short "
                     "(8.3) name, which pythonfmu cannot open on Windows: extract the FMU into a folder whose path "
                     "is ASCII", dir);
            to_host(s, s->name, fmi2Error, "logStatusError", s->reason);
            return s;
        }
        long bad = not_utf8_at(dir);
        if (bad >= 0) {
            /* pythonfmu hands the path to Python as UTF-8, and on a failure there its error path
               segfaulted (a folder named in Latin-1, from a Windows zip or an old home folder) */
            char shown[1000];
            escaped(dir, shown, sizeof shown);
            snprintf(s->reason, sizeof s->reason, "the FMU's folder %s has a name that is not UTF-8 (byte 0x%02X at "
                     "%ld), which the FMU's Python cannot open: extract the FMU into a folder whose name is UTF-8 (or "
                     "ASCII)", shown, (unsigned char)dir[bad], bad);
            to_host(s, s->name, fmi2Error, "logStatusError", s->reason);
            return s;
        }
        if (guid && model_guid(dir, expected, sizeof expected) && strcmp(guid, expected)) {
            snprintf(s->reason, sizeof s->reason, "the host passed GUID %s, this FMU's is %s (modelDescription.xml)",
                     guid, expected);
            to_host(s, s->name, fmi2Error, "logStatusError", s->reason);
            return s;
        }
        snprintf(module, sizeof module, "%s/slavemodule.txt", dir);
        if (!readable(module) || strstr(dir, "%20")) {
            /* pythonfmu would fail on it, and its failure path calls a NULL class (a segfault); and it
               reads a literal "%20" in a folder's name as a space */
            snprintf(s->reason, sizeof s->reason, strstr(dir, "%20")
                     ? "the FMU's folder %.900s holds \"%%20\" in a name, which pythonfmu reads as a space: extract "
                       "the FMU into another folder"
                     : "fmuResourceLocation %.900s: no readable slavemodule.txt in it (the extracted FMU's resources "
                       "folder?)", strstr(dir, "%20") ? dir : resources);
            to_host(s, s->name, fmi2Error, "logStatusError", s->reason);
            return s;
        }
        {
            instantiate_guard guard = instantiate_lock();
            s->inner = inst(name, type, guid, dir, &s->mine, visible, fmi2True);
            instantiate_unlock(guard);
        }
    }
    if (!s->inner) {
        /* the reason reached the host just now, from pythonfmu's own message: named here in short */
        char text[2600], shown[SUMMARY_CHARS + 8];
        summary(s->reason, shown, sizeof shown);
        snprintf(text, sizeof text, "fmi2Instantiate failed%s%s%s; every later call of this instance is refused: fmi2Error "
                 "from fmi2DoStep, fmi2Reset and the state, status and derivative calls, fmi2Warning from the others",
                 shown[0] ? ": " : "", shown, python_home_hint());
        to_host(s, s->name, fmi2Error, "logStatusError", text);
    }
    s->worst = fmi2OK;
    return s;
}

FMI2_Export void fmi2FreeInstance(fmi2Component c) {
    Shim *s = (Shim *)c;
    if (!s) return;
    if (s->inner) ((fmi2FreeInstanceTYPE *)real("fmi2FreeInstance"))(s->inner);
    free(s->states);
    free(s);
}

FMI2_Export fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cats[]) {
    Shim *s = (Shim *)c;
    if (!s) return fmi2Error;
    fmi2Status status = fmi2OK;
    int every = 0;   /* logAll listed */
    s->logging_on = on;
    s->n_categories = 0;
    for (size_t i = 0; on && cats && i < n; i++) {
        size_t j = 0;
        while (j < N_KNOWN && !(cats[i] && !strcmp(cats[i], KNOWN_CATEGORIES[j]))) j++;
        if (j == N_KNOWN) {
            /* a warning, not an error: a host's logging set-up should not stop its run */
            char text[600], known[200] = "";
            for (size_t k = 0; k < N_KNOWN; k++)
                snprintf(known + strlen(known), sizeof known - strlen(known), "%s%s", k ? ", " : "", KNOWN_CATEGORIES[k]);
            snprintf(text, sizeof text, "fmi2SetDebugLogging: category %.100s is not one of this FMU's (%s): ignored",
                     cats[i] ? cats[i] : "(NULL)", known);
            to_host(s, s->name, fmi2Warning, "logStatusWarning", text);
            status = fmi2Warning;
        } else if (!strcmp(KNOWN_CATEGORIES[j], "logAll")) {
            every = 1;
        } else {
            int seen = 0;
            for (size_t k = 0; k < s->n_categories; k++) seen |= !strcmp(s->categories[k], KNOWN_CATEGORIES[j]);
            if (!seen) snprintf(s->categories[s->n_categories++], CATEGORY_CHARS, "%s", KNOWN_CATEGORIES[j]);
        }
    }
    if (every) s->n_categories = 0;
    if (on && cats && n && !s->n_categories && !every)
        s->logging_on = fmi2False;   /* none of the categories listed is this FMU's: none is logged */
    if (!s->inner) return status;
    /* pythonfmu keeps logging every category to the shim, which filters */
    s->worst = status;
    return settle(s, ((fmi2SetDebugLoggingTYPE *)real("fmi2SetDebugLogging"))(s->inner, fmi2True, 0, NULL));
}

/* fmi2Status fmi2X(fmi2Component c, PARAMS) forwarded to pythonfmu's with ARGS. On an instance whose
   instantiation failed: ZOMBIE_STATUS, after ZOMBIE_FILL (a getter's values: zeros, never garbage).
   Calls before the first step answer fmi2Warning there, because libcosim terminates the process on an
   error during its initialisation phase (an exception escapes its worker thread) but stops cleanly
   on an error from fmi2DoStep. */
#define FORWARD(X, PARAMS, ARGS, ZOMBIE_STATUS, ZOMBIE_FILL)                            \
    FMI2_Export fmi2Status X PARAMS {                                                   \
        Shim *s = (Shim *)c;                                                            \
        static X##TYPE *fn;                                                             \
        if (!s) return fmi2Error;                                                       \
        if (!s->inner) { ZOMBIE_FILL; return refuse(s, #X, ZOMBIE_STATUS); }            \
        if (!fn) fn = (X##TYPE *)real(#X);                                              \
        if (!fn) return refuse(s, #X, fmi2Error);                                       \
        pin_thread();                                                                   \
        s->worst = fmi2OK;                                                              \
        return settle(s, fn ARGS);                                                      \
    }
#define ZEROS(v) for (size_t i = 0; v && i < n; i++) v[i] = 0
#define NOTHING (void)0

FORWARD(fmi2SetupExperiment, (fmi2Component c, fmi2Boolean td, fmi2Real tol, fmi2Real t0, fmi2Boolean sd, fmi2Real t1),
        (s->inner, td, tol, t0, sd, t1), fmi2Warning, NOTHING)
FORWARD(fmi2EnterInitializationMode, (fmi2Component c), (s->inner), fmi2Warning, NOTHING)
FORWARD(fmi2ExitInitializationMode, (fmi2Component c), (s->inner), fmi2Warning, NOTHING)
FORWARD(fmi2Terminate, (fmi2Component c), (s->inner), fmi2Warning, NOTHING)
FORWARD(fmi2Reset, (fmi2Component c), (s->inner), fmi2Error, NOTHING)
FORWARD(fmi2GetReal, (fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real v[]), (s->inner, vr, n, v),
        fmi2Warning, ZEROS(v))
FORWARD(fmi2GetInteger, (fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer v[]),
        (s->inner, vr, n, v), fmi2Warning, ZEROS(v))
FORWARD(fmi2GetBoolean, (fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean v[]),
        (s->inner, vr, n, v), fmi2Warning, ZEROS(v))
FORWARD(fmi2GetString, (fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String v[]),
        (s->inner, vr, n, v), fmi2Warning, for (size_t i = 0; v && i < n; i++) v[i] = "")
FORWARD(fmi2SetReal, (fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real v[]),
        (s->inner, vr, n, v), fmi2Warning, NOTHING)
FORWARD(fmi2SetInteger, (fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer v[]),
        (s->inner, vr, n, v), fmi2Warning, NOTHING)
FORWARD(fmi2SetBoolean, (fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Boolean v[]),
        (s->inner, vr, n, v), fmi2Warning, NOTHING)
FORWARD(fmi2SetString, (fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2String v[]),
        (s->inner, vr, n, v), fmi2Warning, NOTHING)
/* The states an instance gave out (fmi2GetFMUstate, fmi2DeSerializeFMUstate) and has not freed: a NULL,
   freed or foreign state handed to pythonfmu ends in a crash of the host process later (it builds a
   Python object from the pointer), so every call that takes a state checks it here first. */
static int state_index(const Shim *s, fmi2FMUstate st) {
    for (size_t i = 0; st && i < s->n_states; i++)
        if (s->states[i] == st) return (int)i;
    return -1;
}

static void state_given(Shim *s, fmi2FMUstate st) {
    if (!st || state_index(s, st) >= 0) return;
    if (s->n_states == s->cap_states) {
        size_t cap = s->cap_states ? 2 * s->cap_states : 8;
        fmi2FMUstate *grown = realloc(s->states, cap * sizeof *grown);
        if (!grown) return;  /* unknown to the check: refused later rather than crashing */
        s->states = grown;
        s->cap_states = cap;
    }
    s->states[s->n_states++] = st;
}

static void state_freed(Shim *s, fmi2FMUstate st) {
    int i = state_index(s, st);
    if (i >= 0) s->states[i] = s->states[--s->n_states];
}

static int state_refused(Shim *s, const char *call, fmi2FMUstate st) {
    char text[400];
    if (state_index(s, st) >= 0) return 0;
    snprintf(text, sizeof text, "%s refused: %s", call, st ? "the FMU state is not one this instance gave out "
             "(freed already, or another instance's: fmi2SerializeFMUstate and fmi2DeSerializeFMUstate move a state "
             "between instances)" : "the FMU state is NULL");
    to_host(s, s->name, fmi2Error, "logStatusError", text);
    return 1;
}

/* fmi2X(fmi2Component c, fmi2FMUstate st, ...) forwarded as FORWARD does, with the state checked. */
#define FORWARD_STATE(X, PARAMS, ARGS)                                                  \
    FMI2_Export fmi2Status X PARAMS {                                                   \
        Shim *s = (Shim *)c;                                                            \
        static X##TYPE *fn;                                                             \
        if (!s) return fmi2Error;                                                       \
        if (!s->inner) return refuse(s, #X, fmi2Error);                                 \
        if (state_refused(s, #X, st)) return fmi2Error;                                 \
        if (!fn) fn = (X##TYPE *)real(#X);                                              \
        if (!fn) return refuse(s, #X, fmi2Error);                                       \
        pin_thread();                                                                   \
        s->worst = fmi2OK;                                                              \
        return settle(s, fn ARGS);                                                      \
    }

FORWARD_STATE(fmi2SetFMUstate, (fmi2Component c, fmi2FMUstate st), (s->inner, st))
FORWARD_STATE(fmi2SerializedFMUstateSize, (fmi2Component c, fmi2FMUstate st, size_t *n), (s->inner, st, n))
FORWARD_STATE(fmi2SerializeFMUstate, (fmi2Component c, fmi2FMUstate st, fmi2Byte b[], size_t n), (s->inner, st, b, n))

/* FMU states as FMI 2.0 (2.1.8) has them; pythonfmu always makes a new state and never clears a freed
   pointer. fmi2FreeFMUstate sets *st to NULL and ignores a NULL state (a host may free twice). */
FMI2_Export fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *st) {
    Shim *s = (Shim *)c;
    static fmi2FreeFMUstateTYPE *fn;
    fmi2Status status;
    if (!s) return fmi2Error;
    if (!s->inner) return refuse(s, "fmi2FreeFMUstate", fmi2Error);
    if (!st || !*st) return fmi2OK;
    if (state_index(s, *st) < 0) {  /* a copy of a pointer freed already: nothing to free */
        to_host(s, s->name, fmi2Warning, "logStatusWarning",
                "fmi2FreeFMUstate ignored: the FMU state is not one this instance holds (freed already?)");
        *st = NULL;
        return fmi2Warning;
    }
    if (!fn) fn = (fmi2FreeFMUstateTYPE *)real("fmi2FreeFMUstate");
    if (!fn) return refuse(s, "fmi2FreeFMUstate", fmi2Error);
    pin_thread();
    s->worst = fmi2OK;
    {
        fmi2FMUstate freed = *st;
        status = settle(s, fn(s->inner, st));
        if (status <= fmi2Warning) {
            state_freed(s, freed);
            *st = NULL;
        }
    }
    return status;
}

/* fmi2GetFMUstate and fmi2DeSerializeFMUstate given a state the host already holds update that
   state: the host owns one state, not two, so the one pythonfmu replaced is freed here (else every
   such call leaks a state; masters that rewind reuse one pointer). */
static fmi2Status replace_state(Shim *s, fmi2FMUstate *st, fmi2FMUstate old, fmi2Status status) {
    static fmi2FreeFMUstateTYPE *release;
    if (status > fmi2Warning) return status;
    state_given(s, *st);
    /* only a state this instance holds is freed: a host's stale pointer in *st is not ours to free */
    if (!old || old == *st || state_index(s, old) < 0) return status;
    if (!release) release = (fmi2FreeFMUstateTYPE *)real("fmi2FreeFMUstate");
    if (release) {
        s->worst = fmi2OK;
        settle(s, release(s->inner, &old));
        state_freed(s, old);
    }
    return status;
}

/* fmi2X(fmi2Component c, PARAMS) that writes a state into *st: forwarded with ARGS, the replaced
   state freed (replace_state). */
#define REPLACE_STATE(X, PARAMS, ARGS)                                                                 \
    FMI2_Export fmi2Status X PARAMS {                                                                  \
        Shim *s = (Shim *)c;                                                                           \
        static X##TYPE *fn;                                                                            \
        fmi2FMUstate old;                                                                              \
        if (!s) return fmi2Error;                                                                      \
        if (!s->inner) return refuse(s, #X, fmi2Error);                                                \
        if (!fn) fn = (X##TYPE *)real(#X);                                                             \
        if (!fn) return refuse(s, #X, fmi2Error);                                                      \
        if (!st) {                                                                                     \
            to_host(s, s->name, fmi2Error, "logStatusError", #X ": the FMUstate pointer is NULL");     \
            return fmi2Error;                                                                          \
        }                                                                                              \
        pin_thread();                                                                                  \
        old = *st;                                                                                     \
        s->worst = fmi2OK;                                                                             \
        return replace_state(s, st, old, settle(s, fn ARGS));                                          \
    }

REPLACE_STATE(fmi2GetFMUstate, (fmi2Component c, fmi2FMUstate *st), (s->inner, st))
REPLACE_STATE(fmi2DeSerializeFMUstate, (fmi2Component c, const fmi2Byte b[], size_t n, fmi2FMUstate *st),
              (s->inner, b, n, st))
FORWARD(fmi2GetDirectionalDerivative, (fmi2Component c, const fmi2ValueReference u[], size_t nu,
        const fmi2ValueReference k[], size_t nk, const fmi2Real dk[], fmi2Real du[]), (s->inner, u, nu, k, nk, dk, du), fmi2Error, NOTHING)
FORWARD(fmi2SetRealInputDerivatives, (fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer o[],
        const fmi2Real v[]), (s->inner, vr, n, o, v), fmi2Error, NOTHING)
FORWARD(fmi2GetRealOutputDerivatives, (fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer o[],
        fmi2Real v[]), (s->inner, vr, n, o, v), fmi2Error, NOTHING)
FORWARD(fmi2DoStep, (fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean no_prior), (s->inner, t, h, no_prior), fmi2Error, NOTHING)
FORWARD(fmi2CancelStep, (fmi2Component c), (s->inner), fmi2Error, NOTHING)
FORWARD(fmi2GetStatus, (fmi2Component c, const fmi2StatusKind k, fmi2Status *v), (s->inner, k, v), fmi2Error, NOTHING)
FORWARD(fmi2GetRealStatus, (fmi2Component c, const fmi2StatusKind k, fmi2Real *v), (s->inner, k, v), fmi2Error, NOTHING)
FORWARD(fmi2GetIntegerStatus, (fmi2Component c, const fmi2StatusKind k, fmi2Integer *v), (s->inner, k, v), fmi2Error, NOTHING)
FORWARD(fmi2GetBooleanStatus, (fmi2Component c, const fmi2StatusKind k, fmi2Boolean *v), (s->inner, k, v), fmi2Error, NOTHING)
FORWARD(fmi2GetStringStatus, (fmi2Component c, const fmi2StatusKind k, fmi2String *v), (s->inner, k, v), fmi2Error, NOTHING)
