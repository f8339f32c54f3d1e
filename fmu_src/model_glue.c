/* The model side of the FMU (see model_glue.h): evaluates the generated CasADi functions of the contract
 * (python/cedra/contract.py) on plain arrays. Sizes come from the generated cedra_vars.h. */
#include "model_glue.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

#include "cedra_model.h"
#include "cedra_vars.h"
#include "heightmap.h"
#include "linalg.h"
#include "rigid.h"
#include "solver.h"

#define NQ CEDRA_NQ
#define NZ CEDRA_NZ
#define NX CEDRA_NX
/* rigid contact: x ends with the contact impulses since the communication step's start (3 per contact) */
#define NIMP CEDRA_NIMP
#define IMP (2 * NQ + NZ)
#define NS CEDRA_NS
#define DIM(n) ((n) > 0 ? (n) : 1)
#define MAX2(a, b) ((a) > (b) ? (a) : (b))

/* CasADi work sizes: the largest over the functions */
#define SZ_ARG MAX2(MAX2(MAX2(cedra_M_SZ_ARG, cedra_f_SZ_ARG), MAX2(cedra_rjac_SZ_ARG, cedra_out_SZ_ARG)), \
                    MAX2(MAX2(cedra_settle_SZ_ARG, cedra_guess_SZ_ARG), cedra_check_SZ_ARG))
#define SZ_RES MAX2(MAX2(MAX2(cedra_M_SZ_RES, cedra_f_SZ_RES), MAX2(cedra_rjac_SZ_RES, cedra_out_SZ_RES)), \
                    MAX2(MAX2(cedra_settle_SZ_RES, cedra_guess_SZ_RES), cedra_check_SZ_RES))
#define SZ_IW MAX2(MAX2(MAX2(cedra_M_SZ_IW, cedra_f_SZ_IW), MAX2(cedra_rjac_SZ_IW, cedra_out_SZ_IW)), \
                   MAX2(MAX2(cedra_settle_SZ_IW, cedra_guess_SZ_IW), cedra_check_SZ_IW))
#define SZ_W MAX2(MAX2(MAX2(cedra_M_SZ_W, cedra_f_SZ_W), MAX2(cedra_rjac_SZ_W, cedra_out_SZ_W)), \
                  MAX2(MAX2(cedra_settle_SZ_W, cedra_guess_SZ_W), cedra_check_SZ_W))

/* force-law switches (cedra_switch, generated when the model has switches) */
#define NSW CEDRA_NSW
#define NH CEDRA_NH
#if NSW > 0
#define SW_SZ_ARG MAX2(SZ_ARG, cedra_switch_SZ_ARG)
#define SW_SZ_RES MAX2(SZ_RES, cedra_switch_SZ_RES)
#define SW_SZ_IW MAX2(SZ_IW, cedra_switch_SZ_IW)
#define SW_SZ_W MAX2(SZ_W, cedra_switch_SZ_W)
#else
#define SW_SZ_ARG SZ_ARG
#define SW_SZ_RES SZ_RES
#define SW_SZ_IW SZ_IW
#define SW_SZ_W SZ_W
#endif
/* chassis and link contact (cedra_cgap, cedra_fc, cedra_fcjac, generated when the scene has collision points) */
#define CHASSIS CEDRA_CHASSIS
#if CHASSIS
#define WS_SZ_ARG MAX2(SW_SZ_ARG, MAX2(MAX2(cedra_cgap_SZ_ARG, cedra_fc_SZ_ARG), cedra_fcjac_SZ_ARG))
#define WS_SZ_RES MAX2(SW_SZ_RES, MAX2(MAX2(cedra_cgap_SZ_RES, cedra_fc_SZ_RES), cedra_fcjac_SZ_RES))
#define WS_SZ_IW MAX2(SW_SZ_IW, MAX2(MAX2(cedra_cgap_SZ_IW, cedra_fc_SZ_IW), cedra_fcjac_SZ_IW))
#define WS_SZ_W MAX2(SW_SZ_W, MAX2(MAX2(cedra_cgap_SZ_W, cedra_fc_SZ_W), cedra_fcjac_SZ_W))
#else
#define WS_SZ_ARG SW_SZ_ARG
#define WS_SZ_RES SW_SZ_RES
#define WS_SZ_IW SW_SZ_IW
#define WS_SZ_W SW_SZ_W
#endif
/* rigid contact (cedra_contact) */
#if CEDRA_RIGID
#define ALL_SZ_ARG MAX2(WS_SZ_ARG, cedra_contact_SZ_ARG)
#define ALL_SZ_RES MAX2(WS_SZ_RES, cedra_contact_SZ_RES)
#define ALL_SZ_IW MAX2(WS_SZ_IW, cedra_contact_SZ_IW)
#define ALL_SZ_W MAX2(WS_SZ_W, cedra_contact_SZ_W)
#else
#define ALL_SZ_ARG WS_SZ_ARG
#define ALL_SZ_RES WS_SZ_RES
#define ALL_SZ_IW WS_SZ_IW
#define ALL_SZ_W WS_SZ_W
#endif
/* a switch is located when the step that crosses it is at most this long (s; more where time cannot resolve it) */
#define LOC_TOL 1e-10
#define MAX_LOCATE 4        /* locations of one switch per call (fmi2DoStep) before it is left to the error control */
#define LOG_LOCATED 8       /* located switches kept for the step's log */

#if CEDRA_RIGID
#define NC CEDRA_NC
#define NCW CEDRA_NCW       /* contacts of each wheel: contacts k NCW .. k NCW + NCW - 1 are wheel k + 1's */
#else
#define NC 1
#define NCW 1
#endif
#define N_WHEELS 6

/* x = [q, u, z] with q' = u: RODAS4's stage systems reduce to NQ x NQ (solver.c); -DCEDRA_SCHUR_N2=0 builds the
 * dense NX x NX solve (the benchmark's comparison) */
