/* FMI 2.0 co-simulation functions that run a pythonfmu slave class in the process's Python.

   The export library for machines pythonfmu 0.7 ships no binary for (its linux64 library is x86-64
   only: an aarch64 Linux host, a Raspberry Pi, a Docker container on an ARM Mac). It is compiled by
   build_scripts/native_host.py at `tapmuscle build` and sits where pythonfmu's library would, behind the
   project's FMI shim (fmi_shim.c), which already checks the host's arguments (resources path,
   GUID), keeps a Python thread state per host thread, names every message's category, logs errors
   with logging off and returns the worst status logged. This file does what pythonfmu's library does
   for the slave:

   - fmi2Instantiate: puts the resources folder first on sys.path, imports the module named in
     resources/slavemodule.txt, takes the first class in it whose MRO holds a class named Fmi2Slave
     (not Fmi2Slave itself) and calls it with instance_name, resources and visible, plus
     fmi_export="tapmuscle" (the slave then knows that this library keeps its references when an
     exception comes through: fmi_slave.base);
   - every other call: the slave's method of the same name (do_step, get_real, _get_fmu_state, ...);
     a false do_step is fmi2Discard; an exception is logged with its type and text and answered
     with fmi2Fatal (an unexpected failure: the slave's state is unknown);
   - after every call the slave's log queue (LogMsg: status, category, msg) goes to the logger,
     each message passed as a format without arguments (the shim takes it literally).

   Python must be running (the loader starts it in a C host; a Python host has it). */
#include <Python.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

typedef struct {
    PyObject *cls;                 /* the slave class */
    PyObject *slave;               /* its instance */
    PyObject *queue;               /* slave._get_log_queue(): a list of LogMsg */
    PyObject *strings;             /* what fmi2GetString's pointers point into, kept until its next call */
    fmi2CallbackFunctions cb;
    int visible;
    char name[256];
    char resources[4096];
} Export;

static void log_text(Export *e, fmi2Status status, const char *category, const char *text) {
    if (e->cb.logger) e->cb.logger(e->cb.componentEnvironment, e->name, status, category, text);
}

/* The slave's queued messages to the host, in order; the queue is emptied. */
static void drain(Export *e) {
    Py_ssize_t n, i;
    if (!e->queue || !PyList_Check(e->queue)) return;
    n = PyList_Size(e->queue);
    for (i = 0; i < n; i++) {
        PyObject *m = PyList_GetItem(e->queue, i);   /* borrowed */
        PyObject *status = PyObject_GetAttrString(m, "status");
        PyObject *category = PyObject_GetAttrString(m, "category");
        PyObject *msg = PyObject_GetAttrString(m, "msg");
        PyObject *text = msg ? PyObject_Str(msg) : NULL;
        long level = status ? PyLong_AsLong(status) : (long)fmi2Error;
        const char *cat = category && PyUnicode_Check(category) ? PyUnicode_AsUTF8(category) : NULL;
        const char *t = text ? PyUnicode_AsUTF8(text) : NULL;
        if (PyErr_Occurred()) PyErr_Clear();
        if (level < fmi2OK || level > fmi2Pending) level = fmi2Error;
        log_text(e, (fmi2Status)level, cat ? cat : "", t ? t : "(a log message that is not text)");
        Py_XDECREF(status);
        Py_XDECREF(category);
        Py_XDECREF(msg);
        Py_XDECREF(text);
    }
    PyList_SetSlice(e->queue, 0, n, NULL);
}

/* The pending Python exception, logged ("<call>: <type>: <text>") and cleared; fmi2Fatal. */
static fmi2Status failed(Export *e, const char *call) {
    PyObject *type, *value, *tb, *text;
    char message[4096];
    const char *what = "unknown error", *kind = "exception";
    PyErr_Fetch(&type, &value, &tb);
    PyErr_NormalizeException(&type, &value, &tb);
    text = value ? PyObject_Str(value) : NULL;
    if (text) what = PyUnicode_AsUTF8(text);
    if (type && PyType_Check(type)) kind = ((PyTypeObject *)type)->tp_name;
    if (!what) what = "(no text)";
    snprintf(message, sizeof message, "%s: Python %s: %s", call, kind, what);
    PyErr_Clear();
    drain(e);
    log_text(e, fmi2Fatal, "logStatusFatal", message);
    Py_XDECREF(text);
    Py_XDECREF(type);
    Py_XDECREF(value);
    Py_XDECREF(tb);
    return fmi2Fatal;
}

