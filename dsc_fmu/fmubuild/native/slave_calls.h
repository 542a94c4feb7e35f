/* What the slave's own files share (slave.c, slave_queue.c, slave_calls.c, slave_values.c,
   slave_states.c): the names of the slave's methods, the message queue's entry and the calls into
   Python. The rest of the binary uses slave.h. */

#ifndef DSC_SLAVE_CALLS_H
#define DSC_SLAVE_CALLS_H

#include "slave.h"

/* The slave's get and set method of each type (DSC_GET_METHODS, DSC_SET_METHODS), and of each vector. */
extern const char *const GET_METHODS[TYPES];
extern const char *const SET_METHODS[TYPES];
extern const char *const VECTOR_METHODS[VECTORS];

/* --- the message queue (slave_queue.c) ---------------------------------------------------------------- */

/* Queue `text` with `status` and `category` for the logger. */
void queue_message(Slave *s, int status, const char *category, const char *text);
/* Queue "<instance name>: " and `format` (printf's) with `status`. */
void say(Slave *s, int status, const char *format, ...);

/* --- calls into Python (slave_calls.c); all but `enter` with the GIL held ------------------------------ */

/* Take the GIL (in `*gil`) for a call of the slave, which first sees what model exchange set since its last
   call: STATUS_OK, or STATUS_ERROR after logging why it could not (the GIL is held all the same; what was set
   stays pending). */
int enter(Slave *s, PyGILState_STATE *gil);
/* Release the GIL, then deliver what was queued under it. */
void leave(Slave *s, PyGILState_STATE gil);
/* Queue the slave's log messages, leave (`gil`) and return `status`. */
int done(Slave *s, PyGILState_STATE gil, int status);

/* Release `*object` (if any) and set it to NULL. */
void clear(PyObject **object);
/* A new reference to `object`. */
PyObject *borrowed(PyObject *object);
/* A tuple of `n` new references, which it steals; NULL (the exception set) if any is NULL. */
PyObject *pack(int n, PyObject **items);
/* Put `item` (a new reference, which it steals, or NULL with the exception set) at `i` of the list `*list`;
   if that fails, the list is released and `*list` is NULL, the exception set. */
void put(PyObject **list, size_t i, PyObject *item);
/* A list of the `n` floats of `values`; NULL with the exception set. */
PyObject *float_list(const double *values, size_t n);
/* Call `function` (a new reference, which it steals) with `args` (stolen; NULL for none, unless an
   exception is set: then the arguments failed and nothing is called). */
PyObject *call(PyObject *function, PyObject *args);
/* Call the function `name` of the build's bridge module (native_bridge.py) with `args` (stolen). */
PyObject *bridge_call(Slave *s, const char *name, PyObject *args);

/* The traced model's mirror (slave_traced.c), the GIL held: read the slave's layout once it exists (a failure
   is logged as a warning: the slave then runs in Python only); take its values at the end of a call; hand
   back what was done in C at the start of the next (0, or -1 after logging why); free it. */
void traced_layout(Slave *s);
void traced_snapshot(Slave *s);
int traced_sync(Slave *s);
void traced_free(Slave *s);

/* Queue the pending exception as the failure of `doing` with `status`, and clear it. */
void log_exception(Slave *s, int status, const char *doing);
/* Queue the messages the slave logged (cheap when there are none). */
void drain_log(Slave *s);
/* The status of a slave call that returned `result` (NULL: it raised; `failure` after logging the
   exception as `what`); releases `result`, queues the slave's log messages and leaves (`gil`). */
int finished(Slave *s, PyGILState_STATE gil, PyObject *result, int failure, const char *what);

#endif