#ifndef CEDRA_SCHUR_N2
#define CEDRA_SCHUR_N2 NQ
#endif
/* The Jacobian's u rows as -dr/dq, -dr/du (r = M u' - f) with M beside them (solver.h mass_rows): the solver's
 * reduced stage matrix is then c^2 M + c dr/du + dr/dq, and the 2 NQ solves with M that A = -M^-1 dr/dq and
 * B = -M^-1 dr/du cost are not needed. The rigid model's Jacobian is a difference quotient of F: no rows to give. */
#define MASS_ROWS (CEDRA_SCHUR_N2 > 0 && !CEDRA_RIGID)

#define SETTLE_MAX_ITER 60
#define SETTLE_MAX_HALVINGS 30
#define SETTLE_RTOL 1e-10

struct model_ws {
    const double *inp, *par;
    const casadi_real *arg[DIM(ALL_SZ_ARG)];
    casadi_real *res[DIM(ALL_SZ_RES)];
    casadi_int iw[DIM(ALL_SZ_IW)];
    casadi_real w[DIM(ALL_SZ_W)];
    /* switch location: s and the held choices at the step's start (cached on (t, x)), s at its end */
    double sw0[DIM(NSW)], sw1[DIM(NSW)], hold[DIM(NH)], hold_tmp[DIM(NH)], sw_t, sw_x[NX];
    int sw_valid;
    /* the last end evaluation: s at (t_new, x_new) with choices that x_new itself makes (then it is the next
     * step's start evaluation, when that step starts there) */
    double swn[DIM(NSW)], swn_t, swn_x[NX];
    int swn_valid;
    long n_located;                     /* switches located since the last model_take_located */
    int sw_count[DIM(NSW)];             /* times each switch was located since then */
    int sw_miss[DIM(NSW)];              /* cuts aimed at each switch that ended no nearer to it (then: bisection) */
    int aim;                            /* 1 + the switch the last step was cut at (0: none) ... */
    double aim_s, aim_s1, aim_t;        /* ... its s at that step's start and end, and the cut's end */
    int loc_which[LOG_LOCATED];
    double loc_t0[LOG_LOCATED], loc_t1[LOG_LOCATED];
    /* factors of the mass matrix at dyn_x: Cholesky in CEDRA_M_ORDER if m_chol (linalg_chol_factor_perm), else LU */
    double M[NQ * NQ];
    int m_chol, m_nz[NQ];
    double Mfull[NQ * NQ];              /* the mass matrix itself there */
    int piv[NQ];
    /* M, f and g are those of dyn_x (2 NQ) when dyn_valid: RODAS4 asks for F and then the Jacobian at the same
     * state, and both need them; cleared by model_bind (the inputs may have changed) and by any other use */
    double dyn_x[2 * NQ];
    int dyn_valid;
    double f[NQ], g[DIM(NZ)];
    double drdq[NQ * NQ], drdu[NQ * NQ], dgdq[DIM(NZ * NQ)], dgdu[DIM(NZ * NQ)];
    /* chassis: whether a collision point touched at f's state (its forces were added to f), and their Jacobian */
    int chassis_touch;
    double fc[CHASSIS ? NQ : 1], dfc_dq[CHASSIS ? NQ * NQ : 1], dfc_du[CHASSIS ? NQ * NQ : 1];
    double col[NQ];
    double sres[DIM(NS)], sjac[DIM(NS * NS)], sdq[DIM(NS)], sq[NQ];
    int spiv[DIM(NS)];
    double ok;
    char msg[256];
    char full_msg[600];                 /* msg and the terrain's reason */
    heightmap *terrain;                 /* heightmap scenes: the instance's map */
    heightmap_memo *memo;               /* and the memo of its rim searches */
    /* rigid contact (unused for compliant models) */
    double Mraw[NQ * NQ], W[3 * NC * NQ], bias[3 * NC], vc[3 * NC], gap[NC], lambda[3 * NC];
    int mode[NC], held_mode[NC], have_modes;
    double dir[2 * NC], held_dir[2 * NC];
    double rwork[RIGID_WORK(NQ, NC)];
    int riwork[RIGID_IWORK(NQ, NC)];
    double xh[NX], fh[NX];
    int i_mu, i_alpha, i_vstick;        /* where mu (input), rigid_alpha and v_stick (parameters) live */
    /* the output slots the contact solution fills: wheel[k].mode and wheel[k].Fx_mean, Fy_mean, Fn_mean (in
     * lambda's component order) */
    int y_mode[N_WHEELS], y_mean[3 * N_WHEELS];
    double impulse[3 * NC];
};

size_t model_ws_size(void) { return sizeof(model_ws); }

#if CEDRA_RIGID
static int find_var(const char *name, int kind) {
    for (int i = 0; i < CEDRA_NVARS; i++)
        if (CEDRA_VARS[i].kind == kind && strcmp(CEDRA_VARS[i].name, name) == 0) return CEDRA_VARS[i].index;
    return -1;
}
#endif

#if CEDRA_RIGID
static int moreau_step(void *ctx, double t, double h, double *x);
#define OWN_STEP moreau_step
#else
#define OWN_STEP NULL
#endif

const solver_structure *model_structure(void) {
    static const solver_structure structure = {CEDRA_SCHUR_N2, MASS_ROWS, 1, CEDRA_RIGID, NIMP, OWN_STEP};
    return &structure;
}

