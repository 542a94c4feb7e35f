/* The model traced to C (traced.h) behind the slave (slave.h, Traced; docs/traced-c.md).

   At the end of each call into Python the slave's values are copied here (its traced_snapshot: the
   parameters, time, state, inputs, the last step's stamped inputs, the held switches, the bookkeeping), or
   nothing where the slave needs Python for what comes next (traced = off, values refused, before the first
   step, input derivatives given, the beta guard or a driver's limit acting in the last step). Until the next
   call into Python, inputs are set, outputs read, co-simulation steps taken and model exchange's derivatives
   and event indicators evaluated here; anything else, a value the checks of the slave would refuse, a step
   the traced model would raise in or watches something in (the guard, the limit), goes to Python, which first
   receives what was done here (traced_sync), so that every message and error is the slave's own. */

#include "slave_calls.h"
#include "traced.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* The roles of the slave's layout (fmu/slave.py, traced_layout: PARAMETER, INPUT_VALUE, ...) and the inputs'
   bounds. */
enum { ROLE_PARAMETER, ROLE_INPUT, ROLE_OUTPUT, ROLE_BOOKKEEPING, ROLE_STATE, ROLE_DERIVATIVE };
enum { BOUND_ANY, BOUND_NONNEGATIVE, BOUND_POSITIVE, CHECK_CELLS = 3 };
/* The sizes of the layout: p, x, u, traced outputs, bookkeeping, the indices of max_step and coupling in p,
   the most sub-steps of a step, the codes of hold and interpolate. */
enum { SIZE_P, SIZE_X, SIZE_U, SIZE_Y, SIZE_B, SIZE_MAX_STEP, SIZE_COUPLING, SIZE_MAX_SUBSTEPS, SIZE_HOLD,
       SIZE_INTERPOLATE, SIZES };
/* The entries of the snapshot (ModelSlave.traced_snapshot). */
enum { SNAP_P, SNAP_TIME, SNAP_STATE, SNAP_INPUTS, SNAP_STAMP, SNAP_STAMPED, SNAP_HELD, SNAP_BOOKKEEPING, SNAPS };

/* The `n` numbers of the sequence `sequence` into `out`: 0, or -1 (a Python error set, or another length). */
static int read_numbers(PyObject *sequence, double *out, size_t n) {
    Py_ssize_t size = sequence ? py.PySequence_Size(sequence) : -1;
    for (Py_ssize_t i = 0; size == (Py_ssize_t)n && i < size && !py.PyErr_Occurred(); i++) {
        PyObject *item = py.PySequence_GetItem(sequence, i);
        if (item) out[i] = py.PyFloat_AsDouble(item);
        clear(&item);
    }
    return size == (Py_ssize_t)n && !py.PyErr_Occurred() ? 0 : -1;
}

/* Item `i` of `sequence` as `n` numbers in a new array (NULL: failed; a Python error set, or another length). */
static double *numbers_at(PyObject *sequence, Py_ssize_t i, size_t *n) {
    PyObject *item = py.PySequence_GetItem(sequence, i);
    Py_ssize_t size = item ? py.PySequence_Size(item) : -1;
    double *out = size >= 0 ? calloc(size ? (size_t)size : 1, sizeof *out) : NULL;
    if (out && read_numbers(item, out, (size_t)size) != 0) {
        free(out);
        out = NULL;
    }
    if (out) *n = (size_t)size;
    clear(&item);
    return out;
}

static double *zeros(size_t n) {
    return calloc(n ? n : 1, sizeof(double));
}

static int *indices(size_t n) {
    int *array = malloc(sizeof(int) * (n ? n : 1));
    for (size_t i = 0; array && i < n; i++) array[i] = -1;
    return array;
}

