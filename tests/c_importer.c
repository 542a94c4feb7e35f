/* A minimal FMI 2.0 / 3.0 co-simulation importer in C, as a non-Python tool loads FMUs.

   usage: c_importer FMI_VERSION UNZIPPED_DIRS MODEL_IDENTIFIER GUIDS STEPS STEP_SIZE VR [VR ...]
   UNZIPPED_DIRS and GUIDS (or instantiation tokens) name one FMU or several of the same model, comma
   separated; each is loaded from its own binaries/linux64/<MODEL_IDENTIFIER>.so (FMI 2.0) or
   binaries/x86_64-linux/... (FMI 3.0), on Windows binaries/win64/<MODEL_IDENTIFIER>.dll or
   binaries/x86_64-windows/..., into this one process. Instantiates and initialises each, does
   STEPS steps of STEP_SIZE with all of them in turn and prints "time,value,..." with the given Real
   (Float64) value references of each FMU in order, at t = 0 and after every step; exits 1 with a
   message on the first failing call, 2 if an instantiation returns NULL.
   DSC_TEST_RESOURCES, if set, is the resource location given to every instance instead of the
   folder's file URI (FMI 2.0) or path (FMI 3.0). DSC_TEST_ROUNDS (default 1) repeats the whole run,
   each round with the binaries unloaded (dlclose, FreeLibrary) and loaded again. */

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi_host.h"

#define MAX_FMUS 8

typedef struct {
    void *library;
    void *instance;
} Fmu;

/* The resource location of the FMU unzipped in `dir`: DSC_TEST_RESOURCES if set, else `format` with `dir`. */
static void resources_of(char *resources, size_t size, const char *format, const char *dir) {
    const char *given = getenv("DSC_TEST_RESOURCES");
    if (given) snprintf(resources, size, "%s", given);
    else snprintf(resources, size, format, dir);
}

static int start2(Fmu *fmu, const char *dir, const char *model, const char *guid) {
    char resources[4096];
    resources_of(resources, sizeof resources, HOST_RESOURCES_URI, dir);
    static fmi2CallbackFunctions callbacks = {logger2, calloc, free, NULL, NULL};
    void *c = ((fmi2InstantiateTYPE *)host_require(fmu->library, "fmi2Instantiate"))(
        model, fmi2CoSimulation, guid, resources, &callbacks, fmi2False, fmi2True);
    if (!c) {
        fprintf(stderr, "fmi2Instantiate returned NULL\n");
        return 2;
    }
    fmu->instance = c;
    check(((fmi2SetupExperimentTYPE *)host_require(fmu->library, "fmi2SetupExperiment"))(c, 0, 0.0, 0.0, 0, 0.0),
          "fmi2SetupExperiment");
    check(((fmi2EnterInitializationModeTYPE *)host_require(fmu->library, "fmi2EnterInitializationMode"))(c),
          "fmi2EnterInitializationMode");
    check(((fmi2ExitInitializationModeTYPE *)host_require(fmu->library, "fmi2ExitInitializationMode"))(c),
          "fmi2ExitInitializationMode");
    return 0;
}

static int start3(Fmu *fmu, const char *dir, const char *model, const char *token) {
    char resources[4096];
    resources_of(resources, sizeof resources, "%s/resources/", dir);
    void *c = ((fmi3InstantiateCoSimulationTYPE *)host_require(fmu->library, "fmi3InstantiateCoSimulation"))(
        model, token, resources, fmi3False, fmi3True, fmi3False, fmi3False, NULL, 0, NULL, logger3, NULL);
    if (!c) {
        fprintf(stderr, "fmi3InstantiateCoSimulation returned NULL\n");
        return 2;
    }
    fmu->instance = c;
    check(((fmi3EnterInitializationModeTYPE *)host_require(fmu->library, "fmi3EnterInitializationMode"))(
              c, fmi3False, 0.0, 0.0, fmi3False, 0.0), "fmi3EnterInitializationMode");
    check(((fmi3ExitInitializationModeTYPE *)host_require(fmu->library, "fmi3ExitInitializationMode"))(c),
          "fmi3ExitInitializationMode");
    return 0;
}

static void get(int version, Fmu *fmu, const unsigned int *vr, double *values, size_t n) {
    if (version == 3) {
        check(((fmi3GetFloat64TYPE *)host_require(fmu->library, "fmi3GetFloat64"))(fmu->instance, vr, n, values, n),
              "fmi3GetFloat64");
    } else {
        check(((fmi2GetRealTYPE *)host_require(fmu->library, "fmi2GetReal"))(fmu->instance, vr, n, values), "fmi2GetReal");
    }
}

