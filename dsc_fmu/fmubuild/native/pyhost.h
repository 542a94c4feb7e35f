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

/* What Py_InitializeFromConfig returns (the same layout in every CPython since 3.8). */
typedef struct {
    int type; /* 0 ok, 1 error, 2 exit */
    const char *func;
    const char *err_msg;
    int exitcode;
} PyStatus;

/* The functions of the Python C API the binary calls, FUNCTION(return type, name, parameters), and the data it
   reads, DATA(type of the field, field, exported name): the fields of PyApi and the symbols resolved. */
#define PY_API(FUNCTION, DATA)                                                                                       \
    FUNCTION(int, Py_IsInitialized, (void))                                                                          \
    FUNCTION(void, _PyConfig_InitCompatConfig, (void *config))                                                       \
    FUNCTION(PyStatus, Py_InitializeFromConfig, (const void *config))                                                \
    FUNCTION(void, PyConfig_Clear, (void *config))                                                                   \
    FUNCTION(void, Py_SetPythonHome, (const wchar_t *))                                                              \
    FUNCTION(wchar_t *, Py_DecodeLocale, (const char *, size_t *))                                                   \
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
    FUNCTION(void, PyErr_Fetch, (PyObject **, PyObject **, PyObject **))                                             \
    FUNCTION(void, PyErr_Restore, (PyObject *, PyObject *, PyObject *))                                              \
    FUNCTION(void, PyErr_Clear, (void))                                                                              \
    FUNCTION(void, Py_DecRef, (PyObject *))                                                                          \
    FUNCTION(void, Py_IncRef, (PyObject *))                                                                          \
    FUNCTION(Py_ssize_t, PySequence_Size, (PyObject *))                                                              \
    FUNCTION(PyObject *, PySequence_GetItem, (PyObject *, Py_ssize_t))                                               \
    FUNCTION(PyObject *, PySys_GetObject, (const char *))                                                            \
    DATA(PyObject *, None, _Py_NoneStruct)                                                                           \
    DATA(int *, Py_IgnoreEnvironmentFlag, Py_IgnoreEnvironmentFlag)                                                  \
    DATA(int *, Py_NoSiteFlag, Py_NoSiteFlag)                                                                        \
    DATA(int *, Py_NoUserSiteDirectory, Py_NoUserSiteDirectory)                                                      \
    DATA(int *, Py_DontWriteBytecodeFlag, Py_DontWriteBytecodeFlag)                                                  \
    DATA(PyObject **, PyExc_KeyboardInterrupt, PyExc_KeyboardInterrupt)                                              \
    FUNCTION(void, PyErr_SetInterrupt, (void))

#define PY_FUNCTION(type, name, parameters) type(*name) parameters;
#define PY_DATA(type, name, symbol) type name;
typedef struct { PY_API(PY_FUNCTION, PY_DATA) } PyApi;

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

/* Take the GIL from any thread, known to Python or not. A thread Python does not know gets a thread
   state that it keeps until it ends; then the state is deleted. */
PyGILState_STATE pyhost_enter(void);
void pyhost_leave(PyGILState_STATE state);

#endif
