/* The Python runtime that runs the model code: found, loaded and started at run time, never linked.

   Any CPython from 3.9 on will do (the bundled Python code is version-neutral, and the binary calls
   only functions every such CPython exports). Order (docs/other-tools.md, "What the importing machine needs"):
     0. a CPython already in the process (fmpy, libcosimpy, PyFMI): used as it is;
     1. DSC_FMU_PYTHON, if set, the only place looked at: the path of a CPython shared library
        (libpython3.X.so.1.0, libpython3.X.dylib or a framework's Python, python3X.dll), or a folder: an
        installation's (platform_library_in: on Linux and macOS its prefix, whose lib/ holds the library,
        on macOS also a framework's version folder; on Windows the folder of python3X.dll), or a virtual
        environment's, which stands for the installation its pyvenv.cfg names (`home`, or on Linux and
        macOS home's parent);
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
   A Python this binary starts gets its home set explicitly (an embeddable CPython on Windows: the paths
   its python3X._pth fixes), ignores PYTHON* environment variables, imports no site packages, writes no
   bytecode and installs no signal handlers; its symbols are made global before it starts (on Linux the
   extension modules it may load while starting, zlib for a compressed zip, resolve the C API there).
   It is started as Py_InitializeEx(0) would start it, but through Py_InitializeFromConfig, whose
   status says why it failed where Py_InitializeEx would end the process; of the configuration it
   touches only the leading fields whose offsets every CPython since 3.8 shares, checked before they
   are set.

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
#define MAX_CANDIDATES 48
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
    Candidate *items;
    int count;
} Candidates;

static const struct {
    const char *name;
    size_t offset;
} SYMBOLS[] = {
#define SYMBOL_OF_FUNCTION(type, name, parameters) {#name, offsetof(PyApi, name)},
#define SYMBOL_OF_DATA(type, name, symbol) {#symbol, offsetof(PyApi, name)},
    PY_API(SYMBOL_OF_FUNCTION, SYMBOL_OF_DATA)
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

/* Fill `py` from `library`; the name of a missing symbol, or NULL. */
static const char *resolve(Library library) {
    for (size_t i = 0; i < sizeof SYMBOLS / sizeof SYMBOLS[0]; i++) {
        void *address = platform_symbol(library, SYMBOLS[i].name);
        if (!address) return SYMBOLS[i].name;
        memcpy((char *)&py + SYMBOLS[i].offset, &address, sizeof address);
    }
    return NULL;
}