/* The value references' roles from the layout's `n` numbers `cells` (value reference, role, index). */
static int fill_roles(Slave *s, const double *cells, size_t n) {
    Traced *t = &s->traced;
    t->role = malloc(s->size ? s->size : 1);
    t->index = indices(s->size);
    t->state_of = indices(s->size);
    t->derivative_of = indices(s->size);
    if (!t->role || !t->index || !t->state_of || !t->derivative_of) return -1;
    memset(t->role, NO_VARIABLE, s->size);
    size_t nx = (size_t)TRACED_MODEL.states;
    size_t counts[] = {t->np, t->nu, t->ny, t->nb, nx, nx};
    for (size_t i = 0; i + 2 < n; i += 3) {
        double vr = cells[i], role = cells[i + 1], index = cells[i + 2];
        if (!(vr >= 0 && vr < s->size && role >= ROLE_PARAMETER && role <= ROLE_DERIVATIVE && index >= 0 &&
              index < counts[(int)role]))
            return -1;
        unsigned int at = (unsigned int)vr;
        if (role == ROLE_STATE) {
            t->state_of[at] = (int)index;
        } else if (role == ROLE_DERIVATIVE) {
            t->derivative_of[at] = (int)index;
        } else {
            t->role[at] = (signed char)role;
            t->index[at] = (int)index;
        }
    }
    return 0;
}

/* Whether the slave's sizes are the traced model's, and its watch fits. */
static int agrees(const Slave *s, const double *sizes) {
    const TracedModel *m = &TRACED_MODEL;
    return sizes[SIZE_P] == m->parameters && sizes[SIZE_X] == m->states && sizes[SIZE_U] == m->inputs &&
           sizes[SIZE_Y] == m->outputs && s->nx == (size_t)m->states && s->nz == (size_t)m->indicators &&
           m->watched <= TRACED_WATCH_SIZE;
}

static int allocate(Slave *s, const double *sizes) {
    Traced *t = &s->traced;
    t->np = (size_t)sizes[SIZE_P];
    t->nu = (size_t)sizes[SIZE_U];
    t->ny = (size_t)sizes[SIZE_Y];
    t->nb = (size_t)sizes[SIZE_B];
    t->max_step = (int)sizes[SIZE_MAX_STEP];
    t->coupling = (int)sizes[SIZE_COUPLING];
    t->max_substeps = (long)sizes[SIZE_MAX_SUBSTEPS];
    t->hold = (long)sizes[SIZE_HOLD];
    t->interpolate = (long)sizes[SIZE_INTERPOLATE];
    size_t ns = TRACED_MODEL.switches;
    t->p = zeros(t->np);
    t->x = zeros((size_t)TRACED_MODEL.states);
    t->next = zeros((size_t)TRACED_MODEL.states);
    t->u = zeros(t->nu);
    t->stamped = zeros(t->nu);
    t->slope = zeros(t->nu);
    t->outputs = zeros(t->ny);
    t->bookkeeping = zeros(t->nb);
    t->held = zeros(ns);
    size_t nx = (size_t)TRACED_MODEL.states;
    t->dx = zeros(nx);
    t->du = zeros(t->nu);
    size_t widest = nx > t->ny ? nx : t->ny;
    t->values = zeros(widest > (size_t)TRACED_MODEL.indicators ? widest : (size_t)TRACED_MODEL.indicators);
    t->drates = zeros(nx);
    t->doutputs = zeros(t->ny);
    return t->p && t->x && t->next && t->u && t->stamped && t->slope && t->outputs && t->bookkeeping && t->held &&
                   t->dx && t->du && t->values && t->drates && t->doutputs &&
                   t->max_step >= 0 && t->max_step < (int)t->np && t->coupling < (int)t->np
               ? 0
               : -1;
}

void traced_layout(Slave *s) {
    if (TRACED_MODEL.parameters == 0 || !TRACED_MODEL.step) return; /* built without the traced model */
    PyObject *layout = call(py.PyObject_GetAttrString(s->slave, "traced_layout"), NULL);
    size_t n_cells = 0, n_sizes = 0, n_checks = 0;
    double *cells = layout ? numbers_at(layout, 0, &n_cells) : NULL;
    double *sizes = cells ? numbers_at(layout, 1, &n_sizes) : NULL;
    s->traced.checks = sizes ? numbers_at(layout, 2, &n_checks) : NULL;
    clear(&layout);
    if (!s->traced.checks) {
        log_exception(s, STATUS_WARNING, "reading the layout of the traced model (the model runs in Python)");
    } else if (n_sizes != SIZES || !agrees(s, sizes) || n_checks != CHECK_CELLS * (size_t)sizes[SIZE_U] ||
               allocate(s, sizes) != 0 || fill_roles(s, cells, n_cells) != 0) {
        say(s, STATUS_WARNING, "the traced model does not match the slave's variables or memory ran out: the model "
            "runs in Python");
    } else {
        s->traced.usable = 1;
    }
    free(cells);
    free(sizes);
    if (!s->traced.usable) traced_free(s);
}

