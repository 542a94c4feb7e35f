/* A C host that calls one FMU from several threads, as GUI tools and thread pools do.

   usage: c_threads MODE FMI_VERSION UNZIPPED_DIR MODEL_IDENTIFIER GUID_OR_TOKEN [ARG...]
     logger VR VALUE STEPS   two instances, A and B. On a second thread A sets the Real (Float64)
                             VR to VALUE, which the FMU refuses with a logged error; A's logger then
                             waits until B, on the main thread, has done STEPS steps (at most 20 s).
                             Prints "steps_while_logger_waited=N logger_calls=M timed_out=0|1".
     threads COUNT           one instance, stepped once by each of 100 short-lived threads, then by
                             COUNT more, one after another. Prints "rss_kb=BEFORE,AFTER
                             thread_states=BEFORE,AFTER": the process's resident memory and the
                             number of Python thread states after the first 100 and after the rest
                             (once the FMU's reaper has caught up: polled for at most 5 s).
     create THREADS ROUNDS   THREADS threads at once, each ROUNDS times creating, initialising, stepping
                             and freeing an instance. Prints "failures=F": instances not created or
                             calls that failed.
     join                    one instance, stepped once by a worker thread, which this thread then
                             joins while holding the GIL (as a Python extension's destructor may).
                             Prints "joined=1", or "joined=0" if the worker had not ended after 20 s.
     steps N STEPS THREADED  N instances, each doing STEPS steps of 1 ms: one after another on this
                             thread (THREADED 0), or each on a thread of its own at once (1). Prints
                             "seconds=S", the wall time of the steps.
     stack KB STEPS VR...    one instance's whole life on a thread with a stack of KB kB (0: on this
                             thread): instantiate, initialise, STEPS steps of 1 ms, free; in a process
                             that has not called the FMU before, so that its first call, which finds
                             and starts CPython, is made there too. Prints "time,value,..." with the
                             Real (Float64) VRs at t = 0 and after every step; messages go to stderr.
   Exits 1 with a message on any failing call. Builds for Linux and Windows (pthreads: MinGW-w64's). */

#include <errno.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "fmi_host.h"

typedef struct {
    int version;
    void *library;
    char resources[4096];
    const char *model, *token;
} Fmu;

static struct {
    pthread_mutex_t lock;
    pthread_cond_t changed;
    int logger_waiting, steps, target, calls, timed_out;
} shared = {PTHREAD_MUTEX_INITIALIZER, PTHREAD_COND_INITIALIZER, 0, 0, 0, 0, 0};

static void fail(const char *format, ...) {
    va_list args;
    va_start(args, format);
    vfprintf(stderr, format, args);
    va_end(args);
    fprintf(stderr, "\n");
    exit(1);
}

static void *symbol(Fmu *fmu, const char *name) {
    void *address = host_symbol(fmu->library, name);
    if (!address) fail("missing %s", name);
    return address;
}

/* The blocking logger of instance A: wait (without a busy loop) until B has done its steps. */
static void block(void) {
    pthread_mutex_lock(&shared.lock);
    shared.calls++;
    shared.logger_waiting = 1;
    pthread_cond_broadcast(&shared.changed);
    struct timespec until;
    clock_gettime(CLOCK_REALTIME, &until);
    until.tv_sec += 20;
    while (shared.steps < shared.target && !shared.timed_out) {
        if (pthread_cond_timedwait(&shared.changed, &shared.lock, &until) == ETIMEDOUT) shared.timed_out = 1;
    }
    pthread_mutex_unlock(&shared.lock);
}

static void blocking2(fmi2ComponentEnvironment env, fmi2String instance, fmi2Status status, fmi2String category,
                      fmi2String message, ...) {
    if (env) block();
}

static void blocking3(fmi3InstanceEnvironment env, fmi3Status status, fmi3String category, fmi3String message) {
    if (env) block();
}

static void silent2(fmi2ComponentEnvironment env, fmi2String instance, fmi2Status status, fmi2String category,
                    fmi2String message, ...) {}

static fmi2CallbackFunctions quiet2 = {silent2, calloc, free, NULL, NULL};

