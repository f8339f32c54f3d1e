/* Rigid wheels on rigid ground: the paper's decision tree (see rigid.h). Dense, small (nq <= 17, nc <= 6). */
#include "rigid.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

#include "linalg.h"

/* Constraint force mixing: with six sticking wheels the tangential contact forces are statically indeterminate
 * (18 constraints on <= 17 speeds), so the Delassus matrix A = C M^-1 D' is singular. A relative diagonal shift
 * of 1e-10 picks the (almost) minimum-norm forces and changes the constraint accelerations by ~1e-10 lambda. */
#define CFM 1e-10
/* Complementarity tolerances of the decision: a normal force (N, or N.s for an impulse) below -FORCE_TOL pulls;
 * a constraint value (m/s^2, or m/s) more than VALUE_TOL below its target drives a wheel into the ground. They
 * are far above the round-off of the solves and far below anything physical. */
#define FORCE_TOL 1e-9
#define VALUE_TOL 1e-8
/* a touching wheel approaching the ground faster than this (m/s) starts an impact; slower approach is round-off
 * and Baumgarte's business */
#define IMPACT_SPEED 1e-9

size_t rigid_workspace_size(int nq, int nc) { return (size_t)RIGID_WORK(nq, nc); }

size_t rigid_iworkspace_size(int nq, int nc) { return (size_t)RIGID_IWORK(nq, nc); }

static double row_dot(const double *W, int ldw, int row, const double *x, int nq) {
    double s = 0;
    for (int j = 0; j < nq; j++) s += W[row + (size_t)j * ldw] * x[j];
    return s;
}

/* Mlu, piv := the LU factors of M; 0, or 1 with the reason in msg */
static int factor_mass(int nq, const double *M, double *Mlu, int *piv, char *msg, size_t msg_len) {
    memcpy(Mlu, M, sizeof(double) * (size_t)nq * nq);
    if (linalg_lu_factor(nq, Mlu, piv)) {
        snprintf(msg, msg_len, "rigid contact: the mass matrix is singular");
        return 1;
    }
    return 0;
}

/* the unit direction of contact k's tangential force in lambda, (1, 0) where it is zero */
static void tangential_dir(const double *lambda, int k, double *d) {
    double fx = lambda[3 * k], fy = lambda[3 * k + 1], ft = hypot(fx, fy);
    d[0] = ft > 0 ? fx / ft : 1;
    d[1] = ft > 0 ? fy / ft : 0;
}

/* The linear complementarity problem of one decision, for accelerations (M udot = f + W' lambda: x0 = M^-1 f,
 * bias = dW/dt u, target = the Baumgarte-stabilized constraint accelerations) or for an impact (M du = W' L:
 * x0 = 0, bias = the contact velocities, target = 0). For every contact row, y = W x + bias is the constraint
 * value; a contact in contact holds y = target on its rows (stick: x, y, n; slip: n). */
typedef struct {
    int nq, nc;
    const double *Mlu;     /* factored M */
    const int *piv;
    const double *x0, *W, *bias, *target;
    double mu;
    const int *touching;   /* contacts that may carry force (gap <= gap_tol) */
    const int *entry;      /* the mode a contact enters contact in (stick, or slip against its sliding) */
    const double *entry_dir;
    /* scratch */
    int *alias;            /* alias[k] = j < k: contact k is contact j (2D pairs), else -1 */
    int *ncopy;            /* how many contacts a primary one stands for */
    double *C, *D, *Dt, *A, *r, *lam, *try_dir, *stick_dir;
    int *piv2, *row_contact, *row_comp, *try_mode, *idx;
} contact_lcp;

#define LCP_WORK(nq, nc) (9 * (nc) * (nq) + 9 * (nc) * (nc) + 10 * (nc))
#define LCP_IWORK(nc) (13 * (nc))

static void lcp_scratch(contact_lcp *s, double *work, int *iwork) {
    const int mmax = 3 * s->nc, nq = s->nq;
    s->C = work;
    s->D = s->C + (size_t)mmax * nq;
    s->Dt = s->D + (size_t)mmax * nq;
    s->A = s->Dt + (size_t)nq * mmax;
    s->r = s->A + (size_t)mmax * mmax;
    s->lam = s->r + mmax;
    s->try_dir = s->lam + mmax;
    s->stick_dir = s->try_dir + 2 * s->nc;
    s->piv2 = iwork;
    s->row_contact = s->piv2 + mmax;
    s->row_comp = s->row_contact + mmax;
    s->alias = s->row_comp + mmax;
    s->ncopy = s->alias + s->nc;
    s->try_mode = s->ncopy + s->nc;
    s->idx = s->try_mode + s->nc;
}

