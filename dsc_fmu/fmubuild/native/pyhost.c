/* The Python runtime that runs the model code: found, loaded and started at run time, never linked.

   Any CPython from 3.9 on will do (the bundled Python code is version-neutral). The binary calls only public
   functions, and only those the path it takes needs: adopting a running CPython resolves what the model's calls
   use (pyhost.h), starting one also what starting that version takes; where a CPython offers the replacement of
   a deprecated function, the replacement is used. A missing symbol is named with the CPython's version and file.
   Order (docs/other-tools.md, "What the importing machine needs"):
     0. a CPython already in the process (fmpy, libcosimpy, PyFMI): used as it is;
     1. DSC_FMU_PYTHON, if set, the only place looked at: the path of a CPython shared library
        (libpython3.X.so.1.0, libpython3.X.dylib or a framework's Python, python3X.dll), or a folder: an
        installation's (platform_library_in: on Linux and macOS its prefix, whose lib/ holds the library,
        on macOS also a framework's version folder; on Windows the folder of python3X.dll), or a virtual
        environment's, which stands for the installation its pyvenv.cfg names (`home`, or on Linux and
        macOS home's parent) and for the version it names (`version`, or virtualenv's `version_info`);
     2. the FMU's own CPython (`dsc-fmu build --bundle-python`), if the folder ROOT = `python` beside
        this binary's file exists, the only place looked at then: ROOT/bundle.txt lists every other
        file of ROOT with its size, all checked before anything is loaded; the library is ROOT's
        (lib/libpython3.X.so.1.0 on Linux, python3X.dll on Windows) and its home ROOT (on Linux
        lib/python3X.zip and lib/python3.X/lib-dynload under it, and the libraries its extension
        modules need in lib/, loaded first; on Windows python3X._pth fixes the paths, and the DLLs
        beside a .pyd are found there). If any of that fails, nothing else is tried: a damaged FMU is reported, not masked by
        whatever Python the machine happens to have, and a CPython whose start failed cannot be
        unloaded to make room for another;
     3. the Python that built the FMU (DSC_BUILD_LIBPYTHON, its home DSC_BUILD_PYTHON_HOME), where it
        exists;
     4. the system's: on Linux libpython3.X.so.1.0 by the dynamic loader's search; on macOS the
        installers' places (python.org, Homebrew, conda, pyenv, Xcode), then libpython3.X.dylib by the
        dynamic loader's search; on Windows the installs registered under PEP 514, then the folders on
        PATH (platform.h).
   Among the candidates of a folder, 3 and 4, those of the minor version that built the FMU come first,
   then the newest. Every CPython 3 is looked for, older ones too: one older than 3.9 is refused before
   it starts, and named with its version in the message if nothing serves.
   A Python this binary starts has the isolated configuration meant for embedding (PYTHON* environment
   variables ignored, the host's locale and signal handlers left alone, no user site), in UTF-8 mode (paths are
   UTF-8 whatever the host's locale), imports no site packages, writes no bytecode, and gets its home set
   explicitly (an embeddable CPython on Windows: the paths its python3X._pth fixes); its symbols are made
   global before it starts (on Linux the extension modules it may load while starting, zlib for a compressed
   zip, resolve the C API there). From 3.14 on that is PEP 741's PyInitConfig; before, PEP 587's PyPreConfig
   and PyConfig, whose fields are set at the offsets of the CPython's version (CONFIG_LAYOUTS), checked first
   against what the CPython's own initialisers write. Either says why a start failed where Py_Initialize would
   end the process. The search runs once per process, on whichever host thread calls first, whose stack may be
   small: its path buffers are static.

   A host thread Python does not know gets a thread state on its first call, kept for its life. When
   the thread ends, its thread state is handed to the reaper, a thread of this binary's that deletes
   it: thread pools cost nothing once their threads are gone. The ending thread cannot delete it
   itself: that needs the GIL, and a host that joins its threads while holding the GIL (a Python
   extension's destructor, a thread pool's) would wait for ever. */

#include "pyhost.h"

#include <ctype.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "platform.h"

#if !defined(DSC_PYTHON_VERSION) || !defined(DSC_OVERRIDE_VARIABLE)
#error DSC_PYTHON_VERSION (for example "3.11") and DSC_OVERRIDE_VARIABLE ("DSC_FMU_PYTHON") must be defined
#endif
#ifndef DSC_BUILD_LIBPYTHON
#define DSC_BUILD_LIBPYTHON ""
#endif
#ifndef DSC_BUILD_PYTHON_HOME
#define DSC_BUILD_PYTHON_HOME ""
#endif

#define OLDEST_MINOR 9
#define OLDEST_LOOKED_FOR 0 /* older than OLDEST_MINOR: looked for, to be named if nothing serves */
#define BUNDLE_FOLDER "python"           /* ROOT, beside this binary's file */
#define BUNDLE_LIST "bundle.txt"         /* in ROOT: the header line, then "<size> <path>" per file */
#define BUNDLE_HEADER "dsc-fmu CPython " /* then "<version> <os>" */

PyApi py;

static int start_result = -1;
static int start_attempted; /* a library on which Py_InitializeFromConfig ran stays loaded, whatever it said */

/* Thread states of host threads that ended, for the reaper. */
typedef struct Ended {
    struct Ended *next;
    PyThreadState *state;
} Ended;
static Ended *ended;
static int reaper_started; /* one reaper for each loaded copy of this binary (each FMU's file) */
static PyInterpreterState *interpreter; /* the one whose thread states this binary makes */
static int (*is_finalizing)(void);      /* Py_IsFinalizing (3.13) or _Py_IsFinalizing, where exported */
static char start_error[4096];
static char not_found[1024]; /* the system's candidates that are not there, named once at the end */
static wchar_t *home_wide;