static void *instantiate(Fmu *fmu, const char *name, int blocking) {
    void *c;
    if (fmu->version == 2) {
        static fmi2CallbackFunctions plain = {blocking2, calloc, free, NULL, NULL};
        static fmi2CallbackFunctions waiting = {blocking2, calloc, free, NULL, &shared};
        c = ((fmi2InstantiateTYPE *)symbol(fmu, "fmi2Instantiate"))(
            name, fmi2CoSimulation, fmu->token, fmu->resources, blocking ? &waiting : &plain, fmi2False, fmi2True);
    } else {
        c = ((fmi3InstantiateCoSimulationTYPE *)symbol(fmu, "fmi3InstantiateCoSimulation"))(
            name, fmu->token, fmu->resources, fmi3False, fmi3True, fmi3False, fmi3False, NULL, 0,
            blocking ? &shared : NULL, blocking3, NULL);
    }
    if (!c) fail("instantiating %s returned NULL", name);
    return c;
}

static void initialize(Fmu *fmu, void *c) {
    if (fmu->version == 2) {
        check(((fmi2SetupExperimentTYPE *)symbol(fmu, "fmi2SetupExperiment"))(c, 0, 0.0, 0.0, 0, 0.0), "setup");
        check(((fmi2EnterInitializationModeTYPE *)symbol(fmu, "fmi2EnterInitializationMode"))(c), "enter");
        check(((fmi2ExitInitializationModeTYPE *)symbol(fmu, "fmi2ExitInitializationMode"))(c), "exit");
    } else {
        check(((fmi3EnterInitializationModeTYPE *)symbol(fmu, "fmi3EnterInitializationMode"))(c, fmi3False, 0.0, 0.0,
                                                                                            fmi3False, 0.0), "enter");
        check(((fmi3ExitInitializationModeTYPE *)symbol(fmu, "fmi3ExitInitializationMode"))(c), "exit");
    }
}

static void set_real(Fmu *fmu, void *c, unsigned int vr, double value) {
    if (fmu->version == 2) check(((fmi2SetRealTYPE *)symbol(fmu, "fmi2SetReal"))(c, &vr, 1, &value), "set");
    else check(((fmi3SetFloat64TYPE *)symbol(fmu, "fmi3SetFloat64"))(c, &vr, 1, &value, 1), "set");
}

static void step(Fmu *fmu, void *c, double t, double h) {
    if (fmu->version == 2) {
        check(((fmi2DoStepTYPE *)symbol(fmu, "fmi2DoStep"))(c, t, h, fmi2True), "step");
    } else {
        fmi3Boolean event, terminate, early;
        fmi3Float64 last;
        check(((fmi3DoStepTYPE *)symbol(fmu, "fmi3DoStep"))(c, t, h, fmi3True, &event, &terminate, &early, &last),
              "step");
    }
}

static void release(Fmu *fmu, void *c) {
    ((void (*)(void *))symbol(fmu, fmu->version == 2 ? "fmi2FreeInstance" : "fmi3FreeInstance"))(c);
}

/* --- logger --------------------------------------------------------------------------------------------- */

typedef struct {
    Fmu *fmu;
    void *c;
    unsigned int vr;
    double value;
} Refusal;

static void *refuse(void *argument) {
    Refusal *r = argument;
    set_real(r->fmu, r->c, r->vr, r->value);
    return NULL;
}

static int run_logger(Fmu *fmu, unsigned int vr, double value, int steps) {
    void *a = instantiate(fmu, "A", 1), *b = instantiate(fmu, "B", 0);
    initialize(fmu, b);
    shared.target = steps;
    Refusal refusal = {fmu, a, vr, value};
    pthread_t thread;
    pthread_create(&thread, NULL, refuse, &refusal);
    pthread_mutex_lock(&shared.lock);
    while (!shared.logger_waiting) pthread_cond_wait(&shared.changed, &shared.lock);
    pthread_mutex_unlock(&shared.lock);
    int done = 0;
    for (int k = 0; k < steps; k++) {
        step(fmu, b, k * 1e-3, 1e-3);
        pthread_mutex_lock(&shared.lock);
        done = shared.timed_out ? done : k + 1;
        shared.steps = k + 1;
        pthread_cond_broadcast(&shared.changed);
        pthread_mutex_unlock(&shared.lock);
    }
    pthread_join(thread, NULL);
    printf("steps_while_logger_waited=%d logger_calls=%d timed_out=%d\n", done, shared.calls, shared.timed_out);
    release(fmu, a);
    release(fmu, b);
    return 0;
}

/* --- threads -------------------------------------------------------------------------------------------- */