/* Contacts that are the same contact twice: the planar model carries each bogie pair as one wheel, so wheels 3
 * and 4 have the rows, gaps and velocities of wheels 1 and 2. Solved as one contact carrying both wheels'
 * force (split evenly), with one mode: two copies of a constraint make the problem degenerate, and a pivoting
 * decision cycles on degenerate problems (the two copies push each other off and back). */
static void find_aliases(contact_lcp *s, const double *gap) {
    const int nq = s->nq, nc = s->nc, ldw = 3 * nc;
    for (int k = 0; k < nc; k++) {
        s->alias[k] = -1;
        s->ncopy[k] = 1;
        if (!s->touching[k]) continue;        /* only contacts that may carry force enter a solve */
        for (int j = 0; j < k && s->alias[k] < 0; j++) {
            if (!s->touching[j] || s->alias[j] >= 0 || fabs(gap[j] - gap[k]) > 1e-12) continue;
            int same = 1;
            for (int c = 0; c < 3 && same; c++) {
                const int a = 3 * j + c, b = 3 * k + c;
                double scale = 1e-300;
                for (int l = 0; l < nq; l++) scale = fmax(scale, fabs(s->W[a + (size_t)l * ldw]));
                for (int l = 0; l < nq && same; l++)
                    same = fabs(s->W[a + (size_t)l * ldw] - s->W[b + (size_t)l * ldw]) <= 1e-12 * scale;
                same = same && fabs(s->bias[a] - s->bias[b]) <= 1e-12 * (1 + fabs(s->bias[a])) &&
                       s->target[a] == s->target[b];
            }
            if (same) {
                s->alias[k] = j;
                s->ncopy[j]++;
            }
        }
    }
}

/* The contact system of the modes held: the rows of the contacts in contact (C: their constraint rows, D: their
 * force columns, a slipping contact's carrying its friction mu Fn dir, Eq. 68), Dt = M^-1 D', the Delassus matrix
 * A = C Dt (m x m, not yet regularized) and r = target - bias - C x0, so that the rows' values are
 * y - target = A lam - r. Aliased contacts take their primary's mode. Returns m, the number of rows. */
static int build_system(const contact_lcp *s, int *mode, double *dir) {
    const int nq = s->nq, nc = s->nc, ldw = 3 * nc, mmax = 3 * nc;
    int m = 0;
    for (int k = 0; k < nc; k++) {
        if (s->alias[k] >= 0) {
            mode[k] = mode[s->alias[k]];
            dir[2 * k] = dir[2 * s->alias[k]];
            dir[2 * k + 1] = dir[2 * s->alias[k] + 1];
            continue;
        }
        if (mode[k] == RIGID_AIRBORNE) continue;
        for (int c = mode[k] == RIGID_STICK ? 0 : 2; c < 3; c++) {
            int w = 3 * k + c;
            for (int j = 0; j < nq; j++) {
                double cw = s->W[w + (size_t)j * ldw];
                s->C[m + (size_t)j * mmax] = cw;
                /* the column of a contact standing for ncopy wheels carries all their forces */
                s->D[m + (size_t)j * mmax] =
                    mode[k] == RIGID_SLIP ? cw + s->mu * (dir[2 * k] * s->W[3 * k + (size_t)j * ldw] +
                                                          dir[2 * k + 1] * s->W[3 * k + 1 + (size_t)j * ldw])
                                          : cw;
            }
            s->row_contact[m] = k;
            s->row_comp[m] = c;
            m++;
        }
    }
    for (int i = 0; i < m; i++) {
        double *col = s->Dt + (size_t)i * nq;
        for (int j = 0; j < nq; j++) col[j] = s->D[i + (size_t)j * mmax];
        linalg_lu_solve(nq, s->Mlu, s->piv, col);
    }
    for (int i = 0; i < m; i++) {
        for (int j = 0; j < m; j++) {
            double acc = 0;
            for (int l = 0; l < nq; l++) acc += s->C[i + (size_t)l * mmax] * s->Dt[l + (size_t)j * nq];
            s->A[i + (size_t)j * m] = acc;
        }
        int w = 3 * s->row_contact[i] + s->row_comp[i];
        double cx0 = 0;
        for (int l = 0; l < nq; l++) cx0 += s->C[i + (size_t)l * mmax] * s->x0[l];
        s->r[i] = s->target[w] - s->bias[w] - cx0;
    }
    return m;
}

