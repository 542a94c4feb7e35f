/* The Python runtime that runs the model code: found, loaded and started at run time, never linked.

   The binary declares the few functions of the Python C API it calls and resolves them at run time
   (platform.h), so it loads in any process: one that has Python (fmpy) and one that has none (a C importer). */

#ifndef DSC_PYHOST_H
#define DSC_PYHOST_H

#include <stddef.h>
#include <stdint.h>
#include <wchar.h>

typedef struct _object PyObject;
typedef intptr_t Py_ssize_t;
typedef int PyGILState_STATE;
typedef struct _ts PyThreadState;
typedef struct _is PyInterpreterState;

/* What Py_PreInitialize and Py_InitializeFromConfig return (the same layout in every CPython since 3.8). */
typedef struct {
    int type; /* 0 ok, 1 error, 2 exit */
    const char *func;
    const char *err_msg;
    int exitcode;
} PyStatus;

typedef struct PyInitConfig PyInitConfig;

/* The functions of the Python C API the binary calls once a CPython runs, FUNCTION(return type, name,
   parameters), and the data it reads, DATA(type of the field, field, exported name): all that adopting
   a CPython already running needs, resolved from every CPython: each is public and in every CPython from
   3.9 on. None, where Python finalizes and the pending exception come through what the CPython offers
   (pyhost.c). */
#define PY_CALLS(FUNCTION, DATA)                                                                                     \
    FUNCTION(int, Py_IsInitialized, (void))                                                                          \
    FUNCTION(const char *, Py_GetVersion, (void))                                                                    \
    FUNCTION(PyThreadState *, PyEval_SaveThread, (void))                                                             \
    FUNCTION(void, PyEval_RestoreThread, (PyThreadState *))                                                          \
    FUNCTION(PyGILState_STATE, PyGILState_Ensure, (void))                                                            \
    FUNCTION(void, PyGILState_Release, (PyGILState_STATE))                                                           \
    FUNCTION(PyThreadState *, PyGILState_GetThisThreadState, (void))                                                 \
    FUNCTION(PyInterpreterState *, PyInterpreterState_Main, (void))                                                  \
    FUNCTION(PyThreadState *, PyThreadState_New, (PyInterpreterState *))                                             \
    FUNCTION(void, PyThreadState_Clear, (PyThreadState *))                                                           \
    FUNCTION(void, PyThreadState_Delete, (PyThreadState *))                                                          \
    FUNCTION(void, PyThreadState_DeleteCurrent, (void))                                                              \
    FUNCTION(PyObject *, PyImport_ImportModule, (const char *))                                                      \
    FUNCTION(PyObject *, PyObject_GetAttrString, (PyObject *, const char *))                                         \
    FUNCTION(PyObject *, PyObject_CallObject, (PyObject *, PyObject *))                                              \
    FUNCTION(PyObject *, PyObject_Str, (PyObject *))                                                                 \
    FUNCTION(PyObject *, PyObject_Type, (PyObject *))                                                                \
    FUNCTION(int, PyObject_IsTrue, (PyObject *))                                                                     \
    FUNCTION(const char *, PyUnicode_AsUTF8, (PyObject *))                                                           \
    FUNCTION(PyObject *, PyUnicode_FromString, (const char *))                                                       \
    FUNCTION(PyObject *, PyLong_FromLong, (long))                                                                    \
    FUNCTION(long, PyLong_AsLong, (PyObject *))                                                                      \
    FUNCTION(PyObject *, PyFloat_FromDouble, (double))                                                               \
    FUNCTION(double, PyFloat_AsDouble, (PyObject *))                                                                 \
    FUNCTION(PyObject *, PyBool_FromLong, (long))                                                                    \
    FUNCTION(PyObject *, PyTuple_New, (Py_ssize_t))                                                                  \
    FUNCTION(int, PyTuple_SetItem, (PyObject *, Py_ssize_t, PyObject *))                                             \
    FUNCTION(PyObject *, PyList_New, (Py_ssize_t))                                                                   \
    FUNCTION(int, PyList_SetItem, (PyObject *, Py_ssize_t, PyObject *))                                              \
    FUNCTION(Py_ssize_t, PyList_Size, (PyObject *))                                                                  \
    FUNCTION(PyObject *, PyDict_GetItemString, (PyObject *, const char *))                                           \
    FUNCTION(int, PyDict_SetItemString, (PyObject *, const char *, PyObject *))                                      \
    FUNCTION(int, PyDict_DelItemString, (PyObject *, const char *))                                                  \
    FUNCTION(PyObject *, PyBytes_FromStringAndSize, (const char *, Py_ssize_t))                                      \
    FUNCTION(int, PyBytes_AsStringAndSize, (PyObject *, char **, Py_ssize_t *))                                      \
    FUNCTION(PyObject *, PyErr_Occurred, (void))                                                                     \
    FUNCTION(int, PyErr_GivenExceptionMatches, (PyObject *, PyObject *))                                             \
    FUNCTION(void, PyErr_Clear, (void))                                                                              \
    FUNCTION(void, PyErr_SetInterrupt, (void))                                                                       \
    FUNCTION(void, Py_DecRef, (PyObject *))                                                                          \
    FUNCTION(void, Py_IncRef, (PyObject *))                                                                          \
    FUNCTION(Py_ssize_t, PySequence_Size, (PyObject *))                                                              \
    FUNCTION(PyObject *, PySequence_GetItem, (PyObject *, Py_ssize_t))                                               \
    FUNCTION(PyObject *, PySys_GetObject, (const char *))                                                            \
    DATA(PyObject **, PyExc_KeyboardInterrupt, PyExc_KeyboardInterrupt)

