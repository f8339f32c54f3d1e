"""The model as parts (cedra.models.parts) equals the monolithic form it replaces (CedraModel.functions(parts=False),
kept as the reference): cedra_f, cedra_rjac and cedra_settle at sampled states of every shipped compliant scene's main run, to
1e-12 relative to the quantity's largest entry.

The coordinates come from the shipped FMU's own run (its pose and joint outputs, every 0.5 s); the speeds and the
accelerations are random (0.3 m/s or rad/s, 1 m/s2 scale), so that every branch of the contact law (damping,
its clip, friction's regularization) is reached while the contacts sit where the run put them. Where a scene's
wheels meet edges (the step, the stairs, the rubble), some of the sampled wheels are in the three-slot form: the
test asserts it, so the per-wheel choice of forms is exercised, not only the one-slot form.
"""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from cedra.mechanics import rim
from cedra.models.parts import SEARCH_INPUT
from cedra.models.scene import load_shipped, shipped
from model_harness import run_coordinates

COMPLIANT = [s for s in shipped() if load_shipped(s).options.contact == "compliant"]
# how long each scene's main run is sampled: its stop time, at most 10 s; rubble3d's 7.5 s (the bump's speed loop,
# which has no heading hold, drives it off the grid's side after 9 s: its own scenario steers)
SECONDS = {"rubble3d": 7.5}
SEVERAL = {"step2d", "stairs2d", "stairs3d", "rubble3d", "rb_step2d"}      # wheels meet edges on the main run
def _calls(fn: ca.Function) -> list[str]:
    """The names of the functions an MX function calls (none for an SX function)."""
    if not fn.is_a("MXFunction"):
        return []
    return [fn.instruction_MX(k).which_function().name() for k in range(fn.n_instructions())
            if fn.instruction_id(k) == ca.OP_CALL]


def _rel(got, want, scale=0.0) -> float:
    """The largest difference relative to want's largest entry (or scale, where larger)."""
    got, want = np.array(got), np.array(want)
    return float(np.max(np.abs(got - want)) / max(np.max(np.abs(want)), scale, 1e-300)) if want.size else 0.0


@pytest.mark.parametrize("scene", COMPLIANT)
def test_parts_equal_the_monolithic_form(scene):
    sc = load_shipped(scene)
    m = sc.model()
    assert m.has_parts
    spec = sc.spec(m)
    mono, parts = m.functions(parts=False), m.functions()
    assert "cedra_part_dyn" in _calls(parts["cedra_f"]) and "cedra_part_dyn" not in _calls(mono["cedra_f"])
    par = np.array([p.start for p in spec.params])
    inp = np.array([p.start for p in spec.inputs])
    rng = np.random.default_rng(7)
    worst, several = 0.0, 0
    search = None
    if m.multi_contact:
        kin = m.parts.kin
        flag = m.parts.contact.flag
    poses = run_coordinates(scene, m, SECONDS.get(scene, min(sc.stop_time, 10.0)))
    for q in poses:
        u, a = rng.normal(0, 0.3, q.size), rng.normal(0, 1.0, q.size)
        # the settle residual f(q, 0) nearly vanishes at the run's poses (they are near equilibrium): it is held to
        # the generalized forces' own scale there, the forces at that pose and the random speeds
        forces = float(np.max(np.abs(np.array(mono["cedra_f"](q, u, inp, par)[0]))))
        for name, args in (("cedra_f", (q, u, inp, par)), ("cedra_rjac", (q, u, a, inp, par)),
                           ("cedra_settle", (q, inp, par))):
            for k, (got, want) in enumerate(zip(parts[name](*args), mono[name](*args))):
                err = _rel(got, want, forces if (name, k) == ("cedra_settle", 0) else 0.0)
                worst = max(worst, err)
                assert err <= 1e-12, (scene, name, k, q)
        if m.multi_contact:
            _, S = kin(q, u, inp, par)
            search = search or m._rim_search
            for k in range(len(m.rover.wheels)):
                s = search(np.array(S[SEARCH_INPUT * k:SEARCH_INPUT * (k + 1)]))
                several += not bool(flag(s))
    print(f"{scene}: worst {worst:.1e} relative; {several} wheel samples in the three-slot form")
    if scene in SEVERAL:
        assert several > 0
    if m.chassis:
        _chassis_parts_equal_the_monolithic_form(scene, m, mono, parts, poses, inp, par)


