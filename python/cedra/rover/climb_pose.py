"""A planar rover's poses on a staircase (cedra.rover.profile) and the balance's terms at a pose, from the rover's
own description (`RoverKind.describe`: the same CasADi graph the plant is built from).

The planar rover has the scene coordinates of a 2D scene (`RoverKind.planar`); its free coordinates are those
minus the spins and the steering joints (2D CEDRA: x, z, pitch, theta1, theta4; the rocker-bogie: x, z, pitch,
beta_L). Twins the planar map merges (a left wheel and its right twin) form one wheel group, the group's own wheel
being the one whose spin the scene keeps; in 2D both carry the same force.

**The pose at the body's position x** puts every wheel the pose holds down as low as the profile and the joint
stops allow (the sum of their centres' heights weighted by their loads at rest least, every wheel at least its
radius from the profile, every joint within its stops), and whatever freedom that leaves (a released wheel's joint, a joint a stop keeps from
reaching) to the least potential energy (gravity, joint springs). Where every wheel can touch, the passive joints
leave one way to do so at each x, and this is that pose: the field's static analysis keeps every wheel on the
ground, and the balance then says whether that can hold. Where a stop keeps one off, the wheels that carry more of
the rover stay down. A wheel released from the pose hangs where its joint's
spring and weight put it (CEDRA's fork wheel where the body is pitched up more than its spring reaches), or rests
on the ground if that is lower. (The weight alone does not choose the pose: on frictionless contacts at a fixed x
it would lift the rear wheel of a rover pushed against an edge, where with friction the rear wheel pushes.)
**A lift-off pose** pins one group's wheel centre where it touches a riser and the tread below at once, x free
(profile.Staircase.lift_off).

**The balance's terms** (cedra.rover.required_friction solves it): along every free coordinate, the generalized
force of each contact force (a normal force N along the contact normal n, a traction T along t = axle x n, at the
rim point c - R_w n; by virtual work, the wheels' spins held) plus gravity and the joints' own torques at rest
(springs, stops; mechanics.statics.with_body_work), plus a joint stop's reaction where a joint rests on its stop.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from cedra.mechanics.rover_kind import SPINS, RoverKind
from cedra.mechanics.statics import with_body_work

CONTACT_GAP = 1e-7          # m: a wheel this close to a block of the profile touches it
STOP_GAP = 1e-7             # rad: a joint this close to its stop rests on it
CLOSURE_MARGIN = 1e-9       # a closed chain's closure (|closure| < 1 where it assembles) is kept this far inside
IPOPT = {"ipopt.print_level": 0, "print_time": 0, "ipopt.sb": "yes", "ipopt.tol": 1e-12,
         "ipopt.constr_viol_tol": 1e-12, "ipopt.max_iter": 500,
         # no early stop at IPOPT's "acceptable" level (1e-6): a wheel would be left 0.6 mm above the ground
         "ipopt.acceptable_tol": 1e-10, "ipopt.acceptable_constr_viol_tol": 1e-10,
         # the bounds as they are: IPOPT's default relaxes them by 1e-8, a contact's gap by as much
         "ipopt.bound_relax_factor": 0.0}


class PoseError(ValueError):
    """The rover's geometry cannot form a pose on the profile."""


@dataclass
class Contact:
    group: int                  # index of the wheel group
    wheel: int                  # the group's own wheel number
    block: int                  # the profile's block touched (profile.Staircase.blocks: 0 the ground, k above
    #                             riser k): its top is a tread, its left side riser k's face, their corner its edge
    point: np.ndarray           # (x, z) on the profile
    normal: np.ndarray          # (x, z) unit, from the profile to the wheel centre


@dataclass
class Pose:
    x: float                    # the body's mass centre
    coords: np.ndarray          # the free coordinates
    centres: np.ndarray         # (groups, 2): each group's wheel centre (x, z)
    contacts: list[Contact]
    stops: list[tuple[int, int]]  # (free coordinate index, +1 at its lower stop / -1 at its upper): resting there
    clearance: float            # m: the lowest collision point's height above the profile (inf: none)
    pinned: int | None = None   # the group whose lift-off pose this is
    riser: int | None = None    # the riser it lifts off at
    gaps: np.ndarray = field(default_factory=lambda: np.zeros(0))   # (groups,) the wheels' least gaps


