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
    """The rim point lying deepest below the terrain, measured vertically (docs/model.md, Contact): the best of
    13 samples, then 4 Newton steps that never move toward a minimum. One point per wheel: the contact of rigid
    scenes and the reference of the heightmap's C search (rim_contacts has several)."""
    rim, gfun = _rim_frame(center, axle, terrain, radius)
    if terrain.planar:
        return rim(0)                      # exact on a plane: the deepest point is along -t
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


def _rim_frame(center, axle, terrain: Terrain, radius, frame=False):
    """The rim's parametrization p(beta) = c + R_w (cos beta r1 + sin beta r2), beta = 0 along the projected terrain
    normal at the center (docs/model.md, Contact), and g(beta) = f(p_X, p_Y) - p_Z with its first two
    beta-derivatives by the chain rule on the terrain's own gradient and Hessian."""
    n0 = terrain.normal(center[0], center[1])
    t = n0 - ca.dot(n0, axle) * axle
    r1 = -unit(t)
    r2 = ca.cross(axle, r1)

    def rim(b):
        return center + radius * (ca.cos(b) * r1 + ca.sin(b) * r2)

    def gfun(b):
        p = rim(b)
        dp = radius * (-ca.sin(b) * r1 + ca.cos(b) * r2)
        ddp = center - p
        h, grad, hess = terrain.local(p[0], p[1])
        d1 = ca.dot(grad, dp[0:2]) - dp[2]
        d2 = ca.dot(dp[0:2], hess @ dp[0:2]) + ca.dot(grad, ddp[0:2]) - ddp[2]
        return h - p[2], d1, d2

    return (rim, gfun, r1, r2) if frame else (rim, gfun)


def contact_frame(axle, n):
    """The contact frame C: z = n, x = unit(a x n) (rolling, forward), y = z x x; columns x, y, z."""
    x = unit(ca.cross(axle, n))
    return ca.horzcat(x, ca.cross(n, x), n)


def slope_angle(axle, n):
    """psi: the angle of n from Z in the wheel's rolling plane, positive uphill ahead."""
    ahead = unit(ca.cross(axle, ca.vertcat(0, 0, 1)))    # horizontal forward direction of the rolling plane
    return ca.atan2(-ca.dot(n, ahead), n[2])


def contact_geometry(center, axle, terrain: Terrain, radius) -> ContactGeometry:
    """One contact per wheel: the deepest rim point (docs/model.md, Contact). Rigid scenes use it, and the heightmap
    where its rim has one maximum (rim_contacts)."""
    if terrain.external_rim:
        # heightmap: the same search in C (one call per wheel, its derivatives exact; see terrain.Terrain)
        p, h, grad = terrain.rim_contact(center, axle, radius)
        n = ca.vertcat(-grad[0], -grad[1], 1)
        n = n / ca.norm_2(n)
    else:
        p = rim_point(center, axle, terrain, radius)
        n = terrain.normal(p[0], p[1])
        h = terrain.height(p[0], p[1])
    return ContactGeometry(p, n, contact_frame(axle, n), (h - p[2]) * n[2], slope_angle(axle, n))


# ---------------- several contacts per wheel (docs/model.md, Several contacts per wheel) ----------------
MAX_CONTACTS = 3
ABSENT_DEPTH = -1.0     # the depth of a contact slot that holds no maximum (m; never in contact)


def _ratio(a, b):
    """a / (a + b) for a, b >= 0, and 1/2 where both are 0."""
    s = a + b
    return ca.if_else(s > 0, a / ca.if_else(s > 0, s, 1), 0.5)


def shared_depths(g, s):
    """The vertical penetrations of up to three maxima g = [g1, g2, g3] ordered by beta, joined by the saddles
    s = [s12, s23] (the smallest g between neighbours), present = len(g). docs/model.md, Several contacts per wheel,
    item 2: maxima on separate arcs (saddle <= 0) are separate; two maxima joined by a saddle s > 0 share the
    penetration below it in proportion to their rises above it; three on one arc split at the lowest saddle first (each
    side in proportion to its highest rise), then within the side the same way. Written as one recursion: a group of
    maxima on a base (a saddle height, 0 at the top level) with a pool (the penetration below the base that the group
    received): a single maximum gets (g - base) + pool; a group splits at its lowest saddle s (clamped at 0), the pool
    grows by s - base, and each side gets its part and recurses with base s."""
    def group(idx, base, pool):
        if len(idx) == 1:
            return [g[idx[0]] - base + pool]
        if len(idx) == 2:
            return split(idx, 1, base, pool)
        low_first = ca.fmax(s[idx[0]], 0) <= ca.fmax(s[idx[1]], 0)       # three: split at the lower saddle
        return [ca.if_else(low_first, x, y) for x, y in zip(split(idx, 1, base, pool), split(idx, 2, base, pool))]

    def split(idx, at, base, pool):
        """idx[:at] | idx[at:] cut at the saddle between idx[at - 1] and idx[at]"""
        cut = ca.fmax(s[idx[at - 1]], 0)
        lhs, rhs = idx[:at], idx[at:]
        a = ca.fmax(ca.mmax(ca.vertcat(*[g[i] for i in lhs])) - cut, 0)
        b = ca.fmax(ca.mmax(ca.vertcat(*[g[i] for i in rhs])) - cut, 0)
        w = _ratio(a, b)
        pool2 = pool + cut - base
        return group(lhs, cut, pool2 * w) + group(rhs, cut, pool2 * (1 - w))

    return group(list(range(len(g))), 0, 0)


