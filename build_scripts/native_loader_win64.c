/* Loader for a pythonfmu FMU on Windows: binaries/win64/<id>.dll. The host loads this library; the FMI
   functions forward to pythonfmu's own library beside it (PYTHONFMU_LIBRARY). That one imports
   python3.dll: a Python host's own, or in a C host the first on the DLL search path, which pythonfmu
   then starts. build_scripts/native_host.py compiles it with PYTHONFMU_LIBRARY (a C string) defined
   before it and fmi_shim.c appended, which uses the same functions from here as from the Linux loader. */
#define WIN32_LEAN_AND_MEAN
#include <windows.h>
#include <io.h>
#include <stdio.h>

static HMODULE pythonfmu_lib;
static char load_error[1024];

/* `wide` (a path, an environment variable) as UTF-8, the encoding of FMI's log messages, in `out`. */
static const char *utf8(const wchar_t *wide, char *out, int size) {
    if (!WideCharToMultiByte(CP_UTF8, 0, wide, -1, out, size, NULL, NULL))
        snprintf(out, (size_t)size, "(a name longer than this message holds)");
    return out;
}

/* Why pythonfmu's library at `path` did not load (`error`, GetLastError's): mostly because the
   python3.dll it imports is not on the DLL search path, which Windows reports only as "module not
   found" (126), the same code as for the library itself. */
static void explain_load_error(const wchar_t *path, DWORD error) {
    wchar_t found[4096] = L"";
    HMODULE python;
    DWORD on_path;
    if (GetFileAttributesW(path) == INVALID_FILE_ATTRIBUTES) {
        snprintf(load_error, sizeof load_error, "it is not in the folder of the FMU's binary (Windows error %lu)",
                 (unsigned long)GetLastError());
        return;
    }
    on_path = SearchPathW(NULL, L"python3.dll", NULL, 4096, found, NULL);
    if (on_path >= 4096) found[0] = 0;
    if (error == ERROR_MOD_NOT_FOUND && !on_path) {
        snprintf(load_error, sizeof load_error, "it imports python3.dll, which is not on the DLL search path: put "
                 "the folder of a 64-bit Python 3 (python3.dll lies beside its python.exe) with numpy, scipy and "
                 "osqp on PATH, or start the host from an environment that has it there");
        return;
    }
    python = LoadLibraryExW(L"python3.dll", NULL, 0);
    if (!python && GetLastError() == ERROR_BAD_EXE_FORMAT) {
        char name[600];
        snprintf(load_error, sizeof load_error, "the python3.dll on the DLL search path is not a 64-bit one (%s): "
                 "put the folder of a 64-bit Python 3 first on PATH", utf8(found, name, sizeof name));
        return;
    }
    if (python) FreeLibrary(python);
    snprintf(load_error, sizeof load_error, "LoadLibrary failed with Windows error %lu", (unsigned long)error);
}

/* A Python already in this process (a Python host, or one an FMU started): its own rules. */
static int python_in_process(void) {
    wchar_t name[32];
    int minor;
    if (GetModuleHandleW(L"python3.dll")) return 1;
    for (minor = 6; minor < 40; minor++) {
        _snwprintf(name, 32, L"python3%d.dll", minor);
        name[31] = 0;
        if (GetModuleHandleW(name)) return 1;
    }
    return 0;
}

/* TAPMUSCLE_PYTHON names the Python that a C host's FMU starts (its python.exe, as on Linux): its
   python3.dll is loaded first, so that pythonfmu's DLL binds to it rather than to the first one on the
   DLL search path (Python finds its prefix from the DLL's folder; the program name is pythonfmu's).
   0 if the variable names no usable Python (load_error says why). */
