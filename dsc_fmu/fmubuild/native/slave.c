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
/* The variable tables are indexed by value reference: the largest they take (about 400 kB of tables). */
#define MAX_VALUE_REFERENCE 100000
/* Room for the message of a Python that cannot start: pyhost.c's whole text (4 kB) and the advice around it. */
#define START_ERROR_SIZE 8192
/* The cells of a row of the variable table (native_bridge.variables). */
enum { CELL_REFERENCE, CELL_TYPE, CELL_CAUSALITY, CELL_VARIABILITY, CELL_STATE, CELLS };

const char *const TYPE_NAMES[TYPES + 1] = {DSC_TYPE_NAMES};
const char *const GET_METHODS[TYPES] = {DSC_GET_METHODS};
const char *const SET_METHODS[TYPES] = {DSC_SET_METHODS};

/* A new string: the first `length` characters of `text`; NULL if out of memory. */
static char *copy_text(const char *text, size_t length) {
    char *copy = malloc(length + 1);
    if (!copy) return NULL;
    memcpy(copy, text, length);
    copy[length] = '\0';
    return copy;
}

/* A new string: the path of the file `name` + `suffix` in `folder`, every '.' of `name` a '/' if `dotted`
   (a module's file). NULL if out of memory. */
static char *file_in(const char *folder, const char *name, const char *suffix, int dotted) {
    size_t head = strlen(folder), length = strlen(name), tail = strlen(suffix);
    char *path = malloc(head + 1 + length + tail + 1);
    if (!path) return NULL;
    memcpy(path, folder, head);
    path[head] = '/';
    for (size_t i = 0; i < length; i++) path[head + 1 + i] = dotted && name[i] == '.' ? '/' : name[i];
    memcpy(path + head + 1 + length, suffix, tail + 1);
    return path;
}

/* The whole text of the (small) file `file`, a new string; NULL if it cannot be read or memory runs out. */
static char *read_text(FILE *file) {
    size_t size = 0, room = 256;
    char *text = malloc(room);
    for (size_t got; text && (got = fread(text + size, 1, room - 1 - size, file)) > 0;) {
        size += got;
        char *larger = size + 1 < room ? text : realloc(text, room *= 2);
        if (!larger) free(text);
        text = larger;
    }
    if (text && ferror(file)) {
        free(text);
        return NULL;
    }
    if (text) text[size] = '\0';
    return text;
}

/* The next whitespace-separated word at `*cursor`, ended in place, `*cursor` moved past it; NULL if none. */
static const char *next_word(char **cursor) {
    char *word = *cursor + strspn(*cursor, " \t\r\n");
    if (!*word) return NULL;
    char *end = word + strcspn(word, " \t\r\n");
    *cursor = *end ? end + 1 : end;
    *end = '\0';
    return word;
}

/* The entry file: the bridge module (its top level the build's private package, in `*bridge`), the slave's
   module and class, and the token, kept in `s->entry`; read before Python is started. */
