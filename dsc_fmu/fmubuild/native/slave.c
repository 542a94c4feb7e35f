/* One Python slave behind an FMU instance, for both FMI versions (see slave.h).

   Every function that touches Python takes the GIL itself, queues what the slave logged and turns
   a Python exception into a queued message, and hands the queue to the logger once the GIL is
   released: nothing here raises, aborts, frees what the slave still uses or calls back into the
   importer with the GIL held. */

#include "slave.h"

#include "platform.h"

#include <stdarg.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#ifndef DSC_ENTRY_FILE
#error DSC_ENTRY_FILE (the resources file that names the bridge, slave and token) must be defined
#endif
#define MAX_VALUE_REFERENCE 100000
#define MAX_VARIABLES 1024

const char *const TYPE_NAMES[TYPES + 1] = {DSC_TYPE_NAMES};
static const char *const GET_METHODS[TYPES] = {DSC_GET_METHODS};
static const char *const SET_METHODS[TYPES] = {DSC_SET_METHODS};
static const char *const STATUS_CATEGORIES[] = {DSC_STATUS_CATEGORIES};
_Static_assert(sizeof STATUS_CATEGORIES / sizeof STATUS_CATEGORIES[0] == STATUS_FATAL + 1,
               "DSC_STATUS_CATEGORIES names the category of every status, OK to fatal");

const char *slave_category(int status) {
    return STATUS_CATEGORIES[status >= STATUS_OK && status <= STATUS_FATAL ? status : STATUS_FATAL];
}

static void queue(Slave *s, int status, const char *category, const char *text) {
    size_t length = strlen(text);
    Message *message = malloc(sizeof *message + length + 1);
    if (!message) return;
    message->next = NULL;
    message->status = status;
    snprintf(message->category, sizeof message->category, "%s", category);
    memcpy(message->text, text, length + 1);
    *s->last = message;
    s->last = &message->next;
}

void slave_deliver(Slave *s) {
    Message *message = s->messages;
    s->messages = NULL;
    s->last = &s->messages;
    while (message) {
        Message *next = message->next;
        s->log(s->context, message->status, message->category, message->text);
        free(message);
        message = next;
    }
}

/* Release the GIL, then deliver what was queued under it. */
static void leave(Slave *s, PyGILState_STATE gil) {
    pyhost_leave(gil);
    slave_deliver(s);
    if (s->interrupted) { /* last: Python run before (a logger on ctypes) would swallow it */
        s->interrupted = 0;
        py.PyErr_SetInterrupt();
    }
}

void slave_vlog(Slave *s, int status, const char *call, const char *format, va_list args) {
    char message[2048];
    int k = call ? snprintf(message, sizeof message, "%s: %s: ", s->instance_name, call)
                 : snprintf(message, sizeof message, "%s: ", s->instance_name);
    vsnprintf(message + k, sizeof message - k, format, args);
    queue(s, status, slave_category(status), message);
}

static void say(Slave *s, int status, const char *format, ...) {
    va_list args;
    va_start(args, format);
    slave_vlog(s, status, NULL, format, args);
    va_end(args);
}

static void clear(PyObject **object) {
    if (*object) py.Py_DecRef(*object);
    *object = NULL;
}

/* The pending exception as "Type: message" in `text`; clears it. 1 if it was a KeyboardInterrupt. */
static int exception_text(char *text, size_t size) {
    PyObject *type = NULL, *value = NULL, *traceback = NULL;
    py.PyErr_Fetch(&type, &value, &traceback);
    int interrupt = type && type == *py.PyExc_KeyboardInterrupt;
    PyObject *type_name = type ? py.PyObject_GetAttrString(type, "__name__") : NULL;
    const char *name = type_name ? py.PyUnicode_AsUTF8(type_name) : NULL;
    PyObject *str = value ? py.PyObject_Str(value) : NULL;
    const char *detail = str ? py.PyUnicode_AsUTF8(str) : NULL;
    if (type) snprintf(text, size, "%s: %s", name ? name : "exception", detail ? detail : "(no message)");
    else snprintf(text, size, "no Python exception was raised");
    py.PyErr_Clear();
    clear(&str);
    clear(&type_name);
    clear(&type);
    clear(&value);
    clear(&traceback);
    return interrupt;
}

