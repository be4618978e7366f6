/* Loader for a pythonfmu FMU in non-Python FMI hosts (Linux): binaries/linux64/<id>.so.
   build_scripts/native_host.py compiles it with these macros (C strings) defined before it:
   PYTHONFMU_LIBRARY (pythonfmu's library beside it, <id>_pythonfmu.so), LIBPYTHON_PATH and
   LIBPYTHON_SONAME (the building Python's shared libpython; "" where it has none), NO_PYTHON_REASON
   (what a host without Python is told then), BUILD_PYTHON and BASE_PYTHON (the interpreter a C host
   starts), BUILD_PYTHON_VERSION (its major.minor), and with fmi_shim.c appended, which uses real(), library_error(), readable(),
   local_path(), instantiate_lock()/instantiate_unlock() and pin_thread() from here. */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <langinfo.h>
#include <locale.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>
#include <wchar.h>

/* Python's API, found in the process: a Python host's own (fmpy: its executable or its libpython), or,
   in a host that runs no Python, that of the libpython this library opens. Neither this library nor
   pythonfmu's is linked to a libpython: an FMU linked to the building machine's would not load in a
   Python host elsewhere whose Python has none at that path (a static build: pyenv's default; conda's
   and Debian's executables have Python linked in). */
static struct {
    int (*IsInitialized)(void);
    void (*InitializeEx)(int initsigs);
    void *(*SaveThread)(void);
    void (*SetProgramName)(const wchar_t *name);            /* deprecated in 3.11, still honoured */
    wchar_t *(*DecodeLocale)(const char *arg, size_t *size);
    int (*GILState_Ensure)(void);
    void *(*GILState_GetThisThreadState)(void);
    void (*RestoreThread)(void *tstate);
    void (*ThreadState_Clear)(void *tstate);
    void (*ThreadState_DeleteCurrent)(void);
    int (*IsFinalizing)(void);                              /* Py_IsFinalizing (3.13 on), else _Py_IsFinalizing */
} py;

static int bind_python(void) {
#define BIND(field, name) (*(void **)&py.field = dlsym(RTLD_DEFAULT, name))
    BIND(IsInitialized, "Py_IsInitialized");
    BIND(InitializeEx, "Py_InitializeEx");
    BIND(SaveThread, "PyEval_SaveThread");
    BIND(SetProgramName, "Py_SetProgramName");
    BIND(DecodeLocale, "Py_DecodeLocale");
    BIND(GILState_Ensure, "PyGILState_Ensure");
    BIND(GILState_GetThisThreadState, "PyGILState_GetThisThreadState");
    BIND(RestoreThread, "PyEval_RestoreThread");
    BIND(ThreadState_Clear, "PyThreadState_Clear");
    BIND(ThreadState_DeleteCurrent, "PyThreadState_DeleteCurrent");
    if (!BIND(IsFinalizing, "Py_IsFinalizing")) BIND(IsFinalizing, "_Py_IsFinalizing");
#undef BIND
    return py.IsInitialized && py.InitializeEx && py.SaveThread && py.SetProgramName && py.DecodeLocale &&
           py.GILState_Ensure && py.GILState_GetThisThreadState && py.RestoreThread && py.ThreadState_Clear &&
           py.ThreadState_DeleteCurrent;
}

static int python_running(void) { return py.IsInitialized && py.IsInitialized(); }

static void *pythonfmu_lib;
static int started_python;                   /* this library started the process's Python (a C host) */
static char load_failure[1400];   /* why pythonfmu's library is not loaded */
static void (*finalize_interpreter)(void);   /* pythonfmu's finalizePythonInterpreter, where it has one */

static void failed(const char *what, const char *why) {
    snprintf(load_failure, sizeof load_failure, "%s%s", what, why ? why : "");
}

/* Why the shared library at ``path`` is shorter than its own ELF header says (its section-header table
   must end within the file), or NULL. The dynamic loader maps a library into the process, so a
   truncated one (a damaged FMU) kills the host with SIGBUS as it reads past the file's end; checked
   before dlopen, it is a failed instantiation with this reason instead. Anything else (no file, not a
   64-bit little-endian ELF file) is left to dlopen, which refuses it with a message. */