/* The result of a slave call: a new reference, or NULL after failed(). */
#define CALL(e, status, call, expr)                                  \
    PyObject *result = (expr);                                       \
    if (!result) status = failed(e, call)

static PyObject *references(const fmi2ValueReference vr[], size_t n) {
    PyObject *list = PyList_New((Py_ssize_t)n);
    size_t i;
    for (i = 0; list && i < n; i++) PyList_SET_ITEM(list, (Py_ssize_t)i, PyLong_FromUnsignedLong(vr[i]));
    return list;
}

/* The class of the slave module: the first one whose MRO holds a class named Fmi2Slave. */
static PyObject *slave_class(PyObject *module) {
    PyObject *dict = PyModule_GetDict(module), *key, *value;
    Py_ssize_t pos = 0;
    while (PyDict_Next(dict, &pos, &key, &value)) {
        PyObject *mro;
        Py_ssize_t i, n;
        if (!PyType_Check(value) || !strcmp(((PyTypeObject *)value)->tp_name, "Fmi2Slave")) continue;
        mro = ((PyTypeObject *)value)->tp_mro;
        n = mro ? PyTuple_Size(mro) : 0;
        for (i = 1; i < n; i++) {
            const char *name = ((PyTypeObject *)PyTuple_GET_ITEM(mro, i))->tp_name;
            const char *dot = strrchr(name, '.');
            if (!strcmp(dot ? dot + 1 : name, "Fmi2Slave")) {
                Py_INCREF(value);
                return value;
            }
        }
    }
    return NULL;
}

/* A new instance of the class with pythonfmu's keyword arguments; 0 on success. */
static int make_slave(Export *e) {
    PyObject *args = PyTuple_New(0);
    PyObject *kwargs = Py_BuildValue("{s:s,s:s,s:O,s:s}", "instance_name", e->name, "resources", e->resources,
                                     "visible", e->visible ? Py_True : Py_False, "fmi_export", "tapmuscle");
    PyObject *slave = args && kwargs ? PyObject_Call(e->cls, args, kwargs) : NULL;
    Py_XDECREF(args);
    Py_XDECREF(kwargs);
    if (!slave) return -1;
    Py_XDECREF(e->slave);
    Py_XDECREF(e->queue);
    e->slave = slave;
    e->queue = PyObject_CallMethod(slave, "_get_log_queue", NULL);
    return e->queue ? 0 : -1;
}

static void release(Export *e) {
    Py_XDECREF(e->slave);
    Py_XDECREF(e->queue);
    Py_XDECREF(e->cls);
    Py_XDECREF(e->strings);
    free(e);
}

FMI2_Export const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
FMI2_Export const char *fmi2GetVersion(void) { return fmi2Version; }