/* Log the pending exception as the failure of `doing` and clear it. A KeyboardInterrupt (the host's
   Ctrl-C arriving while the model code ran) is not the model's failure: the call still fails, and
   the interrupt is raised again in the host's Python once the call has returned (``leave``). */
static void log_exception(Slave *s, int status, const char *doing) {
    char text[1536];
    if (exception_text(text, sizeof text)) {
        say(s, status, "%s interrupted: the KeyboardInterrupt goes on to the host", doing);
        s->interrupted = 1;
    } else {
        say(s, status, "%s failed: %s", doing, text);
    }
}

/* A tuple of `n` new references, which it steals; NULL (the exception set) if any is NULL. */
static PyObject *pack(int n, PyObject **items) {
    int complete = 1;
    for (int i = 0; i < n; i++) complete = complete && items[i];
    PyObject *tuple = complete ? py.PyTuple_New(n) : NULL;
    for (int i = 0; i < n; i++) {
        if (tuple) py.PyTuple_SetItem(tuple, i, items[i]);
        else if (items[i]) py.Py_DecRef(items[i]);
    }
    return tuple;
}

static PyObject *borrowed(PyObject *object) {
    py.Py_IncRef(object);
    return object;
}

/* Call `function` (a new reference, which it steals) with `args` (stolen; NULL for none, unless an
   exception is set: then the arguments failed and nothing is called). */
static PyObject *call(PyObject *function, PyObject *args) {
    PyObject *result = function && (args || !py.PyErr_Occurred()) ? py.PyObject_CallObject(function, args) : NULL;
    if (function) py.Py_DecRef(function);
    if (args) py.Py_DecRef(args);
    return result;
}

static PyObject *bridge_call(Slave *s, const char *name, PyObject *args) {
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

/* Take the GIL for a call of the slave, which first sees what model exchange set since its last call. */
static PyGILState_STATE enter(Slave *s) {
    PyGILState_STATE gil = pyhost_enter();
    if (s->pending) apply_pending(s);
    return gil;
}

/* Queue the messages the slave logged (cheap when there are none). */
static void drain_log(Slave *s) {
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
            queue(s, (int)py.PyLong_AsLong(status), category_text, message_text);
        }
        clear(&text);
        clear(&category);
        clear(&status);
        clear(&message);
    }
    clear(&messages);
    py.PyErr_Clear();
}

/* The entry file: the bridge module (its top level the build's private package), the slave's
   module and class, and the token; read before Python is started. */
static int read_entry(Slave *s, char bridge[256]) {
    char path[sizeof s->resources + 32];
    snprintf(path, sizeof path, "%s/%s", s->resources, DSC_ENTRY_FILE);
    FILE *file = platform_open_file(path, "r");
    if (!file) {
        say(s, STATUS_ERROR, "cannot read %s: the FMU's resources are incomplete", path);
        return -1;
    }
    int found = fscanf(file, "%255s %255s %127s %127s", bridge, s->module, s->class_name, s->token);
    fclose(file);
    if (found != 4 || !strchr(bridge, '.')) {
        say(s, STATUS_ERROR, "%s does not name the bridge, module, class and token", path);
        return -1;
    }
    return 0;
}

/* Hold (`hold` 1) or release (0) the import system's lock, under which the instances of a build are
   created and freed: threads creating and freeing instances of one build at once see its modules
   whole. 0, or -1 with the exception set. */
static int import_lock(int hold) {
    PyObject *imp = py.PyImport_ImportModule("_imp");
    PyObject *done = imp ? call(py.PyObject_GetAttrString(imp, hold ? "acquire_lock" : "release_lock"), NULL) : NULL;
    int result = done ? 0 : -1;
    clear(&done);
    clear(&imp);
    return result;
}