/* A Python to try: its shared library, its home ("" to look for it), what to call it ("" for one
   of the system's: named among those not found if it cannot be loaded), its minor version as its
   name or registration tells it (-1 if they do not). */
typedef struct {
    char library[PLATFORM_PATH_MAX];
    char home[PLATFORM_PATH_MAX];
    char label[PLATFORM_PATH_MAX + 64];
    int minor;
} Candidate;

typedef struct {
    Candidate **items; /* each malloc'ed, as the list */
    int count;
} Candidates;

typedef struct {
    const char *name;
    size_t offset;
} Symbol;

#define SYMBOL_OF_FUNCTION(type, name, parameters) {#name, offsetof(PyApi, name)},
#define SYMBOL_OF_DATA(type, name, symbol) {#symbol, offsetof(PyApi, name)},
static const Symbol CALLS[] = {PY_CALLS(SYMBOL_OF_FUNCTION, SYMBOL_OF_DATA)};
static const Symbol RAISED[] = {PY_RAISED(SYMBOL_OF_FUNCTION)};
static const Symbol FETCHED[] = {PY_FETCHED(SYMBOL_OF_FUNCTION)};
static const Symbol INIT_CONFIG[] = {PY_START_INIT_CONFIG(SYMBOL_OF_FUNCTION)};
static const Symbol CONFIG[] = {PY_START_CONFIG(SYMBOL_OF_FUNCTION)};
#define COUNT(array) (sizeof array / sizeof array[0])

#define INIT_CONFIG_MINOR 14 /* PEP 741's PyInitConfig from here on, PEP 587's PyConfig before */
#define RAISED_MINOR 12      /* PyErr_GetRaisedException */
#define CONSTANT_MINOR 13    /* Py_GetConstantBorrowed, Py_IsFinalizing */
#define Py_CONSTANT_NONE 0

/* Where PyConfig (Include/cpython/initconfig.h) keeps the fields set here, CPython 3.9 to 3.13, as
   offsets in bytes: on Windows (LLP64, where `hash_seed` is 4 bytes and `legacy_windows_stdio` comes
   before `check_hash_pycs_mode`) and elsewhere (LP64). The leading ints (`isolated`, `use_environment`)
   sit where they do in every version. Checked against every version's header by the tests, and at run
   time against what PyConfig_InitIsolatedConfig and PyConfig_InitPythonConfig write. */
typedef struct {
    int parse_argv, site_import, write_bytecode, user_site_directory, configure_c_stdio, home;
} ConfigLayout;
#ifdef _WIN32
static const ConfigLayout CONFIG_LAYOUTS[] = {
    [9] = {80, 144, 168, 180, 184, 240},  [10] = {80, 152, 180, 192, 196, 264},
    [11] = {96, 168, 196, 208, 212, 288}, [12] = {96, 168, 196, 208, 212, 288},
    [13] = {96, 168, 196, 208, 212, 296},
};
#else
static const ConfigLayout CONFIG_LAYOUTS[] = {
    [9] = {88, 152, 176, 188, 192, 240},  [10] = {80, 152, 180, 192, 196, 256},
    [11] = {96, 168, 196, 208, 212, 280}, [12] = {104, 176, 204, 216, 220, 288},
    [13] = {104, 176, 204, 216, 220, 296},
};
#endif
enum { CONFIG_ISOLATED = sizeof(int), CONFIG_USE_ENVIRONMENT = 2 * sizeof(int) }; /* the same in every layout */
enum { PRECONFIG_UTF8_MODE_LP64 = 7, PRECONFIG_UTF8_MODE_WINDOWS = 8 }; /* int fields of PyPreConfig */
/* Room for a PyConfig or PyPreConfig of any version (448 bytes in 3.13). */
#define CONFIG_SIZE 8192

static void append(char *text, size_t size, const char *format, ...) {
    size_t used = strlen(text);
    if (used + 1 >= size) return;
    va_list args;
    va_start(args, format);
    vsnprintf(text + used, size - used, format, args);
    va_end(args);
}

/* The symbol `name` of `library`, or NULL. A test build treats the names in DSC_ABSENT_SYMBOLS (separated
   by spaces) as absent, as a CPython that removed them would. */
static void *symbol(Library library, const char *name) {
#ifdef DSC_ABSENT_SYMBOLS
    static const char absent[] = DSC_ABSENT_SYMBOLS;
    size_t length = strlen(name);
    for (const char *p = strstr(absent, name); p; p = strstr(p + 1, name)) {
        if ((p == absent || p[-1] == ' ') && (p[length] == ' ' || p[length] == '\0')) return NULL;
    }
#endif
    return platform_symbol(library, name);
}

/* Fill the fields of `py` that `symbols` name from `library`; the name of the first missing one, or NULL. */
static const char *resolve(Library library, const Symbol *symbols, size_t count) {
    for (size_t i = 0; i < count; i++) {
        void *address = symbol(library, symbols[i].name);
        if (!address) return symbols[i].name;
        memcpy((char *)&py + symbols[i].offset, &address, sizeof address);
    }
    return NULL;
}