FMI2_Export fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String resources,
                                          const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                                          fmi2Boolean loggingOn) {
    Export *e = calloc(1, sizeof *e);
    char path[4200], module_name[512] = "";
    PyGILState_STATE gil;
    PyObject *sys_path, *module = NULL;
    FILE *f;
    (void)guid;
    (void)loggingOn;   /* the shim filters */
    if (!e) return NULL;
    if (functions) e->cb = *functions;
    e->visible = visible;
    snprintf(e->name, sizeof e->name, "%s", name ? name : "");
    if (type != fmi2CoSimulation) {
        log_text(e, fmi2Error, "logStatusError", "fmi2Instantiate: this FMU is for co-simulation only");
        free(e);
        return NULL;
    }
    if (!Py_IsInitialized()) {
        log_text(e, fmi2Error, "logStatusError", "fmi2Instantiate: Python is not running in this process");
        free(e);
        return NULL;
    }
    /* a file URI without percent-encoding, or the path the shim decoded */
    if (resources && !strncmp(resources, "file://", 7)) resources += 7;
    snprintf(e->resources, sizeof e->resources, "%s", resources ? resources : "");
    snprintf(path, sizeof path, "%s/slavemodule.txt", e->resources);
    if ((f = fopen(path, "r"))) {
        if (fgets(module_name, sizeof module_name, f)) module_name[strcspn(module_name, "\r\n")] = 0;
        fclose(f);
    }
    if (!module_name[0]) {
        snprintf(path, sizeof path, "fmi2Instantiate: %.4000s/slavemodule.txt names no module", e->resources);
        log_text(e, fmi2Error, "logStatusError", path);
        free(e);
        return NULL;
    }
    gil = PyGILState_Ensure();
    sys_path = PySys_GetObject("path");   /* borrowed */
    if (sys_path) {
        PyObject *folder = PyUnicode_DecodeFSDefault(e->resources);
        if (!folder || PyList_Insert(sys_path, 0, folder) != 0) sys_path = NULL;
        Py_XDECREF(folder);
    }
    if (sys_path) module = PyImport_ImportModule(module_name);
    if (module && !(e->cls = slave_class(module)) && !PyErr_Occurred())
        PyErr_Format(PyExc_TypeError, "module %s has no class derived from pythonfmu's Fmi2Slave", module_name);
    Py_XDECREF(module);
    if (!sys_path || !e->cls || make_slave(e) != 0) {
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_RuntimeError, "sys.path cannot be changed");
        failed(e, "fmi2Instantiate");
        release(e);
        PyGILState_Release(gil);
        return NULL;
    }
    drain(e);
    PyGILState_Release(gil);
    return e;
}

FMI2_Export void fmi2FreeInstance(fmi2Component c) {
    PyGILState_STATE gil;
    if (!c) return;
    gil = PyGILState_Ensure();
    release((Export *)c);
    PyGILState_Release(gil);
}

FMI2_Export fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cats[]) {
    (void)c, (void)on, (void)n, (void)cats;   /* every message goes to the shim, which filters */
    return fmi2OK;
}

/* A slave method called with a Py_BuildValue format and arguments; its result is dropped. */
#define METHOD(X, PARAMS, METHOD_NAME, ...)                                                 \
    FMI2_Export fmi2Status X PARAMS {                                                       \
        Export *e = (Export *)c;                                                            \
        fmi2Status status = fmi2OK;                                                         \
        PyGILState_STATE gil = PyGILState_Ensure();                                         \
        CALL(e, status, #X, PyObject_CallMethod(e->slave, METHOD_NAME, __VA_ARGS__));       \
        Py_XDECREF(result);                                                                 \
        drain(e);                                                                           \
        PyGILState_Release(gil);                                                            \
        return status;                                                                      \
    }

FMI2_Export fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean td, fmi2Real tol, fmi2Real t0, fmi2Boolean sd,
                                           fmi2Real t1) {
    Export *e = (Export *)c;
    fmi2Status status = fmi2OK;
    PyGILState_STATE gil = PyGILState_Ensure();
    PyObject *stop = sd ? PyFloat_FromDouble(t1) : Py_NewRef(Py_None);
    PyObject *tolerance = td ? PyFloat_FromDouble(tol) : Py_NewRef(Py_None);
    CALL(e, status, "fmi2SetupExperiment",
         stop && tolerance ? PyObject_CallMethod(e->slave, "setup_experiment", "dOO", t0, stop, tolerance) : NULL);
    Py_XDECREF(result);
    Py_XDECREF(stop);
    Py_XDECREF(tolerance);
    drain(e);
    PyGILState_Release(gil);
    return status;
}

METHOD(fmi2EnterInitializationMode, (fmi2Component c), "enter_initialization_mode", NULL)
METHOD(fmi2ExitInitializationMode, (fmi2Component c), "exit_initialization_mode", NULL)
METHOD(fmi2Terminate, (fmi2Component c), "terminate", NULL)