static int choose_python(void) {
    wchar_t program[4096], dll[4096], *slash;
    char name[400];
    DWORD n = GetEnvironmentVariableW(L"TAPMUSCLE_PYTHON", program, 4096), attributes;
    HMODULE python;
    HANDLE found;
    WIN32_FIND_DATAW entry;
    if (n == 0 || python_in_process()) return 1;
    if (n >= 4096) {
        snprintf(load_error, sizeof load_error, "TAPMUSCLE_PYTHON is longer than 4095 characters");
        return 0;
    }
    attributes = GetFileAttributesW(program);
    if (attributes == INVALID_FILE_ATTRIBUTES || (attributes & FILE_ATTRIBUTE_DIRECTORY)) {
        snprintf(load_error, sizeof load_error, "TAPMUSCLE_PYTHON=%s is not a file (name the python.exe of a "
                 "64-bit Python 3 with numpy, scipy and osqp)", utf8(program, name, sizeof name));
        return 0;
    }
    wcscpy(dll, program);
    slash = wcsrchr(dll, L'\\');
    if (!slash) slash = wcsrchr(dll, L'/');
    if (!slash || (size_t)(slash + 1 - dll) + 12 > 4096) {
        snprintf(load_error, sizeof load_error, "TAPMUSCLE_PYTHON=%s is not an absolute path",
                 utf8(program, name, sizeof name));
        return 0;
    }
    /* python3.dll only forwards to the full python3XY.dll beside it, which the loader would look for
       on the search path when it binds the forwarders: loaded from here first */
    wcscpy(slash + 1, L"python3*.dll");
    found = FindFirstFileW(dll, &entry);
    if (found != INVALID_HANDLE_VALUE) {
        do {
            if (_wcsicmp(entry.cFileName, L"python3.dll") && wcslen(entry.cFileName) < 32) {
                wcscpy(slash + 1, entry.cFileName);
                LoadLibraryExW(dll, NULL, LOAD_WITH_ALTERED_SEARCH_PATH);
            }
        } while (FindNextFileW(found, &entry));
        FindClose(found);
    }
    wcscpy(slash + 1, L"python3.dll");
    python = LoadLibraryExW(dll, NULL, LOAD_WITH_ALTERED_SEARCH_PATH);
    if (!python) {
        DWORD error = GetLastError();
        char dll_name[400];
        snprintf(load_error, sizeof load_error, "TAPMUSCLE_PYTHON=%s: %s could not be loaded (Windows error %lu); "
                 "name the python.exe of a Python installation (a venv's Scripts\\python.exe has no python3.dll "
                 "beside it: name its base Python's and set TAPMUSCLE_SITE_PACKAGES to the venv's "
                 "Lib\\site-packages)", utf8(program, name, sizeof name), utf8(dll, dll_name, sizeof dll_name),
                 (unsigned long)error);
        return 0;
    }
    return 1;
}

/* Whether a file matching `pattern` (wildcards) lies in `folder`. */
static int has_file(const wchar_t *folder, const wchar_t *pattern) {
    wchar_t probe[4200];
    WIN32_FIND_DATAW entry;
    HANDLE found;
    _snwprintf(probe, 4200, L"%ls\\%ls", folder, pattern);
    probe[4199] = 0;
    found = FindFirstFileW(probe, &entry);
    if (found == INVALID_HANDLE_VALUE) return 0;
    FindClose(found);
    return 1;
}

/* Whether this process had no Python when pythonfmu's library was loaded: pythonfmu then starts one. */
static int starts_python;

/* PYTHONHOME as the Python that pythonfmu starts takes it, once pythonfmu's library has loaded its
   python3.dll: NULL where it is not set, or where a python3XY._pth beside that Python's DLL makes it
   ignore PYTHONHOME (the embeddable distribution's). `home` receives it, empty if longer than 4095
   characters. */
static const wchar_t *python_home_taken(wchar_t home[4096]) {
    wchar_t dll[4096], *slash;
    HMODULE python = GetModuleHandleW(L"python3.dll");
    DWORD n = GetEnvironmentVariableW(L"PYTHONHOME", home, 4096), m;
    if (n == 0 || !python) return NULL;
    if (n >= 4096) home[0] = 0;
    m = GetModuleFileNameW(python, dll, 4096);
    if (m == 0 || m >= 4096 || !(slash = wcsrchr(dll, L'\\'))) return home;   /* unknown: as taken */
    *slash = 0;
    return has_file(dll, L"python3*._pth") ? NULL : home;
}

/* What a failed instantiation adds when the Python pythonfmu starts takes a PYTHONHOME (set once, in
   load_pythonfmu): a standard library there of another Python ("No module named '_ctypes'") says
   nothing of it. */
static char home_hint[900];

/* In a host without Python: a PYTHONHOME without a standard library (an installation's Lib\\encodings,
   the embeddable distribution's python3XY.zip) cannot start the FMU's Python; checked before Python
   starts (at the first fmi2Instantiate), the instances fail naming it, rather than later at whichever
   module Python cannot find. */
static int python_home_usable(void) {
    wchar_t home[4096], probe[4200];
    char name[600];
    if (!python_home_taken(home)) return 1;
    if (!home[0]) {
        snprintf(load_error, sizeof load_error, "PYTHONHOME is longer than 4095 characters");
        return 0;
    }
    utf8(home, name, sizeof name);
    _snwprintf(probe, 4200, L"%ls\\Lib\\encodings", home);
    probe[4199] = 0;
    if (has_file(probe, L"__init__.py") || has_file(home, L"python3*.zip")) {
        snprintf(home_hint, sizeof home_hint, " (PYTHONHOME=%s is set: the FMU's Python took its standard library "
                 "from there; unset it unless it is the home of the Python whose python3.dll the FMU loaded)", name);
        return 1;
    }
    snprintf(load_error, sizeof load_error, "PYTHONHOME=%s has no Python standard library (no Lib\\encodings, "
             "no python3*.zip), so the FMU cannot start its Python: unset PYTHONHOME in this host's environment, "
             "or point it at a Python 3 installation", name);
    return 0;
}

