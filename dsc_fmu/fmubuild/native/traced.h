/* The model of the FMU traced to C at build time (docs/traced-c.md): the table through which the binary
   steps and evaluates it without Python (slave_traced.c). The build generates it beside the model's traced
   functions (fmubuild/traced_models.py, fmu_source); an FMU built without them has an empty table
   (parameters == 0). Every function returns 0, or 1 where the model's Python would raise or has no traced
   function for the parameters' choices: the caller then runs the call in Python. */

#ifndef DSC_TRACED_H
#define DSC_TRACED_H

/* What a step's `watch` receives: nothing; [1, t, beta] of the first evaluation with the beta guard acting
   (left as given if none); in watch[0] the number of evaluations with a driver limiting. */
enum { TRACED_WATCH_NONE, TRACED_WATCH_FIRST, TRACED_WATCH_COUNT, TRACED_WATCH_SIZE = 3 };

typedef struct {
    int parameters; /* the lengths of p (every parameter, in the order of the model's table), */
    int states;     /* the state, */
    int inputs;     /* the inputs, */
    int outputs;    /* the traced Real outputs (the model's table without its bookkeeping), */
    int switches;   /* the held switches s of model exchange, */
    int indicators; /* the event indicators */
    int watch;      /* TRACED_WATCH_* */
    int watched;    /* the values a step writes into watch (at most TRACED_WATCH_SIZE) */
    /* `count` RK4 sub-steps of the step from t0: x becomes the state at t0 + step_size; the inputs held at u,
       or with `slope` on the line through u at `stamp`. */
    int (*step)(const double *p, const double *u, const double *slope, double stamp, double t0, double step_size,
                long count, double *x, double *watch);
    /* The traced outputs at (t, x, u), the switches held at s (model exchange) or, with s NULL, chosen there. */
    int (*outputs_of)(const double *p, double t, const double *x, const double *u, const double *s, double *out);
    /* The state's derivative and the event indicators, the switches held at s (model exchange). */
    int (*rates)(const double *p, double t, const double *x, const double *u, const double *s, double *out);
    int (*indicators_of)(const double *p, const double *x, const double *u, const double *s, double *out);
    /* Their values and their tangents along dx, du (models/dual.py: x[i], u[i] a dual where its seed is
       nonzero), in `out` and `dout`. */
    int (*outputs_tangent)(const double *p, double t, const double *x, const double *u, const double *s,
                           const double *dx, const double *du, double *out, double *dout);
    int (*rates_tangent)(const double *p, double t, const double *x, const double *u, const double *s,
                         const double *dx, const double *du, double *out, double *dout);
} TracedModel;

extern const TracedModel TRACED_MODEL;

#endif