void model_bind(model_ws *ws, const double *inp, const double *par) {
    ws->dyn_valid = 0;
    ws->inp = inp;
    ws->par = par;
    ws->sw_valid = 0;       /* s at a step's start depends on the inputs: evaluate it again */
    ws->swn_valid = 0;
#if CEDRA_RIGID
    ws->have_modes = 0;     /* the first evaluation decides the modes from the state */
    ws->i_mu = find_var("mu", CEDRA_K_INP);
    ws->i_alpha = find_var("rigid_alpha", CEDRA_K_PAR);
    ws->i_vstick = find_var("v_stick", CEDRA_K_PAR);
    for (int k = 0; k < N_WHEELS; k++) {
        char name[64];
        snprintf(name, sizeof name, "wheel[%d].mode", k + 1);
        ws->y_mode[k] = find_var(name, CEDRA_K_OUT);
        for (int c = 0; c < 3; c++) {
            snprintf(name, sizeof name, "wheel[%d].%s_mean", k + 1, c == 0 ? "Fx" : c == 1 ? "Fy" : "Fn");
            ws->y_mean[3 * k + c] = find_var(name, CEDRA_K_OUT);
        }
    }
#endif
}

void model_bind_terrain(model_ws *ws, void *terrain, void *memo) {
    ws->terrain = (heightmap *)terrain;
    ws->memo = (heightmap_memo *)memo;
}

/* the generated functions of a heightmap scene evaluate the thread's active map: this instance's (its reason
 * cleared, so a message names the failure of this evaluation, not an earlier one) */
static void activate(model_ws *ws) {
#if CEDRA_HEIGHTMAP
    heightmap_activate(ws->terrain, ws->memo);
    if (ws->terrain) ws->terrain->msg[0] = '\0';
#else
    (void)ws;
#endif
}

const char *model_message(const model_ws *ws) {
    model_ws *w = (model_ws *)ws;
    if (ws->terrain && ws->terrain->msg[0] && ws->msg[0]) {
        snprintf(w->full_msg, sizeof w->full_msg, "%s: %s", ws->msg, ws->terrain->msg);
        return ws->full_msg;
    }
    return ws->msg;
}

void model_clear_message(model_ws *ws) {
    ws->msg[0] = '\0';
    if (ws->terrain) ws->terrain->msg[0] = '\0';
}

static int all_finite(const double *v, int n) {
    for (int i = 0; i < n; i++)
        if (!isfinite(v[i])) return 0;
    return 1;
}

int model_check(model_ws *ws, const double *q, const double *u) {
    activate(ws);
    ws->arg[0] = q;
    ws->arg[1] = u;
    ws->arg[2] = ws->inp;
    ws->arg[3] = ws->par;
    ws->res[0] = &ws->ok;
    if (cedra_check(ws->arg, ws->res, ws->iw, ws->w, 0) || !(ws->ok >= 0.5)) {
        /* the codes of python/cedra/contract.py CHECK_REASONS */
        const char *why = ws->ok == -1 ? "the front four-bar cannot be assembled (fork beyond its toggle)"
                          : ws->ok == -2 ? "the body has tipped over (|pitch| or |roll| > 80 deg): the model has "
                                           "no body-ground contact"
                                         : "the state is outside the model's domain";
        snprintf(ws->msg, sizeof ws->msg, "%s (cedra_check)", why);
        return 0;
    }
    return 1;
}

/* f and g at (q, u); the arguments stay set to (q, u, inp, par) for a following call */
static int eval_f(model_ws *ws, const double *q, const double *u, double t) {
    ws->dyn_valid = 0;     /* ws->f and g are about to change */
    ws->arg[0] = q;
    ws->arg[1] = u;
    ws->arg[2] = ws->inp;
    ws->arg[3] = ws->par;
    ws->res[0] = ws->f;
    ws->res[1] = ws->g;
    if (cedra_f(ws->arg, ws->res, ws->iw, ws->w, 0)) {
        snprintf(ws->msg, sizeof ws->msg, "cedra_f failed at t=%.17g", t);
        return 1;
    }
#if CHASSIS
    /* the collision points' forces only while one touches: elsewhere they and their Jacobian are exactly zero,
     * and evaluating them would cost about a third of a 3D model's f and Jacobian */
    double depth;
    ws->arg[1] = ws->inp;
    ws->arg[2] = ws->par;
    ws->res[0] = &depth;
    if (cedra_cgap(ws->arg, ws->res, ws->iw, ws->w, 0)) {
        snprintf(ws->msg, sizeof ws->msg, "cedra_cgap failed at t=%.17g", t);
        return 1;
    }
    ws->chassis_touch = depth > 0;
    ws->arg[1] = u;
    ws->arg[2] = ws->inp;
    ws->arg[3] = ws->par;
    if (ws->chassis_touch) {
        ws->res[0] = ws->fc;
        if (cedra_fc(ws->arg, ws->res, ws->iw, ws->w, 0)) {
            snprintf(ws->msg, sizeof ws->msg, "cedra_fc failed at t=%.17g", t);
            return 1;
        }
        for (int i = 0; i < NQ; i++) ws->f[i] += ws->fc[i];
    }
#endif
    return 0;
}

/* M at q into M, f and g at (q, u); the arguments stay set to (q, u, inp, par) for a following call */
static int eval_M_f(model_ws *ws, const double *q, const double *u, double t, double *M) {
    ws->dyn_valid = 0;
    ws->arg[0] = q;
    ws->arg[1] = ws->par;
    ws->res[0] = M;
    if (cedra_M(ws->arg, ws->res, ws->iw, ws->w, 0)) {
        snprintf(ws->msg, sizeof ws->msg, "cedra_M failed at t=%.17g", t);
        return 1;
    }
    return eval_f(ws, q, u, t);
}

/* b := M^-1 b with the factors of eval_dynamics */
static void mass_solve(const model_ws *ws, double *b) {
    double work[NQ];
    if (ws->m_chol)
        linalg_chol_solve_perm(NQ, ws->M, CEDRA_M_ORDER, b, work);
    else
        linalg_lu_solve(NQ, ws->M, ws->piv, b);
}