static int read_entry(Slave *s, const char **bridge) {
    char *path = file_in(s->resources, DSC_ENTRY_FILE, "", 0);
    FILE *file = path ? platform_open_file(path, "r") : NULL;
    s->entry = file ? read_text(file) : NULL;
    if (file) fclose(file);
    char *cursor = s->entry;
    *bridge = cursor ? next_word(&cursor) : NULL;
    s->module = *bridge ? next_word(&cursor) : NULL;
    s->class_name = s->module ? next_word(&cursor) : NULL;
    s->token = s->class_name ? next_word(&cursor) : NULL;
    int result = -1;
    if (!path) say(s, STATUS_ERROR, "out of memory for the path of the entry file in %s", s->resources);
    else if (!file) say(s, STATUS_ERROR, "cannot read %s: the FMU's resources are incomplete", path);
    else if (!s->entry) say(s, STATUS_ERROR, "cannot read %s to its end", path);
    else if (!s->token || !strchr(*bridge, '.')) say(s, STATUS_ERROR, "%s does not name the bridge, module, class "
                                                      "and token", path);
    else result = 0;
    free(path);
    return result;
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
    PyObject *items[] = {util ? py.PyUnicode_FromString(name) : NULL, util ? py.PyUnicode_FromString(path) : NULL};
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
    char *path = known ? NULL : file_in(s->resources, bridge, ".py", 1);
    if (!known && !path) {
        say(s, STATUS_ERROR, "out of memory for the path of the module %s", bridge);
        return -1;
    }
    s->bridge = known ? borrowed(known) : load_file(bridge, path);
    free(path);
    PyObject *items[] = {s->bridge ? py.PyUnicode_FromString(s->resources) : NULL};
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

/* The numbers of continuous states and event indicators (native_bridge.dimensions), each at most the number
   of variables, `variables`. */
static int read_dimensions(Slave *s, Py_ssize_t variables) {
    PyObject *items[] = {borrowed(s->slave)};
    PyObject *sizes = bridge_call(s, "dimensions", pack(1, items));
    PyObject *nx = sizes ? py.PySequence_GetItem(sizes, 0) : NULL;
    PyObject *nz = nx ? py.PySequence_GetItem(sizes, 1) : NULL;
    long states = nz ? py.PyLong_AsLong(nx) : -1;
    long indicators = nz && !py.PyErr_Occurred() ? py.PyLong_AsLong(nz) : -1;
    clear(&nz);
    clear(&nx);
    clear(&sizes);
    if (py.PyErr_Occurred()) {
        log_exception(s, STATUS_ERROR, "reading the numbers of states and event indicators");
        return -1;
    }
    if (states < 0 || indicators < 0 || states > variables || indicators > variables) {
        say(s, STATUS_ERROR, "the slave has %ld continuous states and %ld event indicators; allowed: 0 to %zd, its "
            "number of variables, each", states, indicators, variables);
        return -1;
    }
    s->nx = (size_t)states;
    s->nz = (size_t)indicators;
    s->x = calloc(s->nx ? s->nx : 1, sizeof *s->x);
    if (!s->x) say(s, STATUS_ERROR, "out of memory for the continuous states");
    return s->x ? 0 : -1;
}

/* The name and allowed values of each cell of a row of the variable table. */
static const char *const CELL_NAMES[CELLS] = {"value reference", "type", "causality", "variability", "state"};
static const long CELL_LIMITS[CELLS][2] = {
    [CELL_REFERENCE] = {0, MAX_VALUE_REFERENCE - 1}, [CELL_TYPE] = {0, 127}, [CELL_CAUSALITY] = {-128, 127},
    [CELL_VARIABILITY] = {-128, 127}, [CELL_STATE] = {0, 1},
};

/* Row `i` of the variable table: value reference, type, causality, variability and whether a state, in
   `cells`; 0, or -1 after logging why (a Python error, a cell that is not a number or out of range). */
static int read_row(Slave *s, PyObject *table, Py_ssize_t i, long cells[CELLS]) {
    PyObject *row = py.PySequence_GetItem(table, i);
    int k = 0, complete = row != NULL;
    for (; complete && k < CELLS; k++) {
        PyObject *cell = py.PySequence_GetItem(row, k);
        cells[k] = cell ? py.PyLong_AsLong(cell) : -1;
        complete = cell && !py.PyErr_Occurred();
        clear(&cell);
    }
    clear(&row);
    if (!complete) {
        log_exception(s, STATUS_ERROR, "reading the variable table");
        return -1;
    }
    for (k = 0; k < CELLS; k++) {
        if (cells[k] < CELL_LIMITS[k][0] || cells[k] > CELL_LIMITS[k][1]) {
            say(s, STATUS_ERROR, "row %zd of the variable table has the %s %ld; allowed: %ld to %ld", i, CELL_NAMES[k],
                cells[k], CELL_LIMITS[k][0], CELL_LIMITS[k][1]);
            return -1;
        }
    }
    return 0;
}

/* The variable table of the slave's `n` variables, `rows`, by value reference, and the model's dimensions. */
static int fill_tables(Slave *s, const long *rows, Py_ssize_t n) {
    long largest = -1;
    for (Py_ssize_t i = 0; i < n; i++) {
        if (rows[CELLS * i + CELL_REFERENCE] > largest) largest = rows[CELLS * i + CELL_REFERENCE];
    }
    if (read_dimensions(s, n) != 0) return -1;
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
        s->type[row[CELL_REFERENCE]] = (signed char)row[CELL_TYPE];
        s->causality[row[CELL_REFERENCE]] = (signed char)row[CELL_CAUSALITY];
        s->variability[row[CELL_REFERENCE]] = (signed char)row[CELL_VARIABILITY];
        s->is_state[row[CELL_REFERENCE]] = row[CELL_STATE] == 1;
    }
    return 0;
}

