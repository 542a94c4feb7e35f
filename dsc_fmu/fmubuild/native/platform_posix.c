/* The platform seam on Linux and macOS (see platform.h), what POSIX gives both: dlopen, pthreads, stat,
   an installation's home. Where a CPython is installed: platform_linux.c, platform_macos.c. */

#define _GNU_SOURCE
#include "platform.h"

#include <dlfcn.h>
#include <limits.h>
#include <pthread.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

/* How a library is loaded: on Linux local, its symbols made global once it is the Python to use
   (platform_share_symbols); on macOS global from the start, since dyld makes a library loaded local
   global by no later call, and extension modules (linked `-undefined dynamic_lookup`) find the C API
   only in the global scope. A CPython refused there after loading (too old, a symbol missing) stays in
   that scope, as dyld keeps any image with thread-local variables (CPython 3.12 on) loaded; the next
   candidate's symbols are found first by the binary (dlsym on its own handle), not by extension modules.
   _POSIX_C_SOURCE must not be defined here: macOS's headers would hide dladdr and RTLD_NOLOAD. */
#ifdef __APPLE__
#define LOAD_MODE RTLD_GLOBAL
#else
#define LOAD_MODE RTLD_LOCAL
#endif

static pthread_once_t once = PTHREAD_ONCE_INIT;
static pthread_key_t thread_key;
static int thread_key_made;
static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;
static pthread_cond_t signal_ = PTHREAD_COND_INITIALIZER;
static pid_t owner; /* the process that last used the lock */

Library platform_load(const char *path, char *error, size_t size) {
    Library library = dlopen(path, RTLD_NOW | LOAD_MODE);
    if (!library) snprintf(error, size, "%s", dlerror());
    return library;
}

void platform_unload(Library library) {
    dlclose(library);
}

void *platform_symbol(Library library, const char *name) {
    return dlsym(library, name);
}

int platform_share_symbols(const char *path, char *error, size_t size) {
#ifdef __APPLE__
    return 0; /* loaded global already (LOAD_MODE) */
#else
    if (dlopen(path, RTLD_NOW | RTLD_NOLOAD | RTLD_GLOBAL)) return 0;
    snprintf(error, size, "%s", dlerror());
    return -1;
#endif
}

/* The process's global scope (the program and the libraries loaded global) as dlopen(NULL) gives it:
   glibc's RTLD_DEFAULT is NULL, the answer for none; macOS's dlopen(NULL) is RTLD_DEFAULT's equivalent. */
Library platform_loaded_with(const char *name) {
    return dlsym(RTLD_DEFAULT, name) ? dlopen(NULL, RTLD_NOW) : NULL;
}

int platform_library_file(const void *address, char *path, size_t size) {
    Dl_info info;
    if (!dladdr(address, &info) || !info.dli_fname) return -1;
    static char resolved[PATH_MAX];
    snprintf(path, size, "%s", realpath(info.dli_fname, resolved) ? resolved : info.dli_fname);
    return 0;
}

int platform_keep_loaded(const void *address) {
    Dl_info self;
    return dladdr(address, &self) && self.dli_fname && dlopen(self.dli_fname, RTLD_NOW | RTLD_NOLOAD | RTLD_NODELETE)
               ? 0 : -1;
}

int platform_is_file(const char *path) {
    struct stat info;
    return stat(path, &info) == 0 && S_ISREG(info.st_mode);
}

int platform_is_folder(const char *path) {
    struct stat info;
    return stat(path, &info) == 0 && S_ISDIR(info.st_mode);
}

long long platform_file_size(const char *path) {
    struct stat info;
    return stat(path, &info) == 0 && S_ISREG(info.st_mode) ? (long long)info.st_size : -1;
}

FILE *platform_open_file(const char *path, const char *mode) {
    return fopen(path, mode);
}

int platform_getenv(const char *name, char *value, size_t size) {
    const char *found = getenv(name);
    if (!found || !*found) return 0;
    snprintf(value, size, "%s", found);
    return 1;
}

