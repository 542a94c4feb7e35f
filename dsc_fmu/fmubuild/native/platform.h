/* What differs between the operating systems the binary runs on: loading libraries, paths and files,
   the places a Python is installed, threads. One implementation per system: platform_posix.c with
   platform_linux.c (Linux) or platform_macos.c (macOS), and platform_windows.c; everything else is the
   same source for all. Paths are UTF-8. The functions that find a Python run only in pyhost_start's one
   search per process, on whatever thread the host calls first: their path buffers are static, not on that
   thread's stack. */

#ifndef DSC_PLATFORM_H
#define DSC_PLATFORM_H

#include <stddef.h>
#include <stdio.h>
#include <wchar.h>

#define PLATFORM_PATH_MAX 4096
/* The newest CPython minor version looked for by name. */
#define NEWEST_MINOR 20

/* A loaded shared library. */
typedef void *Library;

/* Load `path`, on Linux and Windows without making its symbols visible to others (macOS: global, see
   platform_posix.c); NULL with why in `error`. */
Library platform_load(const char *path, char *error, size_t size);
void platform_unload(Library library);
void *platform_symbol(Library library, const char *name);
/* Make the symbols of the loaded library `path` visible to libraries loaded later (Python's
   extension modules resolve the C API that way on Linux; nothing to do on Windows and macOS). */
int platform_share_symbols(const char *path, char *error, size_t size);
/* A library already in the process that exports `name`, or NULL. */
Library platform_loaded_with(const char *name);
/* The file of the library that holds `address`; 0, or -1. */
int platform_library_file(const void *address, char *path, size_t size);
/* Keep the library that holds `address` loaded until the process ends; 0, or -1. */
int platform_keep_loaded(const void *address);

int platform_is_file(const char *path);
int platform_is_folder(const char *path);
/* The size in bytes of the file `path`, or -1 if it is not a file. */
long long platform_file_size(const char *path);
FILE *platform_open_file(const char *path, const char *mode);
/* The value of the environment variable `name` in `value` (UTF-8); 1 if set and not empty. */
int platform_getenv(const char *name, char *value, size_t size);
int platform_is_absolute(const char *path);
/* `path` as a native path in place: on Windows "/C:/x" (a file URI's path) becomes "C:/x". */
void platform_native_path(char *path);
/* `path` as the wide string PyConfig_SetString takes (malloc'ed; `decode` is Python's
   Py_DecodeLocale, which Linux uses); NULL if it cannot be converted. */
wchar_t *platform_wide_path(const char *path, wchar_t *(*decode)(const char *, size_t *));

/* This system's name in a bundle's bundle.txt: "linux", "windows" or "darwin". */
extern const char PLATFORM_OS[];

/* The CPythons 3.`oldest` and newer this system registers, each as `visit(context, library, home,
   label, minor)`: on Linux libpython3.X.so.1.0 for the dynamic loader to search (label ""); on macOS
   the installers' places that hold a library (python.org's framework, Homebrew's on Apple Silicon and
   Intel, $CONDA_PREFIX/lib, pyenv's versions, Xcode's and the Command Line Tools' Python3.framework),
   then libpython3.X.dylib for the dynamic loader; on Windows the installs under PEP 514 (HKCU, then
   HKLM, each python3X.dll in its InstallPath), then python3X.dll in the folders on PATH; newest first
   where the system gives no order. */
void platform_registered_pythons(void (*visit)(void *context, const char *library, const char *home,
                                               const char *label, int minor),
                                 void *context, int oldest);
/* The `place`-th place (from 0) where the installation in `folder` keeps the shared library of CPython
   3.`minor`, in `path` ("" where this place cannot hold it): on Linux <folder>/lib/libpython3.X.so.1.0,
   then <folder>/lib/<multiarch>/libpython3.X.so.1.0 (Debian's layout, the CPU's folder); on macOS
   <folder>/lib/libpython3.X.dylib, <folder>/Python or Python3 where <folder> is a framework's Versions/3.X,
   then <folder>/Frameworks/Python.framework/Versions/3.X/Python (Homebrew's prefix); on Windows
   <folder>\python3X.dll. 0, or -1 past the last place. */
int platform_library_in(const char *folder, int place, int minor, char *path, size_t size);
/* Those places, for messages. */
extern const char PLATFORM_LIBRARY_PLACES[];
/* The home of the CPython 3.`minor` whose library is the file `library`: `given` if not empty,
   checked; else found from the library's folder (on Linux and macOS the nearest folder above it that
   holds a standard library). HOME_TO_SET; HOME_FIXED where the installation fixes its paths itself (Windows'
   embeddable CPython: a python3X._pth file in the home, which setting a home would override); or -1
   with why in `why`. */
enum { HOME_TO_SET = 0, HOME_FIXED = 1 };
int platform_python_home(const char *library, const char *given, int minor, char *home, size_t size, char *why,
                         size_t why_size);

/* One call of `function` per process, whichever thread comes first. */
void platform_once(void (*function)(void));

/* A value per host thread, with `on_end(value)` called when a thread that set one ends (never once
   the binary is unloaded: a binary that has set one stays loaded on Windows, forgets its key on Linux). */
int platform_thread_key(void (*on_end)(void *value));
void platform_thread_set(void *value);

/* One lock with one condition, for the thread that deletes ended threads' Python states. */
void platform_lock(void);
void platform_unlock(void);
void platform_wait(void);
void platform_signal(void);
/* Start `function` in a detached thread; 0, or -1. */
int platform_start_thread(void (*function)(void));
/* 1 the first time it is called in a process forked from the one that last used the lock (the
   lock and condition are then new, whatever state fork() caught them in), else 0. No fork handler
   is registered: one would outlive this binary when the host unloads it, and the next fork() would
   call into unmapped memory. */
int platform_forked(void);

#endif
