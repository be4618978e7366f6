/* The FMI 2.0 logger a master gives an FMU whose messages are printf formats with arguments.

   FMI 2.0 (2.1.5) makes the logger variadic: `message` is a format and the values follow it, as C
   exports (OpenModelica, Dymola, Simulink) pass them. ctypes cannot read those arguments, so this
   function formats the message and hands the text to a Python callable (set_target): the master's
   router of messages by instance. The text is cut at 16 kB. pythonfmu's FMUs send plain text, which
   the master logs without this function (a '%' in it is no format there). A "%n" (which would write
   through an argument) is shown, not formatted. An FMU that sends plain text with a '%' in it breaks
   FMI's rule and shows what its format reads (fmpy's logger does the same); TAPMUSCLE_FMU_LOG=plain
   takes every FMU's messages as plain text instead.
*/
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

static PyObject *target = NULL;

/* Whether `format` holds a %n conversion (flags, width, precision and length skipped). */
static int writes_through_an_argument(const char *format) {
    for (const char *p = format; *p; p++) {
        if (*p != '%') continue;
        p++;
        if (*p == '%') continue;
        while (*p && strchr("-+ #0123456789.*'hlLqjzt", *p)) p++;
        if (*p == 'n') return 1;
        if (!*p) break;
    }
    return 0;
}

static void log_formatted(void *env, const char *name, int status, const char *category, const char *message, ...) {
    char text[16384];
    va_list args;
    (void)env;
    text[0] = 0;
    if (message && writes_through_an_argument(message)) {
        snprintf(text, sizeof text, "%s", message);
    } else if (message) {
        va_start(args, message);
        if (vsnprintf(text, sizeof text, message, args) < 0)
            snprintf(text, sizeof text, "%s", message);  /* a format the C library refuses: as written */
        va_end(args);
    }
    PyGILState_STATE gil = PyGILState_Ensure();  /* an FMU may log from a thread Python does not know */
    PyObject *callable = target;
    if (callable) {
        Py_INCREF(callable);  /* held through the call: set_target may replace it meanwhile */
        PyObject *result = PyObject_CallFunction(callable, "yiyy", name ? name : "", status,
                                                 category ? category : "", text);
        if (result) {
            Py_DECREF(result);
        } else if (PyErr_ExceptionMatches(PyExc_KeyboardInterrupt)) {
            /* a Ctrl-C that Python took here, inside an FMI call: raised again once the call returns */
            PyErr_Clear();
            PyErr_SetInterrupt();
        } else {
            PyErr_WriteUnraisable(callable);  /* an FMI call is in progress: nothing to raise into */
        }
        Py_DECREF(callable);
    }
    PyGILState_Release(gil);
}

static PyObject *set_target(PyObject *self, PyObject *callable) {
    (void)self;
    if (!PyCallable_Check(callable)) {
        PyErr_SetString(PyExc_TypeError, "the target must be callable (name, status, category, text)");
        return NULL;
    }
    Py_INCREF(callable);
    Py_XSETREF(target, callable);
    Py_RETURN_NONE;
}

static PyObject *address(PyObject *self, PyObject *unused) {
    (void)self;
    (void)unused;
    return PyLong_FromVoidPtr((void *)log_formatted);
}

static PyMethodDef methods[] = {
    {"set_target", set_target, METH_O, "Set the callable(name: bytes, status: int, category: bytes, text: bytes)."},
    {"address", address, METH_NOARGS, "The address of the C logger function (an fmi2CallbackLogger)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_fmi_log", NULL, -1, methods};

PyMODINIT_FUNC PyInit__fmi_log(void) { return PyModule_Create(&module); }
