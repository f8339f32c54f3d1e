"""Wheel kinematics of CEDRA (paper Eqs. 5-22, docs/model.md): wheel Jacobians, the actuated inverse solution
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
  the ground point under the wheel. It recedes along -x as the wheel rolls forward, because the model makes
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

from cedra.rover.parameters import DEFAULTS
from cedra.rover.mechanism import four_bar
from cedra.mechanics.transforms import homogeneous, rot_x, rot_y, rot_z, translation

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
        # bogie rotates about -y by theta (e(theta) lifts the front wheel); undo it, then psi about the axle
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


# ---------------------------------------------------------------- inverse kinematics (Eqs. 9-13)
# Known in the inverse problem: xdot_d, phidot_d (= yawdot), the carrier rates thetadot1, thetadot2, thetadot4 and
# psidot_i. Unknown: gammadot_i (actuated), xidot_i, ydot, zdot, pitchdot, rolldot. The steering rates are taken
# as zero: about the steering axis they are indistinguishable from the rotational slip xidot (identical Jacobian
# columns at psi = 0; the paper: "the steering rate ... is coupled with the rotational slip"), so xidot absorbs them.

def _qvec(theta, steer):
    return np.array([theta[0], theta[1], theta[2], steer[0], steer[1]], dtype=float)


def _known_rate(name, theta_dot):
    """Carrier rate known to the inverse solution (steering rates: zero, see above)."""
    return {"theta1": theta_dot[0], "theta2": theta_dot[1], "theta4": theta_dot[2]}.get(name, 0.0)


def wheel_rates_numeric(xdot_d, phidot_d, theta, theta_dot, psi, psi_dot, xi, steer, p=None):
    """Eqs. 9-12 with the Jacobians: gammadot_i = [Ja' D(Ju) Ja]^-1 Ja' D(Ju) E v_d, D(J) = J (J'J)^-1 J' - I.
    theta = (theta1, theta2, theta4), theta_dot likewise; psi, psi_dot, xi: six each; steer = (theta3, theta6)."""
    q = _qvec(theta, steer)
    eye = np.eye(6)
    out = np.zeros(6)
    for i in range(1, 7):
        jac = np.array(wheel_jacobian(i, p)(q, psi[i - 1], xi[i - 1]))
        nc = len(CARRIER[i])
        carrier_dot = np.array([_known_rate(n, theta_dot) for n in CARRIER[i]])
        b = xdot_d * eye[:, 0] + phidot_d * eye[:, 3] - jac[:, :nc] @ carrier_dot - jac[:, nc + 2] * psi_dot[i - 1]
        ja = jac[:, nc:nc + 1]
        ju = np.column_stack([jac[:, nc + 1], -eye[:, 1], -eye[:, 2], -eye[:, 4], -eye[:, 5]])
        delta = ju @ np.linalg.solve(ju.T @ ju, ju.T) - eye
        out[i - 1] = np.linalg.solve(ja.T @ delta @ ja, ja.T @ delta @ b)[0]
    return out


# ---------------------------------------------------------------- closed forms, symbolic (one copy)
# The closed forms below are CasADi expressions: the same graph gives the numpy wrappers further down (tests,
# scenario scripts) and the controller FMU's generated C (drive_functions). Parameters are symbols too, so a
# controller FMU takes the rover's geometry as parameters like the plant does.

KIN_PARAMS = ("R_w", "bogie_x", "bogie_y", "bogie_z", "bogie_half", "rear_x", "rear_z", "fork_ax", "fork_az",
              "fork_bx", "fork_bz", "fork_a", "fork_b", "fork_c", "fork_wheel")


def _e(a):
    return ca.vertcat(ca.cos(a), 0, ca.sin(a))


def _fork(theta4, p):
    """Four-bar: theta5, dtheta5/dtheta4 (exact derivative of the closure) and the joint C, for a symbol theta4."""
    c_pt, th5, _ = four_bar(theta4, p)
    return th5, ca.jacobian(th5, theta4), c_pt


def _wheel6(theta4, theta6, psi6, xi6, p):
    """Wheel 6 geometry in R: center, d(center)/dtheta4, contact-frame angular velocity per thetadot4, axle,
    contact normal z_C and rolling direction x_M."""
    th5, dth5, c_pt = _fork(theta4, p)
    center = c_pt - p["fork_wheel"] * _e(th5)
    dcenter = ca.jacobian(center, theta4)
    k = ca.skew(_e(th5))
    steer = ca.SX.eye(3) + ca.sin(theta6) * k + (1 - ca.cos(theta6)) * (k @ k)     # rotation about s by theta6
    cp, sp, cx, sx = ca.cos(psi6), ca.sin(psi6), ca.cos(xi6), ca.sin(xi6)
    axle = steer @ ca.vertcat(0, 1, 0)
    z_c = steer @ ca.vertcat(sp, 0, cp)
    x_m = steer @ ca.vertcat(cp * cx, sx, -sp * cx)
    omega = dth5 * (axle - ca.vertcat(0, 1, 0))   # C_6 = Rot(s(theta5), theta6) Rot_y(psi6) turns with theta5
    return center, dcenter, omega, axle, z_c, x_m


def _wheel_rates(xdot_d, phidot_d, theta, theta_dot, psi, psi_dot, xi, steer, p):
    """Eq. 13 with resolved signs (see wheel_rates), on CasADi expressions; theta[2] must be a symbol."""
    rw, l2, l3, l4 = p["R_w"], p["bogie_y"], p["bogie_z"], p["bogie_half"]
    out = []
    for i, th, side, front in ((1, 0, 1, 1), (2, 0, 1, -1), (3, 1, -1, 1), (4, 1, -1, -1)):
        s_th = ca.sin(theta[th])
        num = (xdot_d - side * l2 * phidot_d - front * l4 * s_th * theta_dot[th]
               - (l3 + front * l4 * s_th) * psi_dot[i - 1])
        out.append(num / (rw * ca.cos(psi[i - 1]) * ca.cos(xi[i - 1])))
    th3, ps5, xi5, l6 = steer[0], psi[4], xi[4], p["rear_z"]
    out.append((xdot_d - l6 * ca.cos(th3) * psi_dot[4] + l6 * ca.tan(ps5) * ca.sin(th3) * phidot_d)
               / (rw * (ca.cos(th3) * ca.cos(ps5) * ca.cos(xi5) - ca.sin(th3) * ca.sin(xi5))))
    c, dc, w, a, z, x_m = _wheel6(theta[2], steer[1], psi[5], xi[5], p)
    b_x = xdot_d - ca.cross(w, c)[0] * theta_dot[2] + dc[0] * theta_dot[2] - ca.cross(a, c)[0] * psi_dot[5]
    b_phi = phidot_d + w[2] * theta_dot[2] + a[2] * psi_dot[5]
    out.append((z[2] * b_x + ca.cross(z, c)[0] * b_phi) / (rw * z[2] * x_m[0]))
    return ca.vertcat(*out)


def _turn_centers(xdot_d, phidot_d, theta, theta_dot, psi, psi_dot, p):
    """Eqs. 14-20 for phidot_d != 0 (see turn_centers): the fixed wheels' turn centers (4 x 3) and their mean."""
    zero6 = ca.DM.zeros(6)
    rates = _wheel_rates(xdot_d, phidot_d, theta, theta_dot, psi, psi_dot, zero6, ca.DM.zeros(2), p)
    rows = []
    for i, th, side, front in ((1, 0, 1, 1), (2, 0, 1, -1), (3, 1, -1, 1), (4, 1, -1, -1)):
        pivot = ca.vertcat(p["bogie_x"], side * p["bogie_y"], p["bogie_z"])
        r_i = p["R_w"] * rates[i - 1] / (phidot_d / ca.cos(psi[i - 1]))
        rows.append((pivot + front * p["bogie_half"] * _e(theta[th]) + r_i * ca.vertcat(0, 1, 0)).T)
    centers = ca.vertcat(*rows)
    return centers, (ca.sum1(centers) / 4).T


def _steer_to(d, lean):
    """Steering angle whose axle, projected on R's x-y plane, is (-lean s, c) and points along d = (dx, dy) or
    its opposite (Eq. 22 with its lost minus sign: atan2(-sign(r_y) r_x, |r_y|); lean = sin of the steering
    axis' elevation, 1 for wheel 5)."""
    sgn = ca.if_else(d[1] >= 0, 1, -1)
    return ca.atan2(-sgn * d[0], lean * ca.fabs(d[1]))


def _steering_angles(xdot_d, phidot_d, theta, theta_dot, psi, psi_dot, p):
    """Eqs. 14-22 (see steering_angles); (0, 0) when phidot_d = 0 (straight), without dividing by it."""
    turning = phidot_d != 0
    phid = ca.if_else(turning, phidot_d, 1)
    _, center = _turn_centers(xdot_d, phid, theta, theta_dot, psi, psi_dot, p)
    c5 = ca.vertcat(p["rear_x"], 0, p["rear_z"])
    th5, _, c_pt = _fork(theta[2], p)
    c6 = c_pt - p["fork_wheel"] * _e(th5)
    return (ca.if_else(turning, _steer_to(center - c5, 1.0), 0),
            ca.if_else(turning, _steer_to(center - c6, ca.sin(th5)), 0))


def drive_symbols():
    """The symbols every drive function takes, in order: xdot_d, phidot_d, theta[3] = (theta1, theta2, theta4),
    theta_dot[3], psi[6], psi_dot[6], xi[6], steer[2] = (theta3, theta6), par[len(KIN_PARAMS)]."""
    sym = ca.SX.sym
    return dict(xdot_d=sym("xdot_d"), phidot_d=sym("phidot_d"), theta=sym("theta", 3), theta_dot=sym("theta_dot", 3),
                psi=sym("psi", 6), psi_dot=sym("psi_dot", 6), xi=sym("xi", 6), steer=sym("steer", 2),
                par=sym("par", len(KIN_PARAMS)))


def drive_expressions(s: dict) -> dict:
    """Wheel rates (Eq. 13), steering angles (Eqs. 14-22) and the mean turn center for the symbols of
    drive_symbols() (the parameters are s["par"] in KIN_PARAMS order)."""
    p = {n: s["par"][k] for k, n in enumerate(KIN_PARAMS)}
    args = (s["xdot_d"], s["phidot_d"], s["theta"], s["theta_dot"], s["psi"], s["psi_dot"])
    rates = _wheel_rates(*args, s["xi"], s["steer"], p)
    th3, th6 = _steering_angles(*args, p)
    turning = s["phidot_d"] != 0
    centers, center = _turn_centers(s["xdot_d"], ca.if_else(turning, s["phidot_d"], 1), *args[2:], p)
    return dict(rates=rates, steer=ca.vertcat(th3, th6), centers=centers, center=center)


@lru_cache(maxsize=1)
def drive_functions() -> dict:
    """CasADi Functions of drive_symbols(): wheel_rates -> 6, steering -> 2, turn_centers -> (4 x 3, 1 x 3)."""
    s = drive_symbols()
    e = drive_expressions(s)
    common = [s[k] for k in ("xdot_d", "phidot_d", "theta", "theta_dot", "psi", "psi_dot")]
    return dict(
        wheel_rates=ca.Function("wheel_rates", common + [s["xi"], s["steer"], s["par"]], [e["rates"]]),
        steering=ca.Function("steering", common + [s["par"]], [e["steer"]]),
        turn_centers=ca.Function("turn_centers", common + [s["par"]], [e["centers"], e["center"]]))


def _par_vector(p):
    p = params(p)
    return np.array([p[n] for n in KIN_PARAMS], dtype=float)


def _num(v):
    return np.asarray(v, dtype=float).reshape(-1)


# ---------------------------------------------------------------- numpy front ends

def wheel_rates(xdot_d, phidot_d, theta, theta_dot, psi, psi_dot, xi, steer, p=None):
    """Eq. 13 with resolved signs: the six gammadot in closed form (same arguments as wheel_rates_numeric).

    Bogie wheels (l1..l4 = bogie_x, bogie_y, bogie_z, bogie_half), exactly the paper's Eq. 13:
      gammadot_1 = (xdot_d - l2 phidot_d - l4 s(th1) thdot1 - (l3 + l4 s(th1)) psidot_1) / (R_w c(psi_1) c(xi_1))
      wheel 2: -l4 -> +l4 (rear); wheels 3, 4: -l2 -> +l2 and theta2.
    Wheel 5 (l5, l6 = rear_x, rear_z):
      gammadot_5 = (xdot_d - l6 c(th3) psidot_5 + l6 t(psi_5) s(th3) phidot_d)
                   / (R_w (c(th3) c(psi_5) c(xi_5) - s(th3) s(xi_5)));
      the paper drops the phidot_d term (zero when psi_5 = 0 or theta3 = 0), the exact solution of Eq. 11 has it.
    All wheels, in vector form (c: wheel center, z = z_C, a: axle, x_M: rolling direction, for each known carrier
    rate qdot the contact frame's angular velocity W qdot and the center's velocity dc qdot, all in R):
      b_x   = xdot_d   - sum((W x c - dc)_x qdot) - (a x c)_x psidot
      b_phi = phidot_d + sum(W_z qdot)            + a_z psidot
      gammadot = (z_z b_x + (z x c)_x b_phi) / (R_w z_z x_M,x)
    (the combination (z_z, (z x c)_x) of the x and yaw rows annihilates the slip column, Eq. 11's projection);
    wheel 6 is evaluated in this form, its theta5 from the four-bar. One CasADi graph (_wheel_rates) gives these
    numbers and the controller FMU's C."""
    f = drive_functions()["wheel_rates"]
    return _num(f(xdot_d, phidot_d, theta, theta_dot, psi, psi_dot, xi, steer, _par_vector(p)))


# ---------------------------------------------------------------- steering angles (Eqs. 14-22)

def turn_centers(xdot_d, phidot_d, theta, theta_dot, psi, psi_dot, p=None):
    """Eqs. 14-20 (phidot_d != 0): the turn centers c_i of the fixed wheels 1-4 in R (rows) and their mean.
    xdot_i = R_w gammadot_i (xi = 0, Eq. 14), phidot_i = phidot_d / cos(psi_i) (the turn rate about the contact
    normal whose yaw part is phidot_d, Eq. 15), r_i = xdot_i / phidot_i (Eq. 16), c_i = T_R,Ci (0, r_i, 0, 1)
    (Eq. 17: r_i along the axle from the contact frame's origin, the wheel center)."""
    centers, center = drive_functions()["turn_centers"](xdot_d, phidot_d, theta, theta_dot, psi, psi_dot,
                                                        _par_vector(p))
    return np.array(centers), _num(center)


def steering_angles(xdot_d, phidot_d, theta, theta_dot, psi, psi_dot, p=None):
    """Eqs. 14-22: (theta3, theta6) so that the steered axles, projected on R's x-y plane, pass through the mean
    turn center of the fixed wheels. phidot_d = 0 (straight) -> (0, 0).
    Eq. 21 takes the turn center relative to the steered wheel's contact frame; since the steering axes are R's z
    (wheel 5) and the coupler axis s = e(theta5) in R's x-z plane (wheel 6), the vector from the wheel center to
    the turn center is projected on R's x-y plane. Wheel 6's axle (0, 1, 0) turned about s by theta6 projects to
    (-sin(theta5) sin(theta6), cos(theta6)), hence the sin(theta5) in its atan2."""
    th = _num(drive_functions()["steering"](xdot_d, phidot_d, theta, theta_dot, psi, psi_dot, _par_vector(p)))
    return float(th[0]), float(th[1])
