"""Wheel kinematics of CEDRA (paper Eqs. 5-22, spec section 7): wheel Jacobians, the actuated inverse solution
for the six wheel rates, and the geometric steering angles.

Conventions (the paper's extraction lost its minus signs; each sign below is resolved by geometry):
- Frames: R is the rover frame (x forward, y left, z up). For wheel i the chain is
  R -> wheel center -> contact frame C_i -> motion frame M_i, all homogeneous transforms (transforms.py).
- Contact frame C_i: origin at the wheel center, y along the axle, and (at psi_i = 0) x along the wheel's heading
  in R's x-y plane (the carrier rotation, bogie theta or the fork's theta5, is undone: psi_i is measured from R,
  as in the paper's Eq. 19 where R_T_C1 holds psi_1 alone). psi_i is then a rotation about the axle by +psi_i
  (right-hand rule about the left-pointing axle): for a bogie wheel x_C = (cos psi, 0, -sin psi). This is the sign
  that reproduces the paper's visible minus signs in Eq. 13 (e.g. "- (l3 + l4 sin theta1) psidot_1").
- Motion frame M_i = Rot_z(xi_i) Trans_z(-R_w) Trans_x(-R_w gamma_i) in C_i (the D-H row of the paper's Table 2):
  the ground point under the wheel. It recedes along -x as the wheel rolls forward, because the spec makes
  positive gammadot drive the rover forward (so the paper's a = R_w gamma gets a minus sign here). xi_i is the
  rotational slip angle about the contact normal; the rolling direction is x_M = C_i Rot_z(xi) e_x.
- No slip: M_i is fixed on the ground, so the twist of R (in R) is minus the twist of M_i relative to R:
  [w^, v; 0 0] = -(dT_RM/dt) T_RM^-1, i.e. v_R = -pdot_M + w_M x p_M and w_R = -w_M.
  Hence w_R = -xidot z_C: the rover yaws by -xidot cos(psi) (the paper's Eq. 15 "phidot_1 = xidot_1" lost a minus).
- v = [xdot, ydot, zdot, yawdot, pitchdot, rolldot]: velocity of R's origin and the angular velocity of R, both in
  R (angular rates about R's z, y, x axes, as the paper's Eq. 6 says; not Euler-angle rates).
- The Jacobians are evaluated at gamma_i = 0 (M_i is redefined at each instant at the current contact point; the
  absolute wheel angle must not appear, as the paper remarks under Eq. 5).
- qdot_i = [carrier rates, gammadot_i, xidot_i, psidot_i] with carrier rates thetadot1 (wheels 1, 2),
  thetadot2 (3, 4), thetadot3 (5: steering), thetadot4 and thetadot6 (6: fork, theta5 follows the four-bar,
  then steering about the coupler axis s).
"""
from functools import lru_cache

import casadi as ca
import numpy as np

from .parameters import DEFAULTS
from .rover import four_bar
from .transforms import homogeneous, rot_x, rot_y, rot_z, translation

JOINTS = ("theta1", "theta2", "theta4", "theta3", "theta6")   # the joint-angle vector all functions take
V_NAMES = ("xdot", "ydot", "zdot", "yawdot", "pitchdot", "rolldot")
CARRIER = {1: ("theta1",), 2: ("theta1",), 3: ("theta2",), 4: ("theta2",), 5: ("theta3",), 6: ("theta4", "theta6")}
STEER = {5: "theta3", 6: "theta6"}


def params(p=None):
    """Numeric parameters: the defaults overridden by p."""
    out = dict(DEFAULTS)
    out.update(p or {})
    return out


def rate_names(i):
    """Names of wheel i's rates qdot_i, in the Jacobian's column order."""
    return [n + "dot" for n in CARRIER[i]] + [f"gamma{i}dot", f"xi{i}dot", f"psi{i}dot"]


def _rot(r):
    return homogeneous(r, ca.DM.zeros(3))


