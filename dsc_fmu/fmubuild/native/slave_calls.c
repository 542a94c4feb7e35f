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

/* Log the pending exception as the failure of `doing` ("<doing> failed: Type: message", whole) and clear it.
   A KeyboardInterrupt (the host's Ctrl-C arriving while the model code ran) is not the model's failure: the
   call still fails, and the interrupt is raised again in the host's Python once the call has returned
   (``leave``). */
void log_exception(Slave *s, int status, const char *doing) {
    PyObject *error = pyhost_take_error();
    PyObject *type = error ? py.PyObject_Type(error) : NULL;
    PyObject *type_name = type ? py.PyObject_GetAttrString(type, "__name__") : NULL;
    const char *name = type_name ? py.PyUnicode_AsUTF8(type_name) : NULL;
    if (!name) py.PyErr_Clear(); /* no Python call with an exception pending */
    PyObject *str = error ? py.PyObject_Str(error) : NULL;
    const char *detail = str ? py.PyUnicode_AsUTF8(str) : NULL;
    if (error && py.PyErr_GivenExceptionMatches(error, *py.PyExc_KeyboardInterrupt)) {
        say(s, status, "%s interrupted: the KeyboardInterrupt goes on to the host", doing);
        s->interrupted = 1;
    } else if (error) {
        say(s, status, "%s failed: %s: %s", doing, name ? name : "exception", detail ? detail : "(no message)");
    } else {
        say(s, status, "%s failed: no Python exception was raised", doing);
    }
    py.PyErr_Clear();
    clear(&str);
    clear(&type_name);
    clear(&type);
    clear(&error);
}

PyObject *pack(int n, PyObject **items) {
    int complete = 1;
    for (int i = 0; i < n; i++) complete = complete && items[i];
    PyObject *tuple = complete ? py.PyTuple_New(n) : NULL;
    for (int i = 0; i < n; i++) {
        if (!tuple) clear(&items[i]);
        else if (py.PyTuple_SetItem(tuple, i, items[i]) != 0) clear(&tuple); /* it released the item */
    }
    return tuple;
}

void put(PyObject **list, size_t i, PyObject *item) {
    if (!item || py.PyList_SetItem(*list, (Py_ssize_t)i, item) != 0) clear(list); /* it released the item */
}

