/* The Python runtime that runs the model code: found, loaded and started at run time, never linked.

   Order (README, "Use in other tools"):
     0. a Python of the right minor version already in the process (fmpy, libcosimpy, PyFMI): used as it is;
     1. DSC_FMU_PYTHON, the path of a libpython shared library: if set, the only candidate;
     2. the Python that built the FMU (DSC_BUILD_LIBPYTHON, its home DSC_BUILD_PYTHON_HOME);
     3. the system's DSC_PYTHON_SONAME (libpython3.X.so.1.0) by the dynamic loader's search.
   A Python this binary starts gets its home set explicitly, ignores PYTHON* environment variables,
   imports no site packages, writes no bytecode and installs no signal handlers. It is started as
   Py_InitializeEx(0) would start it, but through Py_InitializeFromConfig, whose status says why it
   failed where Py_InitializeEx would end the process; of the configuration it touches only the
   leading fields whose offsets every CPython since 3.8 shares, checked before they are set.

   A host thread Python does not know gets a thread state on its first call, kept for its life. When
   the thread ends, its thread state is handed to the reaper, a thread of this binary's that deletes
   it: thread pools cost nothing once their threads are gone. The ending thread cannot delete it
   itself: that needs the GIL, and a host that joins its threads while holding the GIL (a Python
   extension's destructor, a thread pool's) would wait for ever. */

#define _GNU_SOURCE
#include "pyhost.h"

#include <ctype.h>
#include <dlfcn.h>
#include <limits.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#ifndef DSC_PYTHON_VERSION
#error DSC_PYTHON_VERSION (for example "3.11") must be defined
#endif
#ifndef DSC_BUILD_LIBPYTHON
#define DSC_BUILD_LIBPYTHON ""
#endif
#ifndef DSC_BUILD_PYTHON_HOME
#define DSC_BUILD_PYTHON_HOME ""
#endif
#ifndef DSC_PYTHON_SONAME
#define DSC_PYTHON_SONAME "libpython" DSC_PYTHON_VERSION ".so.1.0"
#endif

#define OVERRIDE_VARIABLE "DSC_FMU_PYTHON"

PyApi py;

static pthread_once_t once = PTHREAD_ONCE_INIT;
static int start_result = -1;
static int start_attempted; /* a library on which Py_InitializeFromConfig ran stays loaded, whatever it said */
static pthread_key_t thread_key; /* the thread state this binary made for a host thread */
static int thread_key_made;

/* Thread states of host threads that ended, for the reaper. */
typedef struct Ended {
    struct Ended *next;
    PyThreadState *state;
} Ended;
static pthread_mutex_t ended_lock = PTHREAD_MUTEX_INITIALIZER;
static pthread_cond_t ended_signal = PTHREAD_COND_INITIALIZER;
static Ended *ended;
static int reaper_started; /* one reaper for each loaded copy of this binary (each FMU's file) */
static PyInterpreterState *interpreter; /* the one whose thread states this binary makes */
static int (*is_finalizing)(void);      /* Py_IsFinalizing (3.13) or _Py_IsFinalizing, where exported */
static char start_error[2048];
static wchar_t *home_wide;

typedef struct {
    const char *name;
    size_t offset;
} Symbol;

#define SYMBOL(name) {#name, offsetof(PyApi, name)}
static const Symbol SYMBOLS[] = {
    SYMBOL(Py_IsInitialized), SYMBOL(_PyConfig_InitCompatConfig), SYMBOL(Py_InitializeFromConfig),
    SYMBOL(PyConfig_Clear), SYMBOL(Py_SetPythonHome), SYMBOL(Py_DecodeLocale), SYMBOL(Py_GetVersion),
    SYMBOL(PyEval_SaveThread), SYMBOL(PyEval_RestoreThread), SYMBOL(PyGILState_Ensure), SYMBOL(PyGILState_Release),
    SYMBOL(PyGILState_GetThisThreadState), SYMBOL(PyInterpreterState_Main), SYMBOL(PyThreadState_New),
    SYMBOL(PyThreadState_Clear), SYMBOL(PyThreadState_Delete), SYMBOL(PyThreadState_DeleteCurrent),
    SYMBOL(PyImport_ImportModule), SYMBOL(PyObject_GetAttrString), SYMBOL(PyObject_CallObject), SYMBOL(PyObject_Str),
    SYMBOL(PyObject_IsTrue), SYMBOL(PyUnicode_AsUTF8), SYMBOL(PyUnicode_FromString), SYMBOL(PyLong_FromLong),
    SYMBOL(PyLong_AsLong), SYMBOL(PyFloat_FromDouble), SYMBOL(PyFloat_AsDouble), SYMBOL(PyBool_FromLong),
    SYMBOL(PyTuple_New), SYMBOL(PyTuple_SetItem), SYMBOL(PyList_New), SYMBOL(PyList_SetItem), SYMBOL(PyList_Size),
    SYMBOL(PyDict_GetItemString), SYMBOL(PyDict_SetItemString), SYMBOL(PyDict_DelItemString),
    SYMBOL(PyBytes_FromStringAndSize), SYMBOL(PyBytes_AsStringAndSize), SYMBOL(PyErr_Occurred), SYMBOL(PyErr_Fetch),
    SYMBOL(PyErr_Restore), SYMBOL(PyErr_Clear), SYMBOL(Py_DecRef), SYMBOL(Py_IncRef), SYMBOL(PySequence_Size),
    SYMBOL(PySequence_GetItem), SYMBOL(PySys_GetObject), {"_Py_NoneStruct", offsetof(PyApi, None)},
    SYMBOL(Py_IgnoreEnvironmentFlag), SYMBOL(Py_NoSiteFlag), SYMBOL(Py_NoUserSiteDirectory),
    SYMBOL(Py_DontWriteBytecodeFlag),
};