/* The module `name` from the file `path`, registered in sys.modules (and removed if it fails). */
static PyObject *load_file(const char *name, const char *path) {
    PyObject *modules = py.PySys_GetObject("modules");
    PyObject *util = py.PyImport_ImportModule("importlib.util");
    PyObject *items[] = {py.PyUnicode_FromString(name), py.PyUnicode_FromString(path)};
    PyObject *spec = util ? call(py.PyObject_GetAttrString(util, "spec_from_file_location"), pack(2, items)) : NULL;
    PyObject *from_spec[] = {spec ? borrowed(spec) : NULL};
    PyObject *module = spec ? call(py.PyObject_GetAttrString(util, "module_from_spec"), pack(1, from_spec)) : NULL;
    PyObject *loader = module ? py.PyObject_GetAttrString(spec, "loader") : NULL;
    PyObject *done = NULL;
    if (loader && modules && py.PyDict_SetItemString(modules, name, module) == 0) {
        PyObject *run[] = {borrowed(module)};
        done = call(py.PyObject_GetAttrString(loader, "exec_module"), pack(1, run));
        if (!done) {
            PyObject *type, *value, *traceback;
            py.PyErr_Fetch(&type, &value, &traceback);
            py.PyDict_DelItemString(modules, name);
            py.PyErr_Restore(type, value, traceback);
        }
    }
    if (!done) clear(&module);
    clear(&done);
    clear(&loader);
    clear(&spec);
    clear(&util);
    return module;
}

/* The build's bridge module, from sys.modules or from its file in the resources (sys.path is left
   alone), counted as one more user of the build's package (native_bridge.acquire imports it).
   The import lock is held. */
static int import_bridge(Slave *s, const char *bridge) {
    PyObject *modules = py.PySys_GetObject("modules");
    PyObject *known = modules ? py.PyDict_GetItemString(modules, bridge) : NULL;
    char path[sizeof s->resources + 256];
    int written = snprintf(path, sizeof path, "%s/", s->resources);
    for (const char *p = bridge; *p && written + 4 < (int)sizeof path; p++) path[written++] = *p == '.' ? '/' : *p;
    snprintf(path + written, sizeof path - written, ".py");
    s->bridge = known ? borrowed(known) : load_file(bridge, path);
    PyObject *items[] = {py.PyUnicode_FromString(s->resources)};
    PyObject *counted = s->bridge ? bridge_call(s, "acquire", pack(1, items)) : NULL;
    if (!counted) {
        log_exception(s, STATUS_ERROR, "importing the FMU's package");
        if (s->bridge && !known) py.PyDict_DelItemString(modules, bridge);
        py.PyErr_Clear();
        clear(&s->bridge);
        return -1;
    }
    clear(&counted);
    return 0;
}

static PyObject *new_slave(Slave *s) {
    PyObject *items[] = {
        py.PyUnicode_FromString(s->module), py.PyUnicode_FromString(s->class_name),
        py.PyUnicode_FromString(s->instance_name), py.PyUnicode_FromString(s->resources),
        py.PyBool_FromLong(s->visible),
    };
    return bridge_call(s, "instantiate", pack(5, items));
}

static void clear_slave(Slave *s) {
    for (int i = 0; i < BOUND_METHODS; i++) clear(&s->bound[i]);
    clear(&s->log_queue);
    clear(&s->slave);
}

static const char *const VECTOR_METHODS[VECTORS] = {"get_derivatives", "get_event_indicators",
                                                     "get_continuous_states", "get_nominals"};

static const char *bound_name(const Slave *s, int i) {
    if (i < TYPES) return GET_METHODS[i];
    if (i < 2 * TYPES) return SET_METHODS[i - TYPES];
    if (i >= BOUND_VECTORS && i < BOUND_SET_POINT) return VECTOR_METHODS[i - BOUND_VECTORS];
    return i == BOUND_DO_STEP ? "do_step" : "set_point";
}

