/* The paper's loop driven from C: a master of the three FMI 2.0 FMUs, as a C importer (a Modelica or
   Simulink-style tool, a container FMU) drives them. No Python in this process.

   usage: c_master PLAN
   PLAN is a text file written by the test or benchmark:
     fmu INDEX UNZIPPED_DIR MODEL_IDENTIFIER GUID     (0 = ReferenceRobot, 1 = MobileRobot, 2 = DSCController)
     plant_out VR...  ref_out VR...  ctl_in VR...  ctl_u VR VR  plant_u VR VR  record FMU VR...
     run STEPS STEP_SIZE ORDER THREADS EVERY         (ORDER gauss-seidel or jacobi; THREADS 0 or 1)
   It runs the exchange of dsc_fmu.cosim.master (same calls, same order, the last step ending at STEPS * STEP_SIZE) and prints "time,recorded values"
   every EVERY steps and at the end. With THREADS = 1 every doStep runs on a worker thread of its FMU
   (threads Python does not know), the FMUs of one phase at the same time. Exits 1 on any failure. */

#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi_host.h"

#define MAX_VR 64

typedef struct {
    void *library;
    fmi2Component c;
    fmi2InstantiateTYPE *instantiate;
    fmi2SetupExperimentTYPE *setup;
    fmi2EnterInitializationModeTYPE *enter;
    fmi2ExitInitializationModeTYPE *exit_init;
    fmi2GetRealTYPE *get;
    fmi2SetRealTYPE *set;
    fmi2DoStepTYPE *do_step;
    fmi2TerminateTYPE *terminate;
    fmi2FreeInstanceTYPE *free_instance;
    /* the worker thread's task */
    pthread_t thread;
    pthread_mutex_t lock;
    pthread_cond_t wake, done;
    int pending, quit;
    double t, h;
    fmi2Status status;
} Fmu;

typedef struct {
    fmi2ValueReference vr[MAX_VR];
    size_t n;
} Refs;

static Fmu fmus[3];
static Refs plant_out, ref_out, ctl_in, ctl_u, plant_u, record[3];

static void fail(const char *what) {
    fprintf(stderr, "c_master: %s\n", what);
    exit(1);
}

static void *symbol(void *library, const char *name) {
    void *address = host_symbol(library, name);
    if (!address) fail(name);
    return address;
}

static void load(Fmu *fmu, const char *dir, const char *model, const char *guid) {
    char path[4096], resources[4096];
    snprintf(path, sizeof path, "%s/binaries/" HOST_FOLDER2 "/%s" HOST_SUFFIX, dir, model);
    snprintf(resources, sizeof resources, HOST_RESOURCES_URI, dir);
    fmu->library = host_load(path);
    if (!fmu->library) fail(host_error());
    fmu->instantiate = symbol(fmu->library, "fmi2Instantiate");
    fmu->setup = symbol(fmu->library, "fmi2SetupExperiment");
    fmu->enter = symbol(fmu->library, "fmi2EnterInitializationMode");
    fmu->exit_init = symbol(fmu->library, "fmi2ExitInitializationMode");
    fmu->get = symbol(fmu->library, "fmi2GetReal");
    fmu->set = symbol(fmu->library, "fmi2SetReal");
    fmu->do_step = symbol(fmu->library, "fmi2DoStep");
    fmu->terminate = symbol(fmu->library, "fmi2Terminate");
    fmu->free_instance = symbol(fmu->library, "fmi2FreeInstance");
    static fmi2CallbackFunctions callbacks = {logger2, calloc, free, NULL, NULL};
    fmu->c = fmu->instantiate(model, fmi2CoSimulation, guid, resources, &callbacks, fmi2False, fmi2False);
    if (!fmu->c) fail("fmi2Instantiate returned NULL");
}

static void *worker(void *argument) {
    Fmu *fmu = argument;
    pthread_mutex_lock(&fmu->lock);
    for (;;) {
        while (!fmu->pending && !fmu->quit) pthread_cond_wait(&fmu->wake, &fmu->lock);
        if (fmu->quit) break;
        fmu->status = fmu->do_step(fmu->c, fmu->t, fmu->h, fmi2True);
        fmu->pending = 0;
        pthread_cond_signal(&fmu->done);
    }
    pthread_mutex_unlock(&fmu->lock);
    return NULL;
}

static void start_step(Fmu *fmu, double t, double h, int threads) {
    if (!threads) {
        check(fmu->do_step(fmu->c, t, h, fmi2True), "fmi2DoStep");
        return;
    }
    pthread_mutex_lock(&fmu->lock);
    fmu->t = t;
    fmu->h = h;
    fmu->pending = 1;
    pthread_cond_signal(&fmu->wake);
    pthread_mutex_unlock(&fmu->lock);
}

static void finish_step(Fmu *fmu, int threads) {
    if (!threads) return;
    pthread_mutex_lock(&fmu->lock);
    while (fmu->pending) pthread_cond_wait(&fmu->done, &fmu->lock);
    pthread_mutex_unlock(&fmu->lock);
    check(fmu->status, "fmi2DoStep (worker thread)");
}

static void read_refs(char *line, Refs *refs) {
    refs->n = 0;
    for (char *token = strtok(line, " \n"); token && refs->n < MAX_VR; token = strtok(NULL, " \n")) {
        refs->vr[refs->n++] = (fmi2ValueReference)strtoul(token, NULL, 10);
    }
}