def _move(x, y=0, z=0):
    return translation(ca.vertcat(x, y, z))


def contact_frame(i, q, psi, p):
    """T_R,Ci of wheel i for joint angles q = (theta1, theta2, theta4, theta3, theta6) and contact angle psi."""
    th1, th2, th4, th3, th6 = (q[k] for k in range(5))
    if i <= 4:
        th, side = (th1, 1) if i <= 2 else (th2, -1)
        front = 1 if i in (1, 3) else -1
        # bogie rotates about -y by theta (spec: e(theta) lifts the front wheel); undo it, then psi about the axle
        return (_move(p["bogie_x"], side * p["bogie_y"], p["bogie_z"]) @ _rot(rot_y(-th))
                @ _move(front * p["bogie_half"]) @ _rot(rot_y(th + psi)))
    if i == 5:   # steering about R's z at the rear wheel's center
        return _move(p["rear_x"], 0, p["rear_z"]) @ _rot(rot_z(th3)) @ _rot(rot_y(psi))
    th5 = four_bar(th4, p)[1]
    # A -> lower link (theta4) -> C -> coupler (theta5) -> wheel center -> steer theta6 about the coupler axis s
    # -> undo the coupler's rotation (so psi6 is measured from R like the others) -> psi6 about the axle
    return (_move(p["fork_ax"], 0, p["fork_az"]) @ _rot(rot_y(-th4)) @ _move(p["fork_a"])
            @ _rot(rot_y(th4 - th5)) @ _move(-p["fork_wheel"]) @ _rot(rot_x(th6)) @ _rot(rot_y(th5 + psi)))


def motion_frame(xi, gamma, p):
    """T_Ci,Mi: slip rotation xi about the contact normal, down to the ground, rolled back by R_w gamma."""
    return _rot(rot_z(xi)) @ _move(0, 0, -p["R_w"]) @ _move(-p["R_w"] * gamma)


def _inverse(t):
    rt = t[0:3, 0:3].T
    return homogeneous(rt, -rt @ t[0:3, 3])


@lru_cache(maxsize=None)
def _functions(i, pkey):
    p = dict(pkey)
    q, psi, xi, gamma = ca.SX.sym("q", 5), ca.SX.sym("psi"), ca.SX.sym("xi"), ca.SX.sym("gamma")
    t = contact_frame(i, q, psi, p) @ motion_frame(xi, gamma, p)
    coords = [q[JOINTS.index(n)] for n in CARRIER[i]] + [gamma, xi, psi]
    t_inv = _inverse(t)
    cols = []
    for c in coords:
        x = -ca.reshape(ca.jacobian(ca.vec(t), c), 4, 4) @ t_inv      # minus the twist of M in R
        cols.append(ca.vertcat(x[0, 3], x[1, 3], x[2, 3], x[1, 0], x[0, 2], x[2, 1]))
    jac = ca.substitute(ca.horzcat(*cols), gamma, 0)
    jfun = ca.Function(f"J{i}", [q, psi, xi], [jac], ["q", "psi", "xi"], ["J"])
    tfun = ca.Function(f"T_RM{i}", [q, psi, xi, gamma], [t], ["q", "psi", "xi", "gamma"], ["T"])
    return jfun, tfun


def _pkey(p):
    return tuple(sorted(params(p).items()))


def wheel_jacobian(i, p=None):
    """Eq. 7-8: CasADi Function (q[5] = (theta1, theta2, theta4, theta3, theta6), psi_i, xi_i) -> J_i (6 x n_i),
    v = J_i qdot_i with qdot_i as in rate_names(i) and v as in V_NAMES."""
    return _functions(i, _pkey(p))[0]


def chain(i, p=None):
    """The chain itself: CasADi Function (q[5], psi_i, xi_i, gamma_i) -> T_R,Mi (4 x 4)."""
    return _functions(i, _pkey(p))[1]