/* Take `slave` (a new reference) with its log queue and the bound methods of every call. */
static int adopt_slave(Slave *s, PyObject *slave) {
    PyObject *queue = py.PyObject_GetAttrString(slave, "log_queue");
    PyObject *bound[BOUND_METHODS] = {NULL};
    int complete = queue != NULL;
    for (int i = 0; complete && i < BOUND_METHODS; i++) {
        bound[i] = py.PyObject_GetAttrString(slave, bound_name(s, i));
        complete = bound[i] != NULL;
    }
    if (!complete) {
        log_exception(s, STATUS_ERROR, "reading the slave's log queue and methods");
        for (int i = 0; i < BOUND_METHODS; i++) clear(&bound[i]);
        clear(&queue);
        py.Py_DecRef(slave);
        return -1;
    }
    clear_slave(s);
    s->slave = slave;
    s->log_queue = queue;
    memcpy(s->bound, bound, sizeof bound);
    return 0;
}

/* The numbers of continuous states and event indicators (native_bridge.dimensions). */
static int read_dimensions(Slave *s) {
    PyObject *items[] = {borrowed(s->slave)};
    PyObject *sizes = bridge_call(s, "dimensions", pack(1, items));
    PyObject *nx = sizes ? py.PySequence_GetItem(sizes, 0) : NULL;
    PyObject *nz = sizes ? py.PySequence_GetItem(sizes, 1) : NULL;
    long states = nx ? py.PyLong_AsLong(nx) : -1, indicators = nz ? py.PyLong_AsLong(nz) : -1;
    clear(&nz);
    clear(&nx);
    clear(&sizes);
    if (py.PyErr_Occurred() || states < 0 || indicators < 0 || states > MAX_VARIABLES || indicators > MAX_VARIABLES) {
        log_exception(s, STATUS_ERROR, "reading the numbers of states and event indicators");
        return -1;
    }
    s->nx = (size_t)states;
    s->nz = (size_t)indicators;
    s->x = calloc(s->nx ? s->nx : 1, sizeof *s->x);
    if (!s->x) say(s, STATUS_ERROR, "out of memory for the continuous states");
    return s->x ? 0 : -1;
}

static int read_variables(Slave *s) {
    PyObject *items[] = {borrowed(s->slave)};
    PyObject *table = bridge_call(s, "variables", pack(1, items));
    Py_ssize_t n = table ? py.PySequence_Size(table) : -1;
    long rows[4 * MAX_VARIABLES];
    if (n < 0 || n > MAX_VARIABLES) {
        clear(&table);
        if (n < 0) log_exception(s, STATUS_ERROR, "reading the variable table");
        else say(s, STATUS_ERROR, "the slave has %zd variables; allowed: at most %d", n, MAX_VARIABLES);
        return -1;
    }
    long largest = -1;
    for (Py_ssize_t i = 0; i < n && !py.PyErr_Occurred(); i++) {
        PyObject *row = py.PySequence_GetItem(table, i);
        for (int k = 0; k < 4 && row && !py.PyErr_Occurred(); k++) {
            PyObject *cell = py.PySequence_GetItem(row, k);
            rows[4 * i + k] = cell ? py.PyLong_AsLong(cell) : -1;
            clear(&cell);
        }
        clear(&row);
        if (rows[4 * i] > largest) largest = rows[4 * i];
    }
    clear(&table);
    if (py.PyErr_Occurred() || largest >= MAX_VALUE_REFERENCE) {
        py.PyErr_Clear();
        say(s, STATUS_ERROR, "the variable table of the slave is not valid");
        return -1;
    }
    if (read_dimensions(s) != 0) return -1;
    s->size = (unsigned int)(largest + 1);
    s->type = malloc(s->size ? s->size : 1);
    s->causality = malloc(s->size ? s->size : 1);
    s->variability = malloc(s->size ? s->size : 1);
    if (!s->type || !s->causality || !s->variability) {
        say(s, STATUS_ERROR, "out of memory for the variable table");
        return -1;
    }
    memset(s->type, NO_VARIABLE, s->size);
    for (Py_ssize_t i = 0; i < n; i++) {
        if (rows[4 * i] < 0) continue;
        s->type[rows[4 * i]] = (signed char)rows[4 * i + 1];
        s->causality[rows[4 * i]] = (signed char)rows[4 * i + 2];
        s->variability[rows[4 * i]] = (signed char)rows[4 * i + 3];
    }
    return 0;
}