typedef struct {
    Fmu *fmu;
    void *c;
    int k;
} Work;

static void *one_step(void *argument) {
    Work *w = argument;
    step(w->fmu, w->c, w->k * 1e-3, 1e-3);
    return NULL;
}

static void run_threads(Fmu *fmu, void *c, int from, int count) {
    for (int k = from; k < from + count; k++) {
        Work work = {fmu, c, k};
        pthread_t thread;
        if (pthread_create(&thread, NULL, one_step, &work) != 0) fail("pthread_create failed");
        pthread_join(thread, NULL);
    }
}

/* The thread states of the main interpreter, counted under the GIL through the Python in this process. */
static int thread_states(void) {
    int (*ensure)(void) = host_python_symbol("PyGILState_Ensure");
    void (*release_gil)(int) = host_python_symbol("PyGILState_Release");
    void *(*main_interpreter)(void) = host_python_symbol("PyInterpreterState_Main");
    void *(*head)(void *) = host_python_symbol("PyInterpreterState_ThreadHead");
    void *(*next)(void *) = host_python_symbol("PyThreadState_Next");
    if (!ensure || !release_gil || !main_interpreter || !head || !next) fail("no Python in this process");
    int gil = ensure(), n = 0;
    for (void *state = head(main_interpreter()); state; state = next(state)) n++;
    release_gil(gil);
    return n;
}

/* The thread states once no more are being deleted, or at most `limit` (s) from now. */
static int settled_thread_states(int target, double limit) {
    struct timespec pause = {0, 10000000};
    int n = thread_states();
    for (int k = 0; n > target && k < limit / 0.01; k++) {
        nanosleep(&pause, NULL);
        n = thread_states();
    }
    return n;
}

static int run_churn(Fmu *fmu, int count) {
    void *c = instantiate(fmu, "churn", 0);
    initialize(fmu, c);
    run_threads(fmu, c, 0, 100);
    int states_before = settled_thread_states(1, 5.0); /* this thread's alone */
    long before = host_resident_kb();
    run_threads(fmu, c, 100, count);
    int states_after = settled_thread_states(states_before, 5.0);
    printf("rss_kb=%ld,%ld thread_states=%d,%d\n", before, host_resident_kb(), states_before, states_after);
    release(fmu, c);
    return 0;
}

/* --- create ------------------------------------------------------------------------------------------- */

static pthread_barrier_t start_line;

typedef struct {
    Fmu *fmu;
    int rounds, failures;
    pthread_t thread;
} Creator;

static int try_step(Fmu *fmu, void *c) {
    if (fmu->version == 2) return ((fmi2DoStepTYPE *)symbol(fmu, "fmi2DoStep"))(c, 0.0, 1e-3, fmi2True);
    fmi3Boolean event, terminate, early;
    fmi3Float64 last;
    return ((fmi3DoStepTYPE *)symbol(fmu, "fmi3DoStep"))(c, 0.0, 1e-3, fmi3True, &event, &terminate, &early, &last);
}

static void *create_and_free(void *argument) {
    Creator *creator = argument;
    Fmu *fmu = creator->fmu;
    pthread_barrier_wait(&start_line);
    for (int k = 0; k < creator->rounds; k++) {
        void *c = fmu->version == 2
            ? ((fmi2InstantiateTYPE *)symbol(fmu, "fmi2Instantiate"))("creator", fmi2CoSimulation, fmu->token,
                                                                    fmu->resources, &quiet2, fmi2False, fmi2False)
            : ((fmi3InstantiateCoSimulationTYPE *)symbol(fmu, "fmi3InstantiateCoSimulation"))(
                  "creator", fmu->token, fmu->resources, fmi3False, fmi3False, fmi3False, fmi3False, NULL, 0, NULL,
                  NULL, NULL);
        if (!c) {
            creator->failures++;
            continue;
        }
        initialize(fmu, c);
        if (try_step(fmu, c) != 0) creator->failures++;
        release(fmu, c);
    }
    return NULL;
}

static int run_creators(Fmu *fmu, int threads, int rounds) {
    Creator creators[16];
    if (threads < 1 || threads > 16) fail("1 to 16 threads");
    pthread_barrier_init(&start_line, NULL, (unsigned)threads);
    for (int i = 0; i < threads; i++) {
        creators[i] = (Creator){fmu, rounds, 0};
        pthread_create(&creators[i].thread, NULL, create_and_free, &creators[i]);
    }
    int failures = 0;
    for (int i = 0; i < threads; i++) {
        pthread_join(creators[i].thread, NULL);
        failures += creators[i].failures;
    }
    printf("failures=%d\n", failures);
    return 0;
}