void traced_free(Slave *s) {
    Traced *t = &s->traced;
    double **arrays[] = {&t->p,       &t->x,    &t->u,  &t->stamped, &t->slope,  &t->next,    &t->outputs,
                         &t->bookkeeping, &t->held, &t->dx, &t->du,      &t->values, &t->drates, &t->doutputs,
                         &t->checks};
    for (size_t i = 0; i < sizeof arrays / sizeof *arrays; i++) free(*arrays[i]);
    free(t->role);
    free(t->index);
    free(t->state_of);
    free(t->derivative_of);
    memset(t, 0, sizeof *t);
}

/* The snapshot's entries into the mirror: 0, or -1 (a Python error set, or another length). */
static int take(Slave *s, PyObject *snapshot) {
    Traced *t = &s->traced;
    PyObject *item[SNAPS] = {NULL};
    int result = py.PySequence_Size(snapshot) == SNAPS ? 0 : -1;
    for (int i = 0; result == 0 && i < SNAPS; i++) result = (item[i] = py.PySequence_GetItem(snapshot, i)) ? 0 : -1;
    size_t nx = (size_t)TRACED_MODEL.states;
    t->has_history = result == 0 && item[SNAP_STAMP] != py.None;
    t->has_held = result == 0 && item[SNAP_HELD] != py.None;
    if (result == 0) result = read_numbers(item[SNAP_P], t->p, t->np);
    if (result == 0) t->time = py.PyFloat_AsDouble(item[SNAP_TIME]);
    if (result == 0) result = read_numbers(item[SNAP_STATE], t->x, nx);
    if (result == 0) result = read_numbers(item[SNAP_INPUTS], t->u, t->nu);
    if (result == 0 && t->has_history) t->stamp = py.PyFloat_AsDouble(item[SNAP_STAMP]);
    if (result == 0 && t->has_history) result = read_numbers(item[SNAP_STAMPED], t->stamped, t->nu);
    if (result == 0 && t->has_held) result = read_numbers(item[SNAP_HELD], t->held, (size_t)TRACED_MODEL.switches);
    if (result == 0) result = read_numbers(item[SNAP_BOOKKEEPING], t->bookkeeping, t->nb);
    for (int i = 0; i < SNAPS; i++) clear(&item[i]);
    return result == 0 && !py.PyErr_Occurred() ? 0 : -1;
}

void traced_snapshot(Slave *s) {
    Traced *t = &s->traced;
    t->ready = 0;
    if (!t->usable || !s->slave || t->ahead || py.PyErr_Occurred()) return; /* ahead: not handed over, kept */
    PyObject *snapshot = call(py.PyObject_GetAttrString(s->slave, "traced_snapshot"), NULL);
    if (snapshot && snapshot != py.None && take(s, snapshot) == 0) {
        t->ready = 1;
        t->outputs_valid = 0;
    } else if (!snapshot || py.PyErr_Occurred()) {
        log_exception(s, STATUS_WARNING, "traced_snapshot (the next call runs in Python)");
    } else if (snapshot != py.None) {
        say(s, STATUS_WARNING, "traced_snapshot returned values whose sizes are not the layout's (the next call runs "
            "in Python)");
    }
    clear(&snapshot);
}

int traced_sync(Slave *s) {
    Traced *t = &s->traced;
    t->ready = 0;
    if (!t->ahead) return 0;
    int stepped = (t->ahead & AHEAD_STEP) != 0;
    PyObject *items[] = {
        float_list(t->u, t->nu),
        stepped ? py.PyFloat_FromDouble(t->time) : borrowed(py.None),
        stepped ? float_list(t->x, (size_t)TRACED_MODEL.states) : borrowed(py.None),
        stepped ? py.PyFloat_FromDouble(t->stamp) : borrowed(py.None),
        stepped ? float_list(t->stamped, t->nu) : borrowed(py.None),
    };
    PyObject *result = call(py.PyObject_GetAttrString(s->slave, "traced_sync"), pack(5, items));
    if (!result) {
        log_exception(s, STATUS_ERROR, "traced_sync");
        return -1;
    }
    clear(&result);
    t->ahead = 0;
    return 0;
}

void traced_touched(Slave *s) {
    s->traced.outputs_valid = 0;
}