FMI2_Export fmi2Status fmi2Reset(fmi2Component c) {
    Export *e = (Export *)c;
    fmi2Status status = fmi2OK;
    PyGILState_STATE gil = PyGILState_Ensure();
    drain(e);
    if (make_slave(e) != 0) status = failed(e, "fmi2Reset");
    drain(e);
    PyGILState_Release(gil);
    return status;
}

FMI2_Export fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    Export *e = (Export *)c;
    fmi2Status status = fmi2OK;
    PyGILState_STATE gil = PyGILState_Ensure();
    int done;
    (void)noSetFMUStatePriorToCurrentPoint;
    {
        CALL(e, status, "fmi2DoStep", PyObject_CallMethod(e->slave, "do_step", "dd", t, h));
        if (result) {
            done = PyObject_IsTrue(result);
            if (done < 0) status = failed(e, "fmi2DoStep");
            else if (!done) status = fmi2Discard;
        }
        Py_XDECREF(result);
    }
    drain(e);
    PyGILState_Release(gil);
    return status;
}

/* fmi2GetX: the slave's get_x(references) as a list of n values, each converted by CONVERT(item, &v[i])
   (0 on success). */
#define GETTER(X, TYPE, METHOD_NAME, CONVERT)                                                               \
    FMI2_Export fmi2Status X(fmi2Component c, const fmi2ValueReference vr[], size_t n, TYPE v[]) {          \
        Export *e = (Export *)c;                                                                            \
        fmi2Status status = fmi2OK;                                                                         \
        PyGILState_STATE gil = PyGILState_Ensure();                                                         \
        PyObject *refs = references(vr, n);                                                                 \
        CALL(e, status, #X, refs ? PyObject_CallMethod(e->slave, METHOD_NAME, "(O)", refs) : NULL);         \
        if (result) {                                                                                       \
            PyObject *seq = PySequence_Fast(result, #X ": the slave returned no sequence");                 \
            if (seq && (size_t)PySequence_Fast_GET_SIZE(seq) != n)                                          \
                PyErr_Format(PyExc_ValueError, #X ": the slave returned %zd values for %zu references",     \
                             PySequence_Fast_GET_SIZE(seq), n);                                             \
            for (size_t i = 0; seq && !PyErr_Occurred() && i < n; i++) {                                    \
                PyObject *item = PySequence_Fast_GET_ITEM(seq, (Py_ssize_t)i);                              \
                CONVERT;                                                                                    \
            }                                                                                               \
            if (PyErr_Occurred()) status = failed(e, #X);                                                   \
            Py_XDECREF(seq);                                                                                \
        }                                                                                                   \
        Py_XDECREF(result);                                                                                 \
        Py_XDECREF(refs);                                                                                   \
        drain(e);                                                                                           \
        PyGILState_Release(gil);                                                                            \
        return status;                                                                                      \
    }

GETTER(fmi2GetReal, fmi2Real, "get_real", v[i] = PyFloat_AsDouble(item))
GETTER(fmi2GetInteger, fmi2Integer, "get_integer", v[i] = (fmi2Integer)PyLong_AsLong(item))
GETTER(fmi2GetBoolean, fmi2Boolean, "get_boolean", { int b = PyObject_IsTrue(item); v[i] = b > 0; })

FMI2_Export fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String v[]) {
    Export *e = (Export *)c;
    fmi2Status status = fmi2OK;
    PyGILState_STATE gil = PyGILState_Ensure();
    PyObject *refs = references(vr, n), *kept = PyList_New(0);
    CALL(e, status, "fmi2GetString", refs && kept ? PyObject_CallMethod(e->slave, "get_string", "(O)", refs) : NULL);
    if (result) {
        PyObject *seq = PySequence_Fast(result, "fmi2GetString: the slave returned no sequence");
        if (seq && (size_t)PySequence_Fast_GET_SIZE(seq) != n)
            PyErr_Format(PyExc_ValueError, "fmi2GetString: the slave returned %zd values for %zu references",
                         PySequence_Fast_GET_SIZE(seq), n);
        for (size_t i = 0; seq && !PyErr_Occurred() && i < n; i++) {
            PyObject *text = PyUnicode_AsUTF8String(PySequence_Fast_GET_ITEM(seq, (Py_ssize_t)i));
            if (text && PyList_Append(kept, text) == 0) v[i] = PyBytes_AS_STRING(text);
            Py_XDECREF(text);
        }
        if (PyErr_Occurred()) status = failed(e, "fmi2GetString");
        Py_XDECREF(seq);
        if (status <= fmi2Warning) {
            Py_XDECREF(e->strings);
            e->strings = kept;
            kept = NULL;
        }
    }
    Py_XDECREF(kept);
    Py_XDECREF(result);
    Py_XDECREF(refs);
    drain(e);
    PyGILState_Release(gil);
    return status;
}

/* fmi2SetX: the slave's set_x(references, values), each value made by MAKE(v[i]). */
#define SETTER(X, TYPE, METHOD_NAME, MAKE)                                                                  \
    FMI2_Export fmi2Status X(fmi2Component c, const fmi2ValueReference vr[], size_t n, const TYPE v[]) {    \
        Export *e = (Export *)c;                                                                            \
        fmi2Status status = fmi2OK;                                                                         \
        PyGILState_STATE gil = PyGILState_Ensure();                                                         \
        PyObject *refs = references(vr, n), *values = PyList_New((Py_ssize_t)n);                            \
        for (size_t i = 0; values && i < n; i++) PyList_SET_ITEM(values, (Py_ssize_t)i, MAKE(v[i]));        \
        CALL(e, status, #X, refs && values && !PyErr_Occurred()                                             \
             ? PyObject_CallMethod(e->slave, METHOD_NAME, "(OO)", refs, values) : NULL);                    \
        Py_XDECREF(result);                                                                                 \
        Py_XDECREF(refs);                                                                                   \
        Py_XDECREF(values);                                                                                 \
        drain(e);                                                                                           \
        PyGILState_Release(gil);                                                                            \
        return status;                                                                                      \
    }

static PyObject *text_value(fmi2String s) { return PyUnicode_FromString(s ? s : ""); }
static PyObject *boolean_value(fmi2Boolean b) { return PyBool_FromLong(b != fmi2False); }

SETTER(fmi2SetReal, fmi2Real, "set_real", PyFloat_FromDouble)
SETTER(fmi2SetInteger, fmi2Integer, "set_integer", PyLong_FromLong)
SETTER(fmi2SetBoolean, fmi2Boolean, "set_boolean", boolean_value)
SETTER(fmi2SetString, fmi2String, "set_string", text_value)

/* An FMU state is the slave's state object (a new reference); a new one at every fmi2GetFMUstate, as
   pythonfmu makes it (the shim frees the one the host passed in). */
FMI2_Export fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *st) {
    Export *e = (Export *)c;
    fmi2Status status = fmi2OK;
    PyGILState_STATE gil = PyGILState_Ensure();
    CALL(e, status, "fmi2GetFMUstate", PyObject_CallMethod(e->slave, "_get_fmu_state", NULL));
    if (result) *st = result;
    drain(e);
    PyGILState_Release(gil);
    return status;
}

METHOD(fmi2SetFMUstate, (fmi2Component c, fmi2FMUstate st), "_set_fmu_state", "(O)",
       st ? (PyObject *)st : Py_None)

FMI2_Export fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *st) {
    PyGILState_STATE gil;
    (void)c;
    if (!st || !*st) return fmi2OK;
    gil = PyGILState_Ensure();
    Py_DECREF((PyObject *)*st);
    *st = NULL;
    PyGILState_Release(gil);
    return fmi2OK;
}