/* M and its factors at q, f and g at (q, u) */
static int eval_dynamics(model_ws *ws, const double *q, const double *u, double t) {
    if (ws->dyn_valid && memcmp(ws->dyn_x, q, sizeof(double) * NQ) == 0 &&
        memcmp(ws->dyn_x + NQ, u, sizeof(double) * NQ) == 0)
        return 0;
    if (eval_M_f(ws, q, u, t, ws->Mfull)) return 1;
    /* Cholesky (M is symmetric positive definite for any assembly of the mechanism), in the generator's order that
     * keeps M's zeros zero (cedra.fmu.mass_order: the wheels first); LU with pivoting where rounding makes it fail
     * to be (then the LU's own test decides whether M can be solved at all) */
    ws->m_chol = !linalg_chol_factor_perm(NQ, ws->Mfull, CEDRA_M_ORDER, ws->M, ws->m_nz);
    if (!ws->m_chol) {
        memcpy(ws->M, ws->Mfull, sizeof ws->M);
        if (linalg_lu_factor(NQ, ws->M, ws->piv)) {
            snprintf(ws->msg, sizeof ws->msg, "the mass matrix is singular or not finite at t=%.17g", t);
            return 1;
        }
    }
    memcpy(ws->dyn_x, q, sizeof(double) * NQ);
    memcpy(ws->dyn_x + NQ, u, sizeof(double) * NQ);
    ws->dyn_valid = 1;
    return 0;
}

#if CEDRA_RIGID
static rigid_params rigid_settings(const model_ws *ws) {
    rigid_params p;
    p.mu = ws->inp[ws->i_mu];
    p.alpha = ws->par[ws->i_alpha];
    p.v_stick = ws->par[ws->i_vstick];
    p.gap_tol = 1e-6;     /* a wheel more than 1 um above the ground is airborne */
    return p;
}

/* cedra_M (unfactored, into Mraw), cedra_f, cedra_contact at (q, u) */
/* cedra_contact at (q, u): W, bias, vc, gap */
static int eval_contact(model_ws *ws, const double *q, const double *u, double t) {
    ws->arg[0] = q;
    ws->arg[1] = u;
    ws->arg[2] = ws->inp;
    ws->arg[3] = ws->par;
    ws->res[0] = ws->W;
    ws->res[1] = ws->bias;
    ws->res[2] = ws->vc;
    ws->res[3] = ws->gap;
    if (cedra_contact(ws->arg, ws->res, ws->iw, ws->w, 0)) {
        snprintf(ws->msg, sizeof ws->msg, "cedra_contact failed at t=%.17g", t);
        return 1;
    }
    return 0;
}

static int eval_rigid_terms(model_ws *ws, const double *q, const double *u, double t) {
    return eval_M_f(ws, q, u, t, ws->Mraw) || eval_contact(ws, q, u, t);
}

/* Accelerations and contact forces. As in the paper, the decision tree runs once per time step: decide != 0
 * runs it at this state (after each accepted step, for outputs, at the start of a communication step); the
 * evaluations inside an integration step hold those modes and slip directions, so that each step integrates
 * one smooth system instead of chattering on the switching surfaces. */
static int rigid_solve(model_ws *ws, const double *q, const double *u, double t, double *udot, int decide) {
    if (eval_rigid_terms(ws, q, u, t)) return 1;
    rigid_params p = rigid_settings(ws);
    char why[160];
    if (!decide) {
        memcpy(ws->mode, ws->held_mode, sizeof ws->mode);
        memcpy(ws->dir, ws->held_dir, sizeof ws->dir);
    }
    if (rigid_solve_modes(NQ, NC, ws->Mraw, ws->f, ws->W, ws->bias, ws->vc, ws->gap, &p, decide, ws->mode,
                          ws->dir, udot, ws->lambda, ws->rwork, ws->riwork, why, sizeof why)) {
        snprintf(ws->msg, sizeof ws->msg, "%s at t=%.17g", why, t);
        return 1;
    }
    return 0;
}

/* run the decision tree at x and hold its modes; 1 if they differ from the held ones */
static int rigid_decide(model_ws *ws, const double *x, double t) {
    if (rigid_solve(ws, x, x + NQ, t, ws->fh, 1)) return -1;
    int changed = !ws->have_modes || memcmp(ws->mode, ws->held_mode, sizeof ws->mode) != 0;
    memcpy(ws->held_mode, ws->mode, sizeof ws->mode);
    memcpy(ws->held_dir, ws->dir, sizeof ws->dir);
    ws->have_modes = 1;
    return changed;
}
#endif

#if CEDRA_RIGID
/* A wheel may land anywhere inside a step (the step holds its modes): a step that ends with a wheel deeper in
 * the ground than PEN_TOL is retried shorter, aimed at the crossing, so that touch-downs are located to within
 * PEN_TOL and the post-step projection only removes what the integration leaves. Projecting a whole step's
 * fall out instead lifts the rover by up to a millimetre per landing and feeds it energy: it keeps hopping. */
#define PEN_TOL 1e-6
#endif

double model_accept_step(void *ctx, double t, const double *x, double t_new, const double *x_new) {
#if CEDRA_RIGID
    model_ws *ws = (model_ws *)ctx;
    activate(ws);
    double gap_new[NC];
    int deep = 0;
    if (eval_contact(ws, x_new, x_new + NQ, t_new)) return -1;     /* only the gaps are needed */
    for (int k = 0; k < NC; k++) {
        gap_new[k] = ws->gap[k];
        deep |= gap_new[k] < -PEN_TOL;
    }
    if (!deep) return 1;
    if (eval_contact(ws, x, x + NQ, t)) return -1;
    double factor = 1;
    for (int k = 0; k < NC; k++) {
        double g0 = ws->gap[k];
        /* a wheel already that deep at the start (a start pose in the ground) is left to the projection: no
         * shorter step would help it */
        if (!(gap_new[k] < -PEN_TOL) || g0 < -PEN_TOL) continue;
        /* a wheel above the ground at the start: aim just past its crossing; one on it: halve */
        factor = fmin(factor, fmin(0.9, g0 > 0 ? (g0 + 0.5 * PEN_TOL) / (g0 - gap_new[k]) : 0.5));
    }
    return factor;                /* the solver bounds how far a step shrinks */
#else
    (void)ctx;
    (void)t;
    (void)x;
    (void)t_new;
    (void)x_new;
    return 1;
#endif
}

