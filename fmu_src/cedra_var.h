/* One row of the FMU's variable table (generated into cedra_vars.h from python/cedra/fmu/variables.py). */
#ifndef CEDRA_VAR_H
#define CEDRA_VAR_H

enum cedra_type { CEDRA_REAL = 0, CEDRA_INTEGER = 1, CEDRA_BOOLEAN = 2 };
enum cedra_kind {
    CEDRA_K_PAR,      /* model parameter par[index] */
    CEDRA_K_INP,      /* input inp[index] */
    CEDRA_K_OUT,      /* output y[index] (Integer: rounded) */
    CEDRA_K_Q_START,  /* start value of q[index] */
    CEDRA_K_U_START,  /* start value of u[index] */
    CEDRA_K_SETTLE,   /* Boolean start.settle */
    CEDRA_K_SOLVER,   /* solver settings: 0 method, 1 tol, 2 h_max */
    CEDRA_K_STAT      /* solver counters: 0 steps, 1 rejected, 2 rhs_evals */
};
enum cedra_causality { CEDRA_PARAMETER, CEDRA_INPUT, CEDRA_OUTPUT };

typedef struct {
    unsigned int vr;
    const char *name;
    int type;          /* enum cedra_type */
    int kind;          /* enum cedra_kind */
    int index;
    double start;      /* Real value, Integer/Boolean as a double */
    double min, max;   /* -HUGE_VAL / HUGE_VAL when not given */
    int min_exclusive; /* value == min is refused too */
    int causality;     /* enum cedra_causality */
} cedra_var;

#endif