/* One solve with the modes held: x, lambda (per contact: Fx, Fy, Fn in the contact frame; 0 when airborne) and,
 * if y != NULL, the constraint values y of every row. Aliased contacts take their primary's mode and share its
 * force. Returns 0, or 1 on a singular contact system. */
static int lcp_solve(const contact_lcp *s, int *mode, double *dir, double *x, double *lambda, double *y) {
    const int nq = s->nq, nc = s->nc, ldw = 3 * nc;
    const int m = build_system(s, mode, dir);
    memcpy(x, s->x0, sizeof(double) * nq);
    memset(lambda, 0, sizeof(double) * 3 * (size_t)nc);
    if (m > 0) {
        double diag = 0;
        for (int i = 0; i < m; i++) diag = fmax(diag, fabs(s->A[i + (size_t)i * m]));
        for (int i = 0; i < m; i++) s->A[i + (size_t)i * m] += CFM * diag;
        if (linalg_lu_factor(m, s->A, s->piv2)) return 1;
        memcpy(s->lam, s->r, sizeof(double) * m);
        linalg_lu_solve(m, s->A, s->piv2, s->lam);
        for (int i = 0; i < m; i++)
            for (int j = 0; j < nq; j++) x[j] += s->Dt[j + (size_t)i * nq] * s->lam[i];
        for (int i = 0; i < m; i++) {
            int k = s->row_contact[i];
            double share = s->lam[i] / s->ncopy[k];
            lambda[3 * k + s->row_comp[i]] = share;
            if (mode[k] == RIGID_SLIP) {
                lambda[3 * k] = s->mu * share * dir[2 * k];
                lambda[3 * k + 1] = s->mu * share * dir[2 * k + 1];
            }
        }
        for (int k = 0; k < nc; k++)
            if (s->alias[k] >= 0) memcpy(lambda + 3 * k, lambda + 3 * s->alias[k], 3 * sizeof(double));
    }
    if (y)
        for (int w = 0; w < 3 * nc; w++) y[w] = row_dot(s->W, ldw, w, x, nq) + s->bias[w];
    return 0;
}

/* A guess of the modes where switching one contact at a time cycles: projected Gauss-Seidel on the touching
 * contacts' all-stick system (per contact: the normal force clipped at 0, then the tangential force projected
 * onto the friction disk mu Fn), PGS_SWEEPS sweeps, then each contact's mode read from its force: no normal
 * force airborne, inside the disk stick, on its rim slip along the force. Bounded cost; the caller checks the
 * guess (it is an approximation). resid: scratch of 3 nc. */
#define PGS_SWEEPS 100
static void pgs_modes(const contact_lcp *s, int *mode, double *dir, double *resid) {
    const int nc = s->nc;
    for (int k = 0; k < nc; k++) {
        mode[k] = s->touching[k] ? RIGID_STICK : RIGID_AIRBORNE;
        dir[2 * k] = 1;
        dir[2 * k + 1] = 0;
    }
    const int m = build_system(s, mode, dir);     /* rows: 3 per touching primary, in contact order x, y, n */
    double *lam = s->lam;
    for (int i = 0; i < m; i++) {
        lam[i] = 0;
        resid[i] = -s->r[i];                       /* A lam - r */
    }
    double scale = 0;
    for (int i = 0; i < m; i++) scale = fmax(scale, fabs(s->A[i + (size_t)i * m]));
    const double tiny = 1e-12 * scale;
    for (int sweep = 0; sweep < PGS_SWEEPS; sweep++)
        for (int b = 0; b + 2 < m; b += 3) {       /* block b, b+1, b+2 = one contact's x, y, n */
            double old[3] = {lam[b], lam[b + 1], lam[b + 2]};
            const double ann = s->A[b + 2 + (size_t)(b + 2) * m];
            if (ann > tiny) lam[b + 2] = fmax(0, lam[b + 2] - resid[b + 2] / ann);
            for (int c = 0; c < 2; c++) {
                const double a = s->A[b + c + (size_t)(b + c) * m];
                if (a > tiny) lam[b + c] -= resid[b + c] / a;
                else lam[b + c] = 0;                /* a row with no motion (2D: lateral) carries nothing */
            }
            const double ft = hypot(lam[b], lam[b + 1]), cap = s->mu * lam[b + 2];
            if (ft > cap) {
                lam[b] *= cap / ft;
                lam[b + 1] *= cap / ft;
            }
            for (int c = 0; c < 3; c++) {
                const double d = lam[b + c] - old[c];
                if (d != 0)
                    for (int i = 0; i < m; i++) resid[i] += s->A[i + (size_t)(b + c) * m] * d;
            }
        }
    for (int b = 0; b + 2 < m; b += 3) {
        const int k = s->row_contact[b];
        const double fn = lam[b + 2], fx = lam[b], fy = lam[b + 1], ft = hypot(fx, fy);
        if (!(fn > 0)) mode[k] = RIGID_AIRBORNE;
        else if (ft < s->mu * fn * (1 - 1e-6)) mode[k] = RIGID_STICK;
        else {
            mode[k] = RIGID_SLIP;
            dir[2 * k] = fx / ft;
            dir[2 * k + 1] = fy / ft;
        }
    }
}