/* Model exchange's time and state where set since the slave's last call, else the mirror's. */
static double current_time(const Slave *s) {
    return s->pending & PENDING_TIME ? s->time : s->traced.time;
}

static const double *current_state(const Slave *s) {
    return s->pending & PENDING_STATES ? s->x : s->traced.x;
}

static const double *held(const Slave *s) {
    return s->traced.has_held ? s->traced.held : NULL;
}

/* Whether the slave's check would take `value` for input `i` (Variable.check). */
static int allowed(const Traced *t, size_t i, double value) {
    const double *check = &t->checks[CHECK_CELLS * i];
    int bound = (int)check[0];
    return isfinite(value) && (bound != BOUND_POSITIVE || value > 0) && (bound != BOUND_NONNEGATIVE || value >= 0) &&
           value >= check[1] && value <= check[2];
}

int traced_set(Slave *s, int type, const unsigned int *vr, size_t n, const void *values, CType ctype) {
    Traced *t = &s->traced;
    if (!t->ready || type != TYPE_REAL || ctype != C_DOUBLE) return 0;
    const double *v = values;
    for (size_t i = 0; i < n; i++) {
        if (vr[i] >= s->size || t->role[vr[i]] != ROLE_INPUT || !allowed(t, (size_t)t->index[vr[i]], v[i])) return 0;
    }
    for (size_t i = 0; i < n; i++) t->u[t->index[vr[i]]] = v[i];
    t->ahead |= AHEAD_INPUTS;
    t->outputs_valid = 0;
    return 1;
}

/* The traced outputs at the current values, computed once per change: 0, or 1 where the model raises. */
static int compute_outputs(Slave *s) {
    Traced *t = &s->traced;
    if (t->outputs_valid) return 0;
    if (TRACED_MODEL.outputs_of(t->p, current_time(s), current_state(s), t->u, held(s), t->outputs) != 0) return 1;
    t->outputs_valid = 1;
    return 0;
}

int traced_get(Slave *s, int type, const unsigned int *vr, size_t n, void *values, CType ctype) {
    Traced *t = &s->traced;
    if (!t->ready || type != TYPE_REAL || ctype != C_DOUBLE) return 0;
    for (size_t i = 0; i < n; i++) {
        if (vr[i] >= s->size || t->role[vr[i]] == NO_VARIABLE) return 0;
        if (t->role[vr[i]] == ROLE_OUTPUT && compute_outputs(s) != 0) return 0;
    }
    const double *sources[] = {t->p, t->u, t->outputs, t->bookkeeping};
    double *v = values;
    for (size_t i = 0; i < n; i++) v[i] = sources[t->role[vr[i]]][t->index[vr[i]]];
    return 1;
}

/* The sub-steps of a step (models.rk4.substeps), or 0 for more than the slave allows. */
static long substeps(const Traced *t, double step) {
    double count = ceil(step / t->p[t->max_step] * (1.0 - 1e-12));
    if (!(count <= (double)t->max_substeps)) return 0;
    return count < 1.0 ? 1 : (long)count;
}

/* The slope of the inputs over a step stamped at `stamp` (ModelSlave._ramp), or NULL: held. */
static const double *ramp(Traced *t, double stamp) {
    long coupling = t->coupling >= 0 ? (long)t->p[t->coupling] : t->hold;
    if (coupling == t->hold || !t->has_history || !(stamp > t->stamp)) return NULL;
    for (size_t i = 0; i < t->nu; i++) t->slope[i] = (t->u[i] - t->stamped[i]) / (stamp - t->stamp);
    return t->slope;
}

int traced_step(Slave *s, double time, double step, int *accepted) {
    Traced *t = &s->traced;
    long count = t->ready && !t->has_held ? substeps(t, step) : 0; /* held switches: model exchange's state */
    if (count == 0) return 0;
    long coupling = t->coupling >= 0 ? (long)t->p[t->coupling] : t->hold;
    double stamp = coupling == t->interpolate ? time + step : time;
    const double *slope = ramp(t, stamp);
    size_t nx = (size_t)TRACED_MODEL.states;
    double watch[TRACED_WATCH_SIZE] = {0};
    memcpy(t->next, t->x, nx * sizeof *t->x);
    if (TRACED_MODEL.step(t->p, t->u, slope, stamp, time, step, count, t->next, watch) != 0 || watch[0] != 0)
        return 0;
    for (size_t i = 0; i < nx; i++) {
        if (!isfinite(t->next[i])) return 0;
    }
    memcpy(t->x, t->next, nx * sizeof *t->x);
    memcpy(t->stamped, t->u, t->nu * sizeof *t->u);
    t->stamp = stamp;
    t->has_history = 1;
    t->time = time + step;
    t->ahead |= AHEAD_STEP;
    t->outputs_valid = 0;
    *accepted = 1;
    return 1;
}

