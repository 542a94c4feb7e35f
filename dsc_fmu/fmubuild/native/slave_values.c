/* The slave's values (slave.h): typed get and set by value reference, input derivatives, and the
   vectors of model exchange, whose time and states wait here for the slave's next call. */

#include "slave_calls.h"

#include <stdbool.h>
#include <stdint.h>
#include <string.h>

int slave_type_of(const Slave *s, unsigned int vr) {
    return vr < s->size ? s->type[vr] : NO_VARIABLE;
}

_Static_assert(sizeof(int) == sizeof(int32_t), "FMI's Integer and Int32 are the C int of every platform built for");

/* A list of the `n` value references of `vr`; NULL with the exception set. */
static PyObject *references(const unsigned int *vr, size_t n) {
    PyObject *list = py.PyList_New((Py_ssize_t)n);
    for (size_t i = 0; list && i < n; i++) put(&list, i, py.PyLong_FromLong((long)vr[i]));
    return list;
}

static PyObject *to_python(const void *values, size_t i, CType ctype) {
    switch (ctype) {
    case C_DOUBLE: return py.PyFloat_FromDouble(((const double *)values)[i]);
    case C_INT: return py.PyLong_FromLong(((const int *)values)[i]);
    case C_INT32: return py.PyLong_FromLong(((const int32_t *)values)[i]);
    case C_BOOL_INT: return py.PyBool_FromLong(((const int *)values)[i] != 0);
    case C_BOOL_BYTE: return py.PyBool_FromLong(((const bool *)values)[i]);
    }
    return NULL;
}

/* Entry `i` of `values`, of `ctype`, from `item`: 0 (a Python error is left set), or 1 if `item` is an integer
   outside the 32 bits of an FMI Integer (Int32), in `*wide`. */
static int from_python(PyObject *item, void *values, size_t i, CType ctype, long *wide) {
    long integer = 0;
    switch (ctype) {
    case C_DOUBLE: ((double *)values)[i] = py.PyFloat_AsDouble(item); break;
    case C_INT:
    case C_INT32:
        integer = py.PyLong_AsLong(item); /* -1 where it raised: in range, and the error is seen */
        if (integer < INT32_MIN || integer > INT32_MAX) {
            *wide = integer;
            return 1;
        }
        if (ctype == C_INT) ((int *)values)[i] = (int)integer;
        else ((int32_t *)values)[i] = (int32_t)integer;
        break;
    case C_BOOL_INT: ((int *)values)[i] = py.PyObject_IsTrue(item) == 1; break;
    case C_BOOL_BYTE: ((bool *)values)[i] = py.PyObject_IsTrue(item) == 1; break;
    }
    return 0;
}

/* The `n` values of `result`, the return of the getter of `type`, into `values`: STATUS_OK, or STATUS_ERROR
   with the exception set or a result of another length or an integer out of range logged. */
static int copy_values(Slave *s, int type, const unsigned int *vr, size_t n, PyObject *result, void *values,
                       CType ctype) {
    Py_ssize_t size = py.PySequence_Size(result);
    if (size >= 0 && size != (Py_ssize_t)n) {
        say(s, STATUS_ERROR, "%s returned %zd values for %zu value references", GET_METHODS[type], size, n);
        return STATUS_ERROR;
    }
    int wide = 0;
    long value = 0;
    size_t i = 0;
    for (; size >= 0 && i < n && !wide && !py.PyErr_Occurred(); i++) {
        PyObject *item = py.PySequence_GetItem(result, (Py_ssize_t)i);
        if (item) wide = from_python(item, values, i, ctype, &value);
        clear(&item);
    }
    if (wide) {
        say(s, STATUS_ERROR, "%s returned %ld for value reference %u; allowed: %ld to %ld (an Integer has 32 bits)",
            GET_METHODS[type], value, vr[i - 1], (long)INT32_MIN, (long)INT32_MAX);
    }
    return wide || py.PyErr_Occurred() ? STATUS_ERROR : STATUS_OK;
}

int slave_get(Slave *s, int type, const unsigned int *vr, size_t n, void *values, CType ctype) {
    if (traced_get(s, type, vr, n, values, ctype)) return STATUS_OK;
    PyGILState_STATE gil;
    if (enter(s, &gil) != STATUS_OK) return done(s, gil, STATUS_ERROR);
    PyObject *items[] = {references(vr, n)};
    PyObject *result = call(borrowed(s->bound[type]), pack(1, items));
    int status = result ? copy_values(s, type, vr, n, result, values, ctype) : STATUS_ERROR;
    if (py.PyErr_Occurred() || !result) log_exception(s, STATUS_ERROR, GET_METHODS[type]);
    clear(&result);
    return done(s, gil, status);
}

int slave_set(Slave *s, int type, const unsigned int *vr, size_t n, const void *values, CType ctype) {
    if (traced_set(s, type, vr, n, values, ctype)) return STATUS_OK;
    PyGILState_STATE gil;
    if (enter(s, &gil) != STATUS_OK) return done(s, gil, STATUS_ERROR);
    PyObject *list = py.PyList_New((Py_ssize_t)n);
    for (size_t i = 0; list && i < n; i++) put(&list, i, to_python(values, i, ctype));
    PyObject *items[] = {references(vr, n), list};
    PyObject *result = call(borrowed(s->bound[TYPES + type]), pack(2, items));
    return finished(s, gil, result, STATUS_ERROR, SET_METHODS[type]);
}

