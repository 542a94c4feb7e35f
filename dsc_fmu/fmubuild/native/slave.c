/* One Python slave behind an FMU instance, for both FMI versions (see slave.h): its creation from the
   FMU's resources, its variable table, its reset and its end. */

#include "slave_calls.h"

#include "platform.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#ifndef DSC_ENTRY_FILE
#error DSC_ENTRY_FILE (the resources file that names the bridge, slave and token) must be defined
#endif
#define MAX_VALUE_REFERENCE 100000
#define MAX_VARIABLES 1024
/* The cells of a row of the variable table (native_bridge.variables). */
enum { CELL_REFERENCE, CELL_TYPE, CELL_CAUSALITY, CELL_VARIABILITY, CELL_STATE, CELLS };

const char *const TYPE_NAMES[TYPES + 1] = {DSC_TYPE_NAMES};
const char *const GET_METHODS[TYPES] = {DSC_GET_METHODS};
const char *const SET_METHODS[TYPES] = {DSC_SET_METHODS};

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
            PyObject *error = pyhost_take_error();
            py.PyDict_DelItemString(modules, name);
            pyhost_restore_error(error);
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

const char *const VECTOR_METHODS[VECTORS] = {"get_derivatives", "get_event_indicators",
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

/* Row `i` of the variable table: value reference, type, causality, variability and whether a state, in
   `cells`; 0, or -1 (the exception set, or a cell that is not a number) with every cell -1. */
static int read_row(PyObject *table, Py_ssize_t i, long cells[CELLS]) {
    PyObject *row = py.PySequence_GetItem(table, i);
    int complete = row != NULL;
    for (int k = 0; k < CELLS; k++) {
        PyObject *cell = complete ? py.PySequence_GetItem(row, k) : NULL;
        cells[k] = cell ? py.PyLong_AsLong(cell) : -1;
        complete = cell && !py.PyErr_Occurred();
        clear(&cell);
    }
    clear(&row);
    if (complete) return 0;
    for (int k = 0; k < CELLS; k++) cells[k] = -1;
    return -1;
}

static int read_variables(Slave *s) {
    PyObject *items[] = {borrowed(s->slave)};
    PyObject *table = bridge_call(s, "variables", pack(1, items));
    Py_ssize_t n = table ? py.PySequence_Size(table) : -1;
    long rows[CELLS * MAX_VARIABLES];
    if (n < 0 || n > MAX_VARIABLES) {
        clear(&table);
        if (n < 0) log_exception(s, STATUS_ERROR, "reading the variable table");
        else say(s, STATUS_ERROR, "the slave has %zd variables; allowed: at most %d", n, MAX_VARIABLES);
        return -1;
    }
    long largest = -1;
    int valid = 1;
    for (Py_ssize_t i = 0; i < n && valid; i++) {
        long *row = &rows[CELLS * i];
        valid = read_row(table, i, row) == 0;
        if (valid && row[CELL_REFERENCE] > largest) largest = row[CELL_REFERENCE];
    }
    clear(&table);
    if (!valid || largest >= MAX_VALUE_REFERENCE) {
        py.PyErr_Clear();
        say(s, STATUS_ERROR, "the variable table of the slave is not valid");
        return -1;
    }
    if (read_dimensions(s) != 0) return -1;
    s->size = (unsigned int)(largest + 1);
    s->type = malloc(s->size ? s->size : 1);
    s->causality = malloc(s->size ? s->size : 1);
    s->variability = malloc(s->size ? s->size : 1);
    s->is_state = calloc(s->size ? s->size : 1, 1);
    if (!s->type || !s->causality || !s->variability || !s->is_state) {
        say(s, STATUS_ERROR, "out of memory for the variable table");
        return -1;
    }
    memset(s->type, NO_VARIABLE, s->size);
    for (Py_ssize_t i = 0; i < n; i++) {
        const long *row = &rows[CELLS * i];
        if (row[CELL_REFERENCE] < 0) continue;
        s->type[row[CELL_REFERENCE]] = (signed char)row[CELL_TYPE];
        s->causality[row[CELL_REFERENCE]] = (signed char)row[CELL_CAUSALITY];
        s->variability[row[CELL_REFERENCE]] = (signed char)row[CELL_VARIABILITY];
        s->is_state[row[CELL_REFERENCE]] = row[CELL_STATE] == 1;
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

/* Let go of the slave's Python objects without touching them: the interpreter they belong to is
   finalizing or gone (a host that frees its instances from destructors at exit), its import system
   torn down, and its objects go with it. */
static void abandon_python(Slave *s) {
    memset(s->bound, 0, sizeof s->bound);
    s->log_queue = NULL;
    s->slave = NULL;
    s->bridge = NULL;
}

void slave_free(Slave *s) {
    int holds_python = s->bridge || s->slave || s->log_queue;
    if (holds_python && !pyhost_alive()) {
        abandon_python(s);
    } else if (holds_python) {
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
    free(s->is_state);
    s->type = NULL;
    s->causality = NULL;
    s->variability = NULL;
    s->is_state = NULL;
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
