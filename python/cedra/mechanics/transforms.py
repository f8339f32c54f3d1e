"""Rotations and homogeneous transforms (the paper's Eq. 1), on CasADi SX. No CEDRA numbers here."""
import casadi as ca


def rot_x(a):
    c, s = ca.cos(a), ca.sin(a)
    return ca.vertcat(ca.horzcat(1, 0, 0), ca.horzcat(0, c, -s), ca.horzcat(0, s, c))


def rot_y(a):
    c, s = ca.cos(a), ca.sin(a)
    return ca.vertcat(ca.horzcat(c, 0, s), ca.horzcat(0, 1, 0), ca.horzcat(-s, 0, c))


def rot_z(a):
    c, s = ca.cos(a), ca.sin(a)
    return ca.vertcat(ca.horzcat(c, -s, 0), ca.horzcat(s, c, 0), ca.horzcat(0, 0, 1))


def rot_axis(axis, a):
    """Rotation by angle a about the unit vector axis (Rodrigues)."""
    k = skew(axis)
    return ca.SX.eye(3) + ca.sin(a) * k + (1 - ca.cos(a)) * (k @ k)


def skew(v):
    return ca.vertcat(ca.horzcat(0, -v[2], v[1]), ca.horzcat(v[2], 0, -v[0]), ca.horzcat(-v[1], v[0], 0))


def homogeneous(rotation, translation):
    """4x4 transform [R p; 0 1]."""
    top = ca.horzcat(rotation, ca.reshape(translation, 3, 1))
    return ca.vertcat(top, ca.horzcat(0, 0, 0, 1))


def translation(p):
    return homogeneous(ca.SX.eye(3), p)


def dh(a, alpha, d, theta):
    """Denavit-Hartenberg transform, the paper's Eq. 1 with the signs its extraction lost:
    Rot_z(theta) Trans_z(d) Trans_x(a) Rot_x(alpha)."""
    ct, st, ca_, sa = ca.cos(theta), ca.sin(theta), ca.cos(alpha), ca.sin(alpha)
    return ca.vertcat(
        ca.horzcat(ct, -st * ca_, st * sa, a * ct),
        ca.horzcat(st, ct * ca_, -ct * sa, a * st),
        ca.horzcat(0, sa, ca_, d),
        ca.horzcat(0, 0, 0, 1))


def position(transform):
    return transform[0:3, 3]


def rotation(transform):
    return transform[0:3, 0:3]


def apply(transform, point):
    """Transform a 3-vector point."""
    return rotation(transform) @ point + position(transform)


def e_xz(a):
    """docs/model.md's e(a) = (cos a, 0, sin a): a unit vector in the x-z plane, a > 0 pointing up."""
    return ca.vertcat(ca.cos(a), 0, ca.sin(a))


def unit(v):
    return v / ca.norm_2(v)
