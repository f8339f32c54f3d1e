"""An exhaustive reference for the contacts of a wheel (docs/model.md, Several contacts per wheel, item 5),
independent of cedra.mechanics.contact's search: g sampled every 0.01 degree of the lower half rim, every maximum
and saddle polished by Newton on g' = 0 to machine precision (derivatives by central differences of g, no symbolic
chain), and the penetration shared by the rule of docs/model.md (Several contacts per wheel, item 2), written as
its own recursion over any number of maxima."""
from __future__ import annotations

import numpy as np

STEP_DEG = 0.01


def rim_frame(center, axle, normal_at_center):
    n0 = np.asarray(normal_at_center, float)
    a = np.asarray(axle, float)
    t = n0 - n0.dot(a) * a
    r1 = -t / np.linalg.norm(t)
    r2 = np.cross(a, r1)
    return r1, r2


def g_of(height, center, radius, r1, r2):
    c = np.asarray(center, float)

    def g(b):
        b = np.asarray(b, float)
        p = c[:, None] + radius * (np.cos(b)[None] * r1[:, None] + np.sin(b)[None] * r2[:, None])
        return height(p[0], p[1]) - p[2]
    return g


def polish(g, b, lo, hi):
    """Newton on g'(b) = 0 with central differences, inside [lo, hi]; stops where the step no longer shrinks."""
    e = 1e-5
    for _ in range(60):
        g0, gp, gm = g(np.array([b, b + e, b - e]))
        d1, d2 = (gp - gm) / (2 * e), (gp - 2 * g0 + gm) / e ** 2
        if d2 == 0:
            break
        nb = min(hi, max(lo, b - d1 / d2))
        if abs(nb - b) < 1e-13:
            b = nb
            break
        b = nb
    return b


def extrema(g):
    """(maxima [(beta, g)], saddles between neighbouring maxima [g]) of g on [-pi/2, pi/2], ordered by beta."""
    n = int(round(180 / STEP_DEG)) + 1
    b = np.linspace(-np.pi / 2, np.pi / 2, n)
    v = g(b)
    h = b[1] - b[0]
    maxima = []
    for j in range(n):
        left = j == 0 or v[j] >= v[j - 1]
        right = j == n - 1 or v[j] > v[j + 1]
        if left and right:
            if 0 < j < n - 1:
                bb = polish(g, b[j], b[j] - h, b[j] + h)
            else:
                bb = b[j]
            maxima.append((bb, float(g(np.array([bb]))[0]), j))
    saddles = []
    for (_, _, j0), (_, _, j1) in zip(maxima, maxima[1:]):
        j = j0 + 1 + int(np.argmin(v[j0 + 1:j1]))
        bb = polish(g, b[j], b[j] - h, b[j] + h)
        saddles.append(min(float(g(np.array([bb]))[0]), v[j]))
    return [(bb, gv) for bb, gv, _ in maxima], saddles


def shares(gmax, saddles):
    """Vertical penetration of each maximum (docs/model.md, Several contacts per wheel, item 2)."""
    def group(idx, base, pool):
        if len(idx) == 1:
            return {idx[0]: gmax[idx[0]] - base + pool}
        inner = [max(saddles[i], 0.0) for i in idx[:-1]]
        c = int(np.argmin(inner))
        cut = inner[c]
        lhs, rhs = idx[:c + 1], idx[c + 1:]
        ra = max(max(gmax[i] for i in lhs) - cut, 0.0)
        rb = max(max(gmax[i] for i in rhs) - cut, 0.0)
        w = 0.5 if ra + rb == 0 else ra / (ra + rb)
        pool2 = pool + cut - base
        return group(lhs, cut, pool2 * w) | group(rhs, cut, pool2 * (1 - w))
    out = group(list(range(len(gmax))), 0.0, 0.0)
    return [out[i] for i in range(len(gmax))]


def wheel_contacts(height, normal, center, axle, radius, max_contacts=3):
    """[(beta, point, delta)] of the wheel's contacts ordered by beta (the max_contacts highest maxima)."""
    r1, r2 = rim_frame(center, axle, normal(center[0], center[1]))
    g = g_of(height, center, radius, r1, r2)
    maxima, saddles = extrema(g)
    if len(maxima) > max_contacts:     # keep the highest; the saddle between kept neighbours is the lowest between
        keep = sorted(sorted(range(len(maxima)), key=lambda i: -maxima[i][1])[:max_contacts])
        sad = [min([saddles[i] for i in range(a, b)]) for a, b in zip(keep, keep[1:])]
        maxima, saddles = [maxima[i] for i in keep], sad
    d = shares([m[1] for m in maxima], saddles)
    out = []
    for (bb, _), dv in zip(maxima, d):
        p = np.asarray(center, float) + radius * (np.cos(bb) * r1 + np.sin(bb) * r2)
        out.append((bb, p, dv * normal(p[0], p[1])[2]))
    return out
