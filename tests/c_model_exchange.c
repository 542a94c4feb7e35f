/* A minimal FMI 2.0 / 3.0 model-exchange importer in C, as a tool with its own solver loads an FMU.

   usage: c_model_exchange FMI_VERSION UNZIPPED_DIR MODEL_IDENTIFIER GUID NX NZ STEPS STEP_SIZE VR [VR ...]
   Instantiates the FMU for model exchange, initialises it (inputs at their start values, held), runs the
   event iteration and integrates its NX states with classical RK4 at STEP_SIZE for STEPS steps; after
   each step it reads the NZ event indicators and, where one changed sign, enters event mode and iterates.
   Prints "time,value,..." with the given Real (Float64) value references at t = 0 and after every step,
   then "events,N"; exits 1 with a message on the first failing call, 2 if the instantiation returns NULL.
   With STATE_VRS set (the states' value references, comma-separated, in the order of the state vector), it
   sets the states by value reference (fmi2SetReal / fmi3SetFloat64), as PyFMI does, instead of with
   fmi2SetContinuousStates / fmi3SetContinuousStates.
   With JACOBIAN set ("KNOWN:UNKNOWN,UNKNOWN,...", value references), it prints after the last step, in
   continuous-time mode, "states,x..." (the state vector) and "jacobian,d..." (the column of the known:
   fmi2GetDirectionalDerivative / fmi3GetDirectionalDerivative with the seed 1), and for FMI 3.0
   "adjoint,d..." (the same entries, each from fmi3GetAdjointDerivative with the unknown's seed 1).
   With TIMING set (a number of calls N), it then prints "timing,E,C": the processor seconds of one derivative
   evaluation (fmiSetTime, the states set, fmiGetDerivatives) and of one JACOBIAN column (0 without it), the
   means over N calls of each. */

#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#include "fmi_host.h"

static void *library;
static void *instance;
static int version;
static unsigned int *state_vrs; /* NULL: the states are set with fmiSetContinuousStates */

static void *symbol(const char *name) {
    return host_require(library, name);
}

