/* What the project's C importers share: loading an FMU's binary on Linux and Windows, its resource
   URI, loggers that print to stderr, and a status check that exits. */

#ifndef DSC_TESTS_FMI_HOST_H
#define DSC_TESTS_FMI_HOST_H

#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#ifdef _WIN32
#include <windows.h>
#include <psapi.h>
#define HOST_FOLDER2 "win64"
#define HOST_FOLDER3 "x86_64-windows"
#define HOST_SUFFIX ".dll"
/* An unzipped FMU's folder (C:/x or C:\x) as its resources' file URI. */
#define HOST_RESOURCES_URI "file:///%s/resources"

static void *host_load(const char *path) {
    char native[4096];
    snprintf(native, sizeof native, "%s", path);
    for (char *c = native; *c; c++) {
        if (*c == '/') *c = '\\';
    }
    return (void *)LoadLibraryA(native);
}

static void *host_symbol(void *library, const char *name) {
    FARPROC address = GetProcAddress((HMODULE)library, name);
    void *result;
    memcpy(&result, &address, sizeof result);
    return result;
}

static void host_unload(void *library) {
    FreeLibrary((HMODULE)library);
}

static const char *host_error(void) {
    static char text[64];
    snprintf(text, sizeof text, "LoadLibrary failed with error %lu", (unsigned long)GetLastError());
    return text;
}

/* A function of the CPython in this process (the FMU's binary loaded or found it). */
static void *host_python_symbol(const char *name) {
    HMODULE modules[1024];
    DWORD needed = 0;
    if (!K32EnumProcessModules(GetCurrentProcess(), modules, sizeof modules, &needed)) return NULL;
    for (DWORD i = 0; i < needed / sizeof modules[0] && i < 1024; i++) {
        if (GetProcAddress(modules[i], "Py_InitializeFromConfig")) return host_symbol(modules[i], name);
    }
    return NULL;
}

/* The process's working set in kB. */
static long host_resident_kb(void) {
    PROCESS_MEMORY_COUNTERS counters;
    return K32GetProcessMemoryInfo(GetCurrentProcess(), &counters, sizeof counters)
               ? (long)(counters.WorkingSetSize / 1024) : -1;
}
#else
#include <dlfcn.h>
#if defined(__linux__) && defined(__aarch64__)
/* FMI 2.0 names no aarch64 Linux folder: the FMUs put that binary in FMI 3.0's. */
#define HOST_FOLDER2 "aarch64-linux"
#define HOST_FOLDER3 "aarch64-linux"
#else
#define HOST_FOLDER2 "linux64"
#define HOST_FOLDER3 "x86_64-linux"
#endif
#define HOST_SUFFIX ".so"
#define HOST_RESOURCES_URI "file://%s/resources"

static void *host_load(const char *path) {
    return dlopen(path, RTLD_NOW | RTLD_LOCAL);
}

static void *host_symbol(void *library, const char *name) {
    return dlsym(library, name);
}

static void host_unload(void *library) {
    dlclose(library);
}

static const char *host_error(void) {
    return dlerror();
}

/* A function of the CPython in this process (the FMU's binary loaded or found it). */
static void *host_python_symbol(const char *name) {
    return dlsym(RTLD_DEFAULT, name);
}

/* The process's resident memory in kB. */
static long host_resident_kb(void) {
    FILE *file = fopen("/proc/self/status", "r");
    char line[256];
    long kb = -1;
    while (file && fgets(line, sizeof line, file)) {
        if (strncmp(line, "VmRSS:", 6) == 0) kb = atol(line + 6);
    }
    if (file) fclose(file);
    return kb;
}
#endif

#include "fmi2Functions.h"
#include "fmi3Functions.h"

static void logger2(fmi2ComponentEnvironment env, fmi2String instance, fmi2Status status, fmi2String category,
                    fmi2String message, ...) {
    va_list args;
    va_start(args, message);
    fprintf(stderr, "[%s %d] ", instance, status);
    vfprintf(stderr, message, args);
    fprintf(stderr, "\n");
    va_end(args);
}

static void logger3(fmi3InstanceEnvironment env, fmi3Status status, fmi3String category, fmi3String message) {
    fprintf(stderr, "[%d] %s\n", status, message);
}

/* The address of `name` in `library`; exit with a message if it has none. */
static void *host_require(void *library, const char *name) {
    void *address = host_symbol(library, name);
    if (!address) {
        fprintf(stderr, "missing %s\n", name);
        exit(1);
    }
    return address;
}

/* Exit with a message if `status` is worse than a warning. */
static void check(int status, const char *call) {
    if (status > 1) {
        fprintf(stderr, "%s failed with status %d\n", call, status);
        exit(1);
    }
}

#endif
