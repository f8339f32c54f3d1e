"""The plant's outputs the paper's inverse kinematics and steering need: joint rates, the contact angle
psi_i in the rover frame, its rate, and the rotational slip angle xi_i, each checked against an independent
derivation: the 2D relation psi_R = -(slope + pitch), the kinematics' own contact frame (kinematics.contact_frame),
finite differences, and a rigid body sliding at a known angle."""
import casadi as ca
import numpy as np
import pytest

from cedra.rover import kinematics as kin
from cedra.models.plant import XI_SPEED, ModelOptions
from cedra.rover.parameters import DEFAULTS
from cedra.mechanics.transforms import rot_x, rot_y, rot_z
from model_harness import Built

D = DEFAULTS
RNG = np.random.default_rng(10)


class Outputs(Built):
    """Built's outputs at the model's default inputs and parameters (unless given)."""

    def __init__(self, opt):
        super().__init__(opt)
        self.par = self.m.default_par()
        self.inp = self.m.default_inp()

    def __call__(self, q, u, inp=None):
        return self.out(q, u, self.inp if inp is None else inp, self.par)

    def q(self, **values):
        q = np.zeros(len(self.m.q_names))
        q[self.m.q_names.index("z")] = D["R_w"] - D["rear_z"]
        q[self.m.q_names.index("theta4")] = D["fork_theta4_ref"]
        for k, v in values.items():
            q[self.m.q_names.index(k)] = v
        return q


@pytest.fixture(scope="module")
def bump2d():
    return Outputs(ModelOptions(dims="2d", terrain="bump"))


@pytest.fixture(scope="module")
def slope3d():
    return Outputs(ModelOptions(dims="3d", terrain="slope", steering=True))


def test_design_pose_on_flat_ground_has_zero_contact_angles():
    out = Outputs(ModelOptions(dims="3d", terrain="flat", steering=True))
    y = out(out.q(), np.zeros(len(out.m.q_names)))
    for i in range(1, 7):
        assert abs(y[f"wheel[{i}].psi_R"]) < 1e-12 and abs(y[f"wheel[{i}].xi"]) < 1e-12


def test_2d_contact_angle_is_minus_slope_minus_pitch(bump2d):
    """In the plane every axle is world Y: the normal's angle about +Y from Z is -slope, the body's z is at pitch."""
    for _ in range(20):
        q = bump2d.q(x=RNG.uniform(0.5, 1.5), pitch=RNG.uniform(-0.3, 0.3), theta1=RNG.uniform(-0.3, 0.3),
                     theta4=D["fork_theta4_ref"] + RNG.uniform(-0.2, 0.2))
        y = bump2d(q, np.zeros(len(q)))
        for i in range(1, 7):
            want = -(y[f"wheel[{i}].psi"] + y["body.pitch"])
            assert abs(np.angle(np.exp(1j * (y[f"wheel[{i}].psi_R"] - want)))) < 1e-12, i


def test_3d_contact_angle_puts_the_kinematics_contact_frame_on_the_normal(slope3d):
    """kinematics.contact_frame(i, joints, psi_R) is the paper's C_i in R; turned into the world by the body's
    rotation, its z axis must be the terrain's normal (the slope's normal lies in every wheel's plane when the
    rover heads down the slope, yaw = roll = 0, steering 0; the bogies and the fork move freely)."""
    slope = 0.2
    inp = slope3d.inp.copy()
    inp[[q.name for q in slope3d.m.inputs].index("terrain_slope")] = slope
    normal = np.array([np.sin(slope), 0.0, np.cos(slope)])       # positive slope descends toward +X
    for _ in range(10):
        joints = dict(theta1=RNG.uniform(-0.3, 0.3), theta2=RNG.uniform(-0.3, 0.3),
                      theta4=D["fork_theta4_ref"] + RNG.uniform(-0.2, 0.2))
        q = slope3d.q(pitch=RNG.uniform(-0.3, 0.3), **joints)
        y = slope3d(q, np.zeros(len(q)), inp)
        r_body = np.array(ca.evalf(rot_z(0) @ rot_y(q[slope3d.m.q_names.index("pitch")]) @ rot_x(0)))
        jv = [joints["theta1"], joints["theta2"], joints["theta4"], 0.0, 0.0]
        for i in range(1, 7):
            c_frame = np.array(ca.evalf(kin.contact_frame(i, ca.DM(jv), y[f"wheel[{i}].psi_R"], D)))
            np.testing.assert_allclose(r_body @ c_frame[:3, 2], normal, atol=1e-12, err_msg=f"wheel {i}")


def test_rates_are_time_derivatives(bump2d):
    """Central differences along the motion q(t) = q + t u on the curved bump: psi_R_rate, the joint rates."""
    h = 1e-6
    for _ in range(10):
        q = bump2d.q(x=RNG.uniform(0.6, 1.4), pitch=RNG.uniform(-0.2, 0.2), theta1=RNG.uniform(-0.2, 0.2))
        u = RNG.uniform(-1, 1, len(q))
        y, yp, ym = bump2d(q, u), bump2d(q + h * u, u), bump2d(q - h * u, u)
        pairs = [(f"wheel[{i}].psi_R_rate", f"wheel[{i}].psi_R") for i in range(1, 7)]
        pairs += [("bogie.rate[1]", "bogie.theta[1]"), ("fork.rate4", "fork.theta4")]
        for rate, angle in pairs:
            assert abs(y[rate] - (yp[angle] - ym[angle]) / (2 * h)) < 1e-6 * max(1, abs(y[rate])), rate


@pytest.mark.parametrize("vx,vy", [(0.1, 0.05), (0.2, -0.2), (-0.1, 0.03), (0.0, 0.1)])
def test_rotational_slip_angle_of_a_sliding_rover(vx, vy):
    """Level rover on flat ground translating with (vx, vy), wheels locked: every unsteered wheel's center moves
    at the body's velocity, heading +X: xi = atan(vy vx / (vx^2 + XI_SPEED^2)), i.e. atan(vy / vx) when moving."""
    out = Outputs(ModelOptions(dims="3d", terrain="flat", steering=True))
    q = out.q()
    u = np.zeros(len(q))
    u[out.m.q_names.index("x")], u[out.m.q_names.index("y")] = vx, vy
    y = out(q, u)
    want = np.arctan(vy * vx / (vx ** 2 + XI_SPEED ** 2))
    for i in range(1, 7):
        assert abs(y[f"wheel[{i}].xi"] - want) < 1e-12, i
    if vx:
        assert abs(want - np.arctan(vy / vx)) < 1e-3