RIM_SAMPLES = 13        # the C search's samples: beta = k pi/12, k = -6..6 (fmu_src/rim.c)


def rim_samples_function(terrain: Terrain) -> ca.Function:
    """cedra_rim_samples: (x[15] = [center, axle, radius, terrain inputs padded]) -> (g[13] at beta = k pi/12,
    frame[6] = [r1, r2], d1[2] = g' at both ends): what the C search (fmu_src/rim.c) starts from, as straight-line
    code (one call instead of 13 terrain calls)."""
    x = ca.SX.sym("x", 7 + terrain.tin().numel())
    t = {n: x[7 + k] for k, n in enumerate(terrain.input_names)}
    local = Terrain.bound(terrain, t)
    rim, gfun, r1, r2 = _rim_frame(x[0:3], x[3:6], local, x[6], frame=True)
    half = (RIM_SAMPLES - 1) // 2
    g = [gfun(k * ca.pi / (2 * half))[0] for k in range(-half, half + 1)]
    ends = [gfun(-ca.pi / 2)[1], gfun(ca.pi / 2)[1]]
    return ca.Function("cedra_rim_samples", [x], [ca.densify(ca.vertcat(*g)), ca.densify(ca.vertcat(r1, r2)),
                                                  ca.densify(ca.vertcat(*ends))],
                       ["x"], ["g", "frame", "d1"], {"cse": True})


def terrain_functions(terrain: Terrain) -> dict[str, ca.Function]:
    """The contract's terrain functions for the C contact search: cedra_terrain, cedra_rim_samples and
    cedra_terrain_bounds."""
    return {"cedra_terrain": terrain.function(), "cedra_rim_samples": rim_samples_function(terrain),
            "cedra_terrain_bounds": terrain.bounds_function()}


def rim_contacts(center, axle, terrain: Terrain, radius, search, freeze=None):
    """The contacts of a wheel (docs/model.md, Several contacts per wheel): the local maxima of g on the lower half
    rim, up to MAX_CONTACTS ordered by beta, with the saddles between neighbours and their shared penetrations.
    Returns the contact slots (always MAX_CONTACTS; a slot without a maximum has depth ABSENT_DEPTH) and their
    presence flags. Planar terrain: one contact (contact_geometry).

    search: the result of the C search (cedra.mechanics.rim: r[8] = beta of maxima 1..3, of saddles 1..2,
    presence 1..3) for this wheel. freeze(expr) -> symbol: the caller stands a free symbol in for expr and puts
    expr back after taking derivatives (CedraModel.resolve), so derivatives never reach the search: a maximum
    enters as b = b0 - g'(b0) / g''(b0) with b0 the search's angle (its value b0 at convergence, its derivative
    what the implicit function theorem gives), a saddle's height as g at its angle (stationary: its derivative
    is the partial one). Every choice of the search is a piecewise-constant start for Newton, so the forces are
    continuous wherever it converges (the exhaustive search in the tests holds it to 1e-9 m)."""
    if terrain.planar:
        geo = contact_geometry(center, axle, terrain, radius)
        absent = ContactGeometry(geo.point, geo.normal, geo.frame, ca.SX(ABSENT_DEPTH), geo.slope)
        return [geo] + [absent] * (MAX_CONTACTS - 1), [1] + [0] * (MAX_CONTACTS - 1)
    freeze = freeze or (lambda e: e)
    rim, gfun = _rim_frame(center, axle, terrain, radius)
    r = [freeze(search[k]) for k in range(8)]
    present = r[5:8]
    b_max = []
    for b0 in r[0:3]:
        _, d1, d2 = gfun(b0)
        inside = ca.logic_and(d2 < 0, ca.fabs(b0) < ca.pi / 2 - 1e-12)     # an end of the rim is not stationary
        b_max.append(b0 - ca.if_else(inside, d1 / ca.if_else(inside, d2, -1), 0))
    g_max = [gfun(b)[0] for b in b_max]
    g_sad = [ca.if_else(present[k + 1], gfun(b)[0], -1) for k, b in enumerate(r[3:5])]
    count = sum(present)
    one = [g_max[0]]
    two = shared_depths(g_max[:2], g_sad[:1])
    three = shared_depths(g_max, g_sad)
    geos = []
    for k in range(MAX_CONTACTS):
        share = ca.if_else(count == 1, (one + [0, 0])[k], ca.if_else(count == 2, (two + [0])[k], three[k]))
        p = rim(b_max[k])
        n = terrain.normal(p[0], p[1])
        depth = ca.if_else(present[k], share * n[2], ABSENT_DEPTH)
        geos.append(ContactGeometry(p, n, contact_frame(axle, n), depth, slope_angle(axle, n)))
    if terrain.external_rim:
        # the heightmap: where the rim has one maximum, the single-contact C search gives that maximum with its
        # exact derivatives in one call (terrain.Terrain), far cheaper than the terrain's external evaluated and
        # differentiated along the Newton step above; the form with one maximum (rim.ONE_MAXIMUM) keeps only it
        one = contact_geometry(center, axle, terrain, radius)
        single = count == 1
        geos[0] = ContactGeometry(*[ca.if_else(single, a, b) for a, b in zip(
            (one.point, one.normal, one.frame, one.depth, one.slope),
            (geos[0].point, geos[0].normal, geos[0].frame, geos[0].depth, geos[0].slope))])
    return geos, present