/* Call the function named by its FMI 2.0 or 3.0 name, of the type given for each, with the same arguments. */
#define CALL(type2, name2, type3, name3, ...)                                                                      \
    (version == 3 ? check(((type3 *)symbol(#name3))(instance, __VA_ARGS__), #name3)                               \
                  : check(((type2 *)symbol(#name2))(instance, __VA_ARGS__), #name2))
#define CALL0(type2, name2, type3, name3)                                                                          \
    (version == 3 ? check(((type3 *)symbol(#name3))(instance), #name3)                                             \
                  : check(((type2 *)symbol(#name2))(instance), #name2))

static int start(const char *dir, const char *model, const char *guid) {
    char resources[4096];
    if (version == 3) {
        snprintf(resources, sizeof resources, "%s/resources/", dir);
        instance = ((fmi3InstantiateModelExchangeTYPE *)symbol("fmi3InstantiateModelExchange"))(
            model, guid, resources, fmi3False, fmi3True, NULL, logger3);
    } else {
        static fmi2CallbackFunctions callbacks = {logger2, calloc, free, NULL, NULL};
        snprintf(resources, sizeof resources, HOST_RESOURCES_URI, dir);
        instance = ((fmi2InstantiateTYPE *)symbol("fmi2Instantiate"))(model, fmi2ModelExchange, guid, resources,
                                                                     &callbacks, fmi2False, fmi2True);
    }
    if (!instance) {
        fprintf(stderr, "the instantiation returned NULL\n");
        return 2;
    }
    if (version == 3) {
        check(((fmi3EnterInitializationModeTYPE *)symbol("fmi3EnterInitializationMode"))(
                  instance, fmi3False, 0.0, 0.0, fmi3False, 0.0), "fmi3EnterInitializationMode");
    } else {
        check(((fmi2SetupExperimentTYPE *)symbol("fmi2SetupExperiment"))(instance, 0, 0.0, 0.0, 0, 0.0),
              "fmi2SetupExperiment");
        check(((fmi2EnterInitializationModeTYPE *)symbol("fmi2EnterInitializationMode"))(instance),
              "fmi2EnterInitializationMode");
    }
    CALL0(fmi2ExitInitializationModeTYPE, fmi2ExitInitializationMode, fmi3ExitInitializationModeTYPE,
          fmi3ExitInitializationMode);
    return 0;
}

/* In event mode: update the discrete states until none needs more, then continuous-time mode. */
static void iterate(void) {
    int more = 1;
    while (more) {
        if (version == 3) {
            fmi3Boolean needed, terminate, nominals, values, defined;
            fmi3Float64 next;
            check(((fmi3UpdateDiscreteStatesTYPE *)symbol("fmi3UpdateDiscreteStates"))(
                      instance, &needed, &terminate, &nominals, &values, &defined, &next), "fmi3UpdateDiscreteStates");
            more = needed;
        } else {
            fmi2EventInfo info;
            check(((fmi2NewDiscreteStatesTYPE *)symbol("fmi2NewDiscreteStates"))(instance, &info),
                  "fmi2NewDiscreteStates");
            more = info.newDiscreteStatesNeeded;
        }
    }
    CALL0(fmi2EnterContinuousTimeModeTYPE, fmi2EnterContinuousTimeMode, fmi3EnterContinuousTimeModeTYPE,
          fmi3EnterContinuousTimeMode);
}

/* The states x: by value reference if STATE_VRS gave them, else as the state vector. */
static void set_states(const double *x, size_t nx) {
    if (!state_vrs) {
        CALL(fmi2SetContinuousStatesTYPE, fmi2SetContinuousStates, fmi3SetContinuousStatesTYPE,
             fmi3SetContinuousStates, x, nx);
    } else if (version == 3) {
        check(((fmi3SetFloat64TYPE *)symbol("fmi3SetFloat64"))(instance, state_vrs, nx, x, nx), "fmi3SetFloat64");
    } else {
        check(((fmi2SetRealTYPE *)symbol("fmi2SetReal"))(instance, state_vrs, nx, x), "fmi2SetReal");
    }
}

/* The value references of `text` ("A,B,..."), up to `capacity` into `vrs`; their number, or -1 if `text` is
   anything else. */
static long parse_vrs(const char *text, unsigned int *vrs, size_t capacity) {
    char *end = (char *)text;
    size_t i = 0;
    for (; i < capacity && *text; i++, text = end + (*end == ',')) {
        vrs[i] = (unsigned int)strtoul(text, &end, 10);
        if (end == text) return -1;
    }
    return *text ? -1 : (long)i;
}

/* The known and the unknowns that JACOBIAN names (see the top): the unknowns' number, 0 if it is not set. */
static long jacobian_request(unsigned int *known, unsigned int unknowns[64]) {
    const char *text = getenv("JACOBIAN");
    if (!text) return 0;
    char *end = (char *)text;
    *known = (unsigned int)strtoul(text, &end, 10);
    long n = *end == ':' && end != text ? parse_vrs(end + 1, unknowns, 64) : -1;
    if (n <= 0) {
        fprintf(stderr, "JACOBIAN = %s: not KNOWN:UNKNOWN,...\n", text);
        exit(1);
    }
    return n;
}

/* The column of the unknowns by the known, seed 1. */
static void jacobian_column(unsigned int known, const unsigned int *unknowns, long n, double *column) {
    double seed = 1.0;
    if (version == 3) {
        check(((fmi3GetDirectionalDerivativeTYPE *)symbol("fmi3GetDirectionalDerivative"))(
                  instance, unknowns, (size_t)n, &known, 1, &seed, 1, column, (size_t)n),
              "fmi3GetDirectionalDerivative");
    } else {
        check(((fmi2GetDirectionalDerivativeTYPE *)symbol("fmi2GetDirectionalDerivative"))(
                  instance, unknowns, (size_t)n, &known, 1, &seed, column), "fmi2GetDirectionalDerivative");
    }
}

/* The Jacobian column that JACOBIAN asks for (see the top), printed; nothing if it is not set. */
static void print_jacobian(const double *x, size_t nx) {
    unsigned int known = 0, unknowns[64];
    long n = jacobian_request(&known, unknowns);
    if (!n) return;
    double seed = 1.0, column[64], entry;
    jacobian_column(known, unknowns, n, column);
    printf("states");
    for (size_t i = 0; i < nx; i++) printf(",%.17g", x[i]);
    printf("\njacobian");
    for (long i = 0; i < n; i++) printf(",%.17g", column[i]);
    printf("\n");
    if (version != 3) return;
    printf("adjoint");
    for (long i = 0; i < n; i++) {
        check(((fmi3GetAdjointDerivativeTYPE *)symbol("fmi3GetAdjointDerivative"))(
                  instance, &unknowns[i], 1, &known, 1, &seed, 1, &entry, 1), "fmi3GetAdjointDerivative");
        printf(",%.17g", entry);
    }
    printf("\n");
}

/* The value references of STATE_VRS, nx of them, or NULL if it is not set; exits 1 if it holds other than nx. */
static unsigned int *read_state_vrs(size_t nx) {
    const char *text = getenv("STATE_VRS");
    if (!text) return NULL;
    unsigned int *vrs = calloc(nx + 1, sizeof *vrs);
    if (!vrs || parse_vrs(text, vrs, nx) != (long)nx) {
        fprintf(stderr, "STATE_VRS = %s: not %zu value references\n", getenv("STATE_VRS"), nx);
        exit(1);
    }
    return vrs;
}

/* The derivatives at time t and states x. */
static void derivatives(double t, const double *x, double *dx, size_t nx) {
    CALL(fmi2SetTimeTYPE, fmi2SetTime, fmi3SetTimeTYPE, fmi3SetTime, t);
    set_states(x, nx);
    CALL(fmi2GetDerivativesTYPE, fmi2GetDerivatives, fmi3GetContinuousStateDerivativesTYPE,
         fmi3GetContinuousStateDerivatives, dx, nx);
}

/* One classical RK4 step of h from time t, in the arithmetic of the FMUs' own (models/rk4.py). */
static void rk4(double t, double h, double *x, size_t nx, double *k[4], double *y) {
    double half = 0.5 * h, sixth = h / 6.0;
    derivatives(t, x, k[0], nx);
    for (size_t i = 0; i < nx; i++) y[i] = x[i] + half * k[0][i];
    derivatives(t + half, y, k[1], nx);
    for (size_t i = 0; i < nx; i++) y[i] = x[i] + half * k[1][i];
    derivatives(t + half, y, k[2], nx);
    for (size_t i = 0; i < nx; i++) y[i] = x[i] + h * k[2][i];
    derivatives(t + h, y, k[3], nx);
    for (size_t i = 0; i < nx; i++) x[i] = x[i] + sixth * (k[0][i] + 2.0 * k[1][i] + 2.0 * k[2][i] + k[3][i]);
}

/* What TIMING asks for (see the top), at time t and states x; nothing if it is not set. */
static void print_timing(double t, const double *x, size_t nx) {
    const char *text = getenv("TIMING");
    long calls = text ? atol(text) : 0;
    if (calls <= 0) return;
    double *dx = calloc(nx + 1, sizeof *dx), column[64];
    clock_t start = clock();
    for (long i = 0; i < calls; i++) derivatives(t, x, dx, nx);
    double evaluation = (double)(clock() - start) / CLOCKS_PER_SEC / (double)calls, per_column = 0.0;
    unsigned int known = 0, unknowns[64];
    long n = jacobian_request(&known, unknowns);
    if (n) {
        start = clock();
        for (long i = 0; i < calls; i++) jacobian_column(known, unknowns, n, column);
        per_column = (double)(clock() - start) / CLOCKS_PER_SEC / (double)calls;
    }
    printf("timing,%.6g,%.6g\n", evaluation, per_column);
    free(dx);
}

static void indicators(double *z, size_t nz) {
    if (nz) CALL(fmi2GetEventIndicatorsTYPE, fmi2GetEventIndicators, fmi3GetEventIndicatorsTYPE, fmi3GetEventIndicators,
                 z, nz);
}

static void print_row(double t, const unsigned int *vr, double *values, size_t n) {
    if (version == 3) {
        check(((fmi3GetFloat64TYPE *)symbol("fmi3GetFloat64"))(instance, vr, n, values, n), "fmi3GetFloat64");
    } else {
        check(((fmi2GetRealTYPE *)symbol("fmi2GetReal"))(instance, vr, n, values), "fmi2GetReal");
    }
    printf("%.17g", t);
    for (size_t i = 0; i < n; i++) printf(",%.17g", values[i]);
    printf("\n");
}

int main(int argc, char **argv) {
    if (argc < 10) {
        fprintf(stderr, "usage: %s FMI_VERSION UNZIPPED_DIR MODEL_IDENTIFIER GUID NX NZ STEPS STEP_SIZE VR [VR ...]\n",
                argv[0]);
        return 2;
    }
    version = atoi(argv[1]);
    const char *dir = argv[2], *model = argv[3], *guid = argv[4];
    size_t nx = strtoul(argv[5], NULL, 10), nz = strtoul(argv[6], NULL, 10);
    int steps = atoi(argv[7]);
    double h = atof(argv[8]);
    size_t n = (size_t)(argc - 9);
    char path[4096];
    snprintf(path, sizeof path, "%s/binaries/%s/%s" HOST_SUFFIX, dir, version == 3 ? HOST_FOLDER3 : HOST_FOLDER2, model);
    library = host_load(path);
    if (!library) {
        fprintf(stderr, "cannot load %s\n", host_error());
        return 1;
    }
    state_vrs = read_state_vrs(nx);
    int started = start(dir, model, guid);
    if (started) return started;
    iterate();
    unsigned int *vr = calloc(n, sizeof *vr);
    double *values = calloc(n, sizeof *values), *x = calloc(nx + 1, sizeof *x), *y = calloc(nx + 1, sizeof *y);
    double *z = calloc(nz + 1, sizeof *z), *before = calloc(nz + 1, sizeof *before), *k[4];
    for (int j = 0; j < 4; j++) k[j] = calloc(nx + 1, sizeof *k[j]);
    for (size_t i = 0; i < n; i++) vr[i] = (unsigned int)strtoul(argv[9 + i], NULL, 10);
    CALL(fmi2GetContinuousStatesTYPE, fmi2GetContinuousStates, fmi3GetContinuousStatesTYPE, fmi3GetContinuousStates,
         x, nx);
    indicators(before, nz);
    print_row(0.0, vr, values, n);
    int events = 0;
    for (int s = 0; s < steps; s++) {
        double t = s * h, end = (s + 1) * h;
        rk4(t, h, x, nx, k, y);
        CALL(fmi2SetTimeTYPE, fmi2SetTime, fmi3SetTimeTYPE, fmi3SetTime, end);
        set_states(x, nx);
        if (version == 3) {
            fmi3Boolean enter, terminate;
            check(((fmi3CompletedIntegratorStepTYPE *)symbol("fmi3CompletedIntegratorStep"))(
                      instance, fmi3True, &enter, &terminate), "fmi3CompletedIntegratorStep");
        } else {
            fmi2Boolean enter, terminate;
            check(((fmi2CompletedIntegratorStepTYPE *)symbol("fmi2CompletedIntegratorStep"))(
                      instance, fmi2True, &enter, &terminate), "fmi2CompletedIntegratorStep");
        }
        indicators(z, nz);
        int crossed = 0;
        for (size_t i = 0; i < nz; i++) crossed |= (before[i] > 0) != (z[i] > 0);
        if (crossed) {
            CALL0(fmi2EnterEventModeTYPE, fmi2EnterEventMode, fmi3EnterEventModeTYPE, fmi3EnterEventMode);
            iterate();
            indicators(z, nz);
            events++;
        }
        for (size_t i = 0; i < nz; i++) before[i] = z[i];
        print_row(end, vr, values, n);
    }
    printf("events,%d\n", events);
    print_jacobian(x, nx);
    print_timing(steps * h, x, nx);
    CALL0(fmi2TerminateTYPE, fmi2Terminate, fmi3TerminateTYPE, fmi3Terminate);
    if (version == 3) ((fmi3FreeInstanceTYPE *)symbol("fmi3FreeInstance"))(instance);
    else ((fmi2FreeInstanceTYPE *)symbol("fmi2FreeInstance"))(instance);
    return 0;
}