static const char *truncated_library(const char *path) {
    static char why[sizeof load_failure];
    unsigned char header[64];
    struct stat st;
    uint64_t shoff;
    uint16_t shentsize, shnum;
    FILE *f = fopen(path, "rb");
    size_t n;
    int sized;
    if (!f) return NULL;
    n = fread(header, 1, sizeof header, f);
    sized = fstat(fileno(f), &st) == 0;
    fclose(f);
    if (!sized || n < sizeof header || memcmp(header, "\x7f" "ELF", 4) || header[4] != 2 || header[5] != 1)
        return NULL;
    memcpy(&shoff, header + 0x28, sizeof shoff);   /* the host is little-endian: x86-64, aarch64 */
    memcpy(&shentsize, header + 0x3A, sizeof shentsize);
    memcpy(&shnum, header + 0x3C, sizeof shnum);
    /* compared without a sum that a garbage offset could wrap */
    if (shoff <= (uint64_t)st.st_size && (uint64_t)shentsize * shnum <= (uint64_t)st.st_size - shoff) return NULL;
    snprintf(why, sizeof why, "%s is truncated: %lld bytes, its ELF header says at least %llu (a damaged FMU: "
             "unpack it again from an intact copy, or build it again)", path, (long long)st.st_size,
             shoff > UINT64_MAX - (uint64_t)shentsize * shnum ? (unsigned long long)UINT64_MAX
                                                               : (unsigned long long)(shoff + (uint64_t)shentsize * shnum));
    return why;
}

/* (a) In a host that runs no Python: the building Python's libpython (recorded path, else its soname on
       the library path: LD_LIBRARY_PATH), global, so that pythonfmu's library and the extension modules
       Python imports (not linked to libpython on Linux) find its symbols. */
/* The folder of the base interpreter behind ``python`` (a path): a venv's pyvenv.cfg names it
   ("home = <dir>", also for a venv made with --copies), else the folder of the file it resolves to. */
static int base_bin_dir(const char *python, char *dir, size_t size) {
    char cfg[4200], line[4200], real[4096], *slash;
    FILE *f;
    int found = 0;
    snprintf(cfg, sizeof cfg, "%s", python);
    if ((slash = strrchr(cfg, '/'))) *slash = 0;      /* <venv>/bin */
    if ((slash = strrchr(cfg, '/'))) {
        snprintf(slash, sizeof cfg - (size_t)(slash - cfg), "/pyvenv.cfg");
        if ((f = fopen(cfg, "r"))) {
            while (!found && fgets(line, sizeof line, f)) {
                char *key = line + strspn(line, " \t"), *value = strchr(key, '=');
                if (!value || strncmp(key, "home", 4) || strspn(key + 4, " \t") != (size_t)(value - key - 4)) continue;
                value += 1 + strspn(value + 1, " \t");
                value[strcspn(value, "\r\n")] = 0;
                while (*value && value[strlen(value) - 1] == ' ') value[strlen(value) - 1] = 0;
                found = snprintf(dir, size, "%s", value) < (int)size;
            }
            fclose(f);
            if (found) return 1;
        }
    }
    if (!realpath(python, real) || !(slash = strrchr(real, '/'))) return 0;
    *slash = 0;
    return snprintf(dir, size, "%s", real) < (int)size;
}

/* The libpython of the interpreter TAPMUSCLE_PYTHON names, where it is that interpreter's own: in
   its installation's lib/, or, for the system's (/usr/bin/python3.11: Debian keeps libpython in
   /usr/lib/<triplet>), by soname on the system's library path. A libpython of another build than the
   interpreter's standard library (the recorded one beside Debian's) fails at its first import ("No
   module named '_struct'"). Anything else (a shim script, an interpreter without a shared libpython)
   keeps the recorded one. */