enum violation { CONSISTENT = 0, PULLS, SINKS, OUTSIDE_CONE, SLIDES_WITH_FRICTION };

/* Is contact k's part of a solution consistent (Eqs. 63-68)? In contact: no pulling normal force; airborne and
 * touching: not driven into the ground; sticking: inside the friction cone; slipping from rest: it does not
 * slide along its own friction. */
static enum violation check_contact(const contact_lcp *s, int k, const int *mode, const double *dir,
                                    const double *lambda, const double *y) {
    double fx = lambda[3 * k], fy = lambda[3 * k + 1], fn = lambda[3 * k + 2];
    if (mode[k] == RIGID_AIRBORNE)
        return s->touching[k] && y[3 * k + 2] < s->target[3 * k + 2] - VALUE_TOL ? SINKS : CONSISTENT;
    if (fn < -FORCE_TOL) return PULLS;
    if (mode[k] == RIGID_STICK) return hypot(fx, fy) > s->mu * fn * (1 + 1e-12) ? OUTSIDE_CONE : CONSISTENT;
    if (s->entry[k] == RIGID_STICK) {      /* slipping from rest: the sliding that starts must oppose dir */
        double ax = y[3 * k] - s->target[3 * k], ay = y[3 * k + 1] - s->target[3 * k + 1];
        if (ax * dir[2 * k] + ay * dir[2 * k + 1] > VALUE_TOL) return SLIDES_WITH_FRICTION;
    }
    return CONSISTENT;
}

static int all_consistent(const contact_lcp *s, const int *mode, const double *dir, const double *lambda,
                          const double *y) {
    for (int k = 0; k < s->nc; k++)
        if (s->alias[k] < 0 && check_contact(s, k, mode, dir, lambda, y) != CONSISTENT) return 0;
    return 1;
}

/* The last resort when switching cycles (friction can make the problem non-monotone, Painleve): every mode set
 * of the touching contacts, stick before slip before airborne (so the first consistent one keeps the most
 * contact and grip). A contact sliding slips against its sliding; one at rest may start to slide either way
 * along the force that held it in the all-stick solution (in the plane that is every direction there is).
 * Returns 0 with the modes set, or 1. */
static int lcp_enumerate(const contact_lcp *s, int *mode, double *dir, double *x, double *lambda, double *y) {
    const int nc = s->nc;
    int n = 0;
    for (int k = 0; k < nc; k++) {
        s->try_mode[k] = s->touching[k] ? RIGID_STICK : RIGID_AIRBORNE;
        s->try_dir[2 * k] = 1;
        s->try_dir[2 * k + 1] = 0;
        if (s->touching[k] && s->alias[k] < 0) s->idx[n++] = k;
    }
    if (lcp_solve(s, s->try_mode, s->try_dir, x, lambda, y)) return 1;
    for (int k = 0; k < nc; k++) {
        if (s->entry[k] == RIGID_SLIP) memcpy(s->stick_dir + 2 * k, s->entry_dir + 2 * k, 2 * sizeof(double));
        else tangential_dir(lambda, k, s->stick_dir + 2 * k);
    }
    long total = 1;
    for (int i = 0; i < n; i++) total *= 4;
    /* per contact: stick, slip along stick_dir, slip against it (contacts at rest only), airborne */
    for (long code = 0; code < total; code++) {
        long c = code;
        int skip = 0;
        for (int i = 0; i < n; i++, c /= 4) {
            int k = s->idx[i], choice = (int)(c % 4);
            double sign = choice == 2 ? -1 : 1;
            if (choice == 2 && s->entry[k] == RIGID_SLIP) skip = 1;   /* a sliding contact has one direction */
            s->try_mode[k] = choice == 0 ? RIGID_STICK : choice == 3 ? RIGID_AIRBORNE : RIGID_SLIP;
            s->try_dir[2 * k] = sign * s->stick_dir[2 * k];
            s->try_dir[2 * k + 1] = sign * s->stick_dir[2 * k + 1];
        }
        if (skip || lcp_solve(s, s->try_mode, s->try_dir, x, lambda, y)) continue;
        if (all_consistent(s, s->try_mode, s->try_dir, lambda, y)) {
            memcpy(mode, s->try_mode, sizeof(int) * (size_t)nc);
            memcpy(dir, s->try_dir, sizeof(double) * 2 * (size_t)nc);
            return 0;
        }
    }
    return 1;
}