/* pythonfmu's library from this library's own folder (not the host's search path); once, whichever
   thread comes first (a parallel master's may come together). */
static INIT_ONCE load_once = INIT_ONCE_STATIC_INIT;

static BOOL CALLBACK load_pythonfmu(PINIT_ONCE once, void *parameter, void **context) {
    (void)once, (void)parameter, (void)context;
    starts_python = !python_in_process();
    if (choose_python()) {
        wchar_t path[4096];
        HMODULE self = NULL;
        DWORD n = 0;
        if (GetModuleHandleExW(GET_MODULE_HANDLE_EX_FLAG_FROM_ADDRESS | GET_MODULE_HANDLE_EX_FLAG_UNCHANGED_REFCOUNT,
                               (LPCWSTR)(void *)&load_pythonfmu, &self))
            n = GetModuleFileNameW(self, path, 4096);
        if (n > 0 && n < 4096) {
            wchar_t *slash = wcsrchr(path, L'\\');
            size_t room = 4096 - (size_t)(slash ? slash + 1 - path : 0);
            if (slash && MultiByteToWideChar(CP_UTF8, 0, PYTHONFMU_LIBRARY, -1, slash + 1, (int)room) > 0) {
                pythonfmu_lib = LoadLibraryExW(path, NULL, LOAD_WITH_ALTERED_SEARCH_PATH);
                if (!pythonfmu_lib) explain_load_error(path, GetLastError());
                else if (starts_python && !python_home_usable()) {   /* Python starts at fmi2Instantiate */
                    FreeLibrary(pythonfmu_lib);
                    pythonfmu_lib = NULL;
                }
            }
        }
        if (!pythonfmu_lib && !load_error[0])
            snprintf(load_error, sizeof load_error, "the FMU's own library path is unknown (Windows error %lu)",
                     (unsigned long)GetLastError());
    }
    return TRUE;
}

static void *real(const char *symbol) {
    InitOnceExecuteOnce(&load_once, load_pythonfmu, NULL, NULL);
    return pythonfmu_lib ? (void *)GetProcAddress(pythonfmu_lib, symbol) : NULL;
}

static const char *library_error(void) { return load_error; }

static const char *python_home_hint(void) { return home_hint; }

static int readable(const char *path) { return _access(path, 4) == 0; }

/* pythonfmu puts the resources path on sys.path as UTF-8 but opens files in it with the narrow C++
   API, which reads the bytes in the ANSI code page: a folder with any non-ASCII character ("Jürgen")
   works in neither way at once. Its short (8.3) name is ASCII and names the same folder, so that is
   what pythonfmu gets; 0 if there is none (8.3 names switched off on the volume). */
static int local_path(char *path, size_t size) {
    wchar_t wide[4096], shortened[4096];
    const char *p;
    DWORD n;
    size_t i;
    for (p = path; *p && !((unsigned char)*p & 0x80); p++) {}
    if (!*p) return 1;
    if (!MultiByteToWideChar(CP_UTF8, MB_ERR_INVALID_CHARS, path, -1, wide, 4096)) return 0;
    n = GetShortPathNameW(wide, shortened, 4096);
    if (n == 0 || n >= 4096 || n >= size) return 0;
    for (i = 0; i <= n; i++) {
        if (shortened[i] > 0x7f) return 0;
        path[i] = (char)shortened[i];
    }
    return 1;
}

/* pythonfmu starts Python at its first fmi2Instantiate under a lock of its own library: a parallel
   master instantiating the plant and the controller at once ran two Py_Initialize together (a crash,
   "failed to initialize importlib"). So the instantiations of the project's FMUs in one process take
   turns under a mutex named for the process (the Linux loader starts Python in its constructor;
   DllMain runs under the loader lock, where starting Python, which loads DLLs, is not safe). */
typedef HANDLE instantiate_guard;
static instantiate_guard instantiate_lock(void) {
    wchar_t name[64];
    HANDLE mutex;
    _snwprintf(name, 64, L"Local\\tapmuscle-fmu-instantiate-%lu", (unsigned long)GetCurrentProcessId());
    name[63] = 0;
    mutex = CreateMutexW(NULL, FALSE, name);
    if (mutex) WaitForSingleObject(mutex, INFINITE);   /* WAIT_ABANDONED also hands it over */
    return mutex;
}
static void instantiate_unlock(instantiate_guard mutex) {
    if (!mutex) return;
    ReleaseMutex(mutex);
    CloseHandle(mutex);
}

