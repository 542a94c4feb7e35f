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

typedef struct {
    int (*Py_IsInitialized)(void);
    void (*_PyConfig_InitCompatConfig)(void *config);
    PyStatus (*Py_InitializeFromConfig)(const void *config);
    void (*PyConfig_Clear)(void *config);
    void (*Py_SetPythonHome)(const wchar_t *);
    wchar_t *(*Py_DecodeLocale)(const char *, size_t *);
    const char *(*Py_GetVersion)(void);
    PyThreadState *(*PyEval_SaveThread)(void);
    void (*PyEval_RestoreThread)(PyThreadState *);
    PyGILState_STATE (*PyGILState_Ensure)(void);
    void (*PyGILState_Release)(PyGILState_STATE);
    PyThreadState *(*PyGILState_GetThisThreadState)(void);
    PyInterpreterState *(*PyInterpreterState_Main)(void);
    PyThreadState *(*PyThreadState_New)(PyInterpreterState *);
    void (*PyThreadState_Clear)(PyThreadState *);
    void (*PyThreadState_Delete)(PyThreadState *);
    void (*PyThreadState_DeleteCurrent)(void);
    PyObject *(*PyImport_ImportModule)(const char *);
    PyObject *(*PyObject_GetAttrString)(PyObject *, const char *);
    PyObject *(*PyObject_CallObject)(PyObject *, PyObject *);
    PyObject *(*PyObject_Str)(PyObject *);
    int (*PyObject_IsTrue)(PyObject *);
    const char *(*PyUnicode_AsUTF8)(PyObject *);
    PyObject *(*PyUnicode_FromString)(const char *);
    PyObject *(*PyLong_FromLong)(long);
    long (*PyLong_AsLong)(PyObject *);
    PyObject *(*PyFloat_FromDouble)(double);
    double (*PyFloat_AsDouble)(PyObject *);
    PyObject *(*PyBool_FromLong)(long);
    PyObject *(*PyTuple_New)(Py_ssize_t);
    int (*PyTuple_SetItem)(PyObject *, Py_ssize_t, PyObject *);
    PyObject *(*PyList_New)(Py_ssize_t);
    int (*PyList_SetItem)(PyObject *, Py_ssize_t, PyObject *);
    Py_ssize_t (*PyList_Size)(PyObject *);
    PyObject *(*PyDict_GetItemString)(PyObject *, const char *);
    int (*PyDict_SetItemString)(PyObject *, const char *, PyObject *);
    int (*PyDict_DelItemString)(PyObject *, const char *);
    PyObject *(*PyBytes_FromStringAndSize)(const char *, Py_ssize_t);
    int (*PyBytes_AsStringAndSize)(PyObject *, char **, Py_ssize_t *);
    PyObject *(*PyErr_Occurred)(void);
    void (*PyErr_Fetch)(PyObject **, PyObject **, PyObject **);
    void (*PyErr_Restore)(PyObject *, PyObject *, PyObject *);
    void (*PyErr_Clear)(void);
    void (*Py_DecRef)(PyObject *);
    void (*Py_IncRef)(PyObject *);
    Py_ssize_t (*PySequence_Size)(PyObject *);
    PyObject *(*PySequence_GetItem)(PyObject *, Py_ssize_t);
    PyObject *(*PySys_GetObject)(const char *);
    PyObject *None;
    PyObject **PyExc_KeyboardInterrupt;
    void (*PyErr_SetInterrupt)(void);
    int *Py_IgnoreEnvironmentFlag;
    int *Py_NoSiteFlag;
    int *Py_NoUserSiteDirectory;
    int *Py_DontWriteBytecodeFlag;
} PyApi;

/* The resolved API; valid once pyhost_start returned 0. */
extern PyApi py;

/* Find, load and start Python once per process (thread-safe). Returns 0, or -1 with a message
   naming every place it looked, and why each failed, in `error` (the same message on every later
   call). A Python that fails to start is such a failure, never an exit of the process. */
int pyhost_start(char *error, size_t size);

/* Take the GIL from any thread, known to Python or not. A thread Python does not know gets a thread
   state that it keeps until it ends; then the state is deleted. */
PyGILState_STATE pyhost_enter(void);
void pyhost_leave(PyGILState_STATE state);

#endif