/* PyConfig's leading int fields (Include/cpython/initconfig.h, 3.8 and later). */
enum { CONFIG_INIT, CONFIG_ISOLATED, CONFIG_USE_ENVIRONMENT, CONFIG_DEV_MODE, CONFIG_INSTALL_SIGNAL_HANDLERS };
enum { CONFIG_INIT_COMPAT = 1 };
/* Room for a PyConfig of any version (about 500 bytes in 3.13). */
#define CONFIG_SIZE 8192

static void append(char *text, size_t size, const char *format, ...) {
    size_t used = strlen(text);
    if (used + 1 >= size) return;
    va_list args;
    va_start(args, format);
    vsnprintf(text + used, size - used, format, args);
    va_end(args);
}

/* Fill `py` from `library` (a dlopen handle or RTLD_DEFAULT); the name of a missing symbol, or NULL. */
static const char *resolve(void *library) {
    for (size_t i = 0; i < sizeof SYMBOLS / sizeof SYMBOLS[0]; i++) {
        void *address = dlsym(library, SYMBOLS[i].name);
        if (!address) return SYMBOLS[i].name;
        memcpy((char *)&py + SYMBOLS[i].offset, &address, sizeof address);
    }
    return NULL;
}

static int right_version(const char *version) {
    size_t n = strlen(DSC_PYTHON_VERSION);
    return strncmp(version, DSC_PYTHON_VERSION, n) == 0 && !isdigit((unsigned char)version[n]);
}

static int is_file(const char *path) {
    struct stat info;
    return stat(path, &info) == 0 && S_ISREG(info.st_mode);
}

static int has_stdlib(const char *home) {
    char path[PATH_MAX + 64];
    snprintf(path, sizeof path, "%s/lib/python%s/os.py", home, DSC_PYTHON_VERSION);
    if (!is_file(path)) return 0;
    snprintf(path, sizeof path, "%s/lib/python%s/encodings/__init__.py", home, DSC_PYTHON_VERSION);
    return is_file(path);
}

/* The prefix whose lib/python3.X holds the standard library, searched upward from the library's folder. */
static int home_of_library(char *home, size_t size) {
    Dl_info info;
    if (!dladdr((void *)py.Py_IsInitialized, &info) || !info.dli_fname) return -1;
    char path[PATH_MAX];
    if (!realpath(info.dli_fname, path)) snprintf(path, sizeof path, "%s", info.dli_fname);
    char *slash;
    while ((slash = strrchr(path, '/')) != NULL && slash != path) {
        *slash = '\0';
        if (has_stdlib(path)) {
            snprintf(home, size, "%s", path);
            return 0;
        }
    }
    return -1;
}

/* Py_InitializeEx(0), with the failure returned: -1 with why in start_error. */
static int start_python(const char *what, const char *home) {
    union {
        int fields[CONFIG_SIZE / sizeof(int)];
        max_align_t align;
    } config;
    memset(&config, 0, sizeof config);
    py._PyConfig_InitCompatConfig(&config);
    if (config.fields[CONFIG_INIT] != CONFIG_INIT_COMPAT || config.fields[CONFIG_INSTALL_SIGNAL_HANDLERS] != 1) {
        append(start_error, sizeof start_error, "%s: its PyConfig does not start as CPython 3.8 and later; ", what);
        return -1;
    }
    config.fields[CONFIG_INSTALL_SIGNAL_HANDLERS] = 0;
    start_attempted = 1;
    PyStatus status = py.Py_InitializeFromConfig(&config);
    py.PyConfig_Clear(&config);
    if (status.type != 0 || !py.Py_IsInitialized()) {
        append(start_error, sizeof start_error, "%s (home %s): Python did not start: %s%s%s",
               what, home, status.func ? status.func : "", status.func ? ": " : "",
               status.err_msg ? status.err_msg : "no reason given");
        if (status.type == 2) append(start_error, sizeof start_error, " (exit code %d)", status.exitcode);
        append(start_error, sizeof start_error, "; ");
        return -1;
    }
    py.PyEval_SaveThread();
    return 0;
}

