"""Wheel-disk contact geometry and the compliant contact law (docs/model.md, Contact). No CEDRA numbers here."""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca

from cedra.mechanics.terrain import Terrain
from cedra.mechanics.transforms import unit

N_SAMPLES = 13          # beta = k pi/12, k = -6..6: the lower half of the rim
N_NEWTON = 4


@dataclass
class ContactGeometry:
    point: ca.SX        # contact point p (world)
    normal: ca.SX       # terrain unit normal n at p: the contact frame's z
    frame: ca.SX        # 3x3, columns x (rolling, forward), y, z = n of the contact frame C_i
    depth: ca.SX        # penetration delta = g(beta) n_Z (> 0 in contact)
    slope: ca.SX        # psi: angle of n from Z in the wheel's rolling plane (positive uphill ahead)


def rim_point(center, axle, terrain: Terrain, radius):
    """The rim point lying deepest below the terrain, measured vertically (docs/model.md, Contact).

    One contact point per wheel: a wheel touching two faces at once (a step's edge and the ground) is modeled
    by the deeper one."""
    n0 = terrain.normal(center[0], center[1])
    t = n0 - ca.dot(n0, axle) * axle
    r1 = -unit(t)
    r2 = ca.cross(axle, r1)

    def rim(b):
        return center + radius * (ca.cos(b) * r1 + ca.sin(b) * r2)

    if terrain.planar:
        return rim(0)                      # exact on a plane: the deepest point is along -t

    def gfun(b):
        """g(beta) = f(p_X, p_Y) - p_Z and its first two beta-derivatives, by the chain rule on the terrain's
        own gradient and Hessian (p' = R_w (-sin b r1 + cos b r2), p'' = -(p - c))."""
        p = rim(b)
        dp = radius * (-ca.sin(b) * r1 + ca.cos(b) * r2)
        ddp = center - p
        h, grad, hess = terrain.local(p[0], p[1])
        d1 = ca.dot(grad, dp[0:2]) - dp[2]
        d2 = ca.dot(dp[0:2], hess @ dp[0:2]) + ca.dot(grad, ddp[0:2]) - ddp[2]
        return h - p[2], d1, d2

    best_b, best_g = 0, gfun(0)[0]
    for k in range(-6, 7):
        if k == 0:
            continue
        b = k * ca.pi / 12
        gk = gfun(b)[0]
        better = gk > best_g
        best_b, best_g = ca.if_else(better, b, best_b), ca.if_else(better, gk, best_g)
    b = best_b
    for _ in range(N_NEWTON):
        _, d1, d2 = gfun(b)
        b = ca.if_else(d2 < 0, b - d1 / ca.if_else(d2 < 0, d2, -1), b)   # never step toward a minimum
    return rim(b)


def contact_geometry(center, axle, terrain: Terrain, radius) -> ContactGeometry:
    if terrain.external_rim:
        # heightmap: the same search in C (one call per wheel, its derivatives exact; see terrain.Terrain)
        p, h, grad = terrain.rim_contact(center, axle, radius)
        n = ca.vertcat(-grad[0], -grad[1], 1)
        n = n / ca.norm_2(n)
    else:
        p = rim_point(center, axle, terrain, radius)
        n = terrain.normal(p[0], p[1])
        h = terrain.height(p[0], p[1])
    x = unit(ca.cross(axle, n))
    y = ca.cross(n, x)
    depth = (h - p[2]) * n[2]
    ahead = unit(ca.cross(axle, ca.vertcat(0, 0, 1)))    # horizontal forward direction of the rolling plane
    slope = ca.atan2(-ca.dot(n, ahead), n[2])
    return ContactGeometry(p, n, ca.horzcat(x, y, n), depth, slope)


def compliant_force(geo: ContactGeometry, v_point, ground_k, ground_d, mu, v_eps):
    """Force on the wheel at the contact point (world) and its contact-frame components (Fn, Fx, Fy), the
    tangential slip velocity's norm, and the contact flag. The paper's ground flexibility:
    F_n = max(0, k delta - d v_n); F_t = -mu F_n v_t / sqrt(|v_t|^2 + v_eps^2)."""
    n = geo.normal
    v_n = ca.dot(v_point, n)
    v_t = v_point - v_n * n
    in_contact = geo.depth > 0
    Fn = ca.if_else(in_contact, ca.fmax(0, ground_k * geo.depth - ground_d * v_n), 0)
    Ft = -mu * Fn * v_t / ca.sqrt(ca.dot(v_t, v_t) + v_eps ** 2)
    force = Fn * n + Ft
    return force, Fn, ca.dot(Ft, geo.frame[:, 0]), ca.dot(Ft, geo.frame[:, 1]), ca.norm_2(v_t), in_contact


def rim_samples(center, axle, terrain: Terrain, radius) -> list:
    """g(beta_k) = f(p_X, p_Y) - p_Z at the rim search's 13 samples beta_k = k pi/12, k = -6..6 (the same frame
    as rim_point). The switching function of the best sample (plant.py, CedraModel.switches) is built from them: when a
    sample that is not a neighbour of the best one overtakes it, the contact point jumps (a wheel at a step's
    edge: from the ground to the face)."""
    n0 = terrain.normal(center[0], center[1])
    t = n0 - ca.dot(n0, axle) * axle
    r1 = -unit(t)
    r2 = ca.cross(axle, r1)
    out = []
    for k in range(-6, 7):
        p = center + radius * (ca.cos(k * ca.pi / 12) * r1 + ca.sin(k * ca.pi / 12) * r2)
        out.append(terrain.height(p[0], p[1]) - p[2])
    return out
