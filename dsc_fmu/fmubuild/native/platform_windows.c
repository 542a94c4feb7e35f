/* The platform seam on Windows (see platform.h): LoadLibraryExW, the registry, fiber-local storage,
   slim reader/writer locks. Strings cross the seam as UTF-8 and reach Windows as UTF-16. The binary
   imports KERNEL32 and the UCRT only: the registry functions are looked up in ADVAPI32 when the
   Pythons are searched. No call opens a dialog (a missing library is an error code, never a box). */

#define WIN32_LEAN_AND_MEAN
#include <windows.h>

#include "platform.h"

#include <psapi.h>
#include <stdlib.h>
#include <string.h>

/* The name of a CPython library (the minor version for %d). */
#ifndef DSC_SYSTEM_PYTHON
#define DSC_SYSTEM_PYTHON "python3%d.dll"
#endif
#define MAX_MODULES 1024

static INIT_ONCE once = INIT_ONCE_STATIC_INIT;
static DWORD thread_key = FLS_OUT_OF_INDEXES;
static void (*thread_end)(void *);
static SRWLOCK lock = SRWLOCK_INIT;
static CONDITION_VARIABLE signal_ = CONDITION_VARIABLE_INIT;
static volatile LONG pinned;

/* `text` (UTF-8) as UTF-16, malloc'ed; NULL if it is not UTF-8. */
static wchar_t *wide(const char *text) {
    int n = MultiByteToWideChar(CP_UTF8, MB_ERR_INVALID_CHARS, text, -1, NULL, 0);
    wchar_t *result = n > 0 ? malloc((size_t)n * sizeof *result) : NULL;
    if (result && MultiByteToWideChar(CP_UTF8, MB_ERR_INVALID_CHARS, text, -1, result, n) != n) {
        free(result);
        return NULL;
    }
    return result;
}

/* `text` (UTF-16) as UTF-8 in `out`; 0, or -1 if it does not fit. */
static int narrow(const wchar_t *text, char *out, size_t size) {
    int n = WideCharToMultiByte(CP_UTF8, 0, text, -1, out, (int)size, NULL, NULL);
    if (n <= 0) {
        if (size) out[0] = '\0';
        return -1;
    }
    return 0;
}

/* The system's text for the last error, with its number. */
static void last_error(char *error, size_t size) {
    DWORD code = GetLastError();
    wchar_t text[512];
    char message[1024];
    DWORD n = FormatMessageW(FORMAT_MESSAGE_FROM_SYSTEM | FORMAT_MESSAGE_IGNORE_INSERTS, NULL, code, 0, text,
                             sizeof text / sizeof text[0], NULL);
    while (n > 0 && (text[n - 1] == L'\r' || text[n - 1] == L'\n' || text[n - 1] == L' ' || text[n - 1] == L'.')) {
        text[--n] = L'\0';
    }
    if (n == 0 || narrow(text, message, sizeof message) != 0) message[0] = '\0';
    snprintf(error, size, "error %lu%s%s", (unsigned long)code, *message ? ": " : "", message);
}

int platform_is_absolute(const char *path) {
    return (path[0] && path[1] == ':') || ((path[0] == '\\' || path[0] == '/') && (path[1] == '\\' || path[1] == '/'));
}

Library platform_load(const char *path, char *error, size_t size) {
    wchar_t *name = wide(path);
    if (!name) {
        snprintf(error, size, "not a UTF-8 path");
        return NULL;
    }
    DWORD previous;
    SetThreadErrorMode(SEM_FAILCRITICALERRORS | SEM_NOOPENFILEERRORBOX, &previous);
    /* An absolute path: the library's own folder is searched for what it needs (vcruntime140.dll). */
    HMODULE library = LoadLibraryExW(name, NULL, platform_is_absolute(path) ? LOAD_WITH_ALTERED_SEARCH_PATH : 0);
    if (!library) last_error(error, size);
    SetThreadErrorMode(previous, NULL);
    free(name);
    return library;
}

void platform_unload(Library library) {
    FreeLibrary(library);
}

void *platform_symbol(Library library, const char *name) {
    FARPROC address = GetProcAddress(library, name);
    void *result;
    memcpy(&result, &address, sizeof result);
    return result;
}

int platform_share_symbols(const char *path, char *error, size_t size) {
    return 0;
}