static int initialize(const char *home, const char *what) {
    home_wide = py.Py_DecodeLocale(home, NULL);
    if (!home_wide) {
        append(start_error, sizeof start_error, "%s: cannot decode its home %s; ", what, home);
        return -1;
    }
    py.Py_SetPythonHome(home_wide);
    *py.Py_IgnoreEnvironmentFlag = 1;
    *py.Py_NoSiteFlag = 1;
    *py.Py_NoUserSiteDirectory = 1;
    *py.Py_DontWriteBytecodeFlag = 1;
    return start_python(what, home);
}

/* Use the Python that `library` holds (initialised already, or started here with `home`). */
static int adopt(void *library, const char *home, const char *what) {
    const char *missing = resolve(library);
    if (missing) {
        append(start_error, sizeof start_error, "%s: no symbol %s; ", what, missing);
        return -1;
    }
    void *finalizing = dlsym(library, "Py_IsFinalizing");
    if (!finalizing) finalizing = dlsym(library, "_Py_IsFinalizing");
    memcpy(&is_finalizing, &finalizing, sizeof finalizing);
    const char *version = py.Py_GetVersion();
    if (!right_version(version)) {
        append(start_error, sizeof start_error, "%s: Python %.20s, not %s; ", what, version, DSC_PYTHON_VERSION);
        return -1;
    }
    if (py.Py_IsInitialized()) return 0;
    char found[PATH_MAX];
    if (!home || !*home) {
        if (home_of_library(found, sizeof found) != 0) {
            append(start_error, sizeof start_error, "%s: no lib/python%s standard library above the library; ",
                   what, DSC_PYTHON_VERSION);
            return -1;
        }
        home = found;
    } else if (!has_stdlib(home)) {
        append(start_error, sizeof start_error, "%s: no standard library in %s/lib/python%s; ", what, home,
               DSC_PYTHON_VERSION);
        return -1;
    }
    return initialize(home, what);
}

/* Open `path` privately, check it, then make its symbols global (extension modules such as math
   resolve the C API from the global scope). */
static int try_library(const char *path, const char *home, const char *what) {
    void *library = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (!library) {
        append(start_error, sizeof start_error, "%s %s: %s; ", what, path, dlerror());
        return -1;
    }
    char label[PATH_MAX + 64];
    snprintf(label, sizeof label, "%s %s", what, path);
    if (adopt(library, home, label) != 0) {
        if (!start_attempted) dlclose(library);
        return -1;
    }
    if (!dlopen(path, RTLD_NOW | RTLD_NOLOAD | RTLD_GLOBAL)) {
        append(start_error, sizeof start_error, "%s: its symbols cannot be made global: %s; ", label, dlerror());
        return -1;
    }
    return 0;
}

static void free_ended(Ended *list) {
    while (list) {
        Ended *next = list->next;
        free(list);
        list = next;
    }
}

/* Delete the thread states in `list` (their threads have ended) and free the list. The reaper takes
   the GIL with a thread state of its own for the batch and never uses PyGILState: since 3.12,
   deleting another thread's state unbinds the deleting thread's own, so every state is cleared
   (which may run Python code) before any is deleted. Nothing is touched while Python finalizes or
   after it was started anew (the states belong to an interpreter that is gone). */
static void delete_ended(Ended *list) {
    int alive = py.Py_IsInitialized() && !(is_finalizing && is_finalizing()) &&
                py.PyInterpreterState_Main() == interpreter;
    PyThreadState *own = alive ? py.PyThreadState_New(interpreter) : NULL;
    if (own) {
        py.PyEval_RestoreThread(own);
        for (Ended *e = list; e; e = e->next) py.PyThreadState_Clear(e->state);
        py.PyThreadState_Clear(own);
        for (Ended *e = list; e; e = e->next) py.PyThreadState_Delete(e->state);
        py.PyThreadState_DeleteCurrent();
    }
    free_ended(list);
}