def point_penetration(terrain: Terrain, point):
    """(the terrain's unit normal under the point, its penetration g n_Z = (h - p_Z) n_Z; > 0 below the surface):
    what a collision point of the body and links meets (docs/model.md, Chassis and links)."""
    h, grad, _ = terrain.local(point[0], point[1])
    n = ca.vertcat(-grad[0], -grad[1], 1)
    n = n / ca.norm_2(n)
    return n, (h - point[2]) * n[2]


def softplus(x, width):
    """width log(1 + exp(x / width)): a smooth max(0, x), within width log 2 of it and tending to it as width -> 0
    (written max(x, 0) + width log(1 + exp(-|x| / width)), which never overflows and is as smooth as the sum)."""
    return ca.fmax(x, 0) + width * ca.log1p(ca.exp(-ca.fabs(x) / width))


def sigmoid(x, width):
    """The logistic sigmoid of x / width, 1 / (1 + exp(-x / width)): a smooth step from 0 to 1 over the width."""
    return 0.5 * (1 + ca.tanh(x / (2 * width)))


def compliant_law(depth, n, v_point, ground_k, ground_d, mu, v_eps, width=None):
    """The paper's ground flexibility at a point with penetration depth, unit normal n and velocity v_point:
    (F_n, F_t, v_n, v_t) with F_n = max(0, k delta - d v_n) (0 where delta <= 0) and
    F_t = -mu F_n v_t / sqrt(|v_t|^2 + v_eps^2). A wheel's contacts and the chassis points share it.

    width (m, a symbol or a number >= 0): the smoothed law the optimizer may integrate instead (never an FMU's),
    F_n = k softplus_w(delta - (d / k) v_n sigmoid(delta / w)): the clip a softplus, the damping's onset at
    delta = 0 a sigmoid, both over the depth width w, so that F_n is infinitely differentiable in the state. It
    tends to the law above as w -> 0 wherever delta != 0; w = 0 is the law above exactly."""
    v_n = ca.dot(v_point, n)
    v_t = v_point - v_n * n
    Fn = ca.if_else(depth > 0, ca.fmax(0, ground_k * depth - ground_d * v_n), 0)
    if width is not None:
        w = ca.if_else(width > 0, width, 1)
        Fn = ca.if_else(width > 0, ground_k * softplus(depth - ground_d / ground_k * v_n * sigmoid(depth, w), w), Fn)
    Ft = -mu * Fn * v_t / ca.sqrt(ca.dot(v_t, v_t) + v_eps ** 2)
    return Fn, Ft, v_n, v_t


def compliant_force(geo: ContactGeometry, v_point, ground_k, ground_d, mu, v_eps, width=None):
    """Force on the wheel at the contact point (world) and its contact-frame components (Fn, Fx, Fy), the
    tangential slip velocity's norm, and the contact flag (compliant_law; width: its smoothed form)."""
    Fn, Ft, _, v_t = compliant_law(geo.depth, geo.normal, v_point, ground_k, ground_d, mu, v_eps, width)
    force = Fn * geo.normal + Ft
    return force, Fn, ca.dot(Ft, geo.frame[:, 0]), ca.dot(Ft, geo.frame[:, 1]), ca.norm_2(v_t), geo.depth > 0


def rim_samples(center, axle, terrain: Terrain, radius) -> list:
    """g(beta_k) = f(p_X, p_Y) - p_Z at the rim search's 13 samples beta_k = k pi/12, k = -6..6 (the same frame
    as rim_point), as symbolic expressions: the samples the C search (fmu_src/rim.c) gets from cedra_rim_samples."""
    n0 = terrain.normal(center[0], center[1])
    t = n0 - ca.dot(n0, axle) * axle
    r1 = -unit(t)
    r2 = ca.cross(axle, r1)
    out = []
    for k in range(-6, 7):
        p = center + radius * (ca.cos(k * ca.pi / 12) * r1 + ca.sin(k * ca.pi / 12) * r2)
        out.append(terrain.height(p[0], p[1]) - p[2])
    return out