/* The minor version of a CPython 3 version string ("3.11.7 (main, ...)"), or -1. */
static int minor_of(const char *version) {
    if (strncmp(version, "3.", 2) != 0 || !isdigit((unsigned char)version[2])) return -1;
    return atoi(version + 2);
}

/* What Py_GetVersion of `library` says ("3.11.7 (main, ...)"), or NULL if it has none: callable before the
   CPython starts. */
static const char *version_of(Library library) {
    const char *(*get_version)(void);
    void *address = symbol(library, "Py_GetVersion");
    memcpy(&get_version, &address, sizeof address);
    return address ? get_version() : NULL;
}

/* The one message of the CPython in `library` (which has Py_GetVersion), named `what`, without the symbol
   `missing`: its version and file. */
static void missing_symbol(Library library, const char *what, const char *missing) {
    static char file[PLATFORM_PATH_MAX];
    const char *version = version_of(library);
    append(start_error, sizeof start_error, "%s: CPython %.*s", what, (int)strcspn(version, " "), version);
    if (platform_library_file(symbol(library, "Py_GetVersion"), file, sizeof file) == 0) {
        append(start_error, sizeof start_error, " in %s", file);
    }
    append(start_error, sizeof start_error, " has no symbol %s; ", missing);
}

/* What Python failed to start with: `status`, or PyInitConfig's message and exit code (`message`, `exit`). */
static void not_started(const char *what, const char *home, const char *function, const char *message, int exit,
                        int exitcode) {
    append(start_error, sizeof start_error, "%s (home %s): Python did not start: %s%s%s", what, home,
           function ? function : "", function ? ": " : "", message ? message : "no reason given");
    if (exit) append(start_error, sizeof start_error, " (exit code %d)", exitcode);
    append(start_error, sizeof start_error, "; ");
}

/* Start CPython 3.14 or newer through PEP 741's PyInitConfig: isolated, UTF-8 mode, no site, no bytecode,
   and `home` unless NULL; 0, or -1 (logged as `what`). */
static int start_with_init_config(const char *what, const char *home) {
    PyInitConfig *config = py.PyInitConfig_Create();
    if (!config) {
        append(start_error, sizeof start_error, "%s: PyInitConfig_Create failed (no memory); ", what);
        return -1;
    }
    int set = py.PyInitConfig_SetInt(config, "utf8_mode", 1) == 0
              && py.PyInitConfig_SetInt(config, "site_import", 0) == 0
              && py.PyInitConfig_SetInt(config, "write_bytecode", 0) == 0
              && (!home || py.PyInitConfig_SetStr(config, "home", home) == 0);
    if (set) start_attempted = 1;
    int result = set && py.Py_InitializeFromInitConfig(config) == 0 && py.Py_IsInitialized() ? 0 : -1;
    if (result != 0) {
        const char *message = NULL;
        int exitcode = 0, exit = py.PyInitConfig_GetExitCode(config, &exitcode) == 1;
        py.PyInitConfig_GetError(config, &message);
        not_started(what, home ? home : "fixed by its ._pth file",
                    set ? "Py_InitializeFromInitConfig" : "PyInitConfig_Set",
                    message, exit, exitcode);
    }
    py.PyInitConfig_Free(config);
    return result;
}

/* A configuration's int and string pointer at an offset in bytes. */
#define INT_AT(config, offset) (*(int *)((char *)(config) + (offset)))
#define POINTER_AT(config, offset) (*(wchar_t **)((char *)(config) + (offset)))

/* PyConfig_InitIsolatedConfig and PyConfig_InitPythonConfig wrote what they write at the offsets of
   `layout`: the layout is this CPython's. */
static int layout_holds(const ConfigLayout *layout, void *isolated, void *python) {
    return INT_AT(isolated, CONFIG_ISOLATED) == 1 && INT_AT(isolated, CONFIG_USE_ENVIRONMENT) == 0
           && INT_AT(isolated, layout->parse_argv) == 0 && INT_AT(python, layout->parse_argv) == 1
           && INT_AT(isolated, layout->user_site_directory) == 0 && INT_AT(python, layout->user_site_directory) == 1
           && INT_AT(isolated, layout->configure_c_stdio) == 0 && INT_AT(python, layout->configure_c_stdio) == 1
           && INT_AT(isolated, layout->site_import) == 1 && INT_AT(isolated, layout->write_bytecode) == 1
           && !POINTER_AT(isolated, layout->home) && !POINTER_AT(python, layout->home);
}

typedef union {
    int fields[CONFIG_SIZE / sizeof(int)];
    max_align_t align;
} ConfigMemory;

/* Start CPython 3.9 to 3.13 through PEP 587's PyPreConfig and PyConfig, as start_with_init_config does;
   0, or -1 (logged as `what`). */