/* --- join ---------------------------------------------------------------------------------------------- */

static void *step_once(void *argument) {
    Work *w = argument;
    step(w->fmu, w->c, 0.0, 1e-3);
    pthread_mutex_lock(&shared.lock);
    shared.steps = 1;
    pthread_cond_broadcast(&shared.changed);
    pthread_mutex_unlock(&shared.lock);
    return NULL;
}

/* Join `thread` if it ends within `seconds`: 1, else 0. */
static int join_within(pthread_t thread, int seconds) {
#ifdef _WIN32
    return WaitForSingleObject(pthread_gethandle(thread), (DWORD)seconds * 1000) == WAIT_OBJECT_0 &&
           pthread_join(thread, NULL) == 0;
#else
    struct timespec until;
    clock_gettime(CLOCK_REALTIME, &until);
    until.tv_sec += seconds;
    return pthread_timedjoin_np(thread, NULL, &until) == 0;
#endif
}

static int run_join(Fmu *fmu) {
    void *c = instantiate(fmu, "join", 0);
    initialize(fmu, c);
    Work work = {fmu, c, 0};
    pthread_t thread;
    pthread_create(&thread, NULL, step_once, &work);
    pthread_mutex_lock(&shared.lock);
    while (!shared.steps) pthread_cond_wait(&shared.changed, &shared.lock);
    pthread_mutex_unlock(&shared.lock);
    int (*ensure)(void) = host_python_symbol("PyGILState_Ensure");
    void (*release_gil)(int) = host_python_symbol("PyGILState_Release");
    if (!ensure || !release_gil) fail("no Python in this process");
    int gil = ensure();
    int joined = join_within(thread, 20);
    release_gil(gil);
    printf("joined=%d\n", joined);
    if (!joined) _exit(0); /* the worker cannot end: leave without waiting for it */
    release(fmu, c);
    return 0;
}

/* --- steps -------------------------------------------------------------------------------------------- */

typedef struct {
    Fmu *fmu;
    void *c;
    int steps;
    pthread_t thread;
} Stepper;

static void *run_steps(void *argument) {
    Stepper *s = argument;
    for (int k = 0; k < s->steps; k++) step(s->fmu, s->c, k * 1e-3, 1e-3);
    return NULL;
}

static double now(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return t.tv_sec + 1e-9 * t.tv_nsec;
}

static int run_steppers(Fmu *fmu, int n, int steps, int threaded) {
    Stepper steppers[16];
    if (n < 1 || n > 16) fail("1 to 16 instances");
    for (int i = 0; i < n; i++) {
        steppers[i] = (Stepper){fmu, instantiate(fmu, "stepper", 0), steps};
        initialize(fmu, steppers[i].c);
    }
    double start = now();
    for (int i = 0; i < n; i++) {
        if (threaded) pthread_create(&steppers[i].thread, NULL, run_steps, &steppers[i]);
        else run_steps(&steppers[i]);
    }
    for (int i = 0; threaded && i < n; i++) pthread_join(steppers[i].thread, NULL);
    printf("seconds=%.6f\n", now() - start);
    for (int i = 0; i < n; i++) release(fmu, steppers[i].c);
    return 0;
}

/* --- stack -------------------------------------------------------------------------------------------- */

typedef struct {
    Fmu *fmu;
    int steps;
    const unsigned int *vr;
    size_t n;
} Life;

static void *instantiate_logged(Fmu *fmu) {
    static fmi2CallbackFunctions callbacks = {logger2, calloc, free, NULL, NULL};
    void *c = fmu->version == 2
        ? ((fmi2InstantiateTYPE *)symbol(fmu, "fmi2Instantiate"))(fmu->model, fmi2CoSimulation, fmu->token,
                                                                fmu->resources, &callbacks, fmi2False, fmi2True)
        : ((fmi3InstantiateCoSimulationTYPE *)symbol(fmu, "fmi3InstantiateCoSimulation"))(
              fmu->model, fmu->token, fmu->resources, fmi3False, fmi3True, fmi3False, fmi3False, NULL, 0, NULL,
              logger3, NULL);
    if (!c) fail("instantiating %s returned NULL", fmu->model);
    return c;
}

