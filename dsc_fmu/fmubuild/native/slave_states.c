/* The slave's FMU states (slave.h): opaque Python objects, and their bytes (native_bridge.state_to_bytes,
   state_from_bytes). */

#include "slave_calls.h"

#include <stdlib.h>
#include <string.h>

/* `finished` releases a reference of its own: the caller keeps the state (also in slave_deserialize). */
int slave_get_state(Slave *s, PyObject **state) {
    PyGILState_STATE gil;
    if (enter(s, &gil) != STATUS_OK) return done(s, gil, STATUS_ERROR);
    *state = call(py.PyObject_GetAttrString(s->slave, "_get_fmu_state"), NULL);
    return finished(s, gil, *state ? borrowed(*state) : NULL, STATUS_ERROR, "getting the FMU state");
}

int slave_set_state(Slave *s, PyObject *state) {
    PyGILState_STATE gil;
    if (enter(s, &gil) != STATUS_OK) return done(s, gil, STATUS_ERROR);
    PyObject *items[] = {borrowed(state)};
    PyObject *result = call(py.PyObject_GetAttrString(s->slave, "_set_fmu_state"), pack(1, items));
    return finished(s, gil, result, STATUS_ERROR, "setting the FMU state");
}

void slave_release(PyObject *object) {
    if (!object || !pyhost_alive()) return;
    PyGILState_STATE gil = pyhost_enter();
    py.Py_DecRef(object);
    pyhost_leave(gil);
}

int slave_serialize(Slave *s, PyObject *state, char **bytes, size_t *size) {
    PyGILState_STATE gil;
    if (enter(s, &gil) != STATUS_OK) return done(s, gil, STATUS_ERROR);
    PyObject *items[] = {borrowed(s->slave), borrowed(state)};
    PyObject *data = bridge_call(s, "state_to_bytes", pack(2, items));
    char *buffer = NULL;
    Py_ssize_t length = 0;
    int status = STATUS_ERROR;
    if (!data || py.PyBytes_AsStringAndSize(data, &buffer, &length) != 0) {
        log_exception(s, STATUS_ERROR, "serializing the FMU state");
    } else if ((*bytes = malloc((size_t)length)) != NULL) {
        memcpy(*bytes, buffer, (size_t)length);
        *size = (size_t)length;
        status = STATUS_OK;
    } else {
        say(s, STATUS_ERROR, "out of memory for the serialized FMU state");
    }
    clear(&data);
    return done(s, gil, status);
}

int slave_deserialize(Slave *s, const char *bytes, size_t size, PyObject **state) {
    PyGILState_STATE gil;
    if (enter(s, &gil) != STATUS_OK) return done(s, gil, STATUS_ERROR);
    PyObject *items[] = {borrowed(s->slave), py.PyBytes_FromStringAndSize(bytes, (Py_ssize_t)size)};
    *state = bridge_call(s, "state_from_bytes", pack(2, items));
    return finished(s, gil, *state ? borrowed(*state) : NULL, STATUS_ERROR, "deserializing the FMU state");
}