/* The serialised state: the slave's _fmu_state_to_bytes(state), a new reference, or NULL after failed(). */
static PyObject *state_bytes(Export *e, fmi2FMUstate st, const char *call) {
    PyObject *b = PyObject_CallMethod(e->slave, "_fmu_state_to_bytes", "(O)", st ? (PyObject *)st : Py_None);
    if (b && !PyBytes_Check(b)) {
        Py_DECREF(b);
        b = NULL;
        PyErr_Format(PyExc_TypeError, "%s: _fmu_state_to_bytes returned no bytes", call);
    }
    if (!b) failed(e, call);
    return b;
}

FMI2_Export fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate st, size_t *n) {
    Export *e = (Export *)c;
    PyGILState_STATE gil = PyGILState_Ensure();
    PyObject *b = state_bytes(e, st, "fmi2SerializedFMUstateSize");
    if (b) *n = (size_t)PyBytes_GET_SIZE(b);
    Py_XDECREF(b);
    drain(e);
    PyGILState_Release(gil);
    return b ? fmi2OK : fmi2Fatal;
}

FMI2_Export fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate st, fmi2Byte bytes[], size_t n) {
    Export *e = (Export *)c;
    fmi2Status status = fmi2OK;
    PyGILState_STATE gil = PyGILState_Ensure();
    PyObject *b = state_bytes(e, st, "fmi2SerializeFMUstate");
    if (!b) status = fmi2Fatal;
    else if ((size_t)PyBytes_GET_SIZE(b) != n) {
        char text[200];
        snprintf(text, sizeof text, "fmi2SerializeFMUstate: the state has %zd bytes, the host passed room for %zu "
                 "(fmi2SerializedFMUstateSize tells)", PyBytes_GET_SIZE(b), n);
        log_text(e, fmi2Error, "logStatusError", text);
        status = fmi2Error;
    } else memcpy(bytes, PyBytes_AS_STRING(b), n);
    Py_XDECREF(b);
    drain(e);
    PyGILState_Release(gil);
    return status;
}