/* how many distinct contacts may carry force (touching, not a copy of another) */
static int touching_count(const contact_lcp *s) {
    int n = 0;
    for (int k = 0; k < s->nc; k++) n += s->touching[k] && s->alias[k] < 0;
    return n;
}

/* The decision: from the modes given, solve and switch one contact at a time until the solution is
 * consistent, in the paper's order (contact first, Eqs. 63-65, then the friction cone, Eqs. 66-68):
 * - a sticking contact that would pull slips first (its slipping friction may press it on), a slipping one
 *   that would pull leaves the ground;
 * - a touching airborne contact that would be driven into the ground enters contact in its entry mode;
 * - a sticking contact outside the friction cone slips with its friction at the limit along the sticking force;
 * - a contact slipping from rest that would slide along its own friction sticks again.
 * Lowest index first, one switch per round (Murty's least-index rule), at most max_rounds switches.
 * 0 consistent, 1 not settled, -1 a singular contact system. */
static int pivot(const contact_lcp *s, int *mode, double *dir, double *x, double *lambda, double *y,
                 int max_rounds) {
    const int nc = s->nc;
    for (int round = 0; round < max_rounds; round++) {
        if (lcp_solve(s, mode, dir, x, lambda, y)) return -1;
        int flip = -1;
        enum violation v = CONSISTENT;
        for (int pass = 0; pass < 2 && flip < 0; pass++)      /* pass 0: normal direction, pass 1: friction */
            for (int k = 0; k < nc && flip < 0; k++) {
                if (s->alias[k] >= 0) continue;
                v = check_contact(s, k, mode, dir, lambda, y);
                if (v != CONSISTENT && (pass == 1 || v == PULLS || v == SINKS)) flip = k;
            }
        if (flip < 0) return 0;
        const int k = flip;
        const int held = hypot(lambda[3 * k], lambda[3 * k + 1]) > 0;   /* a tangential force holds it */
        if ((v == PULLS && mode[k] == RIGID_STICK && held) || v == OUTSIDE_CONE) {
            mode[k] = RIGID_SLIP;
            tangential_dir(lambda, k, dir + 2 * k);
        } else if (v == PULLS) {
            mode[k] = RIGID_AIRBORNE;
        } else if (v == SINKS) {
            mode[k] = s->entry[k];
            dir[2 * k] = s->entry_dir[2 * k];
            dir[2 * k + 1] = s->entry_dir[2 * k + 1];
        } else {                                   /* SLIDES_WITH_FRICTION */
            mode[k] = RIGID_STICK;
        }
    }
    return 1;
}

/* The decision: pivot from the modes given; if that has not settled after 4 n + 4 switches (n: the contacts that
 * may carry force), pivot from a projected Gauss-Seidel guess (pgs_modes); if that has not settled either,
 * every mode set is tried (lcp_enumerate). Returns 0, or 1 with the reason in msg. */
static int lcp_decide(const contact_lcp *s, int *mode, double *dir, double *x, double *lambda, double *y,
                      char *msg, size_t msg_len) {
    const int max_rounds = 4 * touching_count(s) + 4;
    int r = pivot(s, mode, dir, x, lambda, y, max_rounds);
    if (r == 0) return 0;
    if (r < 0) {
        snprintf(msg, msg_len, "rigid contact: singular contact system");
        return 1;
    }
    /* cycling (friction can make the problem non-monotone, Painleve): switch from a projected Gauss-Seidel
     * guess instead, then, as the last resort, try every mode set */
    pgs_modes(s, mode, dir, y);
    if (pivot(s, mode, dir, x, lambda, y, max_rounds) == 0) return 0;
    if (lcp_enumerate(s, mode, dir, x, lambda, y) == 0) return 0;
    snprintf(msg, msg_len, "rigid contact: no consistent stick/slip/airborne mode set (%d switches twice, then "
             "every set of the touching contacts tried)", max_rounds);
    return 1;
}