static int start_with_config(const char *what, const char *home, int minor) {
    static ConfigMemory preconfig, config, python;
    const ConfigLayout *layout = minor < (int)COUNT(CONFIG_LAYOUTS) ? &CONFIG_LAYOUTS[minor] : NULL;
    if (!layout || !layout->home) {
        append(start_error, sizeof start_error, "%s: no PyConfig layout of CPython 3.%d is known; ", what, minor);
        return -1;
    }
    py.PyConfig_InitIsolatedConfig(&config);
    py.PyConfig_InitPythonConfig(&python);
    int holds = layout_holds(layout, &config, &python);
    py.PyConfig_Clear(&python);
    if (!holds) {
        py.PyConfig_Clear(&config);
        append(start_error, sizeof start_error, "%s: its PyConfig is not laid out as CPython 3.%d's (a free-threaded "
               "or debug build?); ", what, minor);
        return -1;
    }
    py.PyPreConfig_InitIsolatedConfig(&preconfig);
#ifdef _WIN32
    preconfig.fields[PRECONFIG_UTF8_MODE_WINDOWS] = 1;
#else
    preconfig.fields[PRECONFIG_UTF8_MODE_LP64] = 1;
#endif
    PyStatus status = py.Py_PreInitialize(&preconfig);
    home_wide = home && status.type == 0 ? platform_wide_path(home, py.Py_DecodeLocale) : NULL;
    if (status.type == 0 && home && !home_wide) {
        append(start_error, sizeof start_error, "%s: cannot decode its home %s; ", what, home);
        py.PyConfig_Clear(&config);
        return -1;
    }
    if (home_wide) status = py.PyConfig_SetString(&config, &POINTER_AT(&config, layout->home), home_wide);
    INT_AT(&config, layout->site_import) = 0;
    INT_AT(&config, layout->write_bytecode) = 0;
    start_attempted = 1;
    if (status.type == 0) status = py.Py_InitializeFromConfig(&config);
    py.PyConfig_Clear(&config);
    if (status.type != 0 || !py.Py_IsInitialized()) {
        not_started(what, home ? home : "fixed by its ._pth file", status.func, status.err_msg, status.type == 2,
                    status.exitcode);
        return -1;
    }
    return 0;
}

/* Start the CPython 3.`minor` resolved in `library`, with `home` (NULL: the paths its installation's
   ._pth file fixes, which a home set here would override), and release the GIL; 0, or -1 (logged). */
static int start_python(Library library, int minor, const char *what, const char *home) {
    int with_init_config = minor >= INIT_CONFIG_MINOR;
    const char *missing = with_init_config ? resolve(library, INIT_CONFIG, COUNT(INIT_CONFIG))
                                           : resolve(library, CONFIG, COUNT(CONFIG));
    if (missing) {
        missing_symbol(library, what, missing);
        return -1;
    }
    int result = with_init_config ? start_with_init_config(what, home) : start_with_config(what, home, minor);
    if (result == 0) py.PyEval_SaveThread();
    return result;
}

/* The minor version of the CPython in `library`, asked before anything else is resolved, so that one too
   old for the rest is named with its version; -1 (logged as `what`) if it is older than 3.OLDEST_MINOR or
   says none. */
static int old_version(Library library, const char *what) {
    const char *version = version_of(library);
    if (!version) {
        append(start_error, sizeof start_error, "%s: no symbol Py_GetVersion (not a CPython library); ", what);
        return -1;
    }
    int minor = minor_of(version);
    if (minor < OLDEST_MINOR) {
        append(start_error, sizeof start_error, "%s: Python %.*s, older than 3.%d; ", what, (int)strcspn(version, " "),
               version, OLDEST_MINOR);
        return -1;
    }
    return minor;
}

/* Resolve what every use calls, the exception API of this version, and where Python finalizes (Py_IsFinalizing
   from 3.13, _Py_IsFinalizing before where exported), into a `py` cleared of any earlier candidate's; the name
   of the first missing symbol, or NULL. */
static const char *resolve_calls(Library library, int minor) {
    memset(&py, 0, sizeof py); /* nothing of a candidate tried before, which may be unloaded */
    const char *missing = resolve(library, CALLS, COUNT(CALLS));
    if (!missing) {
        missing = minor >= RAISED_MINOR ? resolve(library, RAISED, COUNT(RAISED))
                                        : resolve(library, FETCHED, COUNT(FETCHED));
    }
    void *finalizing = symbol(library, minor >= CONSTANT_MINOR ? "Py_IsFinalizing" : "_Py_IsFinalizing");
    memcpy(&is_finalizing, &finalizing, sizeof finalizing);
    return missing;
}

/* None, once Python runs; 0, or -1 (logged as `what`). */
static int resolve_none(Library library, int minor, const char *what) {
    if (minor >= CONSTANT_MINOR) {
        PyObject *(*constant)(unsigned int);
        void *address = symbol(library, "Py_GetConstantBorrowed");
        memcpy(&constant, &address, sizeof address);
        py.None = address ? constant(Py_CONSTANT_NONE) : NULL;
    } else {
        py.None = symbol(library, "_Py_NoneStruct");
    }
    if (py.None) return 0;
    missing_symbol(library, what, minor >= CONSTANT_MINOR ? "Py_GetConstantBorrowed" : "_Py_NoneStruct");
    return -1;
}

/* Make the symbols of the library loaded from `path` (NULL: one already global) visible to those loaded
   later: extension modules resolve the C API from the global scope on Linux, zlib already while CPython
   starts if its standard library is a compressed zip. 0, or -1 (logged as `what`). */
static int share(const char *path, const char *what) {
    char why[512];
    if (!path || platform_share_symbols(path, why, sizeof why) == 0) return 0;
    append(start_error, sizeof start_error, "%s: its symbols cannot be made global: %s; ", what, why);
    return -1;
}

/* Use the Python that `library` (loaded from `path`, NULL if global already) holds: initialised already,
   or started here with `home`, found from the library's file if empty. Its symbols are made global only
   once it is the one to use (a library made global stays loaded). */