/* Count one user less of the build's package; the last forgets its modules (native_bridge.release).
   The import lock is held. */
static void release_bridge(Slave *s) {
    if (!s->bridge) return;
    PyObject *result = bridge_call(s, "release", NULL);
    if (!result) log_exception(s, STATUS_WARNING, "releasing the FMU's package");
    clear(&result);
    clear(&s->bridge);
}

/* Whether the import lock is now held (if not, logged). */
static int lock_imports(Slave *s) {
    if (import_lock(1) == 0) return 1;
    log_exception(s, STATUS_ERROR, "taking the import lock");
    return 0;
}

static void unlock_imports(Slave *s) {
    if (import_lock(0) != 0) log_exception(s, STATUS_WARNING, "releasing the import lock");
}

void slave_init(Slave *s, const char *instance_name, SlaveLog log, void *context) {
    s->instance_name = instance_name;
    s->log = log;
    s->context = context;
    s->last = &s->messages;
}

int slave_create(Slave *s, const char *resources, const char *token, int visible) {
    s->visible = visible;
    snprintf(s->resources, sizeof s->resources, "%s", resources);
    size_t length = strlen(s->resources);
    while (length > 1 && s->resources[length - 1] == '/') s->resources[--length] = '\0';
    char bridge[256] = "", error[3072];
    int result = read_entry(s, bridge);
    if (result == 0 && (!token || strcmp(token, s->token) != 0)) {
        say(s, STATUS_ERROR, "the token %s does not match this FMU's %s", token ? token : "(null)", s->token);
        result = -1;
    }
    if (result == 0 && pyhost_start(error, sizeof error) != 0) {
        say(s, STATUS_ERROR, "%s", error);
        result = -1;
    }
    if (result == 0) {
        PyGILState_STATE gil = pyhost_enter();
        int locked = lock_imports(s);
        result = locked ? import_bridge(s, bridge) : -1;
        if (result == 0) {
            PyObject *slave = new_slave(s);
            if (!slave) log_exception(s, STATUS_ERROR, "creating the slave");
            result = slave && adopt_slave(s, slave) == 0 ? read_variables(s) : -1;
        }
        if (result != 0) release_bridge(s);
        if (locked) unlock_imports(s);
        drain_log(s);
        pyhost_leave(gil);
    }
    if (result != 0) slave_free(s);
    slave_deliver(s);
    return result;
}

void slave_free(Slave *s) {
    if (s->bridge || s->slave || s->log_queue) {
        PyGILState_STATE gil = pyhost_enter();
        clear_slave(s);
        if (s->bridge) {
            int locked = lock_imports(s);
            release_bridge(s);
            if (locked) unlock_imports(s);
        }
        leave(s, gil);
    }
    free(s->x);
    s->x = NULL;
    free(s->type);
    free(s->causality);
    free(s->variability);
    s->type = NULL;
    s->causality = NULL;
    s->variability = NULL;
}

int slave_reset(Slave *s) {
    s->pending = 0;
    PyGILState_STATE gil = pyhost_enter();
    PyObject *slave = new_slave(s);
    int status = STATUS_OK;
    if (!slave) {
        log_exception(s, STATUS_ERROR, "creating the slave anew");
        status = STATUS_ERROR;
    } else if (adopt_slave(s, slave) != 0) {
        status = STATUS_ERROR;
    }
    drain_log(s);
    leave(s, gil);
    return status;
}

