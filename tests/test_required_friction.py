"""The friction a climb requires (cedra.rover.required_friction), checked against a vehicle solved by hand.

**The vehicle**: one rigid body of weight W = m g carrying two wheels of radius R, the front one a_f ahead of its
mass centre G and the rear one a_r behind it, both axles a depth d below G (frame R: wheel centres (a_f, 0, -d)
and (-a_r, 0, -d)). In 2D it has x, z and pitch, no joint: at a pose with both wheels touching, three equations and
four forces, one force left free.

**The climbing wheel**, at its lift-off from the tread below a riser, touches only the riser: at the edge (x_e, h)
for h < R, its centre a distance R back and up, so that the contact normal is n = (-sin a, cos a) with
cos a = (R - h) / R; for h >= R it touches the face at its centre's height, a = 90 degrees. Its traction T_c acts
along t = (cos a, sin a) (forward and up), its load N_c along n. **The other wheel** stands on a tread: load N_p
up, traction T_p forward. With P that wheel's contact point, C the climbing wheel's, D = C_x - P_x, H = C_z - P_z
and e = G_x - P_x:

    x:      T_p - N_c sin a + T_c cos a = 0
    z:      N_p + N_c cos a + T_c sin a = W
    moment about P:  D (N_c cos a + T_c sin a) - H (T_c cos a - N_c sin a) = e W

(the motor torques are internal to the vehicle; its wheels are massless). **The least largest ratio**: along the
free force, raising the pushing wheel's traction T_p lowers the climbing wheel's ratio T_c / N_c and raises the
pusher's T_p / N_p, so the smallest largest ratio r is where they are equal: T_p = r N_p, T_c = r N_c. Then x gives
N_p = N_c (sin a - r cos a) / r, z gives N_c = W r / (sin a (1 + r^2)), and the moment equation becomes

    r^2 ((D - e) sin a - H cos a) + r (D cos a + H sin a) - e sin a = 0,

whose root in 0 < r <= tan a (N_p >= 0) is the required friction; the torques are R T = R r N. **The poses**: at
the front wheel's lift-off both centres are R above the ground (pitch 0), the edge sin a R ahead of the front
centre: D = a_f + a_r + R sin a, H = h (R at the face), e = a_r. At the rear wheel's lift-off the front wheel
stands on the top tread: the rear centre is (x_e - R sin a, R), the front one L = a_f + a_r further along a line
rising by h (sin b = h / L), G = rear centre + a_r (cos b, sin b) - d (sin b, -cos b), P below the front centre.
"""
import math

import casadi as ca
import numpy as np
import pytest

from cedra.contract import Quantity
from cedra.mechanics.kane import Body
from cedra.mechanics.rover_kind import POSE, SPINS, RoverDescription, RoverKind, Wheel
from cedra.mechanics.transforms import rot_y
from cedra.rover.climb_pose import PlanarRover, PoseError
from cedra.rover.mechanism import CEDRA
from cedra.rover.required_friction import Balance, Staircase, required_friction
from cedra.rover.rocker_bogie import ROCKER_BOGIE

EY = ca.DM([0, 1, 0])


def _describe(qf, rate, p, tau, steer_cmd=None, stop_width=None):
    idx = {n: i for i, n in enumerate(POSE + SPINS)}
    x, z, pitch = qf[idx["x"]], qf[idx["z"]], qf[idx["pitch"]]
    R = rot_y(pitch)
    G = ca.vertcat(x, 0, z)
    w_body = EY * rate(pitch)
    wheels = []
    for i, local in ((1, ca.vertcat(p["a_f"], 0, -p["d"])), (2, ca.vertcat(-p["a_r"], 0, -p["d"]))):
        c = G + R @ local
        wheels.append(Wheel(i, c, R @ EY, w_body + R @ EY * rate(qf[idx[f"gamma{i}"]]), rate(c), R @ ca.DM([0, 0, 1])))
    body = Body("body", p["m"], G, w_body, ca.SX.eye(3), R)
    Q = ca.SX.zeros(len(idx))
    for i in (1, 2):
        Q[idx[f"gamma{i}"]] = tau[i - 1]
    return RoverDescription(bodies=[body], wheels=wheels, coordinate_torques=Q, potential=p["m"] * p["g"] * z,
                            closure=ca.SX(0), body_omega=w_body, body_velocity=rate(G), collision_points=[])


def two_wheeler(a_f, a_r, d=0.05, R=0.065, m=10.0) -> RoverKind:
    params = [Quantity("R_w", R, "m", "wheel radius"), Quantity("a_f", a_f, "m", "front axle ahead of G"),
              Quantity("a_r", a_r, "m", "rear axle behind G"), Quantity("d", d, "m", "axles below G"),
              Quantity("m", m, "kg", "mass"), Quantity("g", 9.81, "m/s2", "gravity")]
    return RoverKind(
        name="two_wheeler", coordinates=POSE + SPINS,
        planar={"y": None, "yaw": None, "roll": None, "gamma3": None, "gamma4": None, "gamma5": None,
                "gamma6": None},
        steering=(), settle=("z", "pitch"), parameters=params, servo_parameters=[], steer_inputs=[],
        describe=_describe, stops=(), design=lambda p: {"z": p["R_w"] + p["d"]},
        joint_outputs=lambda *a: [])