static int adopt(Library library, const char *path, const char *home, const char *what) {
    int minor = old_version(library, what);
    if (minor < 0) return -1;
    const char *missing = resolve_calls(library, minor);
    if (missing) {
        missing_symbol(library, what, missing);
        return -1;
    }
    if (py.Py_IsInitialized()) return share(path, what) == 0 ? resolve_none(library, minor, what) : -1;
    static char file[PLATFORM_PATH_MAX], found[PLATFORM_PATH_MAX], why[256];
    why[0] = '\0';
    if (platform_library_file((const void *)py.Py_IsInitialized, file, sizeof file) != 0) file[0] = '\0';
    int layout = platform_python_home(file, home, minor, found, sizeof found, why, sizeof why);
    if (layout < 0) {
        append(start_error, sizeof start_error, "%s: %s; ", what, why);
        return -1;
    }
    if (share(path, what) != 0) return -1;
    if (start_python(library, minor, what, layout == HOME_TO_SET ? found : NULL) != 0) return -1;
    return resolve_none(library, minor, what);
}

/* Load, check and start the candidate. */
static int try_candidate(const Candidate *candidate) {
    static char label[3 * PLATFORM_PATH_MAX + 64], why[512], file[PLATFORM_PATH_MAX];
    why[0] = '\0';
    snprintf(label, sizeof label, "%s %s", *candidate->label ? candidate->label : "the system's", candidate->library);
    Library library = platform_load(candidate->library, why, sizeof why);
    if (!library && !*candidate->label) {
        if (candidate->minor >= OLDEST_MINOR) {
            append(not_found, sizeof not_found, "%s%s", *not_found ? ", " : "", candidate->library);
        }
        return -1;
    }
    void *version = library && !*candidate->label ? platform_symbol(library, "Py_GetVersion") : NULL;
    if (version && platform_library_file(version, file, sizeof file) == 0) {
        append(label, sizeof label, " (%s)", file); /* the loader found it: where */
    }
    if (!library) {
        append(start_error, sizeof start_error, "%s: %s; ", label, why);
        return -1;
    }
    if (adopt(library, candidate->library, candidate->home, label) != 0) {
        if (!start_attempted) platform_unload(library);
        return -1;
    }
    return 0;
}

static void add_candidate(void *context, const char *library, const char *home, const char *label, int minor) {
    Candidates *list = context;
    for (int i = 0; i < list->count; i++) {
        if (strcmp(list->items[i]->library, library) == 0) return;
    }
    Candidate **more = realloc(list->items, (size_t)(list->count + 1) * sizeof *more);
    if (more) list->items = more;
    Candidate *c = more ? malloc(sizeof *c) : NULL;
    if (!c) {
        append(start_error, sizeof start_error, "out of memory listing %s; ", library);
        return;
    }
    list->items[list->count++] = c;
    snprintf(c->library, sizeof c->library, "%s", library);
    snprintf(c->home, sizeof c->home, "%s", home ? home : "");
    snprintf(c->label, sizeof c->label, "%s", label);
    c->minor = minor;
}

/* The candidates in turn, until one starts or one has been started (and failed); 0, or -1. */
static int try_in_turn(const Candidates *list) {
    for (int i = 0; i < list->count && !start_attempted; i++) {
        if (try_candidate(list->items[i]) == 0) return 0;
    }
    return -1;
}

/* The candidates of the minor version that built the FMU first; the rest in the order found. */
static void prefer_building_minor(Candidates *list) {
    int preferred = minor_of(DSC_PYTHON_VERSION), first = 0;
    for (int i = 0; i < list->count; i++) {
        if (list->items[i]->minor != preferred) continue;
        Candidate *moved = list->items[i];
        memmove(&list->items[first + 1], &list->items[first], (size_t)(i - first) * sizeof moved);
        list->items[first++] = moved;
    }
}

/* The Python that built the FMU, then the system's. */
static void gather(Candidates *list) {
    if (*DSC_BUILD_LIBPYTHON) {
        add_candidate(list, DSC_BUILD_LIBPYTHON, DSC_BUILD_PYTHON_HOME, "the Python that built the FMU,",
                      minor_of(DSC_PYTHON_VERSION));
    } else {
        append(start_error, sizeof start_error, "the Python that built the FMU is not on this system; ");
    }
    platform_registered_pythons(add_candidate, list, OLDEST_LOOKED_FOR);
    prefer_building_minor(list);
}

/* The value of `key` in a line "key = value" of pyvenv.cfg, trimmed, in `value`; 1 if the line has it. */
static int venv_value(const char *line, const char *key, char *value, size_t size) {
    const char *p = line + strspn(line, " \t");
    size_t length = strlen(key);
    if (strncmp(p, key, length) != 0) return 0;
    p += length + strspn(p + length, " \t");
    if (*p != '=') return 0;
    p += 1 + strspn(p + 1, " \t");
    length = strlen(p);
    while (length > 0 && isspace((unsigned char)p[length - 1])) length--;
    snprintf(value, size, "%.*s", (int)length, p);
    return 1;
}

/* The virtual environment in `folder`: its pyvenv.cfg's `home`, and in `minor` the minor version its `version`
   (the venv module's) or `version_info` (virtualenv's, uv's) names, -1 if neither does; 1 if there is one. */
static int venv_home(const char *folder, char *home, size_t size, int *minor) {
    static char path[PLATFORM_PATH_MAX + 16], line[PLATFORM_PATH_MAX + 16];
    char version[64] = "";
    snprintf(path, sizeof path, "%s/pyvenv.cfg", folder);
    FILE *file = platform_open_file(path, "r");
    if (!file) return 0;
    *home = '\0';
    while (fgets(line, sizeof line, file)) {
        if (!venv_value(line, "home", home, size) && !venv_value(line, "version", version, sizeof version)) {
            venv_value(line, "version_info", version, sizeof version);
        }
    }
    fclose(file);
    *minor = minor_of(version);
    return *home != '\0';
}

