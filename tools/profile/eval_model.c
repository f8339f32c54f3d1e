/* Cost of one evaluation of a scene's generated functions, for callgrind (instruction counts are immune to the
 * noise of a shared machine). Compiled with the scene's sources/ (the generated cedra_*.c, heightmap.c) by
 * tools/profile/profile.py:
 *     eval_model <state file> <heightmap file or -> <function: f | rjac | switch | out | M> <repetitions>
 * The state file holds nq, nin, npar, then q, u, a (nq each), inp, par. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "cedra_model.h"
#include "heightmap.h"

static double *read_vec(FILE *f, int n) {
    double *v = calloc((size_t)(n > 0 ? n : 1), sizeof *v);
    for (int i = 0; i < n; i++)
        if (fscanf(f, "%lf", &v[i]) != 1) exit(3);
    return v;
}

int main(int argc, char **argv) {
    if (argc != 5) {
        fprintf(stderr, "usage: %s state heightmap f|rjac|switch|out|M reps\n", argv[0]);
        return 2;
    }
    FILE *f = fopen(argv[1], "r");
    int nq, nin, npar;
    if (!f || fscanf(f, "%d %d %d", &nq, &nin, &npar) != 3) return 3;
    double *q = read_vec(f, nq), *u = read_vec(f, nq), *a = read_vec(f, nq), *inp = read_vec(f, nin),
           *par = read_vec(f, npar);
    fclose(f);
    static heightmap hm;
    if (strcmp(argv[2], "-") != 0) {
        char msg[512];
        if (heightmap_read(&hm, argv[2], calloc, free, msg, sizeof msg)) {
            fprintf(stderr, "%s\n", msg);
            return 3;
        }
        heightmap_activate(&hm, NULL);
    }
    int reps = atoi(argv[4]);
    static double out[4][4096];
    static const double *arg[64];
    static double *res[64];
    static casadi_int iw[100000];
    static double w[2000000];
    double z = 0.0;
    int rc = 0;
    for (int k = 0; k < 4; k++) res[k] = out[k];
    static double hold[64];
    const double x0 = q[0];
    for (int r = 0; r < reps; r++) {
        /* a new pose every repetition (x moves by 1e-9 m): the FMU's memo of contact searches, which a repeated
         * pose would hit, costs what it costs in a run, where every stage of a step is a new pose */
        q[0] = x0 + 1e-9 * r;
        if (strcmp(argv[3], "f") == 0) {
            arg[0] = q, arg[1] = u, arg[2] = inp, arg[3] = par;
            rc |= cedra_f(arg, res, iw, w, 0);
        } else if (strcmp(argv[3], "rjac") == 0) {
            arg[0] = q, arg[1] = u, arg[2] = a, arg[3] = inp, arg[4] = par;
            rc |= cedra_rjac(arg, res, iw, w, 0);
#ifdef HAS_SWITCH       /* a scene with force-law switches (profile.py defines it where cedra_switch exists) */
        } else if (strcmp(argv[3], "switch") == 0) {
            arg[0] = q, arg[1] = u, arg[2] = inp, arg[3] = par, arg[4] = hold;
            rc |= cedra_switch(arg, res, iw, w, 0);
#endif
        } else if (strcmp(argv[3], "out") == 0) {
            arg[0] = q, arg[1] = u, arg[2] = &z, arg[3] = inp, arg[4] = par;
            rc |= cedra_out(arg, res, iw, w, 0);
        } else {
            arg[0] = q, arg[1] = par;
            rc |= cedra_M(arg, res, iw, w, 0);
        }
    }
    double s = 0;
    for (int k = 0; k < 4096; k++) s += out[0][k] + out[1][k];
    printf("rc %d checksum %.17g\n", rc, s);
    return rc;
}