static void print_row(Fmu *fmu, void *c, const Life *life, double t, double *values) {
    if (fmu->version == 2) {
        check(((fmi2GetRealTYPE *)symbol(fmu, "fmi2GetReal"))(c, life->vr, life->n, values), "get");
    } else {
        check(((fmi3GetFloat64TYPE *)symbol(fmu, "fmi3GetFloat64"))(c, life->vr, life->n, values, life->n), "get");
    }
    printf("%.17g", t);
    for (size_t i = 0; i < life->n; i++) printf(",%.17g", values[i]);
    printf("\n");
}

static void *live(void *argument) {
    Life *life = argument;
    Fmu *fmu = life->fmu;
    double *values = calloc(life->n ? life->n : 1, sizeof *values); /* not on the small stack under test */
    if (!values) fail("out of memory");
    void *c = instantiate_logged(fmu);
    initialize(fmu, c);
    print_row(fmu, c, life, 0.0, values);
    for (int k = 0; k < life->steps; k++) {
        step(fmu, c, k * 1e-3, 1e-3);
        print_row(fmu, c, life, (k + 1) * 1e-3, values);
    }
    if (fmu->version == 2) check(((fmi2TerminateTYPE *)symbol(fmu, "fmi2Terminate"))(c), "terminate");
    else check(((fmi3TerminateTYPE *)symbol(fmu, "fmi3Terminate"))(c), "terminate");
    release(fmu, c);
    free(values);
    return NULL;
}

static int run_stack(Fmu *fmu, int kb, int steps, char **refs, int n) {
    unsigned int *vr = calloc(n ? (size_t)n : 1, sizeof *vr);
    if (!vr) fail("out of memory");
    for (int i = 0; i < n; i++) vr[i] = (unsigned int)strtoul(refs[i], NULL, 10);
    Life life = {fmu, steps, vr, (size_t)n};
    if (kb == 0) {
        live(&life);
    } else {
        pthread_attr_t attributes;
        pthread_t thread;
        pthread_attr_init(&attributes);
        int error = pthread_attr_setstacksize(&attributes, (size_t)kb * 1024);
        if (error) fail("a stack of %d kB: pthread_attr_setstacksize failed: %s", kb, strerror(error));
        error = pthread_create(&thread, &attributes, live, &life);
        if (error) fail("pthread_create failed: %s", strerror(error));
        pthread_join(thread, NULL);
        pthread_attr_destroy(&attributes);
    }
    free(vr);
    return 0;
}

int main(int argc, char **argv) {
    if (argc < 6) fail("usage: %s MODE FMI_VERSION UNZIPPED_DIR MODEL_IDENTIFIER GUID_OR_TOKEN [ARG...]", argv[0]);
    Fmu fmu = {atoi(argv[2]), NULL, "", argv[4], argv[5]};
    const char *dir = argv[3];
    char path[4096];
    snprintf(path, sizeof path, "%s/binaries/%s/%s" HOST_SUFFIX, dir, fmu.version == 3 ? HOST_FOLDER3 : HOST_FOLDER2,
             fmu.model);
    snprintf(fmu.resources, sizeof fmu.resources, fmu.version == 3 ? "%s/resources/" : HOST_RESOURCES_URI, dir);
    fmu.library = host_load(path);
    if (!fmu.library) fail("cannot load %s", host_error());
    if (strcmp(argv[1], "logger") == 0 && argc == 9) {
        return run_logger(&fmu, (unsigned int)strtoul(argv[6], NULL, 10), atof(argv[7]), atoi(argv[8]));
    }
    if (strcmp(argv[1], "threads") == 0 && argc == 7) return run_churn(&fmu, atoi(argv[6]));
    if (strcmp(argv[1], "join") == 0) return run_join(&fmu);
    if (strcmp(argv[1], "create") == 0 && argc == 8) return run_creators(&fmu, atoi(argv[6]), atoi(argv[7]));
    if (strcmp(argv[1], "steps") == 0 && argc == 9) {
        return run_steppers(&fmu, atoi(argv[6]), atoi(argv[7]), atoi(argv[8]));
    }
    if (strcmp(argv[1], "stack") == 0 && argc >= 8) {
        return run_stack(&fmu, atoi(argv[6]), atoi(argv[7]), argv + 8, argc - 8);
    }
    fail("unknown mode %s or wrong arguments", argv[1]);
    return 1;
}
