/* The plant block's state (see glue.h): the model's ODE state x = [q, u, z], its start values, the embedded
 * solver's settings and counters. */
#ifndef CEDRA_PLANT_H
#define CEDRA_PLANT_H

#include "solver.h"

typedef struct {
    double x[CEDRA_NX];
    double q_start[CEDRA_NQ];
    double u_start[CEDRA_NQ];
    int settle;
    int tol_explicit;               /* solver.tol was set by the user: the importer's tolerance does not replace it */
    solver_settings solver;
    solver_stats stats;
    /* ROS34PW2 keeps its Jacobian (and the mass matrix beside it) from call to call: state, so that a restored
     * FMU state continues exactly as the original did (solver.h solver_keep_size) */
    double jac_keep[CEDRA_NX * CEDRA_NX + CEDRA_NQ * CEDRA_NQ];
} block_state;

#endif