/* The CPython libraries of the installation in `folder`, newest first, of the minor version `only` (every one
   if -1), each called `label` and started with `home` (NULL: the home found from the library's file). */
static void add_installation(Candidates *list, const char *folder, const char *home, const char *label, int only) {
    static char library[PLATFORM_PATH_MAX];
    for (int minor = NEWEST_MINOR; minor >= OLDEST_LOOKED_FOR; minor--) {
        if (only >= 0 && minor != only) continue;
        for (int place = 0; platform_library_in(folder, place, minor, library, sizeof library) == 0; place++) {
            if (platform_is_file(library)) add_candidate(list, library, home, label, minor);
        }
    }
}

/* The candidates of the folder that DSC_FMU_PYTHON names: its installation's, or those of the installation
   its virtual environment names (home, and home's parent: on Linux and macOS home is the installation's bin),
   of the environment's version only. */
static void gather_folder(Candidates *list, const char *folder, int *venv_minor) {
    static char home[PLATFORM_PATH_MAX];
    const char *label = DSC_OVERRIDE_VARIABLE " folder:";
    *venv_minor = -1;
    if (!venv_home(folder, home, sizeof home, venv_minor)) {
        add_installation(list, folder, NULL, label, -1);
    } else {
        add_installation(list, home, NULL, label, *venv_minor);
        char *separator = strrchr(home, '/'), *other = strrchr(home, '\\');
        if (other > separator) separator = other;
        if (separator && separator != home) {
            *separator = '\0';
            add_installation(list, home, NULL, label, *venv_minor);
        }
    }
    prefer_building_minor(list);
}

/* `pattern` with every "%d" written "X", appended to start_error. */
static void append_pattern(const char *pattern) {
    for (const char *p = pattern; *p; p++) {
        int minor = p[0] == '%' && p[1] == 'd';
        append(start_error, sizeof start_error, "%c", minor ? 'X' : *p);
        p += minor;
    }
}

/* The candidates of the folder `folder` tried in turn; -1 (logged) if none serves or there is none. */
static int start_from_folder(Candidates *list, const char *folder) {
    int venv_minor;
    gather_folder(list, folder, &venv_minor);
    if (list->count == 0 && venv_minor >= 0) {
        append(start_error, sizeof start_error, DSC_OVERRIDE_VARIABLE " = %s: a virtual environment of CPython 3.%d "
               "(its pyvenv.cfg), whose installation has no CPython 3.%d library (looked for ", folder, venv_minor,
               venv_minor);
        append_pattern(PLATFORM_LIBRARY_PLACES);
        append(start_error, sizeof start_error, " in its home and the home's parent); ");
        return -1;
    }
    if (list->count == 0) {
        append(start_error, sizeof start_error, DSC_OVERRIDE_VARIABLE " = %s: a folder without a CPython library "
               "(looked for ", folder);
        append_pattern(PLATFORM_LIBRARY_PLACES);
        append(start_error, sizeof start_error, " in it, or in the installation its pyvenv.cfg names); ");
        return -1;
    }
    return try_in_turn(list);
}

/* ROOT, the folder `python` beside this binary's file, in `root`, and the separator of that file's path;
   1 if ROOT is a folder. */
static int bundle_root(char *root, size_t size, char *separator) {
    static char file[PLATFORM_PATH_MAX];
    if (platform_library_file((const void *)bundle_root, file, sizeof file) != 0) {
        append(start_error, sizeof start_error, "this binary's own file is unknown, so is the FMU's own CPython; ");
        return 0;
    }
    char *slash = strrchr(file, '/'), *other = strrchr(file, '\\');
    if (other > slash) slash = other;
    if (!slash) return 0;
    *separator = *slash;
    snprintf(root, size, "%.*s%c" BUNDLE_FOLDER, (int)(slash - file), file, *separator);
    return platform_is_folder(root);
}

/* The first line of bundle.txt names a CPython for this system; 0, or -1 (logged as `what`). */
static int check_header(FILE *list, const char *what) {
    char line[256], version[64], os[64];
    if (!fgets(line, sizeof line, list)) {
        append(start_error, sizeof start_error, "%s: " BUNDLE_LIST " is empty; ", what);
        return -1;
    }
    if (sscanf(line, BUNDLE_HEADER "%63s %63s", version, os) == 2 && strcmp(os, PLATFORM_OS) == 0) return 0;
    append(start_error, sizeof start_error, "%s: the first line of " BUNDLE_LIST " is not \"" BUNDLE_HEADER
           "<version> %s\"; ", what, PLATFORM_OS);
    return -1;
}

/* The libraries beside a bundled CPython that its extension modules need (on Linux lib/lib*.so*, but
   libpython), loaded before it starts so that the loader finds them by soname. */
static char **preloads;
static int preload_count;

/* `path` kept in `preloads`; 0, or -1 (logged as `what`) out of memory. */
static int add_preload(const char *path, const char *what) {
    size_t size = strlen(path) + 1;
    char **more = realloc(preloads, (size_t)(preload_count + 1) * sizeof *more);
    if (more) preloads = more;
    char *copy = more ? malloc(size) : NULL;
    if (!copy) {
        append(start_error, sizeof start_error, "%s: out of memory listing the libraries to load first; ", what);
        return -1;
    }
    preloads[preload_count++] = memcpy(copy, path, size);
    return 0;
}