#if NSW > 0
/* s (and the discrete choices the model makes now, into hold_now) at x, with the choices `hold` held */
static int eval_switch(model_ws *ws, const double *x, const double *hold, double *s, double *hold_now) {
    ws->arg[0] = x;
    ws->arg[1] = x + NQ;
    ws->arg[2] = ws->inp;
    ws->arg[3] = ws->par;
    ws->arg[4] = hold;
    ws->res[0] = s;
    ws->res[1] = hold_now;
    if (cedra_switch(ws->arg, ws->res, ws->iw, ws->w, 0) || !all_finite(s, NSW)) {
        snprintf(ws->msg, sizeof ws->msg, "cedra_switch failed or is not finite");
        return 1;
    }
    return 0;
}
#endif

double model_locate_step(void *ctx, double t, const double *x, double t_new, const double *x_new) {
#if NSW > 0
    model_ws *ws = (model_ws *)ctx;
    const double loc_tol = fmax(LOC_TOL, 10 * solver_time_resolution(t_new));
    activate(ws);
    int retry = 0;
    if (ws->sw_valid && ws->sw_t == t && memcmp(ws->sw_x, x, sizeof ws->sw_x) == 0) {
        retry = 1;          /* the same start as the last call (a retried step) */
    } else if (ws->swn_valid && ws->swn_t == t && memcmp(ws->swn_x, x, sizeof ws->swn_x) == 0) {
        /* the end of the last step, evaluated with its own choices: hold stays, s0 is that evaluation */
        memcpy(ws->sw0, ws->swn, sizeof ws->sw0);
        ws->sw_t = t;
        memcpy(ws->sw_x, x, sizeof ws->sw_x);
        ws->sw_valid = 1;
    } else {
        /* the step's start: the model's choices there, held over the step, and s relative to them */
        if (eval_switch(ws, x, ws->hold, ws->sw0, ws->hold_tmp)) return -1;
        memcpy(ws->hold, ws->hold_tmp, sizeof ws->hold);
        if (NH > 0 && eval_switch(ws, x, ws->hold, ws->sw0, ws->hold_tmp)) return -1;
        ws->sw_t = t;
        memcpy(ws->sw_x, x, sizeof ws->sw_x);
        ws->sw_valid = 1;
    }
    if (ws->aim > 0 && !retry && fabs(t - ws->aim_t) <= 1e-9 * fmax(1.0, fabs(t))) {
        /* The last step was cut short of a switch, aimed just before it, and this step starts where that one
         * ended. Where s is close to linear over a step it is now far nearer to 0. An s that has not come halfway
         * (a switch function that changed its branch, say a contact slot that now holds another maximum, or one
         * that bends sharply within the step) cannot be reached by interpolation: each cut would end short of it
         * again and the call would creep in steps of the cut's length. Such a switch is located by bisection for
         * the rest of the call (below), which finds any sign change of s, continuous or not. */
        const int i = ws->aim - 1;
        if ((ws->sw0[i] > 0) == (ws->aim_s > 0) && fabs(ws->sw0[i]) > 0.5 * fabs(ws->aim_s)) ws->sw_miss[i]++;
    }
    if (!retry) ws->aim = 0;
    if (eval_switch(ws, x_new, ws->hold, ws->sw1, ws->hold_tmp)) return -1;
    ws->swn_valid = NH == 0 || memcmp(ws->hold_tmp, ws->hold, sizeof ws->hold) == 0;
    if (ws->swn_valid) {
        memcpy(ws->swn, ws->sw1, sizeof ws->swn);
        ws->swn_t = t_new;
        memcpy(ws->swn_x, x_new, sizeof ws->swn_x);
    }
    /* A switch crossed back and forth (a force law sliding along its switch, e.g. a wheel that barely touches)
     * would be located again and again: after MAX_LOCATE locations in one call it is left to the error control
     * for the rest of the call. */
    for (int i = 0; i < NSW; i++)
        if (ws->sw_count[i] >= MAX_LOCATE) ws->sw1[i] = ws->sw0[i];
    int which;
    double len = solver_locate_switches(NSW, ws->sw0, ws->sw1, t, t_new, loc_tol, &which);
    if (which >= 0 && len >= 0 && len < t_new - t) {
        /* a retry of a step cut at this switch whose end is no nearer to it: the interpolation does not converge
         * either (s jumps inside the step) */
        if (retry && ws->aim == which + 1 && (ws->sw1[which] > 0) == (ws->aim_s1 > 0) &&
            fabs(ws->sw1[which]) > 0.5 * fabs(ws->aim_s1))
            ws->sw_miss[which]++;
        if (ws->sw_miss[which] > 0) len = 0.5 * (t_new - t);       /* bisection: half the step, every time */
    }
    if (which >= 0 && len >= t_new - t) {      /* accepted with the switch inside: located */
        int k = (int)(ws->n_located % LOG_LOCATED);
        ws->loc_which[k] = which;
        ws->loc_t0[k] = t;
        ws->loc_t1[k] = t_new;
        ws->n_located++;
        ws->sw_count[which]++;
    } else if (which >= 0 && len >= 0 && len < t_new - t) {   /* a cut: the step is retried ending before it */
        ws->aim = which + 1;
        ws->aim_s = ws->sw0[which];
        ws->aim_s1 = ws->sw1[which];
        ws->aim_t = t + len;
    }
    return len;
#else
    (void)ctx;
    (void)x;
    (void)x_new;
    return t_new - t;
#endif
}