Library platform_loaded_with(const char *name) {
    HMODULE modules[MAX_MODULES];
    DWORD needed = 0;
    if (!K32EnumProcessModules(GetCurrentProcess(), modules, sizeof modules, &needed)) return NULL;
    DWORD count = needed / sizeof modules[0];
    for (DWORD i = 0; i < count && i < MAX_MODULES; i++) {
        if (GetProcAddress(modules[i], name)) return modules[i];
    }
    return NULL;
}

static int module_file(HMODULE module, char *path, size_t size) {
    static wchar_t name[PLATFORM_PATH_MAX];
    DWORD n = GetModuleFileNameW(module, name, PLATFORM_PATH_MAX);
    if (n == 0 || n >= PLATFORM_PATH_MAX) return -1;
    return narrow(name, path, size);
}

int platform_library_file(const void *address, char *path, size_t size) {
    HMODULE module;
    if (!GetModuleHandleExW(GET_MODULE_HANDLE_EX_FLAG_FROM_ADDRESS | GET_MODULE_HANDLE_EX_FLAG_UNCHANGED_REFCOUNT,
                            (LPCWSTR)address, &module)) {
        return -1;
    }
    return module_file(module, path, size);
}

int platform_keep_loaded(const void *address) {
    HMODULE module;
    return GetModuleHandleExW(GET_MODULE_HANDLE_EX_FLAG_FROM_ADDRESS | GET_MODULE_HANDLE_EX_FLAG_PIN,
                              (LPCWSTR)address, &module) ? 0 : -1;
}

static DWORD attributes(const char *path) {
    wchar_t *name = wide(path);
    DWORD result = name ? GetFileAttributesW(name) : INVALID_FILE_ATTRIBUTES;
    free(name);
    return result;
}

int platform_is_file(const char *path) {
    DWORD found = attributes(path);
    return found != INVALID_FILE_ATTRIBUTES && !(found & FILE_ATTRIBUTE_DIRECTORY);
}

int platform_is_folder(const char *path) {
    DWORD found = attributes(path);
    return found != INVALID_FILE_ATTRIBUTES && (found & FILE_ATTRIBUTE_DIRECTORY);
}

long long platform_file_size(const char *path) {
    wchar_t *name = wide(path);
    WIN32_FILE_ATTRIBUTE_DATA data;
    BOOL found = name && GetFileAttributesExW(name, GetFileExInfoStandard, &data);
    free(name);
    if (!found || (data.dwFileAttributes & FILE_ATTRIBUTE_DIRECTORY)) return -1;
    return (long long)(((unsigned long long)data.nFileSizeHigh << 32) | data.nFileSizeLow);
}

FILE *platform_open_file(const char *path, const char *mode) {
    wchar_t *name = wide(path), *how = wide(mode);
    FILE *file = name && how ? _wfopen(name, how) : NULL;
    free(name);
    free(how);
    return file;
}

int platform_getenv(const char *name, char *value, size_t size) {
    wchar_t *key = wide(name);
    DWORD length = key ? GetEnvironmentVariableW(key, NULL, 0) : 0; /* with the terminating zero */
    wchar_t *found = length > 1 ? malloc(length * sizeof *found) : NULL;
    int result = found && GetEnvironmentVariableW(key, found, length) == length - 1 && narrow(found, value, size) == 0;
    free(found);
    free(key);
    return result;
}

void platform_native_path(char *path) {
    if (path[0] == '/' && ((path[1] >= 'A' && path[1] <= 'Z') || (path[1] >= 'a' && path[1] <= 'z')) && path[2] == ':') {
        memmove(path, path + 1, strlen(path));
    }
}

wchar_t *platform_wide_path(const char *path, wchar_t *(*decode)(const char *, size_t *)) {
    return wide(path);
}

/* The registry functions of ADVAPI32, looked up once they are needed. */
typedef LSTATUS(WINAPI *RegOpenKeyExWType)(HKEY, LPCWSTR, DWORD, REGSAM, PHKEY);
typedef LSTATUS(WINAPI *RegEnumKeyExWType)(HKEY, DWORD, LPWSTR, LPDWORD, LPDWORD, LPWSTR, LPDWORD, PFILETIME);
typedef LSTATUS(WINAPI *RegGetValueWType)(HKEY, LPCWSTR, LPCWSTR, DWORD, LPDWORD, PVOID, LPDWORD);
typedef LSTATUS(WINAPI *RegCloseKeyType)(HKEY);

typedef struct {
    RegOpenKeyExWType open;
    RegEnumKeyExWType enumerate;
    RegGetValueWType get;
    RegCloseKeyType close;
} Registry;

