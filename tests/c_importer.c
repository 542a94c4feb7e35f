/* A minimal FMI 2.0 / 3.0 co-simulation importer in C, as a non-Python tool loads one FMU.

   usage: c_importer FMI_VERSION UNZIPPED_DIR MODEL_IDENTIFIER GUID_OR_TOKEN STEPS STEP_SIZE VR [VR ...]
   Loads binaries/linux64/<MODEL_IDENTIFIER>.so (FMI 2.0) or binaries/x86_64-linux/... (FMI 3.0),
   instantiates, initialises, does STEPS steps of STEP_SIZE and prints "time,value,..." of the given
   Real (Float64) value references at t = 0 and after every step; exits 1 with a message on the first
   failing call, 2 if instantiation returns NULL. */

#include <dlfcn.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

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

static void *symbol(void *library, const char *name) {
    void *address = dlsym(library, name);
    if (!address) {
        fprintf(stderr, "missing %s\n", name);
        exit(1);
    }
    return address;
}

static void check(int status, const char *call) {
    if (status > 1) {
        fprintf(stderr, "%s failed with status %d\n", call, status);
        exit(1);
    }
}

static void print_row(double t, const double *values, size_t n) {
    printf("%.17g", t);
    for (size_t i = 0; i < n; i++) printf(",%.17g", values[i]);
    printf("\n");
}

static int run2(void *library, const char *dir, const char *model, const char *guid, int steps, double h,
                const unsigned int *vr, double *values, size_t n) {
    char resources[4096];
    snprintf(resources, sizeof resources, "file://%s/resources", dir);
    static fmi2CallbackFunctions callbacks = {logger2, calloc, free, NULL, NULL};
    fmi2Component c = ((fmi2InstantiateTYPE *)symbol(library, "fmi2Instantiate"))(
        model, fmi2CoSimulation, guid, resources, &callbacks, fmi2False, fmi2True);
    if (!c) {
        fprintf(stderr, "fmi2Instantiate returned NULL\n");
        return 2;
    }
    fmi2GetRealTYPE *get = symbol(library, "fmi2GetReal");
    fmi2DoStepTYPE *step = symbol(library, "fmi2DoStep");
    check(((fmi2SetupExperimentTYPE *)symbol(library, "fmi2SetupExperiment"))(c, 0, 0.0, 0.0, 0, 0.0), "fmi2SetupExperiment");
    check(((fmi2EnterInitializationModeTYPE *)symbol(library, "fmi2EnterInitializationMode"))(c), "fmi2EnterInitializationMode");
    check(((fmi2ExitInitializationModeTYPE *)symbol(library, "fmi2ExitInitializationMode"))(c), "fmi2ExitInitializationMode");
    for (int k = 0; k <= steps; k++) {
        check(get(c, vr, n, values), "fmi2GetReal");
        print_row(k * h, values, n);
        if (k < steps) check(step(c, k * h, h, fmi2True), "fmi2DoStep");
    }
    check(((fmi2TerminateTYPE *)symbol(library, "fmi2Terminate"))(c), "fmi2Terminate");
    ((fmi2FreeInstanceTYPE *)symbol(library, "fmi2FreeInstance"))(c);
    return 0;
}

static int run3(void *library, const char *dir, const char *model, const char *token, int steps, double h,
                const unsigned int *vr, double *values, size_t n) {
    char resources[4096];
    snprintf(resources, sizeof resources, "%s/resources/", dir);
    fmi3Instance c = ((fmi3InstantiateCoSimulationTYPE *)symbol(library, "fmi3InstantiateCoSimulation"))(
        model, token, resources, fmi3False, fmi3True, fmi3False, fmi3False, NULL, 0, NULL, logger3, NULL);
    if (!c) {
        fprintf(stderr, "fmi3InstantiateCoSimulation returned NULL\n");
        return 2;
    }
    fmi3GetFloat64TYPE *get = symbol(library, "fmi3GetFloat64");
    fmi3DoStepTYPE *step = symbol(library, "fmi3DoStep");
    check(((fmi3EnterInitializationModeTYPE *)symbol(library, "fmi3EnterInitializationMode"))(c, fmi3False, 0.0, 0.0,
                                                                                                fmi3False, 0.0),
          "fmi3EnterInitializationMode");
    check(((fmi3ExitInitializationModeTYPE *)symbol(library, "fmi3ExitInitializationMode"))(c), "fmi3ExitInitializationMode");
    for (int k = 0; k <= steps; k++) {
        check(get(c, vr, n, values, n), "fmi3GetFloat64");
        print_row(k * h, values, n);
        fmi3Boolean event, terminate, early;
        fmi3Float64 last;
        if (k < steps) check(step(c, k * h, h, fmi3True, &event, &terminate, &early, &last), "fmi3DoStep");
    }
    check(((fmi3TerminateTYPE *)symbol(library, "fmi3Terminate"))(c), "fmi3Terminate");
    ((fmi3FreeInstanceTYPE *)symbol(library, "fmi3FreeInstance"))(c);
    return 0;
}

int main(int argc, char **argv) {
    if (argc < 8) {
        fprintf(stderr, "usage: %s FMI_VERSION UNZIPPED_DIR MODEL_IDENTIFIER GUID STEPS STEP_SIZE VR [VR ...]\n", argv[0]);
        return 2;
    }
    int version = atoi(argv[1]);
    const char *dir = argv[2], *model = argv[3], *guid = argv[4];
    int steps = atoi(argv[5]);
    double h = atof(argv[6]);
    size_t n = (size_t)(argc - 7);
    unsigned int *vr = calloc(n, sizeof *vr);
    double *values = calloc(n, sizeof *values);
    for (size_t i = 0; i < n; i++) vr[i] = (unsigned int)strtoul(argv[7 + i], NULL, 10);

    char path[4096];
    snprintf(path, sizeof path, "%s/binaries/%s/%s.so", dir, version == 3 ? "x86_64-linux" : "linux64", model);
    void *library = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (!library) {
        fprintf(stderr, "cannot load %s\n", dlerror());
        return 1;
    }
    int result = version == 3 ? run3(library, dir, model, guid, steps, h, vr, values, n)
                              : run2(library, dir, model, guid, steps, h, vr, values, n);
    free(vr);
    free(values);
    return result;
}