long model_take_located(model_ws *ws, int k, const char **name, double *t0, double *t1) {
    long n = ws->n_located;
    if (k < 0) {
        ws->n_located = 0;
        memset(ws->sw_count, 0, sizeof ws->sw_count);
#if NSW > 0
        memset(ws->sw_miss, 0, sizeof ws->sw_miss);
        ws->aim = 0;
#endif
        return n;
    }
#if NSW > 0
    int j = (int)((n - 1 - k) % LOG_LOCATED);
    if (name && t0 && t1 && k < n && k < LOG_LOCATED && j >= 0) {
        *name = CEDRA_SW_NAMES[ws->loc_which[j]];
        *t0 = ws->loc_t0[j];
        *t1 = ws->loc_t1[j];
    }
#else
    (void)name;
    (void)t0;
    (void)t1;
#endif
    return n;
}

#if CEDRA_RIGID
/* Gauss-Newton on the gaps: project x's positions until no contact penetrates; 1 if they moved, 0 if not, -1 on
 * failure (ws->msg) */
static int project_positions(model_ws *ws, double t, double *x) {
    rigid_params p = rigid_settings(ws);
    char why[160];
    int r = 0;
    for (int it = 0; it < 30; it++) {
        if (eval_rigid_terms(ws, x, x + NQ, t)) return -1;
        int rk = rigid_project(NQ, NC, x, ws->Mraw, ws->W, ws->gap, &p, ws->rwork, ws->riwork, why, sizeof why);
        if (rk < 0) {
            snprintf(ws->msg, sizeof ws->msg, "%s at t=%.17g", why, t);
            return rk;
        }
        if (rk == 0) break;
        r = 1;
    }
    return r;
}

/* solver.method moreau (solver.h own_step): one Moreau-Jean step, midpoint rule. Positions to the midpoint
 * q + h/2 u, where M, f and the contacts are evaluated; the velocities jump to u+ by the impulse problem of the
 * contacts touching there (rigid_moreau: forces and impacts alike are impulses over the step, so a step carries
 * no mode from its start); positions from the midpoint with u+. The impulses P add to the step's (wheel[k].F*_mean),
 * the work integral gets h times the power at (q_mid, (u + u+) / 2). Then penetration is projected out as after
 * any other method's step (the impacts are in the step already). */
static int moreau_step(void *ctx, double t, double h, double *x) {
    model_ws *ws = (model_ws *)ctx;
    activate(ws);
    double qm[NQ], u0[NQ];
    for (int j = 0; j < NQ; j++) qm[j] = x[j] + 0.5 * h * x[NQ + j];
    memcpy(u0, x + NQ, sizeof u0);
    if (!model_check(ws, qm, x + NQ)) return 1;
    if (eval_rigid_terms(ws, qm, x + NQ, t + 0.5 * h)) return 1;
    rigid_params p = rigid_settings(ws);
    char why[160];
    if (rigid_moreau(NQ, NC, x + NQ, ws->impulse, ws->Mraw, ws->f, h, ws->W, ws->vc, ws->gap, &p, ws->rwork,
                     ws->riwork, why, sizeof why)) {
        snprintf(ws->msg, sizeof ws->msg, "%s at t=%.17g", why, t);
        return 1;
    }
    double um[NQ];     /* the work integral at the step's mean velocity: the torques' work tau (q+ - q) exactly */
    for (int j = 0; j < NQ; j++) {
        um[j] = 0.5 * (u0[j] + x[NQ + j]);
        x[j] = qm[j] + 0.5 * h * x[NQ + j];
    }
    if (NZ > 0 && eval_f(ws, qm, um, t + 0.5 * h)) return 1;
    for (int i = 0; i < NZ; i++) x[2 * NQ + i] += h * ws->g[i];
    for (int i = 0; i < NIMP; i++) x[IMP + i] += ws->impulse[i];
    ws->have_modes = 0;        /* the outputs' decision starts from the state, as after any other step */
    return project_positions(ws, t + h, x) < 0;
}
#endif

int model_post_step(void *ctx, double t, double *x) {
#if CEDRA_RIGID
    model_ws *ws = (model_ws *)ctx;
    activate(ws);
    rigid_params p = rigid_settings(ws);
    char why[160];
    int r = project_positions(ws, t, x);
    if (r < 0) return r;
    if (eval_rigid_terms(ws, x, x + NQ, t)) return -1;
    int ri = rigid_impact(NQ, NC, x + NQ, ws->impulse, ws->Mraw, ws->W, ws->vc, ws->gap, &p, ws->rwork,
                          ws->riwork, why, sizeof why);
    if (ri < 0) {
        snprintf(ws->msg, sizeof ws->msg, "%s at t=%.17g", why, t);
        return ri;
    }
    if (ri)      /* the impact's impulses belong to the communication step's (wheel[k].F*_mean) */
        for (int i = 0; i < NIMP; i++) x[IMP + i] += ws->impulse[i];
    r |= ri;
    int d = rigid_decide(ws, x, t);
    if (d < 0) return -1;
    return r || d;     /* a new mode set changes F at x: the solver must not reuse F (FSAL) */
#else
    (void)ctx;
    (void)t;
    (void)x;
    return 0;
#endif
}

