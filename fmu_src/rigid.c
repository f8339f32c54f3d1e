/* Rigid wheels on rigid ground: the paper's decision tree (see rigid.h). Dense, small (nq <= 17, nc <= 6). */
#include "rigid.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

#include "linalg.h"

#define MAX_ROWS(nc) (3 * (nc))
/* Constraint force mixing: with six sticking wheels the tangential contact forces are statically indeterminate
 * (18 constraints on <= 17 speeds), so the Delassus matrix A = C M^-1 D' is singular. A relative diagonal shift
 * of 1e-10 picks the (almost) minimum-norm forces and changes the constraint accelerations by ~1e-10 lambda. */
#define CFM 1e-10

size_t rigid_workspace_size(int nq, int nc) { return (size_t)RIGID_WORK(nq, nc); }

size_t rigid_iworkspace_size(int nq, int nc) { return (size_t)RIGID_IWORK(nq, nc); }

static double row_dot(const double *W, int ldw, int row, const double *x, int nq) {
    double s = 0;
    for (int j = 0; j < nq; j++) s += W[row + (size_t)j * ldw] * x[j];
    return s;
}

int rigid_solve_modes(int nq, int nc, const double *M, const double *f, const double *W, const double *bias,
                      const double *vc, const double *gap, const rigid_params *p, int decide, int *mode,
                      double *dir, double *udot, double *lambda, double *work, int *iwork, char *msg,
                      size_t msg_len) {
    const int ldw = 3 * nc, mmax = MAX_ROWS(nc);
    double *Mlu = work, *Xf = Mlu + nq * nq, *C = Xf + nq, *D = C + (size_t)mmax * nq,
           *Dt = D + (size_t)mmax * nq, *A = Dt + (size_t)nq * mmax, *r = A + (size_t)mmax * mmax,
           *lam = r + mmax, *target = lam + mmax; /* target + mmax: spare */
    int *piv = iwork, *piv2 = piv + nq, *row_contact = piv2 + mmax, *row_comp = row_contact + mmax;

    memcpy(Mlu, M, sizeof(double) * (size_t)nq * nq);
    if (linalg_lu_factor(nq, Mlu, piv)) {
        snprintf(msg, msg_len, "rigid contact: the mass matrix is singular");
        return 1;
    }
    memcpy(Xf, f, sizeof(double) * nq);
    linalg_lu_solve(nq, Mlu, piv, Xf);

    /* held modes: a slipping contact's friction still follows its current sliding direction (Eq. 67), which is
     * smooth while it slides; only near |v_t| = 0 the direction held from the decision is kept */
    for (int k = 0; !decide && k < nc; k++) {
        double vx = vc[3 * k], vy = vc[3 * k + 1], vt = hypot(vx, vy);
        if (mode[k] == RIGID_SLIP && vt > p->v_stick) {
            dir[2 * k] = -vx / vt;
            dir[2 * k + 1] = -vy / vt;
        }
    }
    /* modes implied by the state */
    for (int k = 0; decide && k < nc; k++) {
        double vx = vc[3 * k], vy = vc[3 * k + 1], vt = hypot(vx, vy);
        if (gap[k] > p->gap_tol) {
            mode[k] = RIGID_AIRBORNE;
        } else if (vt <= p->v_stick) {
            mode[k] = RIGID_STICK;
        } else {
            mode[k] = RIGID_SLIP;
            dir[2 * k] = -vx / vt;          /* friction opposes sliding (Eq. 67) */
            dir[2 * k + 1] = -vy / vt;
        }
    }

    const int max_rounds = 4 * nc + 4;
    for (int round = 0; round < max_rounds; round++) {
        /* rows: stick = x, y, n (3 unknowns); slip = n only, its force column carries mu Fn dir (Eq. 68) */
        int m = 0;
        for (int k = 0; k < nc; k++) {
            if (mode[k] == RIGID_AIRBORNE) continue;
            int first = mode[k] == RIGID_STICK ? 0 : 2;
            for (int c = first; c < 3; c++) {
                int w = 3 * k + c;
                for (int j = 0; j < nq; j++) {
                    double cw = W[w + (size_t)j * ldw];
                    C[m + (size_t)j * mmax] = cw;
                    D[m + (size_t)j * mmax] = cw;
                    if (mode[k] == RIGID_SLIP)
                        D[m + (size_t)j * mmax] += p->mu * (dir[2 * k] * W[3 * k + (size_t)j * ldw] +
                                                            dir[2 * k + 1] * W[3 * k + 1 + (size_t)j * ldw]);
                }
                double v = vc[w];
                target[m] = c == 2 ? -2 * p->alpha * v - p->alpha * p->alpha * gap[k] : -2 * p->alpha * v;
                row_contact[m] = k;
                row_comp[m] = c;
                m++;
            }
        }
        for (int i = 0; i < nq; i++) udot[i] = Xf[i];
        memset(lambda, 0, sizeof(double) * 3 * (size_t)nc);
        if (m == 0) return 0;   /* all airborne */

        /* Dt = M^-1 D', A = C Dt, r = target - bias - C M^-1 f */
        for (int i = 0; i < m; i++) {
            double *col = Dt + (size_t)i * nq;
            for (int j = 0; j < nq; j++) col[j] = D[i + (size_t)j * mmax];
            linalg_lu_solve(nq, Mlu, piv, col);
        }
        double diag = 0;
        for (int i = 0; i < m; i++) {
            for (int j = 0; j < m; j++) {
                double s = 0;
                for (int l = 0; l < nq; l++) s += C[i + (size_t)l * mmax] * Dt[l + (size_t)j * nq];
                A[i + (size_t)j * m] = s;
            }
            diag = fmax(diag, fabs(A[i + (size_t)i * m]));
            int w = 3 * row_contact[i] + row_comp[i];
            double cxf = 0;
            for (int l = 0; l < nq; l++) cxf += C[i + (size_t)l * mmax] * Xf[l];
            r[i] = target[i] - bias[w] - cxf;
        }
        for (int i = 0; i < m; i++) A[i + (size_t)i * m] += CFM * diag;
        if (linalg_lu_factor(m, A, piv2)) {
            snprintf(msg, msg_len, "rigid contact: singular contact system (%d constraint rows)", m);
            return 1;
        }
        memcpy(lam, r, sizeof(double) * m);
        linalg_lu_solve(m, A, piv2, lam);
        for (int i = 0; i < m; i++)
            for (int j = 0; j < nq; j++) udot[j] += Dt[j + (size_t)i * nq] * lam[i];
        for (int i = 0; i < m; i++) {
            int k = row_contact[i];
            lambda[3 * k + row_comp[i]] = lam[i];
            if (mode[k] == RIGID_SLIP) {
                lambda[3 * k] = p->mu * lam[i] * dir[2 * k];
                lambda[3 * k + 1] = p->mu * lam[i] * dir[2 * k + 1];
            }
        }

        if (!decide) return 0;
        /* the decision tree: lift-off first (Eq. 64 no longer holds), then the friction cone (Eq. 66) */
        int changed = 0;
        for (int k = 0; k < nc; k++)
            if (mode[k] != RIGID_AIRBORNE && lambda[3 * k + 2] < 0) {
                mode[k] = RIGID_AIRBORNE;
                changed = 1;
            }
        if (!changed)
            for (int k = 0; k < nc; k++) {
                if (mode[k] != RIGID_STICK) continue;
                double fx = lambda[3 * k], fy = lambda[3 * k + 1], ft = hypot(fx, fy), fn = lambda[3 * k + 2];
                if (ft > p->mu * fn) {
                    mode[k] = RIGID_SLIP;      /* slide with the friction at its limit, along the sticking force */
                    dir[2 * k] = ft > 0 ? fx / ft : 1;
                    dir[2 * k + 1] = ft > 0 ? fy / ft : 0;
                    changed = 1;
                }
            }
        if (!changed) {
            for (int k = 0; k < nc; k++)
                if (mode[k] == RIGID_AIRBORNE) memset(lambda + 3 * k, 0, sizeof(double) * 3);
            return 0;
        }
    }
    snprintf(msg, msg_len, "rigid contact: no consistent stick/slip/airborne mode set after %d rounds",
             max_rounds);
    return 1;
}