def hand_ratio(D, H, e, a):
    """The root of the module docstring's quadratic in 0 < r <= tan a."""
    A = (D - e) * math.sin(a) - H * math.cos(a)
    B = D * math.cos(a) + H * math.sin(a)
    C = -e * math.sin(a)
    roots = np.roots([A, B, C]) if abs(A) > 1e-15 else np.array([-C / B])
    ok = [float(r.real) for r in roots if abs(r.imag) < 1e-12 and 0 < r.real <= math.tan(a) + 1e-12]
    assert len(ok) == 1, roots
    return ok[0]


def hand_climb(a_f, a_r, d, R, m, h):
    """(front lift-off ratio, its climbing wheel's torque, rear lift-off ratio, its torque) by hand."""
    W = m * 9.81
    a = math.acos((R - h) / R) if h < R else math.pi / 2
    L = a_f + a_r
    # the front wheel lifts off: both wheels on the ground
    D, H = L + R * math.sin(a), (h if h < R else R)
    r_front = hand_ratio(D, H, a_r, a)
    tau_front = R * r_front * W * r_front / (math.sin(a) * (1 + r_front ** 2))
    # the rear wheel lifts off: the front one on the top tread
    rear = np.array([-R * math.sin(a), R])                  # the edge at x = 0
    b = math.asin(h / L)
    u, down = np.array([math.cos(b), math.sin(b)]), np.array([math.sin(b), -math.cos(b)])
    front = rear + L * u
    G = rear + a_r * u - d * down                        # the centre is G - a_r u + d down
    P = front - np.array([0.0, R])
    contact = np.array([0.0, h]) if h < R else np.array([0.0, R])
    D, H, e = contact[0] - P[0], contact[1] - P[1], G[0] - P[0]
    r_rear = hand_ratio(D, H, e, a)
    tau_rear = R * r_rear * W * r_rear / (math.sin(a) * (1 + r_rear ** 2))
    return r_front, tau_front, r_rear, tau_rear


CASES = [(0.15, 0.15, 0.3), (0.15, 0.15, 0.8), (0.10, 0.25, 0.5), (0.25, 0.10, 0.5), (0.10, 0.25, 1.4),
         (0.2, 0.2, 1.0)]


@pytest.mark.parametrize("a_f, a_r, h_over_R", CASES)
def test_two_wheeler_at_a_step_matches_the_hand_solution(a_f, a_r, h_over_R):
    """At both lift-offs the general function gives the hand solution's ratio and the climbing wheel's torque to
    1e-9, over step heights below, at and above the wheel radius and mass centres ahead of and behind the middle."""
    d, R, m = 0.05, 0.065, 10.0
    h = h_over_R * R
    climb = required_friction(two_wheeler(a_f, a_r, d, R, m), Staircase(h, x0=0.0), ds=R / 16)
    r_front, tau_front, r_rear, tau_rear = hand_climb(a_f, a_r, d, R, m, h)
    lift = {p.phase[0]: p for p in climb.poses if p.s == 0.0}
    assert lift[1].ratio == pytest.approx(r_front, abs=1e-9, rel=1e-9)
    assert lift[2].ratio == pytest.approx(r_rear, abs=1e-9, rel=1e-9)
    # with equal ratios the climbing wheel's torque is R r N_c; the least largest torque is the larger of the two
    W = m * 9.81
    for wheel, r, tau_c in ((1, r_front, tau_front), (2, r_rear, tau_rear)):
        a = math.acos((R - h) / R) if h < R else math.pi / 2
        n_c = W * r / (math.sin(a) * (1 + r * r))
        n_p = n_c * (math.sin(a) - r * math.cos(a)) / r
        assert lift[wheel].torque == pytest.approx(max(tau_c, R * r * n_p), rel=1e-8)
        assert lift[wheel].loads[wheel] == pytest.approx(n_c, rel=1e-8)
    # the lift-off is the climb's worst pose: the contact angle only flattens as the wheel rises
    assert climb.ratio == pytest.approx(max(r_front, r_rear), rel=1e-9)