/* A thread with no Python thread state (any thread of a C host) gets one for its life at its first FMI
   call, as on Linux: pythonfmu brackets every call with PyGILState_Ensure/Release, which otherwise
   creates and destroys a thread state each time (a heap block and a VirtualAlloc'd frame stack). The
   GIL is released again at once, so other threads (a parallel master's) can run the FMUs. Python's C
   API comes from the Python DLL that pythonfmu's library imports (python3.dll forwards to the full
   python3XY.dll, which also exports the calls outside the stable ABI). A fiber-local slot's callback
   deletes the thread state when the thread exits (a master that starts threads per run or per step
   would otherwise leak one per thread); it also marks the thread as seen. */
static struct {
    int (*is_initialized)(void);
    int (*is_finalizing)(void);
    void *(*this_thread_state)(void);
    int (*ensure)(void);
    void *(*save_thread)(void);
    void (*restore_thread)(void *);
    void (*clear)(void *);
    void (*delete_current)(void);
    unsigned char (*shutdown_in_progress)(void);   /* ntdll's RtlDllShutdownInProgress */
} py;
static DWORD pin_slot = FLS_OUT_OF_INDEXES;
static INIT_ONCE pin_once = INIT_ONCE_STATIC_INIT;
#define PYTHON_THREAD ((void *)1)   /* the slot's value for a thread that had a thread state already */

static void WINAPI unpin_thread(void *saved) {
    if (!saved || saved == PYTHON_THREAD) return;
    /* not at process exit (the other threads are gone, one of them may hold the GIL), nor once Python
       is finalising */
    if ((py.shutdown_in_progress && py.shutdown_in_progress()) || !py.is_initialized()
        || (py.is_finalizing && py.is_finalizing()))
        return;
    py.restore_thread(saved);
    py.clear(saved);
    py.delete_current();   /* and releases the GIL */
}

static BOOL CALLBACK resolve_python(PINIT_ONCE once, void *parameter, void **context) {
    HMODULE stable = GetModuleHandleW(L"python3.dll"), full = NULL, self = NULL;
    FARPROC probe = stable ? GetProcAddress(stable, "Py_IsInitialized") : NULL;
    (void)once, (void)parameter, (void)context;
    if (!probe || !GetModuleHandleExW(GET_MODULE_HANDLE_EX_FLAG_FROM_ADDRESS | GET_MODULE_HANDLE_EX_FLAG_UNCHANGED_REFCOUNT,
                                      (LPCWSTR)(void *)probe, &full))
        return TRUE;
#define PY_CALL(field, name) py.field = (__typeof__(py.field))(void (*)(void))GetProcAddress(full, name)
    PY_CALL(is_initialized, "Py_IsInitialized");
    PY_CALL(this_thread_state, "PyGILState_GetThisThreadState");
    PY_CALL(ensure, "PyGILState_Ensure");
    PY_CALL(save_thread, "PyEval_SaveThread");
    PY_CALL(restore_thread, "PyEval_RestoreThread");
    PY_CALL(clear, "PyThreadState_Clear");
    PY_CALL(delete_current, "PyThreadState_DeleteCurrent");
    PY_CALL(is_finalizing, "Py_IsFinalizing");   /* 3.13 on */
    if (!py.is_finalizing) PY_CALL(is_finalizing, "_Py_IsFinalizing");   /* 3.11, 3.12 */
#undef PY_CALL
    py.shutdown_in_progress = (__typeof__(py.shutdown_in_progress))(void (*)(void))GetProcAddress(
        GetModuleHandleW(L"ntdll.dll"), "RtlDllShutdownInProgress");
    if (!py.is_initialized || !py.this_thread_state || !py.ensure || !py.save_thread || !py.restore_thread
        || !py.clear || !py.delete_current || !py.shutdown_in_progress)
        return TRUE;   /* not pinned: pythonfmu's own per-call thread states, slower, not wrong */
    /* The callback must outlive the host's FreeLibrary of this FMU: pin this library (and with it
       pythonfmu's, never freed) for the life of the process. */
    if (!GetModuleHandleExW(GET_MODULE_HANDLE_EX_FLAG_FROM_ADDRESS | GET_MODULE_HANDLE_EX_FLAG_PIN,
                            (LPCWSTR)(void *)&unpin_thread, &self))
        return TRUE;
    pin_slot = FlsAlloc(unpin_thread);
    return TRUE;
}

static void pin_thread(void) {
    void *saved;
    InitOnceExecuteOnce(&pin_once, resolve_python, NULL, NULL);
    if (pin_slot == FLS_OUT_OF_INDEXES || FlsGetValue(pin_slot) || !py.is_initialized()) return;
    if (py.this_thread_state()) {   /* a Python thread (fmpy), or pinned by the other FMU */
        FlsSetValue(pin_slot, PYTHON_THREAD);
        return;
    }
    py.ensure();
    saved = py.save_thread();
    if (!FlsSetValue(pin_slot, saved)) FlsSetValue(pin_slot, PYTHON_THREAD);
}