int model_rhs(void *ctx, double t, const double *x, double *xdot) {
    model_ws *ws = (model_ws *)ctx;
    activate(ws);
    const double *q = x, *u = x + NQ;
    if (!all_finite(x, NX)) {
        snprintf(ws->msg, sizeof ws->msg, "the state is not finite at t=%.17g", t);
        return 1;
    }
    if (!model_check(ws, q, u)) {
        size_t len = strlen(ws->msg);
        snprintf(ws->msg + len, sizeof ws->msg - len, " at t=%.17g", t);
        return 1;
    }
#if CEDRA_RIGID
    if (!ws->have_modes && rigid_decide(ws, x, t) < 0) return 1;
    if (rigid_solve(ws, q, u, t, xdot + NQ, 0)) return 1;
    memcpy(xdot, u, sizeof(double) * NQ);
    memcpy(xdot + IMP, ws->lambda, sizeof(double) * NIMP);     /* the impulses' rates: the contact forces */
#else
    if (eval_dynamics(ws, q, u, t)) return 1;
    memcpy(xdot, u, sizeof(double) * NQ);
    memcpy(xdot + NQ, ws->f, sizeof(double) * NQ);
    mass_solve(ws, xdot + NQ);
#endif
    if (NZ > 0) memcpy(xdot + 2 * NQ, ws->g, sizeof(double) * NZ);   /* the impulses follow, at IMP */
    if (!all_finite(xdot, NX)) {
        snprintf(ws->msg, sizeof ws->msg, "the derivative is not finite at t=%.17g", t);
        return 1;
    }
    return 0;
}

/* dF/dx = [[0, I, 0], [-M^-1 dr_dq, -M^-1 dr_du, 0], [dg_dq, dg_du, 0]] at a = udot, column-major NX x NX */
int model_jac(void *ctx, double t, const double *x, const double *xdot, double *jac) {
    model_ws *ws = (model_ws *)ctx;
    activate(ws);
    const double *q = x, *u = x + NQ;
#if CEDRA_RIGID
    /* The decision tree has no symbolic Jacobian: forward differences of F (rodas4 then runs with an
     * approximate Jacobian; its error control still holds, its order may drop near mode switches). */
    memcpy(ws->xh, x, sizeof(double) * NX);
    memset(jac + (size_t)2 * NQ * NX, 0, sizeof(double) * (size_t)(NX - 2 * NQ) * NX);   /* F ignores z, impulses */
    for (int j = 0; j < 2 * NQ; j++) {
        double d = 1e-7 * fmax(1.0, fabs(x[j]));
        ws->xh[j] = x[j] + d;
        if (model_rhs(ctx, t, ws->xh, ws->fh)) return 1;
        for (int i = 0; i < NX; i++) jac[i + (size_t)j * NX] = (ws->fh[i] - xdot[i]) / d;
        ws->xh[j] = x[j];
    }
    (void)q;
    (void)u;
    return 0;
#endif
    if (eval_dynamics(ws, q, u, t)) return 1;
    ws->arg[0] = q;
    ws->arg[1] = u;
    ws->arg[2] = xdot + NQ;
    ws->arg[3] = ws->inp;
    ws->arg[4] = ws->par;
    ws->res[0] = ws->drdq;
    ws->res[1] = ws->drdu;
    ws->res[2] = ws->dgdq;
    ws->res[3] = ws->dgdu;
    if (cedra_rjac(ws->arg, ws->res, ws->iw, ws->w, 0)) {
        snprintf(ws->msg, sizeof ws->msg, "cedra_rjac failed at t=%.17g", t);
        return 1;
    }
#if CHASSIS
    if (ws->chassis_touch) {      /* of eval_dynamics' state, which is this one: r = M a - f - Qc */
        ws->arg[2] = ws->inp;
        ws->arg[3] = ws->par;
        ws->res[0] = ws->dfc_dq;
        ws->res[1] = ws->dfc_du;
        if (cedra_fcjac(ws->arg, ws->res, ws->iw, ws->w, 0)) {
            snprintf(ws->msg, sizeof ws->msg, "cedra_fcjac failed at t=%.17g", t);
            return 1;
        }
        for (int i = 0; i < NQ * NQ; i++) {
            ws->drdq[i] -= ws->dfc_dq[i];
            ws->drdu[i] -= ws->dfc_du[i];
        }
    }
#endif
    memset(jac, 0, sizeof(double) * NX * NX);
    for (int j = 0; j < NQ; j++) {
        jac[j + (size_t)(NQ + j) * NX] = 1.0;                       /* dqdot/du = I */
        for (int blk = 0; blk < 2; blk++) {                          /* column j of q, then of u */
            const double *dr = blk ? ws->drdu : ws->drdq;
            for (int i = 0; i < NQ; i++) ws->col[i] = -dr[i + (size_t)j * NQ];
            if (!MASS_ROWS) mass_solve(ws, ws->col);
            int cj = blk * NQ + j;
            for (int i = 0; i < NQ; i++) jac[NQ + i + (size_t)cj * NX] = ws->col[i];
            for (int i = 0; i < NZ; i++)
                jac[2 * NQ + i + (size_t)cj * NX] = (blk ? ws->dgdu : ws->dgdq)[i + (size_t)j * NZ];
        }
    }
    if (MASS_ROWS) memcpy(jac + (size_t)NX * NX, ws->Mfull, sizeof ws->Mfull);   /* solver.h: M at jac + n n */
    if (!all_finite(jac, NX * NX)) {
        snprintf(ws->msg, sizeof ws->msg, "the Jacobian is not finite at t=%.17g", t);
        return 1;
    }
    return 0;
}

#if CEDRA_RIGID
/* a wheel's mode from its contacts': stick if one sticks, else slip if one slips, else airborne */
static int wheel_mode(const int *mode) {
    int m = RIGID_AIRBORNE;
    for (int j = 0; j < NCW; j++)
        if (mode[j] == RIGID_STICK || (mode[j] == RIGID_SLIP && m == RIGID_AIRBORNE)) m = mode[j];
    return m;
}

/* wheel[k].F*_mean: the impulses of the wheel's contacts (3 per contact, lambda's layout) added by component,
 * divided by h (with several contacts the sums of their impulses, each along its own contact frame) */
static void wheel_means(const model_ws *ws, const double *impulse, double h, double *y) {
    for (int k = 0; k < N_WHEELS; k++)
        for (int c = 0; c < 3; c++) {
            if (ws->y_mean[3 * k + c] < 0) continue;
            double sum = 0;
            for (int j = 0; j < NCW; j++) sum += impulse[3 * (k * NCW + j) + c];
            y[ws->y_mean[3 * k + c]] = sum / h;
        }
}
#endif