static int open_named_libpython(void) {
    const char *named = getenv("TAPMUSCLE_PYTHON");
    char bin[4096], lib[4300], *slash;
    if (!named || !*named || !base_bin_dir(named, bin, sizeof bin) || !(slash = strrchr(bin, '/'))) return 0;
    *slash = 0;                                          /* the installation's prefix */
    snprintf(lib, sizeof lib, "%s/lib/%s", bin, LIBPYTHON_SONAME);
    if (access(lib, R_OK) == 0) return dlopen(lib, RTLD_NOW | RTLD_GLOBAL) != NULL;
    return (!strcmp(bin, "/usr") || !strcmp(bin, "/usr/local")) && dlopen(LIBPYTHON_SONAME, RTLD_NOW | RTLD_GLOBAL);
}

static int open_libpython(void) {
    const char *why;
    if (!LIBPYTHON_SONAME[0]) {
        failed(NO_PYTHON_REASON, NULL);
        return 0;
    }
    if (open_named_libpython() || (LIBPYTHON_PATH[0] && dlopen(LIBPYTHON_PATH, RTLD_NOW | RTLD_GLOBAL)) ||
        dlopen(LIBPYTHON_SONAME, RTLD_NOW | RTLD_GLOBAL)) {
        if (bind_python()) return 1;
        failed("libpython lacks Python's embedding API: ", LIBPYTHON_SONAME);
        return 0;
    }
    why = dlerror();
    snprintf(load_failure, sizeof load_failure, "this process runs no Python, and the FMU cannot load %s (%s) to "
             "start one: %s. The FMU was built by CPython %s: set LD_LIBRARY_PATH to the folder of the %s of a "
             "CPython %s built with --enable-shared, and TAPMUSCLE_PYTHON to its python; or build the FMUs with a "
             "Python of yours (tapmuscle build; docs/fmu-native-hosts.md)", LIBPYTHON_SONAME,
             LIBPYTHON_PATH[0] ? LIBPYTHON_PATH : "not recorded", why ? why : "not found", BUILD_PYTHON_VERSION,
             LIBPYTHON_SONAME, BUILD_PYTHON_VERSION);
    return 0;
}

/* A PYTHONHOME without the standard library stops Python's start with a fatal error, which exits the
   host process inside the dynamic loader (before any FMI call, past the host's logger): checked
   first, and the instances then fail naming it. */
static int python_home_usable(void) {
    const char *home = getenv("PYTHONHOME"), *exec_part;
    char stdlib[4200];
    if (!home || !*home) return 1;
    snprintf(stdlib, sizeof stdlib, "%.*s/lib/python%s/encodings/__init__.py", (int)strcspn(home, ":"), home,
             BUILD_PYTHON_VERSION);
    if (access(stdlib, R_OK) == 0) {
        exec_part = strchr(home, ':');   /* PYTHONHOME=prefix:exec_prefix: the compiled modules' folder */
        if (!exec_part) return 1;
        snprintf(stdlib, sizeof stdlib, "%s/lib/python%s/lib-dynload", exec_part + 1, BUILD_PYTHON_VERSION);
        if (access(stdlib, R_OK) == 0) return 1;
    }
    snprintf(load_failure, sizeof load_failure, "PYTHONHOME=%.600s has no standard library of CPython %s (no %.600s), "
             "so the FMU cannot start its Python: unset PYTHONHOME in this host's environment, or point it at "
             "a CPython %s installation", home, BUILD_PYTHON_VERSION, stdlib, BUILD_PYTHON_VERSION);
    return 0;
}

/* A TAPMUSCLE_PYTHON that names no executable file (a typo, a venv deleted since) would leave Python
   to its own search (the first python3 on PATH: another installation, or none with the packages),
   silently: the instances fail naming it instead, as on Windows. */
static int named_python_usable(const char *python) {
    struct stat st;
    if (!python || !*python || (stat(python, &st) == 0 && S_ISREG(st.st_mode) && access(python, X_OK) == 0)) return 1;
    snprintf(load_failure, sizeof load_failure, "TAPMUSCLE_PYTHON=%.900s is not an executable file (name the "
             "python of a CPython %s that has numpy, scipy and osqp: a venv's bin/python, or an installation's "
             "bin/python%s; or unset it for the Python that built the FMU)", python, BUILD_PYTHON_VERSION,
             BUILD_PYTHON_VERSION);
    return 0;
}