static int registry(Registry *r) {
    HMODULE advapi = LoadLibraryExW(L"advapi32.dll", NULL, LOAD_LIBRARY_SEARCH_SYSTEM32);
    if (!advapi) advapi = LoadLibraryW(L"advapi32.dll");
    if (!advapi) return -1;
    FARPROC functions[] = {GetProcAddress(advapi, "RegOpenKeyExW"), GetProcAddress(advapi, "RegEnumKeyExW"),
                           GetProcAddress(advapi, "RegGetValueW"), GetProcAddress(advapi, "RegCloseKey")};
    for (int i = 0; i < 4; i++) {
        if (!functions[i]) return -1;
    }
    memcpy(&r->open, &functions[0], sizeof r->open);
    memcpy(&r->enumerate, &functions[1], sizeof r->enumerate);
    memcpy(&r->get, &functions[2], sizeof r->get);
    memcpy(&r->close, &functions[3], sizeof r->close);
    return 0;
}

/* The minor version of a PEP 514 tag of CPython 3 for this architecture ("3.11"; not "3.11-32" or
   "3.13t"), or -1. */
static int tag_minor(const wchar_t *tag) {
    if (tag[0] != L'3' || tag[1] != L'.' || tag[2] < L'0' || tag[2] > L'9') return -1;
    int minor = 0;
    const wchar_t *p = tag + 2;
    for (; *p >= L'0' && *p <= L'9'; p++) minor = minor * 10 + (*p - L'0');
    return *p ? -1 : minor;
}

typedef void (*Visit)(void *, const char *, const char *, const char *, int);

/* `folder`\python3X.dll (DSC_SYSTEM_PYTHON) in `path`. */
static void join(char *path, size_t size, const char *folder, int minor) {
    char name[64];
    size_t n = strlen(folder);
    snprintf(name, sizeof name, DSC_SYSTEM_PYTHON, minor);
    snprintf(path, size, "%s%s%s", folder, n && folder[n - 1] != '\\' && folder[n - 1] != '/' ? "\\" : "", name);
}

const char PLATFORM_OS[] = "windows";
const char PLATFORM_LIBRARY_PLACES[] = DSC_SYSTEM_PYTHON;

int platform_library_in(const char *folder, int place, int minor, char *path, size_t size) {
    if (place != 0) return -1;
    join(path, size, folder, minor);
    return 0;
}

/* The CPythons under `root`\Software\Python\PythonCore, newest first. */
static void registered_under(const Registry *r, HKEY root, const char *label, Visit visit, void *context, int oldest) {
    HKEY core;
    if (r->open(root, L"Software\\Python\\PythonCore", 0, KEY_READ | KEY_WOW64_64KEY, &core) != ERROR_SUCCESS) return;
    static wchar_t found[NEWEST_MINOR + 1][PLATFORM_PATH_MAX / 4];
    memset(found, 0, sizeof found);
    wchar_t tag[64];
    for (DWORD i = 0;; i++) {
        DWORD length = sizeof tag / sizeof tag[0];
        if (r->enumerate(core, i, tag, &length, NULL, NULL, NULL, NULL) != ERROR_SUCCESS) break;
        int minor = tag_minor(tag);
        if (minor < oldest || minor > NEWEST_MINOR) continue;
        wchar_t key[96];
        DWORD bytes = sizeof found[minor];
        swprintf(key, sizeof key / sizeof key[0], L"%ls\\InstallPath", tag);
        if (r->get(core, key, NULL, RRF_RT_REG_SZ, NULL, found[minor], &bytes) != ERROR_SUCCESS) found[minor][0] = 0;
    }
    r->close(core);
    for (int minor = NEWEST_MINOR; minor >= oldest; minor--) {
        static char folder[PLATFORM_PATH_MAX], library[PLATFORM_PATH_MAX + 32];
        if (!found[minor][0] || narrow(found[minor], folder, sizeof folder) != 0) continue;
        join(library, sizeof library, folder, minor);
        if (platform_is_file(library)) visit(context, library, NULL, label, minor);
    }
}