/* The minor version of a CPython 3 version string ("3.11.7 (main, ...)"), or -1. */
static int minor_of(const char *version) {
    if (strncmp(version, "3.", 2) != 0 || !isdigit((unsigned char)version[2])) return -1;
    return atoi(version + 2);
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

/* Start Python with `home`, or (`set_home` 0) with the paths its installation's ._pth file fixes,
   which a home set here would override. */
static int initialize(const char *home, int set_home, const char *what) {
    home_wide = set_home ? platform_wide_path(home, py.Py_DecodeLocale) : NULL;
    if (set_home && !home_wide) {
        append(start_error, sizeof start_error, "%s: cannot decode its home %s; ", what, home);
        return -1;
    }
    if (set_home) py.Py_SetPythonHome(home_wide);
    *py.Py_IgnoreEnvironmentFlag = 1;
    *py.Py_NoSiteFlag = 1;
    *py.Py_NoUserSiteDirectory = 1;
    *py.Py_DontWriteBytecodeFlag = 1;
    return start_python(what, home);
}

/* The minor version of the CPython in `library`, asked before anything else is resolved, so that one too
   old for the rest is named with its version; -1 (logged as `what`) if it is older than 3.OLDEST_MINOR or
   says none. */
static int old_version(Library library, const char *what) {
    const char *(*get_version)(void);
    void *address = platform_symbol(library, "Py_GetVersion");
    if (!address) {
        append(start_error, sizeof start_error, "%s: no symbol Py_GetVersion (not a CPython library); ", what);
        return -1;
    }
    memcpy(&get_version, &address, sizeof address);
    const char *version = get_version();
    int minor = minor_of(version);
    if (minor < OLDEST_MINOR) {
        append(start_error, sizeof start_error, "%s: Python %.*s, older than 3.%d; ", what, (int)strcspn(version, " "),
               version, OLDEST_MINOR);
        return -1;
    }
    return minor;
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
    const char *missing = resolve(library);
    if (missing) {
        append(start_error, sizeof start_error, "%s: no symbol %s; ", what, missing);
        return -1;
    }
    void *finalizing = platform_symbol(library, "Py_IsFinalizing");
    if (!finalizing) finalizing = platform_symbol(library, "_Py_IsFinalizing");
    memcpy(&is_finalizing, &finalizing, sizeof finalizing);
    if (py.Py_IsInitialized()) return share(path, what);
    char file[PLATFORM_PATH_MAX], found[PLATFORM_PATH_MAX], why[256] = "";
    if (platform_library_file((const void *)py.Py_IsInitialized, file, sizeof file) != 0) file[0] = '\0';
    int layout = platform_python_home(file, home, minor, found, sizeof found, why, sizeof why);
    if (layout < 0) {
        append(start_error, sizeof start_error, "%s: %s; ", what, why);
        return -1;
    }
    if (share(path, what) != 0) return -1;
    return initialize(found, layout == HOME_TO_SET, what);
}

/* Load, check and start the candidate. */
static int try_candidate(const Candidate *candidate) {
    char label[3 * PLATFORM_PATH_MAX + 64], why[512] = "", file[PLATFORM_PATH_MAX];
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
        if (strcmp(list->items[i].library, library) == 0) return;
    }
    if (list->count == MAX_CANDIDATES) return;
    Candidate *c = &list->items[list->count++];
    snprintf(c->library, sizeof c->library, "%s", library);
    snprintf(c->home, sizeof c->home, "%s", home ? home : "");
    snprintf(c->label, sizeof c->label, "%s", label);
    c->minor = minor;
}

/* The candidates in turn, until one starts or one has been started (and failed); 0, or -1. */
static int try_in_turn(const Candidates *list) {
    for (int i = 0; i < list->count && !start_attempted; i++) {
        if (try_candidate(&list->items[i]) == 0) return 0;
    }
    return -1;
}

