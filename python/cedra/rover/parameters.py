"""The CEDRA rover's parameters (docs/model.md) and the ground/servo parameters, with units. The single place
where the robot's numbers live; the symbolic model reads them as symbols (they are FMU parameters)."""
from math import atan2, sqrt

from cedra.contract import Quantity as Q

STEER_LIMIT = 1.5       # rad: the steering servos' range (the plant's steer[1..2] inputs, the controller's clip)

ROVER = [
    Q("R_w", 0.065, "m", "wheel radius", min=1e-4),
    Q("bogie_x", 0.02, "m", "bogie pivot, x in the body frame (paper l1)"),
    Q("bogie_y", 0.17, "m", "bogie pivot, half track (paper l2)", min=0.0),
    Q("bogie_z", -0.135, "m", "bogie pivot, z in the body frame (paper l3)"),
    Q("bogie_half", 0.11, "m", "bogie pivot to wheel center (paper l4)", min=1e-4),
    Q("rear_x", -0.30, "m", "rear wheel center, x (paper l5)"),
    Q("rear_z", -0.135, "m", "rear wheel center, z (paper l6)"),
    Q("fork_ax", 0.16, "m", "front four-bar lower body pivot A, x (paper l7)"),
    Q("fork_az", -0.05, "m", "front four-bar lower body pivot A, z (paper l7)"),
    Q("fork_bx", 0.18, "m", "front four-bar upper body pivot B, x (paper l8)"),
    Q("fork_bz", 0.07, "m", "front four-bar upper body pivot B, z (paper l8)"),
    Q("fork_a", sqrt(0.02), "m", "four-bar lower link A-C (paper l9)", min=1e-4),
    Q("fork_b", sqrt(0.0148), "m", "four-bar upper link B-D", min=1e-4),
    Q("fork_c", 0.12, "m", "four-bar coupler C-D", min=1e-4),
    Q("fork_wheel", 0.065, "m", "C to wheel 6 center, along the coupler, downward"),
    Q("fork_mass_at", 0.06, "m", "C to the fork mass, along the coupler"),
    Q("fork_theta4_ref", atan2(-0.02, 0.14), "rad", "design fork angle (spring rest angle)"),
    Q("fork_k", 20.0, "N.m/rad", "fork spring stiffness", min=0.0),
    Q("fork_d", 0.5, "N.m.s/rad", "fork damper", min=0.0),
    Q("bogie_stop", 0.6, "rad", "bogie joint stop |theta1|, |theta2| <= bogie_stop", min=0.0),
    Q("fork_stop_lo", -0.8, "rad", "fork joint lower stop on theta4"),
    Q("fork_stop_hi", 0.6, "rad", "fork joint upper stop on theta4"),
    Q("stop_k", 500.0, "N.m/rad", "joint stop stiffness", min=0.0),
    Q("stop_d", 5.0, "N.m.s/rad", "joint stop damping", min=0.0),
    Q("m_B", 20.0, "kg", "body mass", min=1e-6),
    Q("I_Bxx", 0.1875, "kg.m2", "body inertia about x", min=1e-9),
    Q("I_Byy", 0.6375, "kg.m2", "body inertia about y", min=1e-9),
    Q("I_Bzz", 0.75, "kg.m2", "body inertia about z", min=1e-9),
    Q("m_F", 1.0, "kg", "fork point mass", min=1e-6),
    Q("I_F", 0.005, "kg.m2", "fork inertia (isotropic)", min=1e-9),
    Q("m_w", 0.5, "kg", "wheel mass", min=1e-6),
    Q("g", 9.81, "m/s2", "gravitational acceleration", min=0.0),
]

GROUND = [
    Q("ground_k", 1e5, "N/m", "ground contact stiffness (compliant model)", min=1e-9),
    Q("ground_d", 600.0, "N.s/m", "ground contact damping (compliant model)", min=0.0),
    Q("v_eps", 0.01, "m/s", "friction regularization speed (compliant model)", min=1e-12),
]

# Rigid contact (the paper's decision tree): Baumgarte drift stabilization of the contact constraints
# (project choice: a critically damped gap error with time constant 1/rigid_alpha), and the slip speed below
# which a slipping wheel is tested for sticking again.
RIGID = [
    Q("rigid_alpha", 50.0, "1/s", "Baumgarte stabilization rate of the rigid contact constraints", min=1e-6),
    Q("v_stick", 1e-4, "m/s", "slip speed below which a slipping wheel may stick again (rigid model)", min=0.0),
]

# The steering servo is not in the paper's numbers: a stiff PD servo holding each steering angle at its command.
# (Project choice, docs/equations.md: about 300 rad/s natural frequency on the steered wheel, damping ratio ~0.9.)
SERVO = [
    Q("steer_k", 50.0, "N.m/rad", "steering servo stiffness", min=0.0),
    Q("steer_d", 0.3, "N.m.s/rad", "steering servo damping", min=0.0),
]

# Drives (docs/model.md, Drives; scene option `drives`): a DC motor behind its gear, seen at the wheel. Its linear
# torque-speed envelope passes through the stall torque at rest and 0 at the no-load speed (0.65 m/s at the rim);
# the gear adds a viscous loss. Both envelope numbers must be > 0 (the envelope divides by the no-load speed, and a
# zero stall torque is no motor).
DRIVES = [
    Q("drive_stall_torque", 6.0, "N.m", "drive stall torque at the wheel (T_s): the most torque the motor and gear "
      "give at rest", min=0.0, min_exclusive=True),
    Q("drive_noload_speed", 10.0, "rad/s", "drive no-load speed at the wheel (w_0): the spin rate relative to the "
      "carrier where the forward torque envelope reaches 0", min=0.0, min_exclusive=True),
    Q("drive_viscous", 0.01, "N.m.s/rad", "viscous loss of the gear at the wheel (b): -b omega is added to the "
      "clipped command", min=0.0),
]

DEFAULTS = {p.name: p.start for p in ROVER + GROUND + RIGID + SERVO + DRIVES}
