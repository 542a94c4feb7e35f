/* A minimal FMI 2.0 co-simulation importer in C, as a non-Python tool loads an FMU.

   usage: c_importer UNZIPPED_DIR MODEL_IDENTIFIER GUID STEPS STEP_SIZE VR [VR ...]
   Loads binaries/linux64/<MODEL_IDENTIFIER>.so, instantiates, initialises, does STEPS steps of
   STEP_SIZE and prints "time,value,..." of the given Real value references at t = 0 and after every
   step; exits 1 with a message on the first failing call. */

#include <dlfcn.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

typedef void *fmi2Component;
typedef unsigned int fmi2ValueReference;
typedef double fmi2Real;
typedef int fmi2Boolean;
typedef int fmi2Status;

typedef struct {
    void (*logger)(void *, const char *, fmi2Status, const char *, const char *, ...);
    void *(*allocateMemory)(size_t, size_t);
    void (*freeMemory)(void *);
    void (*stepFinished)(void *, fmi2Status);
    void *componentEnvironment;
} fmi2CallbackFunctions;

typedef fmi2Component (*Instantiate)(const char *, int, const char *, const char *,
                                     const fmi2CallbackFunctions *, fmi2Boolean, fmi2Boolean);
typedef fmi2Status (*SetupExperiment)(fmi2Component, fmi2Boolean, fmi2Real, fmi2Real, fmi2Boolean, fmi2Real);
typedef fmi2Status (*Simple)(fmi2Component);
typedef fmi2Status (*GetReal)(fmi2Component, const fmi2ValueReference *, size_t, fmi2Real *);
typedef fmi2Status (*DoStep)(fmi2Component, fmi2Real, fmi2Real, fmi2Boolean);
typedef void (*FreeInstance)(fmi2Component);

static void logger(void *env, const char *instance, fmi2Status status, const char *category, const char *message, ...) {
    (void)env;
    (void)category;
    va_list args;
    va_start(args, message);
    fprintf(stderr, "[%s %d] ", instance, status);
    vfprintf(stderr, message, args);
    fprintf(stderr, "\n");
    va_end(args);
}

static void *symbol(void *library, const char *name) {
    void *address = dlsym(library, name);
    if (!address) {
        fprintf(stderr, "missing %s\n", name);
        exit(1);
    }
    return address;
}

static void check(fmi2Status status, const char *call) {
    if (status > 1) {
        fprintf(stderr, "%s failed with status %d\n", call, status);
        exit(1);
    }
}

int main(int argc, char **argv) {
    if (argc < 7) {
        fprintf(stderr, "usage: %s UNZIPPED_DIR MODEL_IDENTIFIER GUID STEPS STEP_SIZE VR [VR ...]\n", argv[0]);
        return 2;
    }
    const char *dir = argv[1], *model = argv[2], *guid = argv[3];
    int steps = atoi(argv[4]);
    double h = atof(argv[5]);
    size_t n = (size_t)(argc - 6);
    fmi2ValueReference *vr = calloc(n, sizeof *vr);
    fmi2Real *values = calloc(n, sizeof *values);
    for (size_t i = 0; i < n; i++) vr[i] = (fmi2ValueReference)atoi(argv[6 + i]);

    char path[4096], resources[4096];
    snprintf(path, sizeof path, "%s/binaries/linux64/%s.so", dir, model);
    snprintf(resources, sizeof resources, "file://%s/resources", dir);
    void *library = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (!library) {
        fprintf(stderr, "cannot load %s\n", dlerror());
        return 1;
    }
    fmi2CallbackFunctions callbacks = {logger, calloc, free, NULL, NULL};
    fmi2Component c = ((Instantiate)symbol(library, "fmi2Instantiate"))(model, 1, guid, resources, &callbacks, 0, 1);
    if (!c) {
        fprintf(stderr, "fmi2Instantiate failed\n");
        return 1;
    }
    GetReal get = (GetReal)symbol(library, "fmi2GetReal");
    DoStep step = (DoStep)symbol(library, "fmi2DoStep");
    check(((SetupExperiment)symbol(library, "fmi2SetupExperiment"))(c, 0, 0.0, 0.0, 0, 0.0), "fmi2SetupExperiment");
    check(((Simple)symbol(library, "fmi2EnterInitializationMode"))(c), "fmi2EnterInitializationMode");
    check(((Simple)symbol(library, "fmi2ExitInitializationMode"))(c), "fmi2ExitInitializationMode");
    for (int k = 0; k <= steps; k++) {
        check(get(c, vr, n, values), "fmi2GetReal");
        printf("%.17g", k * h);
        for (size_t i = 0; i < n; i++) printf(",%.17g", values[i]);
        printf("\n");
        if (k < steps) check(step(c, k * h, h, 1), "fmi2DoStep");
    }
    check(((Simple)symbol(library, "fmi2Terminate"))(c), "fmi2Terminate");
    ((FreeInstance)symbol(library, "fmi2FreeInstance"))(c);
    free(vr);
    free(values);
    return 0;
}