/* per contact, the mode it enters contact in: stick when sliding slower than v_stick, else slip against the
 * sliding (Eq. 67) */
static void entry_modes(int nc, const double *vc, const rigid_params *p, int *entry, double *entry_dir) {
    for (int k = 0; k < nc; k++) {
        double vx = vc[3 * k], vy = vc[3 * k + 1], vt = hypot(vx, vy);
        entry[k] = vt <= p->v_stick ? RIGID_STICK : RIGID_SLIP;
        entry_dir[2 * k] = vt <= p->v_stick ? 1 : -vx / vt;
        entry_dir[2 * k + 1] = vt <= p->v_stick ? 0 : -vy / vt;
    }
}

int rigid_solve_modes(int nq, int nc, const double *M, const double *f, const double *W, const double *bias,
                      const double *vc, const double *gap, const rigid_params *p, int decide, int *mode,
                      double *dir, double *udot, double *lambda, double *work, int *iwork, char *msg,
                      size_t msg_len) {
    double *Mlu = work, *x0 = Mlu + (size_t)nq * nq, *target = x0 + nq, *y = target + 3 * nc,
           *entry_dir = y + 3 * nc, *scratch = entry_dir + 2 * nc;
    int *piv = iwork, *touching = piv + nq, *entry = touching + nc, *iscratch = entry + nc;
    contact_lcp s = {.nq = nq, .nc = nc, .Mlu = Mlu, .piv = piv, .x0 = x0, .W = W, .bias = bias,
                     .target = target, .mu = p->mu, .touching = touching, .entry = entry, .entry_dir = entry_dir};
    lcp_scratch(&s, scratch, iscratch);

    if (factor_mass(nq, M, Mlu, piv, msg, msg_len)) return 1;
    memcpy(x0, f, sizeof(double) * nq);
    linalg_lu_solve(nq, Mlu, piv, x0);
    for (int k = 0; k < nc; k++) {       /* Baumgarte: gap'' + 2 alpha gap' + alpha^2 gap = 0, v_t' + 2 alpha v_t = 0 */
        for (int c = 0; c < 3; c++) target[3 * k + c] = -2 * p->alpha * vc[3 * k + c];
        target[3 * k + 2] -= p->alpha * p->alpha * gap[k];
        /* may carry force: on the ground, or (held modes) in contact by the decision */
        touching[k] = gap[k] <= p->gap_tol || (!decide && mode[k] != RIGID_AIRBORNE);
    }
    find_aliases(&s, gap);

    if (!decide) {
        /* held modes: a slipping contact's friction still follows its current sliding direction (Eq. 67), which
         * is smooth while it slides; only near |v_t| = 0 the direction held from the decision is kept */
        for (int k = 0; k < nc; k++) {
            double vx = vc[3 * k], vy = vc[3 * k + 1], vt = hypot(vx, vy);
            if (mode[k] == RIGID_SLIP && vt > p->v_stick) {
                dir[2 * k] = -vx / vt;
                dir[2 * k + 1] = -vy / vt;
            }
        }
        if (lcp_solve(&s, mode, dir, udot, lambda, NULL)) {
            snprintf(msg, msg_len, "rigid contact: singular contact system");
            return 1;
        }
        return 0;
    }
    /* the decision starts from the modes the state implies: a wheel farther than gap_tol from the ground is
     * airborne, one on it sticks or slips by its sliding speed */
    entry_modes(nc, vc, p, entry, entry_dir);
    for (int k = 0; k < nc; k++) {
        mode[k] = touching[k] ? entry[k] : RIGID_AIRBORNE;
        dir[2 * k] = entry_dir[2 * k];
        dir[2 * k + 1] = entry_dir[2 * k + 1];
    }
    return lcp_decide(&s, mode, dir, udot, lambda, y, msg, msg_len);
}

/* Wn_a Y_b for the contacts in act, into A (na x na), with Y[:, b] = M^-1 Wn_b', regularized: coinciding wheels
 * (2D pairs) make it singular */