FMI2_Export fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte bytes[], size_t n, fmi2FMUstate *st) {
    Export *e = (Export *)c;
    fmi2Status status = fmi2OK;
    PyGILState_STATE gil = PyGILState_Ensure();
    PyObject *b = PyBytes_FromStringAndSize(bytes, (Py_ssize_t)n);
    CALL(e, status, "fmi2DeSerializeFMUstate", b ? PyObject_CallMethod(e->slave, "_fmu_state_from_bytes", "(O)", b) : NULL);
    if (result) *st = result;
    Py_XDECREF(b);
    drain(e);
    PyGILState_Release(gil);
    return status;
}

/* What the model description declares unsupported. */
static fmi2Status unsupported(fmi2Component c, const char *call) {
    char text[200];
    snprintf(text, sizeof text, "%s is not supported by this FMU (see its modelDescription.xml)", call);
    log_text((Export *)c, fmi2Error, "logStatusError", text);
    return fmi2Error;
}

FMI2_Export fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference u[], size_t nu,
                                                    const fmi2ValueReference z[], size_t nz, const fmi2Real du[],
                                                    fmi2Real dz[]) {
    (void)u, (void)nu, (void)z, (void)nz, (void)du, (void)dz;
    return unsupported(c, "fmi2GetDirectionalDerivative");
}
FMI2_Export fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                                   const fmi2Integer order[], const fmi2Real v[]) {
    (void)vr, (void)n, (void)order, (void)v;
    return unsupported(c, "fmi2SetRealInputDerivatives");
}
FMI2_Export fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                                    const fmi2Integer order[], fmi2Real v[]) {
    (void)vr, (void)n, (void)order, (void)v;
    return unsupported(c, "fmi2GetRealOutputDerivatives");
}
/* fmi2DoStep always completes before it returns: there is no asynchronous step to cancel or ask about. */
FMI2_Export fmi2Status fmi2CancelStep(fmi2Component c) { return unsupported(c, "fmi2CancelStep"); }
/* fmi2GetXStatus on fmi2DoStep's asynchronous step */
#define STATUS_INQUIRY(X, TYPE)                                                       \
    FMI2_Export fmi2Status X(fmi2Component c, const fmi2StatusKind k, TYPE *v) {      \
        (void)k, (void)v;                                                             \
        return unsupported(c, #X);                                                    \
    }
STATUS_INQUIRY(fmi2GetStatus, fmi2Status)
STATUS_INQUIRY(fmi2GetRealStatus, fmi2Real)
STATUS_INQUIRY(fmi2GetIntegerStatus, fmi2Integer)
STATUS_INQUIRY(fmi2GetBooleanStatus, fmi2Boolean)
STATUS_INQUIRY(fmi2GetStringStatus, fmi2String)
