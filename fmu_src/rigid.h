/* Rigid wheels on rigid ground: the paper's stick/slip decision tree (Eqs. 63-68, docs/model.md, "Rigid contact").
 * Works on plain arrays from the generated cedra_M, cedra_f and cedra_contact; knows nothing about FMI. */
#ifndef CEDRA_RIGID_H
#define CEDRA_RIGID_H

#include <stddef.h>

enum rigid_mode { RIGID_AIRBORNE = 0, RIGID_STICK = 1, RIGID_SLIP = 2 };

typedef struct {
    double mu;        /* friction coefficient */
    double alpha;     /* Baumgarte rate: gap'' + 2 alpha gap' + alpha^2 gap = 0, stick: v_t' + 2 alpha v_t = 0 */
    double v_stick;   /* a wheel slipping slower than this is tested for sticking */
    double gap_tol;   /* a wheel farther from the ground than this is airborne */
} rigid_params;

/* workspace sizes as constant expressions (for static arrays) and as functions */
#define RIGID_WORK(nq, nc) ((nq) * (nq) + 2 * (nq) + 9 * (nc) * (nq) + 9 * (nc) * (nc) + 24 * (nc))
#define RIGID_IWORK(nq, nc) ((nq) + 16 * (nc))
size_t rigid_workspace_size(int nq, int nc);   /* doubles */
size_t rigid_iworkspace_size(int nq, int nc);  /* ints */

/* Accelerations udot and contact forces lambda (per contact: Fx, Fy, Fn in the contact frame) for
 * M udot = f + W' lambda.
 * decide != 0, the decision tree: start from the modes the state implies (gap > gap_tol: airborne;
 * |v_t| <= v_stick: stick; else slip against the sliding), solve, and switch one contact at a time (lowest index
 * first) until the modes are consistent: a sticking contact whose normal force would pull slips, a slipping one
 * leaves the ground; a touching airborne contact that would be accelerated into the ground enters it; a sticking
 * contact outside the friction cone slips with its friction at the limit along the sticking force; one slipping
 * from rest along its own friction sticks again. After 4 nc + 4 switches every mode set of the touching contacts
 * is tried (rigid.c, lcp_enumerate). Contacts that are the same contact twice (the 2D bogie pairs) are solved as
 * one and share its force. mode and dir (2 per contact: a slipping contact's friction direction in the contact
 * frame's x-y) are outputs.
 * decide == 0: one solve with the given modes, no switching (what an integration step uses between decisions);
 * a slipping contact's friction follows its current sliding direction while it slides faster than v_stick.
 * Returns 0, or 1 with the reason in msg. */
int rigid_solve_modes(int nq, int nc, const double *M, const double *f, const double *W, const double *bias,
                      const double *vc, const double *gap, const rigid_params *p, int decide, int *mode,
                      double *dir, double *udot, double *lambda, double *work, int *iwork, char *msg,
                      size_t msg_len);

/* Post-step stabilization, positions: penetrating contacts (gap < 0) are moved onto gap = 0 by the smallest step
 * in the mass metric, dq = M^-1 Wn' m, m >= 0, over the penetrating contacts and the touching ones the step would
 * push in (using dgap/dq = Wn since qdot = u). q is modified in place; returns 1 if it changed, 0 if not, -1 on
 * a singular system (msg). */
int rigid_project(int nq, int nc, double *q, const double *M, const double *W, const double *gap,
                  const rigid_params *p, double *work, int *iwork, char *msg, size_t msg_len);

/* Post-step stabilization, velocities: when a touching contact approaches the ground (v_n < 0), an inelastic
 * impact with Coulomb friction over all touching contacts: M du = W' L, decided like the forces on the
 * post-impact contact velocities (stick: W (u + du) = 0; slip: normal row, |L_t| = mu L_n; no pulling impulse).
 * u is modified in place; returns 1 if it changed, 0 if not, -1 if no consistent impact was found (msg).
 * impulse (3 nc, or NULL): with 1, the impulses L (per contact: x, y, n in the contact frame, as lambda). */
int rigid_impact(int nq, int nc, double *u, double *impulse, const double *M, const double *W, const double *vc,
                 const double *gap, const rigid_params *p, double *work, int *iwork, char *msg, size_t msg_len);

/* One Moreau-Jean step's velocities (the caller evaluated M, f, W, vc and gap at the step's midpoint positions
 * q + h/2 u): M (u+ - u) = h f + W' P with the contacts touching there (gap <= gap_tol) decided on the post-step
 * contact velocities like an impact (stick: W u+ = 0; slip: normal row, |P_t| = mu P_n; no pulling impulse).
 * u is replaced by u+, impulse (3 nc) gets P (per contact: x, y, n in the contact frame); 0, or 1 (msg). */
int rigid_moreau(int nq, int nc, double *u, double *impulse, const double *M, const double *f, double h,
                 const double *W, const double *vc, const double *gap, const rigid_params *p, double *work, int *iwork,
                 char *msg, size_t msg_len);

#endif