static void measure(double *measurements) {
    check(fmus[1].get(fmus[1].c, plant_out.vr, plant_out.n, measurements), "fmi2GetReal plant");
    check(fmus[0].get(fmus[0].c, ref_out.vr, ref_out.n, measurements + plant_out.n), "fmi2GetReal reference");
}

static void exchange(const double *measurements, int set_inputs) {
    double u[2];
    if (set_inputs) check(fmus[2].set(fmus[2].c, ctl_in.vr, ctl_in.n, measurements), "fmi2SetReal controller");
    check(fmus[2].get(fmus[2].c, ctl_u.vr, 2, u), "fmi2GetReal u");
    check(fmus[1].set(fmus[1].c, plant_u.vr, 2, u), "fmi2SetReal plant");
}

static void print_row(double t) {
    double values[MAX_VR];
    printf("%.17g", t);
    for (int i = 0; i < 3; i++) {
        if (!record[i].n) continue;
        check(fmus[i].get(fmus[i].c, record[i].vr, record[i].n, values), "fmi2GetReal record");
        for (size_t k = 0; k < record[i].n; k++) printf(",%.17g", values[k]);
    }
    printf("\n");
}

int main(int argc, char **argv) {
    if (argc != 2) fail("usage: c_master PLAN");
    FILE *plan = fopen(argv[1], "r");
    if (!plan) fail("cannot open the plan");
    char line[8192], key[32];
    long steps = 0, every = 1;
    double h = 0;
    char order[32] = "gauss-seidel";
    int threads = 0, offset;
    while (fgets(line, sizeof line, plan)) {
        if (sscanf(line, "%31s %n", key, &offset) != 1) continue;
        char *rest = line + offset;
        if (strcmp(key, "fmu") == 0) {
            int index;
            char dir[4096], model[256], guid[256];
            if (sscanf(rest, "%d %4095s %255s %255s", &index, dir, model, guid) != 4 || index < 0 || index > 2) fail("bad fmu line");
            load(&fmus[index], dir, model, guid);
        } else if (strcmp(key, "plant_out") == 0) read_refs(rest, &plant_out);
        else if (strcmp(key, "ref_out") == 0) read_refs(rest, &ref_out);
        else if (strcmp(key, "ctl_in") == 0) read_refs(rest, &ctl_in);
        else if (strcmp(key, "ctl_u") == 0) read_refs(rest, &ctl_u);
        else if (strcmp(key, "plant_u") == 0) read_refs(rest, &plant_u);
        else if (strcmp(key, "record") == 0) {
            int index = atoi(rest);
            if (index < 0 || index > 2) fail("bad record line");
            read_refs(strchr(rest, ' ') ? strchr(rest, ' ') + 1 : rest + strlen(rest), &record[index]);
        } else if (strcmp(key, "run") == 0) {
            if (sscanf(rest, "%ld %lf %31s %d %ld", &steps, &h, order, &threads, &every) != 5) fail("bad run line");
        }
    }
    fclose(plan);
    int jacobi = strcmp(order, "jacobi") == 0;
    double stop = steps * h, measurements[2 * MAX_VR];
    for (int i = 0; i < 3; i++) {
        check(fmus[i].setup(fmus[i].c, fmi2False, 0.0, 0.0, fmi2True, stop), "fmi2SetupExperiment");
        check(fmus[i].enter(fmus[i].c), "fmi2EnterInitializationMode");
        check(fmus[i].exit_init(fmus[i].c), "fmi2ExitInitializationMode");
        if (threads) {
            pthread_mutex_init(&fmus[i].lock, NULL);
            pthread_cond_init(&fmus[i].wake, NULL);
            pthread_cond_init(&fmus[i].done, NULL);
            pthread_create(&fmus[i].thread, NULL, worker, &fmus[i]);
        }
    }
    measure(measurements);
    for (long k = 0; k < steps; k++) {
        double t = k * h, step = k < steps - 1 ? h : stop - t;
        exchange(measurements, jacobi || k == 0);
        if (k % every == 0) print_row(t);
        start_step(&fmus[0], t, step, threads);
        start_step(&fmus[1], t, step, threads);
        if (jacobi) start_step(&fmus[2], t, step, threads);
        finish_step(&fmus[0], threads);
        finish_step(&fmus[1], threads);
        measure(measurements);
        if (!jacobi) {
            check(fmus[2].set(fmus[2].c, ctl_in.vr, ctl_in.n, measurements), "fmi2SetReal controller");
            start_step(&fmus[2], t, step, threads);
        }
        finish_step(&fmus[2], threads);
    }
    exchange(measurements, jacobi);
    print_row(stop);
    for (int i = 2; i >= 0; i--) {
        if (threads) {
            pthread_mutex_lock(&fmus[i].lock);
            fmus[i].quit = 1;
            pthread_cond_signal(&fmus[i].wake);
            pthread_mutex_unlock(&fmus[i].lock);
            pthread_join(fmus[i].thread, NULL);
        }
        check(fmus[i].terminate(fmus[i].c), "fmi2Terminate");
        fmus[i].free_instance(fmus[i].c);
    }
    return 0;
}