/* Python's UTF-8 mode where the environment gives the process no encoding (LANG unset, or a locale
   that is not installed: the C/POSIX locale of containers, services, cron and CI runners), as the
   python executable switches it on there (PEP 540), and where PYTHONUTF8=1 asks for it:
   Py_InitializeEx's legacy configuration does neither, and decoded file names as ASCII, so an FMU in
   a folder "Müller" could not import its own module. Python's legacy flag Py_UTF8Mode is the one
   setting that configuration reads; PYTHONUTF8=0 keeps the locale's encoding. */
static void python_utf8_mode_where_needed(locale_t environment) {
    const char *asked = getenv("PYTHONUTF8");
    int ascii = 1, *mode;
    if (asked && !strcmp(asked, "0")) return;
    if (!asked || strcmp(asked, "1")) {
        if (environment) {
            const char *codeset = nl_langinfo_l(CODESET, environment);
            ascii = !strcmp(codeset, "ANSI_X3.4-1968") || !strcmp(codeset, "ASCII");
        }
        if (!ascii) return;
    }
    if ((mode = (int *)dlsym(RTLD_DEFAULT, "Py_UTF8Mode"))) *mode = 1;
}

static void release_pythonfmu_interpreter(void) {
    /* Runs before pythonfmu's static destructor (registered later than it, at_exit order is LIFO):
       releases the interpreter holder once, properly; pythonfmu's own two releases then find it empty. */
    if (finalize_interpreter) finalize_interpreter();
}

__attribute__((constructor)) static void tapmuscle_fmu_loader(void) {
    Dl_info self;
    char path[4096];
    const char *python, *slash = NULL;
    int located;
    if (!bind_python() && !open_libpython()) return;   /* fmi2Instantiate tells the host why (real()) */
    /* (b) in a host that is not Python, start the building environment's interpreter (a venv's python:
           Python then reads its pyvenv.cfg), else its base installation, not the first python3 on PATH. */
    if (!py.IsInitialized()) {
        locale_t environment;
        if (!python_home_usable()) return;
        /* the environment's LC_CTYPE, the one Python starts in, read without setlocale: the host's own
           (a C host's is "C", ASCII) stays as it is for its other threads */
        environment = newlocale(LC_CTYPE_MASK, "", (locale_t)0);
        python_utf8_mode_where_needed(environment);
        python = getenv("TAPMUSCLE_PYTHON");
        if (!named_python_usable(python)) {
            if (environment) freelocale(environment);
            return;
        }
        if (!python || !*python) python = access(BUILD_PYTHON, X_OK) == 0 ? BUILD_PYTHON : BASE_PYTHON;
        if (access(python, X_OK) == 0) {
            /* decoded as Python will encode it, in the environment's locale: in the host's "C" a path
               named beyond ASCII (/tmp/Zürich/venv) would read Z\udcc3\udcbcrich in sys.executable and
               in every message that names it */
            locale_t host = environment ? uselocale(environment) : (locale_t)0;
            wchar_t *name = py.DecodeLocale(python, NULL);   /* kept for the life of the process */
            if (environment) uselocale(host);
            if (name) py.SetProgramName(name);
        }
        if (environment) freelocale(environment);
        /* (d) and start it here. Each pythonfmu binary starts Python at its first fmi2Instantiate under a
               lock of its own, so a parallel master instantiating the plant and the controller at once
               ran two Py_Initialize together (a segfault); constructors run under the dynamic loader's
               lock, one library at a time. No signal handlers: the host keeps its Ctrl-C. The GIL is
               released for the host's threads. pythonfmu then finds Python running and never finalises
               it, so a C host exits without Py_Finalize (which pythonfmu runs in a thread of its own;
               this thread may be gone by then). */
        py.InitializeEx(0);
        py.SaveThread();
        started_python = 1;
    }
    /* pythonfmu's library, beside this one, now that Python's symbols are in the process */
    located = dladdr((void *)&tapmuscle_fmu_loader, &self) && self.dli_fname;
    if (!located || !(slash = strrchr(self.dli_fname, '/')) ||
        snprintf(path, sizeof path, "%.*s/%s", (int)(slash - self.dli_fname), self.dli_fname,
                 PYTHONFMU_LIBRARY) >= (int)sizeof path)
        snprintf(path, sizeof path, "%s", PYTHONFMU_LIBRARY);
    const char *truncated = truncated_library(path);
    if (truncated) {
        failed("", truncated);
        return;
    }
    if (!(pythonfmu_lib = dlopen(path, RTLD_NOW | RTLD_NODELETE))) {
        failed("", dlerror());
        return;
    }
    /* (c) see release_pythonfmu_interpreter; registered after pythonfmu's library registered its own exit
           work, so it runs first. atexit() in a shared library runs its handler when the library is
           unloaded, and hosts (fmpy) dlclose the FMU at fmi2FreeInstance: the handler would then tear
           down the interpreter holder that other loaded FMUs still use (a segfault in their next call).
           So this library is pinned for the life of the process first (pythonfmu's is, RTLD_NODELETE). */
    *(void **)&finalize_interpreter = dlsym(pythonfmu_lib, "finalizePythonInterpreter");
    if (located) dlopen(self.dli_fname, RTLD_NOW | RTLD_NOLOAD | RTLD_NODELETE);
    atexit(release_pythonfmu_interpreter);
}