int platform_is_absolute(const char *path) {
    return path[0] == '/';
}

void platform_native_path(char *path) {
}

wchar_t *platform_wide_path(const char *path, wchar_t *(*decode)(const char *, size_t *)) {
    return decode(path, NULL);
}

/* A standard library under `home`: lib/python3.X with os.py and encodings, or lib/python3X.zip (a bundle's,
   which CPython puts first on sys.path for that home). */
static int has_stdlib(const char *home, int minor) {
    static char path[PATH_MAX + 64];
    snprintf(path, sizeof path, "%s/lib/python3%d.zip", home, minor);
    if (platform_is_file(path)) return 1;
    snprintf(path, sizeof path, "%s/lib/python3.%d/os.py", home, minor);
    if (!platform_is_file(path)) return 0;
    snprintf(path, sizeof path, "%s/lib/python3.%d/encodings/__init__.py", home, minor);
    return platform_is_file(path);
}

int platform_python_home(const char *library, const char *given, int minor, char *home, size_t size, char *why,
                         size_t why_size) {
    if (given && *given) {
        if (has_stdlib(given, minor)) {
            snprintf(home, size, "%s", given);
            return HOME_TO_SET;
        }
        snprintf(why, why_size, "no standard library in %s (neither lib/python3.%d/os.py nor lib/python3%d.zip)", given,
                 minor, minor);
        return -1;
    }
    static char path[PATH_MAX];
    snprintf(path, sizeof path, "%s", library);
    char *slash;
    while ((slash = strrchr(path, '/')) != NULL && slash != path) {
        *slash = '\0';
        if (has_stdlib(path, minor)) {
            snprintf(home, size, "%s", path);
            return HOME_TO_SET;
        }
    }
    snprintf(why, why_size, "no lib/python3.%d standard library above the library", minor);
    return -1;
}

void platform_once(void (*function)(void)) {
    pthread_once(&once, function);
}

int platform_thread_key(void (*on_end)(void *)) {
    thread_key_made = pthread_key_create(&thread_key, on_end) == 0;
    return thread_key_made ? 0 : -1;
}

void platform_thread_set(void *value) {
    if (thread_key_made) pthread_setspecific(thread_key, value);
}

/* The binary unloaded: threads still running keep their values, and no callback that is gone runs. */
__attribute__((destructor)) static void unload(void) {
    if (thread_key_made) pthread_key_delete(thread_key);
}

void platform_lock(void) {
    pthread_mutex_lock(&lock);
}

void platform_unlock(void) {
    pthread_mutex_unlock(&lock);
}

void platform_wait(void) {
    pthread_cond_wait(&signal_, &lock);
}

void platform_signal(void) {
    pthread_cond_signal(&signal_);
}

static void *run(void *function) {
    void (*start)(void);
    memcpy(&start, &function, sizeof start);
    start();
    return NULL;
}

int platform_start_thread(void (*function)(void)) {
    pthread_t thread;
    pthread_attr_t attributes;
    void *argument;
    memcpy(&argument, &function, sizeof argument);
    pthread_attr_init(&attributes);
    pthread_attr_setdetachstate(&attributes, PTHREAD_CREATE_DETACHED);
    int result = pthread_create(&thread, &attributes, run, argument) == 0 ? 0 : -1;
    pthread_attr_destroy(&attributes);
    return result;
}

int platform_forked(void) {
    pid_t now = getpid(), was = __atomic_load_n(&owner, __ATOMIC_ACQUIRE);
    if (was == now || !__atomic_compare_exchange_n(&owner, &was, now, 0, __ATOMIC_ACQ_REL, __ATOMIC_ACQUIRE)) return 0;
    if (was == 0) return 0; /* the first use, in the process that loaded this binary or in a child */
    pthread_mutex_init(&lock, NULL);
    pthread_cond_init(&signal_, NULL);
    return 1;
}