/* The slave's variable table (native_bridge.variables), read into memory of the table's size. */
static int read_variables(Slave *s) {
    PyObject *items[] = {borrowed(s->slave)};
    PyObject *table = bridge_call(s, "variables", pack(1, items));
    Py_ssize_t n = table ? py.PySequence_Size(table) : -1;
    long *rows = n >= 0 ? malloc(sizeof *rows * CELLS * (size_t)(n ? n : 1)) : NULL;
    int result = rows ? 0 : -1;
    if (n < 0) log_exception(s, STATUS_ERROR, "reading the variable table");
    else if (!rows) say(s, STATUS_ERROR, "out of memory for the variable table of %zd variables", n);
    for (Py_ssize_t i = 0; result == 0 && i < n; i++) result = read_row(s, table, i, &rows[CELLS * i]);
    clear(&table);
    if (result == 0) result = fill_tables(s, rows, n);
    free(rows);
    return result;
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

/* Start Python if needed: 0, or -1 after logging why not. */
static int start_python(Slave *s) {
    char *error = malloc(START_ERROR_SIZE);
    if (!error) {
        say(s, STATUS_ERROR, "out of memory for starting Python");
        return -1;
    }
    int result = pyhost_start(error, START_ERROR_SIZE);
    if (result != 0) say(s, STATUS_ERROR, "%s", error);
    free(error);
    return result;
}

int slave_create(Slave *s, const char *resources, const char *token, int visible) {
    s->visible = visible;
    size_t length = strlen(resources);
    while (length > 1 && resources[length - 1] == '/') length--;
    s->resources = copy_text(resources, length);
    const char *bridge = NULL;
    int result = s->resources ? read_entry(s, &bridge) : -1;
    if (!s->resources) say(s, STATUS_ERROR, "out of memory for the path of the resources");
    if (result == 0 && (!token || strcmp(token, s->token) != 0)) {
        say(s, STATUS_ERROR, "the token %s does not match this FMU's %s", token ? token : "(null)", s->token);
        result = -1;
    }
    if (result == 0) result = start_python(s);
    if (result == 0) {
        PyGILState_STATE gil = pyhost_enter();
        int locked = lock_imports(s);
        result = locked ? import_bridge(s, bridge) : -1;
        if (result == 0) {
            PyObject *slave = new_slave(s);
            if (!slave) log_exception(s, STATUS_ERROR, "creating the slave");
            result = slave && adopt_slave(s, slave) == 0 ? read_variables(s) : -1;
        }
        if (result == 0) traced_layout(s);
        drain_log(s);
        if (result != 0) release_bridge(s);
        if (locked) unlock_imports(s);
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
    traced_free(s);
    free(s->x);
    s->x = NULL;
    free(s->entry);
    free(s->resources);
    s->entry = s->resources = NULL;
    s->module = s->class_name = s->token = NULL;
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
    } else {
        s->traced.ready = 0; /* what the C did belonged to the slave replaced; a failed reset keeps both */
        s->traced.ahead = 0;
    }
    drain_log(s);
    leave(s, gil);
    return status;
}
