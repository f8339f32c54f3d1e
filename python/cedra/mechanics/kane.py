"""Kane's method for a system of rigid bodies and point masses (no CEDRA numbers here).

Describing a mechanism (bodies with positions and angular velocities as CasADi expressions of the generalized
coordinates q and speeds u, applied forces and torques) is separate from forming its equations, which this
module does: partial velocities are Jacobians of the velocities with respect to u, and

    M(q) udot = f(q, u)    with    M = sum m V_r.V_s + w_r.I w_s,
    f = F_r (generalized active forces) - sum [ m V_r.a0 + w_r.(I alpha0 + w x I w) ]

where a0, alpha0 are the accelerations at udot = 0. The generalized coordinates' rates are the generalized
speeds (qdot = u), so a velocity is jtimes(position, q, u).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca


@dataclass
class Body:
    """A rigid body (or a point mass: inertia None). `position` (world) is a function of q; `omega` (world
    angular velocity) is linear in u; `inertia_frame` is the world rotation of the frame in which the constant
    `inertia` (about the mass center) is diagonal/known."""
    name: str
    mass: ca.SX
    position: ca.SX
    omega: ca.SX | None = None
    inertia: ca.SX | None = None
    inertia_frame: ca.SX | None = None


@dataclass
class KaneSystem:
    q: ca.SX
    u: ca.SX
    bodies: list[Body] = field(default_factory=list)
    generalized_forces: ca.SX | None = None   # forces acting directly on coordinates (joint torques)
    point_forces: list[tuple[ca.SX, ca.SX]] = field(default_factory=list)  # (velocity of the point, force)

    def velocity(self, position):
        return ca.jtimes(position, self.q, self.u)

    def add_generalized_force(self, q_force):
        self.generalized_forces = q_force if self.generalized_forces is None else self.generalized_forces + q_force

    def add_point_force(self, point_velocity, force, partial_velocities=None):
        """A force applied at a material point whose velocity (linear in u) is given. partial_velocities: d v/d u
        when the caller has it (default: the Jacobian of point_velocity)."""
        if partial_velocities is None:
            partial_velocities = ca.jacobian(point_velocity, self.u)
        self.point_forces.append((partial_velocities, force))

    def add_torque(self, omega, torque):
        """A torque on a body with angular velocity omega (linear in u)."""
        self.add_generalized_force(ca.jacobian(omega, self.u).T @ torque)

    def equations(self):
        """(M, f): mass matrix and right-hand side of Kane's equations M udot = f."""
        n = self.u.numel()
        M = ca.SX.zeros(n, n)
        f = ca.SX.zeros(n, 1) if self.generalized_forces is None else self.generalized_forces
        for b in self.bodies:
            v = self.velocity(b.position)
            Jv = ca.jacobian(v, self.u)
            a0 = ca.jtimes(v, self.q, self.u)          # acceleration at udot = 0
            M += b.mass * (Jv.T @ Jv)
            f -= b.mass * (Jv.T @ a0)
            if b.inertia is not None:
                R = b.inertia_frame
                I = R @ b.inertia @ R.T
                Jw = ca.jacobian(b.omega, self.u)
                alpha0 = ca.jtimes(b.omega, self.q, self.u)
                M += Jw.T @ I @ Jw
                f -= Jw.T @ (I @ alpha0 + ca.cross(b.omega, I @ b.omega))
        for partials, force in self.point_forces:
            f += partials.T @ force
        return M, f

    def kinetic_energy(self):
        T = 0
        for b in self.bodies:
            v = self.velocity(b.position)
            T += 0.5 * b.mass * ca.dot(v, v)
            if b.inertia is not None:
                R = b.inertia_frame
                T += 0.5 * ca.dot(b.omega, R @ b.inertia @ R.T @ b.omega)
        return T