/* A file of the bundle to load before CPython starts: lib/lib*.so* but libpython. */
static int is_preload(const char *path) {
    return strncmp(path, "lib/lib", 7) == 0 && strstr(path, ".so") && strncmp(path, "lib/libpython", 13) != 0;
}

/* Every later line of bundle.txt, "<size> <path>" (empty lines skipped): the file <path> of `root` is there
   with that size, and at least one is listed; the libraries to load first are kept in `preloads`. 0, or -1
   (logged as `what`) at the first line that fails. */
static int check_files(FILE *list, const char *root, char separator, const char *what) {
    static char line[PLATFORM_PATH_MAX + 32], path[2 * PLATFORM_PATH_MAX + 32];
    int files = 0;
    for (int number = 2; fgets(line, sizeof line, list); number++) {
        size_t length = strcspn(line, "\r\n");
        int whole = line[length] != '\0' || feof(list);
        line[length] = '\0';
        if (whole && length == 0) continue;
        char *end;
        long long listed = strtoll(line, &end, 10);
        if (!whole || end == line || listed < 0 || *end != ' ' || !end[1]) {
            append(start_error, sizeof start_error, "%s: line %d of " BUNDLE_LIST " is not \"<size> <path>\": %.200s; ",
                   what, number, line);
            return -1;
        }
        snprintf(path, sizeof path, "%s%c%s", root, separator, end + 1);
        long long size = platform_file_size(path);
        if (size < 0) {
            append(start_error, sizeof start_error, "%s: %s is missing (" BUNDLE_LIST " lists it with %lld bytes); ",
                   what, end + 1, listed);
            return -1;
        }
        if (size != listed) {
            append(start_error, sizeof start_error, "%s: %s has %lld bytes where " BUNDLE_LIST " says %lld; ", what,
                   end + 1, size, listed);
            return -1;
        }
        if (is_preload(end + 1) && add_preload(path, what) != 0) return -1;
        files++;
    }
    if (ferror(list)) {
        append(start_error, sizeof start_error, "%s: " BUNDLE_LIST " cannot be read to its end; ", what);
        return -1;
    }
    if (files > 0) return 0;
    append(start_error, sizeof start_error, "%s: " BUNDLE_LIST " lists no file; ", what);
    return -1;
}

/* Load the libraries of `preloads`, each kept for the process's life, in as many rounds as it takes for
   those that need one another; 0, or -1 (logged as `what`) if one does not load. */
static int load_preloads(const char *what) {
    char why[512] = "";
    int left = preload_count;
    for (int progress = 1; left > 0 && progress;) {
        progress = 0;
        for (int i = 0; i < preload_count; i++) {
            if (!preloads[i] || !platform_load(preloads[i], why, sizeof why)) continue;
            free(preloads[i]);
            preloads[i] = NULL;
            progress = 1;
            left--;
        }
    }
    if (left == 0) return 0;
    append(start_error, sizeof start_error, "%s: %s; ", what, why);
    return -1;
}

/* The bundle in `root` as its bundle.txt lists it, checked before anything of it is loaded; 0, or -1
   (logged as `what`). */
static int check_bundle(const char *root, char separator, const char *what) {
    static char path[PLATFORM_PATH_MAX + 32];
    snprintf(path, sizeof path, "%s%c" BUNDLE_LIST, root, separator);
    if (!platform_is_file(path)) {
        append(start_error, sizeof start_error, "%s: no " BUNDLE_LIST " in it; ", what);
        return -1;
    }
    FILE *list = platform_open_file(path, "r");
    if (!list) {
        append(start_error, sizeof start_error, "%s: " BUNDLE_LIST " cannot be opened; ", what);
        return -1;
    }
    int result = check_header(list, what) == 0 ? check_files(list, root, separator, what) : -1;
    fclose(list);
    return result;
}

/* The FMU's own CPython in `root`: checked, then its library started with home `root`; -1 (logged) if
   anything fails, and then no other Python is tried (the header comment says why). */
static int start_own(Candidates *list, const char *root, char separator) {
    static char what[PLATFORM_PATH_MAX + 64], label[PLATFORM_PATH_MAX + 64];
    snprintf(what, sizeof what, "the FMU's own CPython (%s)", root);
    snprintf(label, sizeof label, "%s:", what);
    int result = check_bundle(root, separator, what);
    if (result == 0) result = load_preloads(what);
    if (result == 0) {
        add_installation(list, root, root, label, -1);
        if (list->count == 0) {
            append(start_error, sizeof start_error, "%s: no CPython library in it (looked for ", what);
            append_pattern(PLATFORM_LIBRARY_PLACES);
            append(start_error, sizeof start_error, "); ");
            result = -1;
        } else {
            result = try_in_turn(list);
        }
    }
    if (result != 0) append(start_error, sizeof start_error, "the FMU carries it, so no other Python is tried; ");
    return result;
}