static void *reap(void *unused) {
    pthread_mutex_lock(&ended_lock);
    for (;;) {
        while (!ended) pthread_cond_wait(&ended_signal, &ended_lock);
        Ended *list = ended;
        ended = NULL;
        pthread_mutex_unlock(&ended_lock);
        delete_ended(list);
        pthread_mutex_lock(&ended_lock);
    }
    return NULL;
}

/* Start the reaper, detached, and keep this binary loaded for as long as the process lives: the
   reaper runs its code. Called with ended_lock held. */
static void start_reaper(void) {
    Dl_info self;
    pthread_t thread;
    pthread_attr_t attributes;
    pthread_attr_init(&attributes);
    pthread_attr_setdetachstate(&attributes, PTHREAD_CREATE_DETACHED);
    if (dladdr((void *)reap, &self) && self.dli_fname &&
        dlopen(self.dli_fname, RTLD_NOW | RTLD_NOLOAD | RTLD_NODELETE) &&
        pthread_create(&thread, &attributes, reap, NULL) == 0) {
        reaper_started = 1;
    }
    pthread_attr_destroy(&attributes);
}

/* At the end of a host thread that has a thread state of this binary's: hand it to the reaper
   (without the GIL; if the reaper cannot start, the thread state is left). */
static void forget_thread(void *state) {
    Ended *entry = malloc(sizeof *entry);
    if (!entry) return;
    entry->state = state;
    pthread_mutex_lock(&ended_lock);
    if (!reaper_started) start_reaper();
    entry->next = ended;
    ended = entry;
    pthread_cond_signal(&ended_signal);
    pthread_mutex_unlock(&ended_lock);
}

/* The binary unloaded (never once the reaper runs): thread states of threads still running are left
   to them, never to a destructor that is gone. */
__attribute__((destructor)) static void unload(void) {
    if (thread_key_made) pthread_key_delete(thread_key);
}

static int find_and_start(void) {
    if (dlsym(RTLD_DEFAULT, "Py_IsInitialized")) return adopt(RTLD_DEFAULT, NULL, "the Python in this process");
    const char *override = getenv(OVERRIDE_VARIABLE);
    if (override && *override) return try_library(override, NULL, OVERRIDE_VARIABLE " =");
    append(start_error, sizeof start_error, OVERRIDE_VARIABLE " not set; ");
    if (*DSC_BUILD_LIBPYTHON && try_library(DSC_BUILD_LIBPYTHON, DSC_BUILD_PYTHON_HOME, "the Python that built the FMU,") == 0) {
        return 0;
    }
    if (!*DSC_BUILD_LIBPYTHON) append(start_error, sizeof start_error, "the Python that built the FMU has no shared library; ");
    if (start_attempted) return -1;
    return try_library(DSC_PYTHON_SONAME, NULL, "the system's");
}

static void before_fork(void) {
    pthread_mutex_lock(&ended_lock);
}

static void after_fork_in_parent(void) {
    pthread_mutex_unlock(&ended_lock);
}

/* In a forked child the reaper is gone and the ended threads' states are not its to delete: start afresh. */
static void after_fork_in_child(void) {
    Ended *list = ended;
    ended = NULL;
    reaper_started = 0;
    pthread_mutex_init(&ended_lock, NULL);
    pthread_cond_init(&ended_signal, NULL);
    free_ended(list);
}

static void start_once(void) {
    start_error[0] = '\0';
    start_result = find_and_start();
    if (start_result != 0) return;
    interpreter = py.PyInterpreterState_Main();
    thread_key_made = pthread_key_create(&thread_key, forget_thread) == 0 &&
                      pthread_atfork(before_fork, after_fork_in_parent, after_fork_in_child) == 0;
}

int pyhost_start(char *error, size_t size) {
    pthread_once(&once, start_once);
    if (start_result != 0) {
        snprintf(error, size, "no usable Python %s: %sset " OVERRIDE_VARIABLE " to the path of a libpython%s shared library",
                 DSC_PYTHON_VERSION, start_error, DSC_PYTHON_VERSION);
    }
    return start_result;
}

/* A thread Python does not know: a thread state of its own, kept until the thread ends. */
static void adopt_thread(void) {
    py.PyGILState_Ensure();
    PyThreadState *state = py.PyEval_SaveThread();
    if (thread_key_made) pthread_setspecific(thread_key, state);
}

PyGILState_STATE pyhost_enter(void) {
    if (!py.PyGILState_GetThisThreadState()) adopt_thread();
    return py.PyGILState_Ensure();
}

void pyhost_leave(PyGILState_STATE state) {
    py.PyGILState_Release(state);
}