/* The candidates of the minor version that built the FMU first; the rest in the order found. */
static void prefer_building_minor(Candidates *list) {
    int preferred = minor_of(DSC_PYTHON_VERSION), first = 0;
    for (int i = 0; i < list->count; i++) {
        if (list->items[i].minor != preferred) continue;
        Candidate moved = list->items[i];
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

/* The `home` of the virtual environment in `folder` (its pyvenv.cfg's "home = ..."); 1 if there is one. */
static int venv_home(const char *folder, char *home, size_t size) {
    char path[PLATFORM_PATH_MAX + 16], line[PLATFORM_PATH_MAX + 16];
    snprintf(path, sizeof path, "%s/pyvenv.cfg", folder);
    FILE *file = platform_open_file(path, "r");
    if (!file) return 0;
    *home = '\0';
    while (!*home && fgets(line, sizeof line, file)) {
        char *p = line + strspn(line, " \t");
        if (strncmp(p, "home", 4) != 0) continue;
        p += 4 + strspn(p + 4, " \t");
        if (*p != '=') continue;
        p += 1 + strspn(p + 1, " \t");
        size_t length = strlen(p);
        while (length > 0 && isspace((unsigned char)p[length - 1])) p[--length] = '\0';
        snprintf(home, size, "%s", p);
    }
    fclose(file);
    return *home != '\0';
}

/* The CPython libraries of the installation in `folder`, newest first, each called `label` and started
   with `home` (NULL: the home found from the library's file). */
static void add_installation(Candidates *list, const char *folder, const char *home, const char *label) {
    char library[PLATFORM_PATH_MAX];
    for (int minor = NEWEST_MINOR; minor >= OLDEST_LOOKED_FOR; minor--) {
        for (int place = 0; platform_library_in(folder, place, minor, library, sizeof library) == 0; place++) {
            if (platform_is_file(library)) add_candidate(list, library, home, label, minor);
        }
    }
}

/* The candidates of the folder that DSC_FMU_PYTHON names: its installation's, or those of the installation
   its virtual environment names (home, and home's parent: on Linux and macOS home is the installation's bin). */
static void gather_folder(Candidates *list, const char *folder) {
    char home[PLATFORM_PATH_MAX];
    const char *label = DSC_OVERRIDE_VARIABLE " folder:";
    if (!venv_home(folder, home, sizeof home)) {
        add_installation(list, folder, NULL, label);
    } else {
        add_installation(list, home, NULL, label);
        char *separator = strrchr(home, '/'), *other = strrchr(home, '\\');
        if (other > separator) separator = other;
        if (separator && separator != home) {
            *separator = '\0';
            add_installation(list, home, NULL, label);
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
    gather_folder(list, folder);
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
    char file[PLATFORM_PATH_MAX];
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
#define MAX_PRELOADS 16
static char preloads[MAX_PRELOADS][PLATFORM_PATH_MAX];
static int preload_count;

/* A file of the bundle to load before CPython starts: lib/lib*.so* but libpython. */
static int is_preload(const char *path) {
    return strncmp(path, "lib/lib", 7) == 0 && strstr(path, ".so") && strncmp(path, "lib/libpython", 13) != 0;
}

/* Every later line of bundle.txt, "<size> <path>" (empty lines skipped): the file <path> of `root` is there
   with that size, and at least one is listed; the libraries to load first are kept in `preloads`. 0, or -1
   (logged as `what`) at the first line that fails. */
static int check_files(FILE *list, const char *root, char separator, const char *what) {
    char line[PLATFORM_PATH_MAX + 32], path[2 * PLATFORM_PATH_MAX + 32];
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
        if (is_preload(end + 1) && preload_count < MAX_PRELOADS) {
            snprintf(preloads[preload_count++], PLATFORM_PATH_MAX, "%s", path);
        }
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
    int loaded[MAX_PRELOADS] = {0}, left = preload_count;
    for (int progress = 1; left > 0 && progress;) {
        progress = 0;
        for (int i = 0; i < preload_count; i++) {
            if (loaded[i] || !platform_load(preloads[i], why, sizeof why)) continue;
            loaded[i] = progress = 1;
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
    char path[PLATFORM_PATH_MAX + 32];
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
    char what[PLATFORM_PATH_MAX + 64], label[PLATFORM_PATH_MAX + 64];
    snprintf(what, sizeof what, "the FMU's own CPython (%s)", root);
    snprintf(label, sizeof label, "%s:", what);
    int result = check_bundle(root, separator, what);
    if (result == 0) result = load_preloads(what);
    if (result == 0) {
        add_installation(list, root, root, label);
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

static int find_and_start(void) {
    /* A function outside the stable ABI: Windows' python3.dll, which forwards that ABI, does not count. */
    Library present = platform_loaded_with("Py_InitializeFromConfig");
    if (present) return adopt(present, NULL, NULL, "the Python in this process");
    static Candidate items[MAX_CANDIDATES];
    Candidates list = {items, 0};
    char override[PLATFORM_PATH_MAX];
    if (platform_getenv(DSC_OVERRIDE_VARIABLE, override, sizeof override)) {
        if (platform_is_folder(override)) return start_from_folder(&list, override);
        add_candidate(&list, override, NULL, DSC_OVERRIDE_VARIABLE " =", -1);
        return try_candidate(&items[0]);
    }
    append(start_error, sizeof start_error, DSC_OVERRIDE_VARIABLE " not set; ");
    char root[PLATFORM_PATH_MAX], separator;
    if (bundle_root(root, sizeof root, &separator)) return start_own(&list, root, separator);
    gather(&list);
    int supported = 0;
    for (int i = 0; i < list.count; i++) supported += items[i].minor >= OLDEST_MINOR;
    if (supported == 0) {
        append(start_error, sizeof start_error,
               "no CPython 3.%d or newer is installed where this system registers one; ", OLDEST_MINOR);
    }
    int result = try_in_turn(&list);
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
    start_result = find_and_start();
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