int traced_vector(Slave *s, Vector which, double *values, size_t n) {
    Traced *t = &s->traced;
    const TracedModel *m = &TRACED_MODEL;
    if (!t->ready || (m->switches && !t->has_held)) return 0;
    int fault = 1;
    if (which == VECTOR_DERIVATIVES && n == (size_t)m->states)
        fault = m->rates(t->p, current_time(s), current_state(s), t->u, held(s), t->values);
    else if (which == VECTOR_INDICATORS && n == (size_t)m->indicators && m->indicators_of)
        fault = m->indicators_of(t->p, current_state(s), t->u, held(s), t->values);
    if (fault) return 0; /* the importer's array untouched: Python answers */
    memcpy(values, t->values, n * sizeof *values);
    return 1;
}

/* The seeds of the knowns into dx (model exchange's states) and du (inputs), summed where a known repeats
   (fmu/directional.py): 0, or -1 for a known the traced path does not take (Python then names it). */
static int seed_knowns(Slave *s, const Partials *q, int model_exchange) {
    Traced *t = &s->traced;
    memset(t->dx, 0, sizeof(double) * (size_t)TRACED_MODEL.states);
    memset(t->du, 0, sizeof(double) * t->nu);
    for (size_t k = 0; k < q->n_knowns; k++) {
        unsigned int vr = q->knowns[k];
        if (vr >= s->size) return -1;
        if (model_exchange && t->state_of[vr] >= 0) {
            t->dx[t->state_of[vr]] = t->dx[t->state_of[vr]] + q->seed[k];
        } else if (t->role[vr] == ROLE_INPUT) {
            t->du[t->index[vr]] = t->du[t->index[vr]] + q->seed[k];
        } else {
            return -1;
        }
    }
    return 0;
}

/* The role of an unknown: 1 a state derivative, 2 a traced output, 3 an output of the bookkeeping (a constant:
   its tangent 0); -1 for an unknown the traced path does not take (Python then names it). */
static int unknown_role(const Slave *s, unsigned int vr, int model_exchange) {
    const Traced *t = &s->traced;
    if (vr >= s->size) return -1;
    if (model_exchange && t->derivative_of[vr] >= 0) return 1;
    if (t->role[vr] == ROLE_OUTPUT) return 2;
    return t->role[vr] == ROLE_BOOKKEEPING ? 3 : -1;
}

int traced_partials(Slave *s, const Partials *q, int adjoint, int model_exchange) {
    Traced *t = &s->traced;
    const TracedModel *m = &TRACED_MODEL;
    if (!t->ready || adjoint || q->n_seed != q->n_knowns || q->n_sensitivity != q->n_unknowns) return 0;
    if (model_exchange && m->switches && !t->has_held) return 0;
    int uses = 0;
    for (size_t k = 0; k < q->n_unknowns; k++) {
        int role = unknown_role(s, q->unknowns[k], model_exchange);
        if (role < 0) return 0;
        uses |= role == 3 ? 0 : role;
    }
    if (seed_knowns(s, q, model_exchange) != 0) return 0;
    double time = model_exchange ? current_time(s) : t->time;
    const double *x = model_exchange ? current_state(s) : t->x;
    if ((uses & 1) && m->rates_tangent(t->p, time, x, t->u, held(s), t->dx, t->du, t->values, t->drates) != 0)
        return 0;
    if ((uses & 2) && m->outputs_tangent(t->p, time, x, t->u, held(s), t->dx, t->du, t->values, t->doutputs) != 0)
        return 0;
    for (size_t k = 0; k < q->n_unknowns; k++) {
        unsigned int vr = q->unknowns[k];
        int role = unknown_role(s, vr, model_exchange);
        q->sensitivity[k] = role == 1 ? t->drates[t->derivative_of[vr]] : role == 2 ? t->doutputs[t->index[vr]] : 0.0;
    }
    return 1;
}