int model_outputs(model_ws *ws, const double *x, double *y) {
    activate(ws);
    if (!all_finite(x, NX)) {
        snprintf(ws->msg, sizeof ws->msg, "the state is not finite");
        return 1;
    }
    if (!model_check(ws, x, x + NQ)) return 1;
#if CEDRA_RIGID
    /* contact forces and modes are the decision tree's solution at this state; cedra_out forms the outputs of
     * the forces (the wheels' totals, the contacts') */
    if (rigid_solve(ws, x, x + NQ, 0.0, ws->xh, 1)) return 1;
    ws->arg[5] = ws->lambda;
#endif
    ws->arg[0] = x;
    ws->arg[1] = x + NQ;
    ws->arg[2] = x + 2 * NQ;
    ws->arg[3] = ws->inp;
    ws->arg[4] = ws->par;
    ws->res[0] = y;
    if (cedra_out(ws->arg, ws->res, ws->iw, ws->w, 0)) {
        snprintf(ws->msg, sizeof ws->msg, "cedra_out failed");
        return 1;
    }
#if CEDRA_RIGID
    for (int k = 0; k < N_WHEELS; k++)
        if (ws->y_mode[k] >= 0) y[ws->y_mode[k]] = wheel_mode(ws->mode + k * NCW);
    wheel_means(ws, ws->lambda, 1.0, y);     /* no interval yet (model_interval_outputs): the force here */
#endif
    for (int i = 0; i < CEDRA_NY; i++) {
        if (!isfinite(y[i])) {
            snprintf(ws->msg, sizeof ws->msg, "the output %s is not finite (%g)", CEDRA_Y_NAMES[i], y[i]);
            return 1;
        }
    }
    return 0;
}

/* residual and Jacobian of the static equilibrium at q; returns 0 or 1 */
static int settle_eval(model_ws *ws, const double *q) {
    ws->arg[0] = q;
    ws->arg[1] = ws->inp;
    ws->arg[2] = ws->par;
    ws->res[0] = ws->sres;
    ws->res[1] = ws->sjac;
    if (cedra_settle(ws->arg, ws->res, ws->iw, ws->w, 0)) return 1;
    return !(all_finite(ws->sres, NS) && all_finite(ws->sjac, NS * NS));
}

static double norm_inf(const double *v, int n) {
    double m = 0;
    for (int i = 0; i < n; i++) m = fmax(m, fabs(v[i]));
    return m;
}

int model_settle(model_ws *ws, double *q) {
    activate(ws);
    ws->arg[0] = q;
    ws->arg[1] = ws->inp;
    ws->arg[2] = ws->par;
    ws->res[0] = ws->sq;
    if (cedra_guess(ws->arg, ws->res, ws->iw, ws->w, 0) || !all_finite(ws->sq, NQ)) {
        snprintf(ws->msg, sizeof ws->msg, "settle: cedra_guess failed or gave a non-finite pose");
        return 1;
    }
    memcpy(q, ws->sq, sizeof(double) * NQ);
    if (NS == 0) return 0;
    if (settle_eval(ws, q)) {
        snprintf(ws->msg, sizeof ws->msg, "settle: the equilibrium residual is not finite at the initial guess");
        return 1;
    }
    double r = norm_inf(ws->sres, NS);
    for (int it = 0; it < SETTLE_MAX_ITER; it++) {
        if (r == 0.0) return 0;
        if (linalg_lu_factor(NS, ws->sjac, ws->spiv)) {
            snprintf(ws->msg, sizeof ws->msg, "settle: singular equilibrium Jacobian at iteration %d "
                     "(residual %.3g)", it, r);
            return 1;
        }
        for (int i = 0; i < NS; i++) ws->sdq[i] = -ws->sres[i];
        linalg_lu_solve(NS, ws->sjac, ws->spiv, ws->sdq);
        double scale = 1.0;
        for (int i = 0; i < NS; i++) scale = fmax(scale, fabs(q[CEDRA_SETTLE_IDX[i]]));
        double dq = norm_inf(ws->sdq, NS);
        /* damped: halve the step until the residual decreases */
        double lam = 1.0, r_new = HUGE_VAL;
        memcpy(ws->sq, q, sizeof(double) * NQ);
        int k;
        for (k = 0; k < SETTLE_MAX_HALVINGS; k++, lam *= 0.5) {
            for (int i = 0; i < NS; i++) ws->sq[CEDRA_SETTLE_IDX[i]] = q[CEDRA_SETTLE_IDX[i]] + lam * ws->sdq[i];
            if (!settle_eval(ws, ws->sq) && (r_new = norm_inf(ws->sres, NS)) < r) break;
        }
        if (k == SETTLE_MAX_HALVINGS) {
            if (dq <= SETTLE_RTOL * scale) return 0;      /* at the floor of the residual's round-off */
            snprintf(ws->msg, sizeof ws->msg, "settle: no decrease of the equilibrium residual %.3g at "
                     "iteration %d", r, it);
            return 1;
        }
        memcpy(q, ws->sq, sizeof(double) * NQ);
        r = r_new;
        if (lam * dq <= SETTLE_RTOL * scale) return 0;
    }
    snprintf(ws->msg, sizeof ws->msg, "settle: no convergence in %d Newton iterations (residual %.3g)",
             SETTLE_MAX_ITER, r);
    return 1;
}

void model_begin_interval(model_ws *ws, double *x) {
    (void)ws;
    for (int i = 0; i < NIMP; i++) x[IMP + i] = 0.0;
}

void model_interval_outputs(model_ws *ws, const double *x, double h, double *y) {
#if CEDRA_RIGID
    wheel_means(ws, x + IMP, h, y);
#else
    (void)ws;
    (void)x;
    (void)h;
    (void)y;
#endif
}