static void normal_gram(int nq, int ldw, const double *W, const int *act, int na, const double *Y, double *A) {
    double diag = 0;
    for (int a = 0; a < na; a++)
        for (int b = 0; b < na; b++) {
            double s = 0;
            for (int j = 0; j < nq; j++) s += W[3 * act[a] + 2 + (size_t)j * ldw] * Y[j + (size_t)b * nq];
            A[a + (size_t)b * na] = s;
            if (a == b) diag = fmax(diag, s);
        }
    for (int a = 0; a < na; a++) A[a + (size_t)a * na] += 1e-12 * diag;
}

/* After a solve for the set act: drop members with a negative multiplier (they would pull), add touching
 * non-members the step would drive into the ground (predicted < -tiny). Returns 1 if the set changed. */
static int update_set(int nc, const double *gap, double gap_tol, const double *mult, const double *predicted,
                      int *act, int *na, int *member) {
    int changed = 0, keep = 0;
    for (int a = 0; a < *na; a++) {
        if (mult[a] >= 0) act[keep++] = act[a];
        else member[act[a]] = 0, changed = 1;
    }
    *na = keep;
    if (changed) return 1;                     /* re-solve with the smaller set before adding any */
    for (int k = 0; k < nc; k++)
        if (!member[k] && gap[k] <= gap_tol && predicted[k] < -1e-12) {
            act[(*na)++] = k;
            member[k] = 1;
            changed = 1;
        }
    return changed;
}

/* Positions: penetrating contacts back onto gap = 0 by the smallest step in the mass metric, dq = M^-1 Wn' m,
 * m >= 0 (the displacement an impulse would cause: light parts move, the heavy body hardly; a step that is
 * smallest in plain coordinates tilts the body and lifts the other wheels off, and they fall back and hop),
 * with every touching contact the step would push into the ground held at gap = 0 too (simultaneously: fixing
 * one wheel must not sink its neighbour); a wheel just above the ground may be lifting off and is left alone
 * unless the step would push it in. Returns 1 if q changed, 0 if not, -1 on a singular system. */
int rigid_project(int nq, int nc, double *q, const double *M, const double *W, const double *gap,
                  const rigid_params *p, double *work, int *iwork, char *msg, size_t msg_len) {
    const int ldw = 3 * nc;
    double *Mlu = work, *Y = Mlu + (size_t)nq * nq, *A = Y + (size_t)nq * nc, *rhs = A + (size_t)nc * nc,
           *step = rhs + nc, *pred = step + nq;
    int *piv = iwork, *act = piv + nq + nc, *member = act + nc;
    int na = 0;
    memset(member, 0, sizeof(int) * (size_t)nc);
    for (int k = 0; k < nc; k++)
        if (gap[k] < -1e-13) act[na++] = k, member[k] = 1;
    if (na == 0) return 0;
    if (factor_mass(nq, M, Mlu, piv, msg, msg_len)) return -1;
    for (int round = 0; na > 0; round++) {
        for (int a = 0; a < na; a++) {
            double *col = Y + (size_t)a * nq;
            for (int j = 0; j < nq; j++) col[j] = W[3 * act[a] + 2 + (size_t)j * ldw];
            linalg_lu_solve(nq, Mlu, piv, col);
        }
        normal_gram(nq, ldw, W, act, na, Y, A);
        for (int a = 0; a < na; a++) rhs[a] = -gap[act[a]];
        if (linalg_lu_factor(na, A, piv + nq)) {
            snprintf(msg, msg_len, "rigid contact: singular position projection");
            return -1;
        }
        linalg_lu_solve(na, A, piv + nq, rhs);
        for (int j = 0; j < nq; j++) {
            double s = 0;
            for (int a = 0; a < na; a++) s += Y[j + (size_t)a * nq] * rhs[a];
            step[j] = s;                                   /* dq = M^-1 Wn' m: m > 0 lifts */
        }
        for (int k = 0; k < nc; k++) pred[k] = gap[k] + row_dot(W, ldw, 3 * k + 2, step, nq);
        /* the set may cycle on degenerate geometry: after 2 nc + 1 rounds take the last step as it is */
        if (round >= 2 * nc || !update_set(nc, gap, p->gap_tol, rhs, pred, act, &na, member)) {
            for (int j = 0; j < nq; j++) q[j] += step[j];
            return 1;
        }
    }
    return 0;
}

