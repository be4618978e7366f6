/* The FMI 2.0 logger a master gives an FMU whose messages are printf formats with arguments.

   FMI 2.0 (2.1.5) makes the logger variadic: `message` is a format and the values follow it, as C
   exports (OpenModelica, Dymola, Simulink) pass them. ctypes cannot read those arguments, so this
   function formats the message and hands the text to a Python callable (set_target): the master's
   router of messages by instance. The text is cut at 16 kB. pythonfmu's FMUs send plain text, which
   the master logs without this function (a '%' in it is no format there).
*/
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdarg.h>
#include <stdio.h>

static PyObject *target = NULL;

static void log_formatted(void *env, const char *name, int status, const char *category, const char *message, ...) {
    char text[16384];
    va_list args;
    (void)env;
    text[0] = 0;
    if (message) {
        va_start(args, message);
        if (vsnprintf(text, sizeof text, message, args) < 0)
            snprintf(text, sizeof text, "%s", message);  /* a format the C library refuses: as written */
        va_end(args);
    }
    PyGILState_STATE gil = PyGILState_Ensure();  /* an FMU may log from a thread Python does not know */
    if (target) {
        PyObject *result = PyObject_CallFunction(target, "yiyy", name ? name : "", status,
                                                 category ? category : "", text);
        if (result)
            Py_DECREF(result);
        else
            PyErr_WriteUnraisable(target);  /* an FMI call is in progress: nothing to raise into */
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