def _chassis_parts_equal_the_monolithic_form(scene, m, mono, parts, poses, inp, par):
    """cedra_fc and cedra_fcjac (the collision points' force and its Jacobian) at the run's poses and at the same
    poses pushed into the terrain by up to 0.25 m, so that some of the body's and links' points touch (in the same
    test as the scene's other functions: forming the monolithic form is most of its cost)."""
    # each point's law and its group's part are one conditional call, taken only where the point touches; the
    # points fixed in the body share one part
    calls = [f"cedra_point_{g.name}" for g in m.chassis_groups for _ in g.points]
    assert [c + "_touch" for c in calls] == [c for c in _calls(parts["cedra_fc"]) if c.endswith("_touch")]
    assert [c + "_jac_touch" for c in calls] == [c for c in _calls(parts["cedra_fcjac"]) if c.endswith("_touch")
                                                 and c.startswith("cedra_point_")]
    assert sum(len(g.points) for g in m.chassis_groups if g.name == "body") >= 3
    rng = np.random.default_rng(11)
    z = m.q_names.index("z")
    touched = 0
    for q in poses:
        for push in (0.0, rng.uniform(0.05, 0.25)):
            qq = q.copy()
            qq[z] -= push
            u = rng.normal(0, 0.3, q.size)
            fc = np.array(mono["cedra_fc"](qq, u, inp, par))
            touched += bool(np.any(fc != 0))
            assert _rel(parts["cedra_fc"](qq, u, inp, par), fc) <= 1e-12, (scene, qq)
            for got, want in zip(parts["cedra_fcjac"](qq, u, inp, par), mono["cedra_fcjac"](qq, u, inp, par)):
                assert _rel(got, want) <= 1e-12, (scene, qq)
    assert touched > 0


def test_the_wheel_part_is_formed_once():
    """One wheel-contact part serves every wheel: the composed cedra_rjac calls the same function for all six."""
    m = load_shipped("bump3d").model()
    P = m.parts.contact
    assert P.wrench_jac.n_in() == 4 and P.wrench_jac.size1_in(0) == 12
    names = _calls(m.functions()["cedra_rjac"])
    assert names.count("cedra_part_wheel_jac_forms") == 6, names
    assert rim.N_RESULT == P.wrench.size1_in(1)


@pytest.mark.parametrize("scene", ["stairs2d", "stairs3d", "rb_stairs3d"])
def test_a_point_grouped_in_a_body_moves_with_it_at_other_parameters(scene):
    """Each collision point of a body's group is o + R r at poses, speeds and parameter values other than those the
    grouping was checked at (its position and velocity against the description's own, to 1e-12 m): the fork's
    joint, which meets the fork's mass point only where fork_mass_at = 0, is a group of its own."""
    m = load_shipped(scene).model()
    planar = m.opt.dims == "2d"
    points = [pt for pt in m.rover.collision_points if (pt.planar_weight if planar else 1) != 0]
    rng = np.random.default_rng(5)
    par0 = m.default_par()
    grouped = 0
    for g in m.chassis_groups:
        if g.body is None:
            continue
        for k, j in enumerate(g.points):
            arm = g.body.inertia_frame @ g.local[:, k]
            err = ca.Function("err", [m.q, m.u, m.par], [ca.vertcat(
                points[j].position - g.body.position - arm,
                m.rate(points[j].position) - m.rate(g.body.position) - ca.cross(g.body.omega, arm))])
            for _ in range(2):
                par = par0 * (1 + 0.2 * rng.uniform(-1, 1, par0.size)) + 0.02 * rng.uniform(-1, 1, par0.size)
                e = np.array(err(rng.uniform(-0.8, 0.8, m.q.numel()), rng.normal(0, 1, m.q.numel()), par))
                assert np.max(np.abs(e)) <= 1e-12, (scene, j)
            grouped += 1
    assert grouped >= 10