/* The impulse problem of an impact (x0 = 0) or of a Moreau-Jean step (x0 = h M^-1 f, the free velocity change):
 * M du = M x0 + W' L with the post-step contact velocities W (u + du) = vc + W du as the constraint values, target
 * 0, every touching contact entering it sticking. du and L; 0, or 1 with the reason in msg. */
static int impulse_problem(int nq, int nc, const double *Mlu, const int *piv, const double *x0, const double *W,
                           const double *vc, const double *gap, const rigid_params *p, double *du, double *L,
                           double *work, int *iwork, char *msg, size_t msg_len) {
    double *zero_target = work, *y = zero_target + 3 * nc, *dir = y + 3 * nc, *entry_dir = dir + 2 * nc,
           *scratch = entry_dir + 2 * nc;
    int *touching = iwork, *entry = touching + nc, *mode = entry + nc, *iscratch = mode + nc;
    memset(zero_target, 0, sizeof(double) * 3 * (size_t)nc);
    contact_lcp s = {.nq = nq, .nc = nc, .Mlu = Mlu, .piv = piv, .x0 = x0, .W = W, .bias = vc,
                     .target = zero_target, .mu = p->mu, .touching = touching, .entry = entry,
                     .entry_dir = entry_dir};
    lcp_scratch(&s, scratch, iscratch);
    for (int k = 0; k < nc; k++) {
        touching[k] = gap[k] <= p->gap_tol;
        entry[k] = RIGID_STICK;
        entry_dir[2 * k] = 1;
        entry_dir[2 * k + 1] = 0;
        mode[k] = touching[k] ? RIGID_STICK : RIGID_AIRBORNE;
        dir[2 * k] = 1;
        dir[2 * k + 1] = 0;
    }
    find_aliases(&s, gap);
    return lcp_decide(&s, mode, dir, du, L, y, msg, msg_len);
}

int rigid_moreau(int nq, int nc, double *u, double *impulse, const double *M, const double *f, double h,
                 const double *W, const double *vc, const double *gap, const rigid_params *p, double *work, int *iwork,
                 char *msg, size_t msg_len) {
    double *Mlu = work, *x0 = Mlu + (size_t)nq * nq, *du = x0 + nq, *scratch = du + nq;
    int *piv = iwork;
    if (factor_mass(nq, M, Mlu, piv, msg, msg_len)) return 1;
    for (int j = 0; j < nq; j++) x0[j] = h * f[j];
    linalg_lu_solve(nq, Mlu, piv, x0);
    char why[160];
    if (impulse_problem(nq, nc, Mlu, piv, x0, W, vc, gap, p, du, impulse, scratch, iwork + nq, why, sizeof why)) {
        snprintf(msg, msg_len, "moreau step: %s", why);
        return 1;
    }
    for (int j = 0; j < nq; j++) u[j] += du[j];
    return 0;
}

int rigid_impact(int nq, int nc, double *u, double *impulse, const double *M, const double *W, const double *vc,
                 const double *gap, const rigid_params *p, double *work, int *iwork, char *msg, size_t msg_len) {
    /* velocities: an inelastic impact with Coulomb friction when a touching wheel approaches the ground. The
     * impulses solve the same complementarity problem as the forces, one level down (M du = W' L, the
     * constraint values are the post-impact contact velocities, target 0): every touching wheel starts sticking
     * (the impact stops its contact point), a wheel that would need a pulling impulse leaves the impact, a
     * sticking impulse outside the cone mu L_n slides at the cone. A frictionless impact would let a wheel that
     * hits a steep face glance off it and hop, where a real wheel grips and climbs. */
    int approaching = 0;
    for (int k = 0; k < nc; k++)
        if (gap[k] <= p->gap_tol && vc[3 * k + 2] < -IMPACT_SPEED) approaching = 1;
    if (!approaching) return 0;
    double *Mlu = work, *zero = Mlu + (size_t)nq * nq, *du = zero + nq, *L = du + nq, *scratch = L + 3 * nc;
    int *piv = iwork;
    if (factor_mass(nq, M, Mlu, piv, msg, msg_len)) return -1;
    memset(zero, 0, sizeof(double) * nq);
    char why[160];
    if (impulse_problem(nq, nc, Mlu, piv, zero, W, vc, gap, p, du, L, scratch, iwork + nq, why, sizeof why)) {
        snprintf(msg, msg_len, "impact: %s", why);
        return -1;
    }
    for (int j = 0; j < nq; j++) u[j] += du[j];
    if (impulse) memcpy(impulse, L, sizeof(double) * 3 * (size_t)nc);
    return 1;
}