class PlanarRover:
    """A rover kind's planar model with its parameter values: geometry, poses and the balance's terms."""

    def __init__(self, kind: RoverKind, params: dict | None = None):
        kind.check()
        self.kind = kind
        values = {q.name: q.start for q in kind.parameters}
        unknown = sorted(set(params or {}) - set(values))
        if unknown:
            raise ValueError(f"rover {kind.name} has no parameters {unknown}")
        values.update(params or {})
        self.values = values
        self.radius = float(values["R_w"])
        planar = kind.planar
        scene = [n for n in kind.coordinates if planar.get(n, n) == n]
        self.free = [n for n in scene if n not in SPINS and n not in kind.steering]
        if "x" not in self.free or "z" not in self.free or "pitch" not in self.free:
            raise ValueError(f"rover {kind.name}: its planar coordinates lack x, z or pitch")
        self._build(planar)
        self._solvers: dict[int, ca.Function] = {}

    # ---------------------------------------------------------------------------------------------- the model

    def _build(self, planar):
        kind, names = self.kind, self.kind.coordinates
        nf = len(self.free)
        # D maps the free coordinates' rates to the full coordinates' (a merged coordinate moves with its keeper)
        D = ca.DM([[1.0 if planar.get(n, n) == f else 0.0 for f in self.free] for n in names])
        q, qd = ca.SX.sym("q", len(names)), ca.SX.sym("qd", len(names))
        psym = {x.name: ca.SX.sym(x.name) for x in kind.parameters}
        par = ca.vertcat(*psym.values())
        self.par = np.array([float(self.values[x.name]) for x in kind.parameters])
        rover = kind.describe(q, lambda e: ca.jtimes(e, q, qd), psym, ca.SX.zeros(6), None)
        v = ca.SX.sym("v", nf)
        q_of_v = D @ v
        # wheel groups: a wheel and the twins whose spins the planar map merges into its spin
        keeper = {w.index: int(planar.get(f"gamma{w.index}", f"gamma{w.index}")[len("gamma"):])
                  for w in rover.wheels}
        self.groups = sorted(set(keeper.values()))
        members = {g: [w for w in rover.wheels if keeper[w.index] == g] for g in self.groups}
        own = {w.index: w for w in rover.wheels}
        centres = ca.horzcat(*[ca.vertcat(own[g].center[0], own[g].center[2]) for g in self.groups])
        points = [c.position for c in rover.collision_points]
        cp = ca.horzcat(*[ca.vertcat(pt[0], pt[2]) for pt in points]) if points else ca.SX.zeros(2, 0)
        self.geometry = ca.Function("geometry", [v, par], [ca.substitute(e, q, q_of_v) for e in
                                                         (centres, rover.potential, rover.closure, cp)],
                                    ["v", "par"], ["centres", "V", "closure", "points"])
        self._potential, self._closure, self._centres = (ca.substitute(e, q, q_of_v) for e in
                                                         (rover.potential, rover.closure, centres))
        self._v, self._psym, self._par = v, psym, par
        # the balance's columns: the generalized force of a unit normal force and a unit traction on a group's
        # wheels, with the contact normal n = (nx, 0, nz) as an argument
        n2 = ca.SX.sym("n", 2)
        n3 = ca.vertcat(n2[0], 0, n2[1])
        col_n, col_t = [], []
        for g in self.groups:
            cn, ct = ca.SX.zeros(nf), ca.SX.zeros(nf)
            for w in members[g]:
                rim = w.velocity + ca.cross(w.omega, -psym["R_w"] * n3)    # the rim point's velocity, spins at 0
                J = ca.substitute(ca.jacobian(rim, qd), qd, ca.DM.zeros(qd.numel())) @ D
                cn += J.T @ n3
                ct += J.T @ ca.cross(w.axle, n3)
            col_n.append(cn)
            col_t.append(ct)
        work = with_body_work(0, rover, q, qd, 0, psym["g"])
        q0 = ca.substitute(ca.jacobian(work, qd), qd, ca.DM.zeros(qd.numel())) @ D
        sub = [ca.substitute(e, q, q_of_v) for e in (ca.horzcat(*col_n), ca.horzcat(*col_t), q0.T)]
        self.columns = ca.Function("columns", [v, n2, par], sub, ["v", "n", "par"], ["N", "T", "Q0"])
        self.multiplicity = [len(members[g]) for g in self.groups]
        self.hold = np.ones(len(self.groups))      # set by hold_weights once the balance can be formed
        # the joints' stops on free coordinates, as numbers
        self.stop_limits = {}
        for stop in kind.stops:
            if stop.coordinate in self.free:
                self.stop_limits[self.free.index(stop.coordinate)] = tuple(float(x) for x in stop.limits(self.values))

    def hold_weights(self, loads: np.ndarray) -> None:
        """The weight each held-down group's centre height gets in the pose's objective: 100 times its load at
        rest in the design pose (`loads`, per group's wheel, times its twins), so that where not every wheel can
        touch, the wheels that carry the rover stay down (the work of the static loads least); 100 times, so that
        the joints' own potential (gravity on the joints, springs) cannot lift a wheel that can touch (an exact
        penalty: a wheel held down rests on its constraint)."""
        self.hold = 100.0 * np.maximum(np.asarray(loads, dtype=float) * self.multiplicity, 1e-3 * max(loads))

    def design_coords(self) -> np.ndarray:
        """The free coordinates of the design pose over flat ground at x = 0."""
        design = self.kind.design(self.values)
        return np.array([float(design.get(n, 0.0)) for n in self.free])

    def closure(self, v) -> float:
        return float(self.geometry(v, self.par)[2])

    def check_design(self) -> np.ndarray:
        """The design pose, or a PoseError when its closed chain cannot be assembled."""
        v = self.design_coords()
        c = self.closure(v)
        if not np.isfinite(c) or abs(c) >= 1:
            raise PoseError(f"rover {self.kind.name}: its design pose cannot be assembled (closure {c:.6g}; a "
                            "closed chain's links meet only where |closure| < 1)")
        return v

    # ----------------------------------------------------------------------------------------------- the poses

    def _solver(self, n_blocks: int) -> ca.Function:
        if n_blocks not in self._solvers:
            v, R = self._v, self._psym["R_w"]
            blocks = ca.SX.sym("blocks", 2, n_blocks)
            targets = ca.SX.sym("targets", 2, len(self.groups))
            gaps = []
            for k in range(len(self.groups)):
                c = self._centres[:, k]
                for j in range(n_blocks):
                    gaps.append(_distance(c, blocks[:, j]) - R)
            g = ca.vertcat(*gaps, self._closure, ca.vec(self._centres - targets))
            # the wheels held down weigh `down` each (hold_weights), the rest of the pose follows the potential
            down = ca.SX.sym("down", len(self.groups))
            f = ca.dot(down, self._centres[1, :].T) + self._potential
            nlp = {"x": v, "p": ca.vertcat(self._par, ca.vec(blocks), ca.vec(targets), down), "f": f, "g": g}
            self._solvers[n_blocks] = ca.nlpsol(f"pose_{self.kind.name}", "ipopt", nlp, IPOPT)
        return self._solvers[n_blocks]

    def pose(self, blocks: np.ndarray, x: float | None, guess: np.ndarray, pin: tuple[int, np.ndarray] | None = None,
             released: tuple = (), where: str = "") -> tuple[np.ndarray, dict]:
        """The free coordinates of the pose at body position x (None with a pin: free) from `guess`; pin: (group
        index, its wheel centre (x, z)); released: the groups not held down. Raises PoseError where no pose is
        found."""
        nb, ng = len(blocks), len(self.groups)
        solver = self._solver(nb)
        lbx, ubx = np.full(len(self.free), -np.inf), np.full(len(self.free), np.inf)
        ix = self.free.index("x")
        if x is not None:
            lbx[ix] = ubx[ix] = x
        for j, (lo, hi) in self.stop_limits.items():
            lbx[j], ubx[j] = lo, hi
        n_gap = ng * nb
        lbg = np.concatenate([np.zeros(n_gap), [-1 + CLOSURE_MARGIN], np.full(2 * ng, -np.inf)])
        ubg = np.concatenate([np.full(n_gap, np.inf), [1 - CLOSURE_MARGIN], np.full(2 * ng, np.inf)])
        targets = np.zeros((2, ng))
        if pin is not None:
            k, centre = pin
            targets[:, k] = centre
            lbg[n_gap + 1 + 2 * k: n_gap + 3 + 2 * k] = 0.0
            ubg[n_gap + 1 + 2 * k: n_gap + 3 + 2 * k] = 0.0
            # the pinned centre is a radius from the profile by construction; its own gaps, active too, would make
            # the constraints dependent
            lbg[k * nb:(k + 1) * nb] = -np.inf
        down = np.array([0.0 if k in released else self.hold[k] for k in range(ng)])
        # ca.vec is column-major: the 2 x n symbols take blocks (one row (x, z) per block) row by row, and
        # targets (2 x groups) column by column
        p = np.concatenate([self.par, _finite(blocks).ravel(), targets.T.ravel(), down])
        # from the guess, else from the design's joint angles lifted clear of the profile at the guess's x
        lifted = self.design_coords()
        lifted[ix] = guess[ix]
        lifted[self.free.index("z")] += float(np.max(blocks[:, 1])) + self.radius
        for start in (guess, lifted):
            sol = solver(x0=np.clip(start, lbx, ubx), p=p, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg)
            stats = solver.stats()
            v = np.array(sol["x"]).ravel()
            g = np.array(sol["g"]).ravel()
            closure = g[n_gap]
            gaps = g[:n_gap] if pin is None else np.delete(g[:n_gap], np.s_[pin[0] * nb:(pin[0] + 1) * nb])
            if stats["success"] and np.min(gaps, initial=0.0) >= -1e-9 and abs(closure) < 1:
                break
        else:
            reason = stats["return_status"]
            if abs(closure) >= 1 - 2 * CLOSURE_MARGIN:
                reason += f"; its closed chain is at the edge of assembly (closure {closure:.9g})"
            raise PoseError(f"rover {self.kind.name} cannot form a pose {where}: {reason}")
        return v, stats

    def describe_pose(self, v, blocks, profile_height, pinned=None, riser=None) -> Pose:
        """The contacts, stops and clearance of the pose with free coordinates v."""
        centres, _, _, points = (np.array(e) for e in self.geometry(v, self.par))
        centres = centres.reshape(2, -1).T
        contacts, least = [], []
        for k, g in enumerate(self.groups):
            found, gap_k = [], np.inf
            for j, (e, top) in enumerate(blocks):
                point = np.array([max(centres[k][0], e), min(centres[k][1], top)])
                d = np.linalg.norm(centres[k] - point)
                if d < 1e-12:
                    raise PoseError(f"rover {self.kind.name}: wheel {g}'s centre is inside the profile at "
                                    f"({centres[k][0]:.4f}, {centres[k][1]:.4f}) m")
                gap_k = min(gap_k, d - self.radius)
                if d - self.radius < CONTACT_GAP:
                    found.append(Contact(k, g, j, point, (centres[k] - point) / d))
            contacts += found
            least.append(gap_k)
        stops = []
        for j, (lo, hi) in self.stop_limits.items():
            if v[j] - lo < STOP_GAP:
                stops.append((j, +1))
            elif hi - v[j] < STOP_GAP:
                stops.append((j, -1))
        points = points.reshape(2, -1).T if points.size else np.zeros((0, 2))
        clearance = float(np.min(points[:, 1] - profile_height(points[:, 0]))) if len(points) else np.inf
        ix = self.free.index("x")
        return Pose(float(v[ix]), v, centres, contacts, stops, clearance, pinned, riser, np.array(least))

    def terms(self, pose: Pose):
        """The balance's columns at a pose: (N columns, T columns) per contact, the stops' reaction columns and
        the right-hand side -Q0 (gravity and the joints' own torques), all along the free coordinates."""
        cols_n, cols_t = [], []
        for c in pose.contacts:
            n_col, t_col, _ = self.columns(pose.coords, c.normal, self.par)
            cols_n.append(np.array(n_col)[:, c.group])
            cols_t.append(np.array(t_col)[:, c.group])
        q0 = np.array(self.columns(pose.coords, np.array([0.0, 1.0]), self.par)[2]).ravel()
        nf = len(self.free)
        cols_s = [sign * np.eye(nf)[j] for j, sign in pose.stops]
        shape = (nf, 0)
        stack = (lambda cols: np.array(cols).T if cols else np.zeros(shape))
        return stack(cols_n), stack(cols_t), stack(cols_s), -q0

    def offsets(self) -> tuple[float, float]:
        """The foremost and rearmost wheel centres' x relative to the body's in the design pose."""
        centres = np.array(self.geometry(self.check_design(), self.par)[0])
        return float(centres[0].max()), float(centres[0].min())


def _distance(c, block):
    """The signed distance from point c to the quadrant {x >= e, z <= H} (CasADi): continuously differentiable
    outside it, minus the depth below its nearer side inside (so that an iterate inside is pushed out)."""
    dx, dz = ca.fmax(0, block[0] - c[0]), ca.fmax(0, c[1] - block[1])
    inside = ca.logic_and(c[0] >= block[0], c[1] <= block[1])
    # + (1e-9 m)^2: a finite derivative on the boundary (the distance changes by 1e-18 m / R)
    return ca.if_else(inside, -ca.fmin(c[0] - block[0], block[1] - c[1]), ca.sqrt(dx * dx + dz * dz + 1e-18))


def _finite(blocks: np.ndarray) -> np.ndarray:
    """The ground's block (e = -inf) as a number the solver takes: far enough left that no wheel is near."""
    out = blocks.copy()
    out[~np.isfinite(out[:, 0]), 0] = -1e6
    return out