static void step(int version, Fmu *fmu, double t, double h) {
    if (version == 3) {
        fmi3Boolean event, terminate, early;
        fmi3Float64 last;
        check(((fmi3DoStepTYPE *)host_require(fmu->library, "fmi3DoStep"))(fmu->instance, t, h, fmi3True, &event, &terminate,
                                                                     &early, &last), "fmi3DoStep");
    } else {
        check(((fmi2DoStepTYPE *)host_require(fmu->library, "fmi2DoStep"))(fmu->instance, t, h, fmi2True), "fmi2DoStep");
    }
}

static void finish(int version, Fmu *fmu) {
    if (version == 3) {
        check(((fmi3TerminateTYPE *)host_require(fmu->library, "fmi3Terminate"))(fmu->instance), "fmi3Terminate");
        ((fmi3FreeInstanceTYPE *)host_require(fmu->library, "fmi3FreeInstance"))(fmu->instance);
    } else {
        check(((fmi2TerminateTYPE *)host_require(fmu->library, "fmi2Terminate"))(fmu->instance), "fmi2Terminate");
        ((fmi2FreeInstanceTYPE *)host_require(fmu->library, "fmi2FreeInstance"))(fmu->instance);
    }
}

/* Split `list` at commas in place; the number of items, or -1 if there are more than MAX_FMUS. */
static int split(char *list, char **items) {
    int n = 0;
    for (char *item = strtok(list, ","); item; item = strtok(NULL, ",")) {
        if (n == MAX_FMUS) return -1;
        items[n++] = item;
    }
    return n;
}

/* One round: load, instantiate and initialise every FMU, step them, print, free and unload; 0, or
   the exit status. */
static int run(int version, int count, char **dirs, const char *model, char **guids, int steps, double h,
               const unsigned int *vr, double *values, size_t n) {
    Fmu fmus[MAX_FMUS];
    for (int f = 0; f < count; f++) {
        char path[4096];
        snprintf(path, sizeof path, "%s/binaries/%s/%s" HOST_SUFFIX, dirs[f], version == 3 ? HOST_FOLDER3 : HOST_FOLDER2, model);
        fmus[f].library = host_load(path);
        if (!fmus[f].library) {
            fprintf(stderr, "cannot load %s\n", host_error());
            return 1;
        }
        int started = version == 3 ? start3(&fmus[f], dirs[f], model, guids[f])
                                   : start2(&fmus[f], dirs[f], model, guids[f]);
        if (started != 0) return started;
    }
    for (int k = 0; k <= steps; k++) {
        printf("%.17g", k * h);
        for (int f = 0; f < count; f++) {
            get(version, &fmus[f], vr, values, n);
            for (size_t i = 0; i < n; i++) printf(",%.17g", values[i]);
        }
        printf("\n");
        for (int f = 0; k < steps && f < count; f++) step(version, &fmus[f], k * h, h);
    }
    for (int f = 0; f < count; f++) finish(version, &fmus[f]);
    for (int f = 0; f < count; f++) host_unload(fmus[f].library);
    return 0;
}

int main(int argc, char **argv) {
    if (argc < 8) {
        fprintf(stderr, "usage: %s FMI_VERSION UNZIPPED_DIRS MODEL_IDENTIFIER GUIDS STEPS STEP_SIZE VR [VR ...]\n",
                argv[0]);
        return 2;
    }
    int version = atoi(argv[1]);
    char *dirs[MAX_FMUS], *guids[MAX_FMUS];
    int count = split(argv[2], dirs);
    const char *model = argv[3];
    if (count < 1 || split(argv[4], guids) != count) {
        fprintf(stderr, "1 to %d UNZIPPED_DIRS and as many GUIDS are needed\n", MAX_FMUS);
        return 2;
    }
    int steps = atoi(argv[5]);
    double h = atof(argv[6]);
    size_t n = (size_t)(argc - 7);
    unsigned int *vr = calloc(n, sizeof *vr);
    double *values = calloc(n, sizeof *values);
    for (size_t i = 0; i < n; i++) vr[i] = (unsigned int)strtoul(argv[7 + i], NULL, 10);

    const char *rounds_text = getenv("DSC_TEST_ROUNDS");
    int rounds = rounds_text ? atoi(rounds_text) : 1;
    for (int round = 0; round < rounds; round++) {
        int status = run(version, count, dirs, model, guids, steps, h, vr, values, n);
        if (status != 0) return status;
    }
    free(vr);
    free(values);
    return 0;
}