static void *real(const char *symbol) { return pythonfmu_lib ? dlsym(pythonfmu_lib, symbol) : NULL; }

/* What a failed instantiation adds when this library started Python with PYTHONHOME set: a standard
   library there of another build than the libpython ("No module named '_struct'") says nothing of it. */
static const char *python_home_hint(void) {
    static char hint[900];
    const char *home = getenv("PYTHONHOME");
    if (!started_python || !home || !*home) return "";
    snprintf(hint, sizeof hint, " (PYTHONHOME=%.600s is set: the FMU's Python took its standard library from there; "
             "unset it unless it is the CPython %s installation the FMU's libpython belongs to)", home,
             BUILD_PYTHON_VERSION);
    return hint;
}

static const char *library_error(void) { return load_failure; }

static int readable(const char *path) { return access(path, R_OK) == 0; }

/* Paths are bytes on Linux: pythonfmu opens the decoded UTF-8 path as it is. */
static int local_path(char *path, size_t size) {
    (void)path;
    (void)size;
    return 1;
}

/* Python is already running when pythonfmu's first fmi2Instantiate comes (the constructor above, or
   the host is a Python). */
typedef int instantiate_guard;
static instantiate_guard instantiate_lock(void) { return 0; }
static void instantiate_unlock(instantiate_guard guard) { (void)guard; }

/* A thread with no Python thread state (any thread of a C host) gets one for its life at its first FMI
   call. pythonfmu brackets every call with PyGILState_Ensure/Release, which otherwise creates and
   destroys a thread state each time (mmap and munmap of its frame stack: six per closed-loop step).
   The GIL is released again at once, so other threads (a parallel master's) can run the FMUs. */
#include <pthread.h>
static __thread int thread_pinned;
static pthread_key_t pin_key;
static pthread_once_t pin_once = PTHREAD_ONCE_INIT;
static int pin_key_made;

/* At the exit of a pinned thread its thread state is deleted: a master that starts new threads (per
   run, per step) would otherwise leak one per thread. Not with PyGILState_Release: the C library may
   already have cleared Python's own thread-local slot of this exiting thread. */
static void unpin_thread(void *saved) {
    if (!python_running() || (py.IsFinalizing && py.IsFinalizing())) return;
    py.RestoreThread(saved);
    py.ThreadState_Clear(saved);
    py.ThreadState_DeleteCurrent();   /* and releases the GIL */
}

static void make_pin_key(void) { pin_key_made = pthread_key_create(&pin_key, unpin_thread) == 0; }

static void pin_thread(void) {
    void *saved;
    if (thread_pinned || !python_running()) return;
    thread_pinned = 1;
    if (py.GILState_GetThisThreadState()) return;   /* a Python thread (fmpy), or pinned by the other FMU */
    py.GILState_Ensure();
    saved = py.SaveThread();
    pthread_once(&pin_once, make_pin_key);
    if (pin_key_made) pthread_setspecific(pin_key, saved);
}