/* python3X.dll in the folders on PATH, newest first in each. */
static void on_path(Visit visit, void *context, int oldest) {
    static char path[3 * 32768]; /* the longest environment variable, in UTF-8 */
    if (!platform_getenv("PATH", path, sizeof path)) return;
    for (char *folder = strtok(path, ";"); folder; folder = strtok(NULL, ";")) {
        for (int minor = NEWEST_MINOR; minor >= oldest; minor--) {
            static char library[PLATFORM_PATH_MAX + 32];
            join(library, sizeof library, folder, minor);
            if (platform_is_file(library)) visit(context, library, NULL, "on PATH:", minor);
        }
    }
}

void platform_registered_pythons(Visit visit, void *context, int oldest) {
    Registry r;
    if (registry(&r) == 0) {
        registered_under(&r, HKEY_CURRENT_USER, "PEP 514 (HKCU):", visit, context, oldest);
        registered_under(&r, HKEY_LOCAL_MACHINE, "PEP 514 (HKLM):", visit, context, oldest);
    }
    on_path(visit, context, oldest);
}

static int has_stdlib(const char *home, int minor) {
    static char path[PLATFORM_PATH_MAX + 64];
    snprintf(path, sizeof path, "%s\\Lib\\os.py", home);
    if (platform_is_file(path)) return 1;
    snprintf(path, sizeof path, "%s\\python3%d.zip", home, minor);
    return platform_is_file(path);
}

int platform_python_home(const char *library, const char *given, int minor, char *home, size_t size, char *why,
                         size_t why_size) {
    static char folder[PLATFORM_PATH_MAX];
    snprintf(folder, sizeof folder, "%s", given && *given ? given : library);
    if (!(given && *given)) {
        char *slash = strrchr(folder, '\\');
        char *other = strrchr(folder, '/');
        if (other > slash) slash = other;
        if (slash) *slash = '\0';
    }
    if (has_stdlib(folder, minor)) {
        static char paths[PLATFORM_PATH_MAX + 32];
        snprintf(home, size, "%s", folder);
        snprintf(paths, sizeof paths, "%s\\python3%d._pth", folder, minor);
        return platform_is_file(paths) ? HOME_FIXED : HOME_TO_SET;
    }
    snprintf(why, why_size, "no standard library in %s (neither Lib\\os.py nor python3%d.zip)", folder, minor);
    return -1;
}

static BOOL CALLBACK run_once(PINIT_ONCE unused, PVOID function, PVOID *context) {
    void (*start)(void);
    memcpy(&start, &function, sizeof start);
    start();
    return TRUE;
}

void platform_once(void (*function)(void)) {
    void *argument;
    memcpy(&argument, &function, sizeof argument);
    InitOnceExecuteOnce(&once, run_once, argument, NULL);
}

static VOID WINAPI on_thread_end(PVOID value) {
    if (value && thread_end) thread_end(value);
}

int platform_thread_key(void (*on_end)(void *)) {
    thread_end = on_end;
    thread_key = FlsAlloc(on_thread_end);
    return thread_key == FLS_OUT_OF_INDEXES ? -1 : 0;
}

/* A thread's value makes the binary stay loaded: its callback must outlive every thread. */
void platform_thread_set(void *value) {
    if (thread_key == FLS_OUT_OF_INDEXES) return;
    if (!pinned && platform_keep_loaded((const void *)on_thread_end) == 0) InterlockedExchange(&pinned, 1);
    if (pinned) FlsSetValue(thread_key, value);
}

void platform_lock(void) {
    AcquireSRWLockExclusive(&lock);
}

void platform_unlock(void) {
    ReleaseSRWLockExclusive(&lock);
}

void platform_wait(void) {
    SleepConditionVariableSRW(&signal_, &lock, INFINITE, 0);
}

void platform_signal(void) {
    WakeConditionVariable(&signal_);
}

static DWORD WINAPI run(LPVOID function) {
    void (*start)(void);
    memcpy(&start, &function, sizeof start);
    start();
    return 0;
}

int platform_start_thread(void (*function)(void)) {
    void *argument;
    memcpy(&argument, &function, sizeof argument);
    HANDLE thread = CreateThread(NULL, 0, run, argument, 0, NULL);
    if (!thread) return -1;
    CloseHandle(thread);
    return 0;
}

int platform_forked(void) {
    return 0;
}

/* Unloaded by FreeLibrary before any thread set a value (else it is pinned): the key goes, no
   callback into this binary is left behind. */
BOOL WINAPI DllMain(HINSTANCE instance, DWORD reason, LPVOID reserved) {
    if (reason == DLL_PROCESS_DETACH && !reserved && thread_key != FLS_OUT_OF_INDEXES) FlsFree(thread_key);
    return TRUE;
}