PyObject *float_list(const double *values, size_t n) {
    PyObject *list = py.PyList_New((Py_ssize_t)n);
    for (size_t i = 0; list && i < n; i++) put(&list, i, py.PyFloat_FromDouble(values[i]));
    return list;
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

/* Hand the time and states set since the slave's last call to its set_point (the GIL held): 0, or -1 after
   logging why (they stay pending). */
static int apply_pending(Slave *s) {
    PyObject *items[] = {s->pending & PENDING_TIME ? py.PyFloat_FromDouble(s->time) : borrowed(py.None),
                         s->pending & PENDING_STATES ? float_list(s->x, s->nx) : borrowed(py.None)};
    PyObject *result = call(borrowed(s->bound[BOUND_SET_POINT]), pack(2, items));
    if (!result) {
        log_exception(s, STATUS_ERROR, "set_point");
        return -1;
    }
    clear(&result);
    s->pending = 0;
    return 0;
}

int enter(Slave *s, PyGILState_STATE *gil) {
    *gil = pyhost_enter();
    if (s->pending && apply_pending(s) != 0) return STATUS_ERROR;
    return traced_sync(s) == 0 ? STATUS_OK : STATUS_ERROR;
}

/* Queue message `i` of `messages`, what the slave logged: (status, category, text); a status that is not
   one of FMI's is an error's. 0, or -1 with the exception set. */
static int queue_logged(Slave *s, PyObject *messages, Py_ssize_t i) {
    PyObject *message = py.PySequence_GetItem(messages, i);
    PyObject *status = message ? py.PySequence_GetItem(message, 0) : NULL;
    PyObject *category = status ? py.PySequence_GetItem(message, 1) : NULL;
    PyObject *text = category ? py.PySequence_GetItem(message, 2) : NULL;
    long code = text ? py.PyLong_AsLong(status) : -1;
    const char *category_text = text && !py.PyErr_Occurred() ? py.PyUnicode_AsUTF8(category) : NULL;
    const char *message_text = category_text ? py.PyUnicode_AsUTF8(text) : NULL;
    if (message_text) {
        queue_message(s, code >= STATUS_OK && code <= STATUS_FATAL ? (int)code : STATUS_ERROR, category_text,
                      message_text);
    }
    clear(&text);
    clear(&category);
    clear(&status);
    clear(&message);
    return message_text ? 0 : -1;
}

void drain_log(Slave *s) {
    if (!s->bridge || !s->log_queue || py.PyList_Size(s->log_queue) <= 0) {
        py.PyErr_Clear();
        return;
    }
    PyObject *items[] = {borrowed(s->slave)};
    PyObject *messages = bridge_call(s, "drain_log", pack(1, items));
    Py_ssize_t n = messages ? py.PySequence_Size(messages) : -1;
    int read = n >= 0;
    for (Py_ssize_t i = 0; read && i < n; i++) read = queue_logged(s, messages, i) == 0;
    clear(&messages);
    if (!read) log_exception(s, STATUS_WARNING, "reading the messages the slave logged");
}

int done(Slave *s, PyGILState_STATE gil, int status) {
    traced_snapshot(s);
    drain_log(s);
    leave(s, gil);
    return status;
}

int finished(Slave *s, PyGILState_STATE gil, PyObject *result, int failure, const char *what) {
    int status = STATUS_OK;
    if (!result) {
        log_exception(s, failure, what);
        status = failure;
    }
    clear(&result);
    return done(s, gil, status);
}

/* A tuple of the `n` floats of `values`, None where `defined` (if not NULL) is 0; NULL with the exception set. */
static PyObject *doubles(int n, const double *values, const int *defined) {
    PyObject *tuple = py.PyTuple_New(n);
    for (int i = 0; tuple && i < n; i++) {
        PyObject *item = !defined || defined[i] ? py.PyFloat_FromDouble(values[i]) : borrowed(py.None);
        if (!item || py.PyTuple_SetItem(tuple, i, item) != 0) clear(&tuple); /* it released the item */
    }
    return tuple;
}

/* Call the method `method` of the slave (`cached`, its bound method, if not NULL) with `n` floats;
   STATUS_OK, or `failure` after logging the exception (STATUS_ERROR if what model exchange set could not be
   handed over first). `truth` (if not NULL) receives whether the result is true. */
static int call_logged(Slave *s, const char *method, PyObject *cached, int n, const double *values,
                       const int *defined, int failure, int *truth) {
    PyGILState_STATE gil;
    if (enter(s, &gil) != STATUS_OK) return done(s, gil, STATUS_ERROR);
    PyObject *function = cached ? borrowed(cached) : py.PyObject_GetAttrString(s->slave, method);
    PyObject *args = n ? doubles(n, values, defined) : NULL;
    PyObject *result = call(function, args);
    int answer = result && truth ? py.PyObject_IsTrue(result) : 0;
    if (answer < 0) clear(&result); /* its truth raised: the call's failure */
    if (truth) *truth = answer == 1;
    return finished(s, gil, result, failure, method);
}

int slave_call(Slave *s, const char *method, int n, const double *values, const int *defined) {
    return call_logged(s, method, NULL, n, values, defined, STATUS_ERROR, NULL);
}

int slave_update_discrete_states(Slave *s, int *changed) {
    return call_logged(s, "update_discrete_states", NULL, 0, NULL, NULL, STATUS_ERROR, changed);
}

int slave_step(Slave *s, double time, double step, int *accepted) {
    if (traced_step(s, time, step, accepted)) return STATUS_OK;
    double values[] = {time, step};
    return call_logged(s, "do_step", s->bound[BOUND_DO_STEP], 2, values, NULL, STATUS_DISCARD, accepted);
}