@pytest.mark.parametrize("h_over_R", [0.5, 1.4])
def test_two_wheeler_up_stairs_meets_the_hand_solution_at_every_riser(h_over_R):
    """Stairs whose treads are longer than the vehicle: at every riser each wheel lifts off with the other on a
    tread, the step's geometry moved by the riser's offset, so every lift-off meets the hand solution to 1e-9. The
    profile's blocks (one row (x, z) per block) reach the pose program as they are: a block taken from another
    block's numbers puts a tread at another height, and no lift-off there matches."""
    a_f, a_r, d, R, m = 0.15, 0.15, 0.05, 0.065, 10.0
    h = h_over_R * R
    stairs = Staircase(h, steps=3, run=0.5, x0=0.2)
    climb = required_friction(two_wheeler(a_f, a_r, d, R, m), stairs, ds=R / 4)
    r_front, _, r_rear, _ = hand_climb(a_f, a_r, d, R, m, h)
    lifts = [p for p in climb.poses if p.s == 0.0]
    assert sorted(p.phase for p in lifts) == [(w, k) for w in (1, 2) for k in (1, 2, 3)]
    for p in lifts:
        assert p.ratio == pytest.approx(r_front if p.phase[0] == 1 else r_rear, abs=1e-9, rel=1e-9), p.phase


@pytest.mark.parametrize("kind", [CEDRA, ROCKER_BOGIE], ids=lambda k: k.name)
def test_a_pose_across_two_risers_keeps_every_wheel_out_of_the_profile(kind):
    """A pose with the rover across both risers of two stairs: every wheel centre at least R_w from every block
    of the profile (the quadrants' distances taken here in numpy, not from the pose program), and the wheels
    touching it within 1e-9 m of R_w: some on each tread and the ground."""
    R = 0.065
    stairs = Staircase(1.5 * R, steps=2, run=0.26, x0=-0.1)
    blocks = stairs.blocks()
    rover = PlanarRover(kind)
    guess = rover.design_coords()
    guess[rover.free.index("z")] += 0.3                   # from above the profile
    v, _ = rover.pose(blocks, 0.0, guess, where="across two risers")
    centres = np.array(rover.geometry(v, rover.par)[0]).reshape(2, -1).T
    dist = np.array([[math.hypot(max(0.0, e - c[0]), max(0.0, c[1] - top)) for e, top in blocks] for c in centres])
    assert dist.min() >= R - 1e-9, dist
    touching = {int(np.argmin(row)) for row in dist if row.min() < R + 1e-9}
    assert touching == {0, 1, 2}, dist


def test_a_wrong_balance_would_fail():
    """The hand solution is not degenerate: it moves with the mass centre and the height by far more than 1e-9."""
    base = hand_climb(0.15, 0.15, 0.05, 0.065, 10.0, 0.5 * 0.065)
    assert abs(hand_climb(0.10, 0.20, 0.05, 0.065, 10.0, 0.5 * 0.065)[0] - base[0]) > 1e-3
    assert abs(hand_climb(0.15, 0.15, 0.05, 0.065, 10.0, 0.6 * 0.065)[0] - base[0]) > 1e-3
    assert abs(base[0] - base[2]) > 1e-3


def test_required_friction_rises_with_the_step_below_the_wheel_radius():
    """Below R the contact at the edge steepens with h, and so does the friction the rocker-bogie needs."""
    heights = [0.25, 0.5, 0.75, 1.0]
    ratios = [required_friction(ROCKER_BOGIE, Staircase(f * 0.065), ds=0.065 / 4).ratio for f in heights]
    assert all(np.isfinite(ratios)) and all(b > a for a, b in zip(ratios, ratios[1:])), ratios


def test_a_four_bar_that_cannot_close_is_refused():
    """A CEDRA fork whose upper link cannot reach the coupler fails before any pose, naming the closure."""
    with pytest.raises(PoseError, match="cannot be assembled.*closure"):
        required_friction(CEDRA, Staircase(0.03), params={"fork_b": 0.01})


def test_a_profile_the_rover_cannot_stand_on_is_refused():
    with pytest.raises(ValueError, match="run .* must exceed the wheel radius"):
        required_friction(ROCKER_BOGIE, Staircase(0.03, steps=3, run=0.05))
    with pytest.raises(ValueError, match="no parameters"):
        required_friction(ROCKER_BOGIE, Staircase(0.03), params={"no_such": 1.0})


def test_a_wedge_is_flagged_not_quoted():
    """A body squeezed between two walls (normals +x and -x, tractions vertical, weight W): the balance holds for
    any squeeze N with T1 + T2 = W, so the ratio W / (2 N) falls without bound as N grows. The least ratio sits on
    the programs' force bound, and the balance says so; a body on one floor contact does not."""
    W = 10.0
    cols_n = np.array([[1.0, -1.0], [0.0, 0.0]])
    cols_t = np.array([[0.0, 0.0], [1.0, 1.0]])
    wedge = Balance(cols_n, cols_t, np.zeros((2, 0)), np.array([0.0, W]), [0, 1], 0.065, False)
    r, u = wedge.least_ratio()
    assert wedge.at_bound(u)
    assert r == pytest.approx(W / (2 * wedge.big), rel=1e-6)
    floor = Balance(np.array([[0.0], [1.0]]), np.array([[1.0], [0.0]]), np.zeros((2, 0)), np.array([0.0, W]), [0],
                    0.065, False)
    r, u = floor.least_ratio()
    assert r == pytest.approx(0.0, abs=1e-12) and not floor.at_bound(u)