int slave_set_input_derivatives(Slave *s, const unsigned int *vr, size_t n, const int *order, const double *values) {
    PyGILState_STATE gil;
    if (enter(s, &gil) != STATUS_OK) return done(s, gil, STATUS_ERROR);
    PyObject *orders = py.PyList_New((Py_ssize_t)n);
    for (size_t i = 0; orders && i < n; i++) put(&orders, i, py.PyLong_FromLong(order[i]));
    PyObject *items[] = {references(vr, n), orders, float_list(values, n)};
    PyObject *result = call(py.PyObject_GetAttrString(s->slave, "set_input_derivatives"), pack(3, items));
    return finished(s, gil, result, STATUS_ERROR, "set_input_derivatives");
}

/* The `n` floats of `result`, the return of `method`, into `values`: STATUS_OK, or STATUS_ERROR with the
   exception set or a result of another length logged. */
static int copy_floats(Slave *s, const char *method, PyObject *result, double *values, size_t n) {
    Py_ssize_t size = py.PySequence_Size(result);
    if (size >= 0 && size != (Py_ssize_t)n) {
        say(s, STATUS_ERROR, "%s returned %zd values; expected %zu", method, size, n);
        return STATUS_ERROR;
    }
    for (Py_ssize_t i = 0; size >= 0 && i < size && !py.PyErr_Occurred(); i++) {
        PyObject *item = py.PySequence_GetItem(result, i);
        if (item) values[i] = py.PyFloat_AsDouble(item);
        clear(&item);
    }
    return py.PyErr_Occurred() ? STATUS_ERROR : STATUS_OK;
}

int slave_partials(Slave *s, const Partials *p, int adjoint, int model_exchange) {
    if (traced_partials(s, p, adjoint, model_exchange)) return STATUS_OK;
    const char *method = adjoint ? "adjoint_derivative" : "directional_derivative";
    PyGILState_STATE gil;
    if (enter(s, &gil) != STATUS_OK) return done(s, gil, STATUS_ERROR);
    PyObject *items[] = {references(p->unknowns, p->n_unknowns), references(p->knowns, p->n_knowns),
                         float_list(p->seed, p->n_seed), py.PyBool_FromLong(model_exchange)};
    PyObject *result = call(py.PyObject_GetAttrString(s->slave, method), pack(4, items));
    int status = result ? copy_floats(s, method, result, p->sensitivity, p->n_sensitivity) : STATUS_ERROR;
    if (py.PyErr_Occurred() || !result) log_exception(s, STATUS_ERROR, method);
    clear(&result);
    return done(s, gil, status);
}

int slave_set_time(Slave *s, double time) {
    traced_touched(s);
    s->time = time;
    s->pending |= PENDING_TIME;
    return STATUS_OK;
}

int slave_get_vector(Slave *s, Vector which, double *values, size_t n, int failure) {
    if (traced_vector(s, which, values, n)) return STATUS_OK;
    PyGILState_STATE gil;
    if (enter(s, &gil) != STATUS_OK) return done(s, gil, STATUS_ERROR);
    const char *method = VECTOR_METHODS[which];
    PyObject *result = call(borrowed(s->bound[BOUND_VECTORS + which]), NULL);
    Py_ssize_t size = result ? py.PySequence_Size(result) : -1;
    if (size >= 0 && size != (Py_ssize_t)n) {
        say(s, STATUS_ERROR, "%s returned %zd values; expected %zu", method, size, n);
        failure = STATUS_ERROR;
    }
    for (Py_ssize_t i = 0; size == (Py_ssize_t)n && i < size && !py.PyErr_Occurred(); i++) {
        PyObject *item = py.PySequence_GetItem(result, i);
        if (item) values[i] = py.PyFloat_AsDouble(item);
        clear(&item);
    }
    int status = result && size == (Py_ssize_t)n && !py.PyErr_Occurred() ? STATUS_OK : failure;
    if (status != STATUS_OK && py.PyErr_Occurred()) log_exception(s, failure, method);
    py.PyErr_Clear();
    clear(&result);
    return done(s, gil, status);
}

int slave_set_states(Slave *s, const double *values, size_t n) {
    traced_touched(s);
    memcpy(s->x, values, n * sizeof *values);
    s->pending |= PENDING_STATES;
    return STATUS_OK;
}

int slave_get_double(Slave *s, const char *attribute, double *value) {
    PyGILState_STATE gil;
    if (enter(s, &gil) != STATUS_OK) return done(s, gil, STATUS_ERROR);
    PyObject *object = py.PyObject_GetAttrString(s->slave, attribute);
    int status = STATUS_OK;
    if (object) *value = py.PyFloat_AsDouble(object);
    if (!object || py.PyErr_Occurred()) {
        log_exception(s, STATUS_ERROR, attribute);
        status = STATUS_ERROR;
    }
    clear(&object);
    return done(s, gil, status);
}