int slave_type_of(const Slave *s, unsigned int vr) {
    return vr < s->size ? s->type[vr] : NO_VARIABLE;
}

static PyObject *references(const unsigned int *vr, size_t n) {
    PyObject *list = py.PyList_New((Py_ssize_t)n);
    for (size_t i = 0; list && i < n; i++) py.PyList_SetItem(list, (Py_ssize_t)i, py.PyLong_FromLong((long)vr[i]));
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

static void from_python(PyObject *item, void *values, size_t i, CType ctype) {
    switch (ctype) {
    case C_DOUBLE: ((double *)values)[i] = py.PyFloat_AsDouble(item); break;
    case C_INT: ((int *)values)[i] = (int)py.PyLong_AsLong(item); break;
    case C_INT32: ((int32_t *)values)[i] = (int32_t)py.PyLong_AsLong(item); break;
    case C_BOOL_INT: ((int *)values)[i] = py.PyObject_IsTrue(item) == 1; break;
    case C_BOOL_BYTE: ((bool *)values)[i] = py.PyObject_IsTrue(item) == 1; break;
    }
}

int slave_get(Slave *s, int type, const unsigned int *vr, size_t n, void *values, CType ctype) {
    PyGILState_STATE gil = enter(s);
    PyObject *items[] = {references(vr, n)};
    PyObject *result = call(borrowed(s->bound[type]), pack(1, items));
    Py_ssize_t size = result ? py.PySequence_Size(result) : -1;
    int status = STATUS_ERROR;
    if (size >= 0 && size != (Py_ssize_t)n) {
        say(s, STATUS_ERROR, "%s returned %zd values for %zu value references", GET_METHODS[type], size, n);
    } else if (size >= 0) {
        for (size_t i = 0; i < n && !py.PyErr_Occurred(); i++) {
            PyObject *item = py.PySequence_GetItem(result, (Py_ssize_t)i);
            if (item) from_python(item, values, i, ctype);
            clear(&item);
        }
        if (!py.PyErr_Occurred()) status = STATUS_OK;
    }
    if (py.PyErr_Occurred() || !result) log_exception(s, STATUS_ERROR, GET_METHODS[type]);
    clear(&result);
    drain_log(s);
    leave(s, gil);
    return status;
}

/* The status of a slave call that returned `result` (NULL: it raised; `failure` after logging the
   exception as `what`); releases `result`, queues the slave's log messages and leaves (`gil`). */
static int finished(Slave *s, PyGILState_STATE gil, PyObject *result, int failure, const char *what) {
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

int slave_set(Slave *s, int type, const unsigned int *vr, size_t n, const void *values, CType ctype) {
    PyGILState_STATE gil = enter(s);
    PyObject *list = py.PyList_New((Py_ssize_t)n);
    for (size_t i = 0; list && i < n; i++) py.PyList_SetItem(list, (Py_ssize_t)i, to_python(values, i, ctype));
    PyObject *items[] = {references(vr, n), list};
    PyObject *result = call(borrowed(s->bound[TYPES + type]), pack(2, items));
    return finished(s, gil, result, STATUS_ERROR, SET_METHODS[type]);
}

int slave_set_input_derivatives(Slave *s, const unsigned int *vr, size_t n, const int *order, const double *values) {
    PyGILState_STATE gil = enter(s);
    PyObject *orders = py.PyList_New((Py_ssize_t)n);
    PyObject *given = py.PyList_New((Py_ssize_t)n);
    for (size_t i = 0; orders && given && i < n; i++) {
        py.PyList_SetItem(orders, (Py_ssize_t)i, py.PyLong_FromLong(order[i]));
        py.PyList_SetItem(given, (Py_ssize_t)i, py.PyFloat_FromDouble(values[i]));
    }
    PyObject *items[] = {references(vr, n), orders, given};
    PyObject *result = call(py.PyObject_GetAttrString(s->slave, "set_input_derivatives"), pack(3, items));
    return finished(s, gil, result, STATUS_ERROR, "set_input_derivatives");
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

int slave_set_time(Slave *s, double time) {
    s->time = time;
    s->pending |= PENDING_TIME;
    return STATUS_OK;
}

int slave_get_vector(Slave *s, Vector which, double *values, size_t n, int failure) {
    PyGILState_STATE gil = enter(s);
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
    drain_log(s);
    leave(s, gil);
    return status;
}

int slave_set_states(Slave *s, const double *values, size_t n) {
    memcpy(s->x, values, n * sizeof *values);
    s->pending |= PENDING_STATES;
    return STATUS_OK;
}

int slave_get_double(Slave *s, const char *attribute, double *value) {
    PyGILState_STATE gil = enter(s);
    PyObject *object = py.PyObject_GetAttrString(s->slave, attribute);
    int status = STATUS_OK;
    if (object) *value = py.PyFloat_AsDouble(object);
    if (!object || py.PyErr_Occurred()) {
        log_exception(s, STATUS_ERROR, attribute);
        status = STATUS_ERROR;
    }
    clear(&object);
    leave(s, gil);
    return status;
}

/* `finished` releases a reference of its own: the caller keeps the state (also in slave_deserialize). */
int slave_get_state(Slave *s, PyObject **state) {
    PyGILState_STATE gil = enter(s);
    *state = call(py.PyObject_GetAttrString(s->slave, "_get_fmu_state"), NULL);
    return finished(s, gil, *state ? borrowed(*state) : NULL, STATUS_ERROR, "getting the FMU state");
}

int slave_set_state(Slave *s, PyObject *state) {
    PyGILState_STATE gil = enter(s);
    PyObject *items[] = {borrowed(state)};
    PyObject *result = call(py.PyObject_GetAttrString(s->slave, "_set_fmu_state"), pack(1, items));
    return finished(s, gil, result, STATUS_ERROR, "setting the FMU state");
}

void slave_release(PyObject *object) {
    if (!object) return;
    PyGILState_STATE gil = pyhost_enter();
    py.Py_DecRef(object);
    pyhost_leave(gil);
}

int slave_serialize(Slave *s, PyObject *state, char **bytes, size_t *size) {
    PyGILState_STATE gil = enter(s);
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
    drain_log(s);
    leave(s, gil);
    return status;
}

int slave_deserialize(Slave *s, const char *bytes, size_t size, PyObject **state) {
    PyGILState_STATE gil = enter(s);
    PyObject *items[] = {borrowed(s->slave), py.PyBytes_FromStringAndSize(bytes, (Py_ssize_t)size)};
    *state = bridge_call(s, "state_from_bytes", pack(2, items));
    return finished(s, gil, *state ? borrowed(*state) : NULL, STATUS_ERROR, "deserializing the FMU state");
}

static int hex(char c) {
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
}

int slave_uri_to_path(const char *uri, char *path, size_t size) {
    if (!uri || !*uri) return -1;
    const char *p = uri;
    int encoded = strncmp(p, "file:", 5) == 0;
    if (encoded) {
        p += 5;
        if (strncmp(p, "//localhost/", 12) == 0) p += 11;
        else if (strncmp(p, "///", 3) == 0) p += 2;
    }
    size_t k = 0;
    for (; *p && k + 1 < size; p++) {
        if (encoded && *p == '%' && hex(p[1]) >= 0 && hex(p[2]) >= 0) {
            path[k++] = (char)(hex(p[1]) * 16 + hex(p[2]));
            p += 2;
        } else {
            path[k++] = *p;
        }
    }
    path[k] = '\0';
    if (*p) return -1;
    platform_native_path(path);
    return platform_is_absolute(path) ? 0 : -1;
}