/* Find and start a Python, the candidates gathered in `list`. */
static int find_and_start(Candidates *list) {
    /* A function outside the stable ABI: Windows' python3.dll, which forwards that ABI, does not count. */
    Library present = platform_loaded_with("Py_InitializeFromConfig");
    if (present) return adopt(present, NULL, NULL, "the Python in this process");
    static char override[PLATFORM_PATH_MAX];
    if (platform_getenv(DSC_OVERRIDE_VARIABLE, override, sizeof override)) {
        if (platform_is_folder(override)) return start_from_folder(list, override);
        add_candidate(list, override, NULL, DSC_OVERRIDE_VARIABLE " =", -1);
        return try_in_turn(list);
    }
    append(start_error, sizeof start_error, DSC_OVERRIDE_VARIABLE " not set; ");
    static char root[PLATFORM_PATH_MAX], separator;
    if (bundle_root(root, sizeof root, &separator)) return start_own(list, root, separator);
    gather(list);
    int supported = 0;
    for (int i = 0; i < list->count; i++) supported += list->items[i]->minor >= OLDEST_MINOR;
    if (supported == 0) {
        append(start_error, sizeof start_error,
               "no CPython 3.%d or newer is installed where this system registers one; ", OLDEST_MINOR);
    }
    int result = try_in_turn(list);
    if (result != 0 && *not_found) append(start_error, sizeof start_error, "the system's, not found: %s; ", not_found);
    return result;
}

static void free_ended(Ended *list) {
    while (list) {
        Ended *next = list->next;
        free(list);
        list = next;
    }
}

int pyhost_alive(void) {
    return py.Py_IsInitialized() && !(is_finalizing && is_finalizing()) && py.PyInterpreterState_Main() == interpreter;
}

PyObject *pyhost_take_error(void) {
    if (py.PyErr_GetRaisedException) return py.PyErr_GetRaisedException();
    PyObject *type = NULL, *value = NULL, *traceback = NULL;
    py.PyErr_Fetch(&type, &value, &traceback);
    if (!type) return NULL;
    py.PyErr_NormalizeException(&type, &value, &traceback);
    if (value && traceback) py.PyException_SetTraceback(value, traceback);
    if (traceback) py.Py_DecRef(traceback);
    if (value) py.Py_DecRef(type);
    return value ? value : type;
}

void pyhost_restore_error(PyObject *error) {
    if (!error) return;
    if (py.PyErr_SetRaisedException) {
        py.PyErr_SetRaisedException(error);
        return;
    }
    py.PyErr_Restore(py.PyObject_Type(error), error, py.PyException_GetTraceback(error));
}

/* Delete the thread states in `list` (their threads have ended) and free the list. The reaper takes
   the GIL with a thread state of its own for the batch and never uses PyGILState: since 3.12,
   deleting another thread's state unbinds the deleting thread's own, so every state is cleared
   (which may run Python code) before any is deleted. Nothing is touched while Python finalizes or
   after it was started anew (the states belong to an interpreter that is gone). */
static void delete_ended(Ended *list) {
    PyThreadState *own = pyhost_alive() ? py.PyThreadState_New(interpreter) : NULL;
    if (own) {
        py.PyEval_RestoreThread(own);
        for (Ended *e = list; e; e = e->next) py.PyThreadState_Clear(e->state);
        py.PyThreadState_Clear(own);
        for (Ended *e = list; e; e = e->next) py.PyThreadState_Delete(e->state);
        py.PyThreadState_DeleteCurrent();
    }
    free_ended(list);
}

static void reap(void) {
    platform_lock();
    for (;;) {
        while (!ended) platform_wait();
        Ended *list = ended;
        ended = NULL;
        platform_unlock();
        delete_ended(list);
        platform_lock();
    }
}

/* Start the reaper and keep this binary loaded for as long as the process lives: the reaper runs
   its code. Called with the lock held. */
static void start_reaper(void) {
    if (platform_keep_loaded((const void *)reap) == 0 && platform_start_thread(reap) == 0) reaper_started = 1;
}

/* At the end of a host thread that has a thread state of this binary's: hand it to the reaper
   (without the GIL; if the reaper cannot start, the thread state is left). In a process forked from
   the one that started the reaper, the reaper is gone and the states listed were the parent's (the
   child's Python has dropped them): the list is let go and a reaper of the child's own starts. */
static void forget_thread(void *state) {
    Ended *entry = malloc(sizeof *entry);
    if (!entry) return;
    entry->state = state;
    if (platform_forked()) {
        free_ended(ended);
        ended = NULL;
        reaper_started = 0;
    }
    platform_lock();
    if (!reaper_started) start_reaper();
    entry->next = ended;
    ended = entry;
    platform_signal();
    platform_unlock();
}

static void start_once(void) {
    start_error[0] = '\0';
    Candidates list = {NULL, 0};
    start_result = find_and_start(&list);
    for (int i = 0; i < list.count; i++) free(list.items[i]);
    free(list.items);
    if (start_result != 0) return;
    interpreter = py.PyInterpreterState_Main();
    platform_thread_key(forget_thread);
}

int pyhost_start(char *error, size_t size) {
    platform_once(start_once);
    if (start_result != 0) {
        snprintf(error, size, "no usable Python (CPython 3.%d or newer): %sset " DSC_OVERRIDE_VARIABLE
                 " to a CPython's folder or shared library (libpython3.X.so.1.0 on Linux, python3X.dll on Windows)",
                 OLDEST_MINOR, start_error);
    }
    return start_result;
}

/* A thread Python does not know: a thread state of its own, kept until the thread ends. */
static void adopt_thread(void) {
    py.PyGILState_Ensure();
    platform_thread_set(py.PyEval_SaveThread());
}

PyGILState_STATE pyhost_enter(void) {
    if (!py.PyGILState_GetThisThreadState()) adopt_thread();
    return py.PyGILState_Ensure();
}

void pyhost_leave(PyGILState_STATE state) {
    py.PyGILState_Release(state);
}