/* The pending exception as one object, from 3.12 on; before, as its type, value and traceback. */
#define PY_RAISED(FUNCTION)                                                                                          \
    FUNCTION(PyObject *, PyErr_GetRaisedException, (void))                                                           \
    FUNCTION(void, PyErr_SetRaisedException, (PyObject *))
#define PY_FETCHED(FUNCTION)                                                                                         \
    FUNCTION(void, PyErr_Fetch, (PyObject **, PyObject **, PyObject **))                                             \
    FUNCTION(void, PyErr_NormalizeException, (PyObject **, PyObject **, PyObject **))                                \
    FUNCTION(void, PyErr_Restore, (PyObject *, PyObject *, PyObject *))                                              \
    FUNCTION(int, PyException_SetTraceback, (PyObject *, PyObject *))                                                \
    FUNCTION(PyObject *, PyException_GetTraceback, (PyObject *))

/* Starting a CPython from 3.14 on: PEP 741's configuration. */
#define PY_START_INIT_CONFIG(FUNCTION)                                                                               \
    FUNCTION(PyInitConfig *, PyInitConfig_Create, (void))                                                            \
    FUNCTION(void, PyInitConfig_Free, (PyInitConfig *))                                                              \
    FUNCTION(int, PyInitConfig_SetInt, (PyInitConfig *, const char *, int64_t))                                      \
    FUNCTION(int, PyInitConfig_SetStr, (PyInitConfig *, const char *, const char *))                                 \
    FUNCTION(int, PyInitConfig_GetError, (PyInitConfig *, const char **))                                            \
    FUNCTION(int, PyInitConfig_GetExitCode, (PyInitConfig *, int *))                                                 \
    FUNCTION(int, Py_InitializeFromInitConfig, (PyInitConfig *))

/* Starting a CPython before 3.14: PEP 587's PyPreConfig and PyConfig. */
#define PY_START_CONFIG(FUNCTION)                                                                                    \
    FUNCTION(void, PyPreConfig_InitIsolatedConfig, (void *))                                                         \
    FUNCTION(PyStatus, Py_PreInitialize, (const void *))                                                             \
    FUNCTION(void, PyConfig_InitIsolatedConfig, (void *))                                                            \
    FUNCTION(void, PyConfig_InitPythonConfig, (void *))                                                              \
    FUNCTION(PyStatus, PyConfig_SetString, (void *, wchar_t **, const wchar_t *))                                    \
    FUNCTION(PyStatus, Py_InitializeFromConfig, (const void *))                                                      \
    FUNCTION(void, PyConfig_Clear, (void *))                                                                         \
    FUNCTION(wchar_t *, Py_DecodeLocale, (const char *, size_t *))

#define PY_FUNCTION(type, name, parameters) type(*name) parameters;
#define PY_DATA(type, name, symbol) type name;
typedef struct {
    PY_CALLS(PY_FUNCTION, PY_DATA)
    PY_RAISED(PY_FUNCTION)
    PY_FETCHED(PY_FUNCTION)
    PY_START_INIT_CONFIG(PY_FUNCTION)
    PY_START_CONFIG(PY_FUNCTION)
    PyObject *None; /* Py_GetConstantBorrowed(Py_CONSTANT_NONE) from 3.13 on, &_Py_NoneStruct before */
} PyApi;

/* The resolved API; valid once pyhost_start returned 0. */
extern PyApi py;

/* Find, load and start Python once per process (thread-safe). Returns 0, or -1 with a message
   naming every place it looked, and why each failed, in `error` (the same message on every later
   call). A Python that fails to start is such a failure, never an exit of the process. */
int pyhost_start(char *error, size_t size);

/* Whether the Python this binary started or adopted can still run code: it is initialised, not finalizing
   (module teardown, where a host's destructors free instances), and still the interpreter whose objects the
   binary holds, not one started anew after it was finalized. Needs no GIL; the binary's Python objects must
   not be touched where it is 0. */
int pyhost_alive(void);

/* The pending exception, taken out of Python's error indicator: a new reference, or NULL if there is none. */
PyObject *pyhost_take_error(void);
/* Make `error` (taken by pyhost_take_error; this takes the reference) the pending exception again. */
void pyhost_restore_error(PyObject *error);

/* Take the GIL from any thread, known to Python or not. A thread Python does not know gets a thread
   state that it keeps until it ends; then the state is deleted. */
PyGILState_STATE pyhost_enter(void);
void pyhost_leave(PyGILState_STATE state);

#endif