/* Wn_a Wn_b' (B = NULL) or Wn_a B Wn_b' with B = columns Y (B != NULL: Y[:, b] = M^-1 Wn_b') for the contacts in
 * act, into A (na x na), regularized: coinciding wheels (2D pairs) make it singular */
static void normal_gram(int nq, int ldw, const double *W, const int *act, int na, const double *Y, double *A) {
    double diag = 0;
    for (int a = 0; a < na; a++)
        for (int b = 0; b < na; b++) {
            double s = 0;
            for (int j = 0; j < nq; j++)
                s += W[3 * act[a] + 2 + (size_t)j * ldw] *
                     (Y ? Y[j + (size_t)b * nq] : W[3 * act[b] + 2 + (size_t)j * ldw]);
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

int rigid_project(int nq, int nc, double *q, double *u, const double *M, const double *W, const double *vc,
                  const double *gap, const rigid_params *p, double *work, int *iwork, char *msg, size_t msg_len) {
    const int ldw = 3 * nc;
    double *A = work, *rhs = A + (size_t)nc * nc, *Mlu = rhs + nc, *Y = Mlu + (size_t)nq * nq;
    double *step = Y + (size_t)nq * nc, *pred = step + nq;
    int *piv = iwork, *act = piv + nq + nc, *member = act + nc;
    int na = 0, changed = 0;

    /* positions: penetrating contacts back onto gap = 0 by the minimum-norm step dq = -Wn' m, m >= 0, with
     * every touching contact the step would push into the ground held at gap = 0 too (simultaneously: fixing
     * one wheel must not sink its neighbour); a wheel just above the ground may be lifting off and is left
     * alone unless the step would push it in */
    memset(member, 0, sizeof(int) * (size_t)nc);
    for (int k = 0; k < nc; k++)
        if (gap[k] < -1e-13) act[na++] = k, member[k] = 1;
    for (int round = 0; na > 0; round++) {
        normal_gram(nq, ldw, W, act, na, NULL, A);
        for (int a = 0; a < na; a++) rhs[a] = -gap[act[a]];
        if (linalg_lu_factor(na, A, piv)) {
            snprintf(msg, msg_len, "rigid contact: singular position projection");
            return -1;
        }
        linalg_lu_solve(na, A, piv, rhs);
        for (int j = 0; j < nq; j++) {
            double s = 0;
            for (int a = 0; a < na; a++) s += W[3 * act[a] + 2 + (size_t)j * ldw] * rhs[a];
            step[j] = s;                                   /* dq = Wn' m: m > 0 lifts */
        }
        for (int k = 0; k < nc; k++) pred[k] = gap[k] + row_dot(W, ldw, 3 * k + 2, step, nq);
        /* the set may cycle on degenerate geometry: after 2 nc + 1 rounds take the last step as it is */
        if (round >= 2 * nc || !update_set(nc, gap, p->gap_tol, rhs, pred, act, &na, member)) {
            for (int j = 0; j < nq; j++) q[j] += step[j];
            changed = 1;
            break;
        }
    }

    /* velocities: inelastic impact of the approaching contacts, L >= 0 with Wn (u + du) = 0 on the impact set;
     * touching contacts the impulse would drive into the ground join the set (the impact is simultaneous),
     * contacts that would need a pulling impulse leave it */
    na = 0;
    memset(member, 0, sizeof(int) * (size_t)nc);
    for (int k = 0; k < nc; k++)
        if (gap[k] <= p->gap_tol && vc[3 * k + 2] < 0) act[na++] = k, member[k] = 1;
    if (na == 0) return changed;
    memcpy(Mlu, M, sizeof(double) * (size_t)nq * nq);
    if (linalg_lu_factor(nq, Mlu, piv)) {
        snprintf(msg, msg_len, "rigid contact: the mass matrix is singular");
        return -1;
    }
    for (int round = 0; round <= 2 * nc && na > 0; round++) {
        for (int a = 0; a < na; a++) {
            double *col = Y + (size_t)a * nq;
            for (int j = 0; j < nq; j++) col[j] = W[3 * act[a] + 2 + (size_t)j * ldw];
            linalg_lu_solve(nq, Mlu, piv, col);
        }
        normal_gram(nq, ldw, W, act, na, Y, A);
        for (int a = 0; a < na; a++) rhs[a] = -row_dot(W, ldw, 3 * act[a] + 2, u, nq);
        if (linalg_lu_factor(na, A, piv + nq)) {
            snprintf(msg, msg_len, "rigid contact: singular impact system");
            return -1;
        }
        linalg_lu_solve(na, A, piv + nq, rhs);
        for (int j = 0; j < nq; j++) {
            double s = 0;
            for (int a = 0; a < na; a++) s += Y[j + (size_t)a * nq] * rhs[a];
            step[j] = s;
        }
        for (int k = 0; k < nc; k++) pred[k] = vc[3 * k + 2] + row_dot(W, ldw, 3 * k + 2, step, nq);
        if (!update_set(nc, gap, p->gap_tol, rhs, pred, act, &na, member)) {
            for (int j = 0; j < nq; j++) u[j] += step[j];
            return 1;
        }
    }
    return changed;
}
