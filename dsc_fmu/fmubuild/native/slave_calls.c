/* Calls into Python for the slave (slave_calls.h): every function that touches Python takes the GIL
   itself, queues what the slave logged, turns a Python exception into a queued message and hands the
   queue to the logger once the GIL is released: nothing here raises, aborts, frees what the slave still
   uses or calls back into the importer with the GIL held. */

#include "slave_calls.h"

#include <stdio.h>

void leave(Slave *s, PyGILState_STATE gil) {
    pyhost_leave(gil);
    slave_deliver(s);
    if (s->interrupted) { /* last: Python run before (a logger on ctypes) would swallow it */
        s->interrupted = 0;
        py.PyErr_SetInterrupt();
    }
}

void clear(PyObject **object) {
    if (*object) py.Py_DecRef(*object);
    *object = NULL;
}

/* The pending exception as "Type: message" in `text`; clears it. 1 if it was a KeyboardInterrupt. */
static int exception_text(char *text, size_t size) {
    PyObject *error = pyhost_take_error();
    int interrupt = error && py.PyErr_GivenExceptionMatches(error, *py.PyExc_KeyboardInterrupt);
    PyObject *type = error ? py.PyObject_Type(error) : NULL;
    PyObject *type_name = type ? py.PyObject_GetAttrString(type, "__name__") : NULL;
    const char *name = type_name ? py.PyUnicode_AsUTF8(type_name) : NULL;
    PyObject *str = error ? py.PyObject_Str(error) : NULL;
    const char *detail = str ? py.PyUnicode_AsUTF8(str) : NULL;
    if (error) snprintf(text, size, "%s: %s", name ? name : "exception", detail ? detail : "(no message)");
    else snprintf(text, size, "no Python exception was raised");
    py.PyErr_Clear();
    clear(&str);
    clear(&type_name);
    clear(&type);
    clear(&error);
    return interrupt;
}

/* Log the pending exception as the failure of `doing` and clear it. A KeyboardInterrupt (the host's
   Ctrl-C arriving while the model code ran) is not the model's failure: the call still fails, and
   the interrupt is raised again in the host's Python once the call has returned (``leave``). */
void log_exception(Slave *s, int status, const char *doing) {
    char text[1536];
    if (exception_text(text, sizeof text)) {
        say(s, status, "%s interrupted: the KeyboardInterrupt goes on to the host", doing);
        s->interrupted = 1;
    } else {
        say(s, status, "%s failed: %s", doing, text);
    }
}

PyObject *pack(int n, PyObject **items) {
    int complete = 1;
    for (int i = 0; i < n; i++) complete = complete && items[i];
    PyObject *tuple = complete ? py.PyTuple_New(n) : NULL;
    for (int i = 0; i < n; i++) {
        if (tuple) py.PyTuple_SetItem(tuple, i, items[i]);
        else if (items[i]) py.Py_DecRef(items[i]);
    }
    return tuple;
}

PyObject *borrowed(PyObject *object) {
    py.Py_IncRef(object);
    return object;
}

PyObject *call(PyObject *function, PyObject *args) {
    PyObject *result = function && (args || !py.PyErr_Occurred()) ? py.PyObject_CallObject(function, args) : NULL;
    if (function) py.Py_DecRef(function);
    if (args) py.Py_DecRef(args);
    return result;
}

PyObject *bridge_call(Slave *s, const char *name, PyObject *args) {
    return call(py.PyObject_GetAttrString(s->bridge, name), args);
}

/* Hand the time and states set since the slave's last call to its set_point (the GIL held). */
static void apply_pending(Slave *s) {
    PyObject *states = s->pending & PENDING_STATES ? py.PyList_New((Py_ssize_t)s->nx) : borrowed(py.None);
    for (size_t i = 0; states && s->pending & PENDING_STATES && i < s->nx; i++) {
        py.PyList_SetItem(states, (Py_ssize_t)i, py.PyFloat_FromDouble(s->x[i]));
    }
    PyObject *items[] = {s->pending & PENDING_TIME ? py.PyFloat_FromDouble(s->time) : borrowed(py.None), states};
    PyObject *result = call(borrowed(s->bound[BOUND_SET_POINT]), pack(2, items));
    if (!result) log_exception(s, STATUS_ERROR, "set_point");
    clear(&result);
    s->pending = 0;
}

PyGILState_STATE enter(Slave *s) {
    PyGILState_STATE gil = pyhost_enter();
    if (s->pending) apply_pending(s);
    return gil;
}

void drain_log(Slave *s) {
    if (!s->log_queue || py.PyList_Size(s->log_queue) <= 0) {
        py.PyErr_Clear();
        return;
    }
    PyObject *items[] = {borrowed(s->slave)};
    PyObject *messages = bridge_call(s, "drain_log", pack(1, items));
    Py_ssize_t n = messages ? py.PySequence_Size(messages) : 0;
    for (Py_ssize_t i = 0; i < n; i++) {
        PyObject *message = py.PySequence_GetItem(messages, i);
        PyObject *status = message ? py.PySequence_GetItem(message, 0) : NULL;
        PyObject *category = message ? py.PySequence_GetItem(message, 1) : NULL;
        PyObject *text = message ? py.PySequence_GetItem(message, 2) : NULL;
        const char *category_text = category ? py.PyUnicode_AsUTF8(category) : NULL;
        const char *message_text = text ? py.PyUnicode_AsUTF8(text) : NULL;
        if (status && category_text && message_text) {
            queue_message(s, (int)py.PyLong_AsLong(status), category_text, message_text);
        }
        clear(&text);
        clear(&category);
        clear(&status);
        clear(&message);
    }
    clear(&messages);
    py.PyErr_Clear();
}

int finished(Slave *s, PyGILState_STATE gil, PyObject *result, int failure, const char *what) {
    int status = STATUS_OK;
    if (!result) {
        log_exception(s, failure, what);
        status = failure;
    }
    clear(&result);
    drain_log(s);
    leave(s, gil);
    return status;
}

/* A tuple of `n` floats; where `defined` (if not NULL) is 0, None. */
static PyObject *doubles(int n, const double *values, const int *defined) {
    PyObject *items[8] = {NULL};
    for (int i = 0; i < n && i < 8; i++) {
        items[i] = !defined || defined[i] ? py.PyFloat_FromDouble(values[i]) : borrowed(py.None);
    }
    return pack(n < 8 ? n : 8, items);
}

/* Call the method `method` of the slave (`cached`, its bound method, if not NULL) with `n` floats;
   STATUS_OK, or `failure` after logging the exception. `truth` (if not NULL) receives whether the
   result is true. */
static int call_logged(Slave *s, const char *method, PyObject *cached, int n, const double *values,
                       const int *defined, int failure, int *truth) {
    PyGILState_STATE gil = enter(s);
    PyObject *function = cached ? borrowed(cached) : py.PyObject_GetAttrString(s->slave, method);
    PyObject *args = n ? doubles(n, values, defined) : NULL;
    PyObject *result = call(function, args);
    if (result && truth) *truth = py.PyObject_IsTrue(result) == 1;
    return finished(s, gil, result, failure, method);
}

int slave_call(Slave *s, const char *method, int n, const double *values, const int *defined) {
    return call_logged(s, method, NULL, n, values, defined, STATUS_ERROR, NULL);
}

int slave_step(Slave *s, double time, double step, int *accepted) {
    double values[] = {time, step};
    return call_logged(s, "do_step", s->bound[BOUND_DO_STEP], 2, values, NULL, STATUS_DISCARD, accepted);
}
