/* A C host that embeds CPython and frees its FMU instances once that Python has finalized, as an
   application's destructors may after Py_FinalizeEx.

   usage: c_finalized LIBPYTHON FMI_VERSION UNZIPPED_DIR MODEL_IDENTIFIER TOKEN WHEN
   Loads LIBPYTHON (global, as an embedding application links it) and starts it (its home from
   PYTHONHOME), loads the FMU in UNZIPPED_DIR and makes a co-simulation and a model-exchange instance,
   each initialised and with an FMU state; then finalizes Python, terminates the instances and frees
   the FMU states and the instances: after Py_FinalizeEx returned (WHEN "after") or from a function Py_AtExit registered,
   which Py_FinalizeEx calls last (WHEN "atexit"). The FMU's messages go to stderr (fmi_host.h's
   loggers); "freed" to stdout once done. Exits 1 on the first failing call. Linux only. */

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi_host.h"

enum { INSTANCES = 2 };

static void *library;
static int version;
static void *instances[INSTANCES];
static void *states[INSTANCES];

static void *start2(const char *dir, const char *model, const char *guid, int model_exchange) {
    static fmi2CallbackFunctions callbacks = {logger2, calloc, free, NULL, NULL};
    char resources[4096];
    snprintf(resources, sizeof resources, HOST_RESOURCES_URI, dir);
    void *c = ((fmi2InstantiateTYPE *)host_require(library, "fmi2Instantiate"))(
        model, model_exchange ? fmi2ModelExchange : fmi2CoSimulation, guid, resources, &callbacks, fmi2False, fmi2True);
    if (!c) exit(1);
    check(((fmi2SetupExperimentTYPE *)host_require(library, "fmi2SetupExperiment"))(c, 0, 0.0, 0.0, 0, 0.0),
          "fmi2SetupExperiment");
    check(((fmi2EnterInitializationModeTYPE *)host_require(library, "fmi2EnterInitializationMode"))(c),
          "fmi2EnterInitializationMode");
    check(((fmi2ExitInitializationModeTYPE *)host_require(library, "fmi2ExitInitializationMode"))(c),
          "fmi2ExitInitializationMode");
    return c;
}

static void *start3(const char *dir, const char *model, const char *token, int model_exchange) {
    char resources[4096];
    snprintf(resources, sizeof resources, "%s/resources/", dir);
    void *c = model_exchange
        ? ((fmi3InstantiateModelExchangeTYPE *)host_require(library, "fmi3InstantiateModelExchange"))(
              model, token, resources, fmi3False, fmi3True, NULL, logger3)
        : ((fmi3InstantiateCoSimulationTYPE *)host_require(library, "fmi3InstantiateCoSimulation"))(
              model, token, resources, fmi3False, fmi3True, fmi3False, fmi3False, NULL, 0, NULL, logger3, NULL);
    if (!c) exit(1);
    check(((fmi3EnterInitializationModeTYPE *)host_require(library, "fmi3EnterInitializationMode"))(
              c, fmi3False, 0.0, 0.0, fmi3False, 0.0), "fmi3EnterInitializationMode");
    check(((fmi3ExitInitializationModeTYPE *)host_require(library, "fmi3ExitInitializationMode"))(c),
          "fmi3ExitInitializationMode");
    return c;
}

static void free_all(void) {
    for (int i = 0; i < INSTANCES; i++) {
        if (version == 3) {
            check(((fmi3TerminateTYPE *)host_require(library, "fmi3Terminate"))(instances[i]), "fmi3Terminate");
            check(((fmi3FreeFMUStateTYPE *)host_require(library, "fmi3FreeFMUState"))(instances[i], &states[i]),
                  "fmi3FreeFMUState");
            ((fmi3FreeInstanceTYPE *)host_require(library, "fmi3FreeInstance"))(instances[i]);
        } else {
            check(((fmi2TerminateTYPE *)host_require(library, "fmi2Terminate"))(instances[i]), "fmi2Terminate");
            check(((fmi2FreeFMUstateTYPE *)host_require(library, "fmi2FreeFMUstate"))(instances[i], &states[i]),
                  "fmi2FreeFMUstate");
            ((fmi2FreeInstanceTYPE *)host_require(library, "fmi2FreeInstance"))(instances[i]);
        }
    }
    printf("freed\n");
    fflush(stdout);
}

int main(int argc, char **argv) {
    if (argc != 7) {
        fprintf(stderr, "usage: %s LIBPYTHON FMI_VERSION UNZIPPED_DIR MODEL_IDENTIFIER TOKEN after|atexit\n", argv[0]);
        return 2;
    }
    void *python = dlopen(argv[1], RTLD_NOW | RTLD_GLOBAL);
    if (!python) {
        fprintf(stderr, "cannot load %s\n", dlerror());
        return 1;
    }
    ((void (*)(int))host_require(python, "Py_InitializeEx"))(0);
    version = atoi(argv[2]);
    char path[4096];
    snprintf(path, sizeof path, "%s/binaries/%s/%s" HOST_SUFFIX, argv[3], version == 3 ? HOST_FOLDER3 : HOST_FOLDER2,
             argv[4]);
    library = host_load(path);
    if (!library) {
        fprintf(stderr, "cannot load %s\n", host_error());
        return 1;
    }
    for (int i = 0; i < INSTANCES; i++) {
        instances[i] = version == 3 ? start3(argv[3], argv[4], argv[5], i) : start2(argv[3], argv[4], argv[5], i);
        if (i == 0 && version == 3) {
            fmi3Boolean event, terminate, early;
            fmi3Float64 last;
            check(((fmi3DoStepTYPE *)host_require(library, "fmi3DoStep"))(instances[i], 0.0, 0.01, fmi3True, &event,
                                                                   &terminate, &early, &last), "fmi3DoStep");
        } else if (i == 0) {
            check(((fmi2DoStepTYPE *)host_require(library, "fmi2DoStep"))(instances[i], 0.0, 0.01, fmi2True), "fmi2DoStep");
        }
        check(version == 3 ? ((fmi3GetFMUStateTYPE *)host_require(library, "fmi3GetFMUState"))(instances[i], &states[i])
                           : ((fmi2GetFMUstateTYPE *)host_require(library, "fmi2GetFMUstate"))(instances[i], &states[i]),
              "getting the FMU state");
    }
    int at_exit = strcmp(argv[6], "atexit") == 0;
    if (at_exit && ((int (*)(void (*)(void)))host_require(python, "Py_AtExit"))(free_all) != 0) return 1;
    if (((int (*)(void))host_require(python, "Py_FinalizeEx"))() != 0) return 1;
    if (!at_exit) free_all();
    return 0;
}
