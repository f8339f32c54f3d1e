"""The friction a climb requires, for any rover description: the field's quasi-static metric (Thueer, Krebs,
Siegwart, IROS 2006: "a static 2D approach that includes optimization of the wheel torques in order to minimize the
required friction").

`required_friction(kind, profile)` takes the planar rover (cedra.rover.climb_pose) up a sharp staircase
(cedra.rover.profile) one phase at a time, in the order the rover meets them: each wheel group over each riser, its
centre along its path from the lift-off (touching the riser and its tread at once, the tread's load gone: the
moment it starts up) up the face and around the edge, every `ds`, the other wheels held down. (Between phases
every wheel stands on a tread and no traction is needed.) At each pose the balance along the free coordinates, with
no acceleration,

    sum_k (N_k col_N,k + T_k col_T,k) + sum_j lambda_j col_stop,j = -Q0,   N_k >= 0, lambda_j >= 0,

has more unknowns than equations (2D CEDRA: 5 equations, 8 forces with four wheel groups touching); the tractions
are distributed to minimize the largest friction ratio r = max_k |T_k| / N_k. That is a generalized
linear-fractional program, solved exactly by Dinkelbach's iteration in the form of Crouzeix, Ferland and Schaible
(each step a linear program, HiGHS): from a balance found first, each step minimizes t subject to
|T_k| - r N_k <= t N_k(previous), and r becomes the new balance's largest ratio, until t = 0. A pose with no balance
at N >= 0 (the rover would tip, or hang on a wheel that cannot push) requires infinite friction. The climb requires
the largest over its poses.

Per pose also: the torque the climb needs (R_w T summed over a wheel's contacts, the largest over the wheels, the
least such at the optimal ratio), and the same ratio and torque with equal torques on every wheel that touches
(the main job's controller). Twins of a group carry the same forces. Where the rover's body or links reach below
the profile (its collision points), the pose's `clearance` is negative: the chassis would hang on the obstacle.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linprog

from cedra.mechanics.rover_kind import RoverKind
from cedra.rover.climb_pose import PlanarRover, Pose, PoseError
from cedra.rover.profile import Staircase

__all__ = ["required_friction", "step_curve", "Climb", "PoseResult", "PoseError", "Staircase"]

HIGHS = {}                      # HiGHS' own tolerances (1e-7): tighter ones call feasible balances infeasible
FORCE_BOUND = 1e3               # |forces| <= this times the balance's largest term: keeps each program bounded
ITERATIONS = 60
HANGS = 1e-10                   # m: a released wheel this far off the ground hangs (the poses are solved to 1e-12)
RATIO_BOUND = 1e3               # a pose that needs a larger friction ratio than this needs more than any ground has


@dataclass
class PoseResult:
    x: float                    # the body's mass centre
    label: str                  # the wheels touching a riser ("" on the treads)
    ratio: float                # the least largest friction ratio (inf: no balance)
    torque: float               # N.m: the largest wheel torque at that ratio (the least such)
    ratio_equal: float          # the same with equal torques on every wheel that touches
    torque_equal: float
    loads: dict                 # wheel -> N at the optimal distribution (summed over its contacts)
    ratios: dict                # wheel -> |T| / N there
    clearance: float            # m: the body's and links' lowest point above the profile (< 0: it would touch)
    phase: tuple                # (wheel, riser): the wheel climbing that riser (1-based)
    s: float                    # m: how far its centre is along its path from the lift-off (0: the lift-off)
    stops: tuple                # the joints resting on a stop
    hanging: tuple = ()         # wheels released from the pose that hang (carry nothing)
    wedged: bool = False        # the least ratio needs forces at the programs' bound (FORCE_BOUND): the rover
                                # squeezes itself between the risers, the ratio is approached only as those internal
                                # forces grow without bound, and the torque there is the bound's, not the climb's


@dataclass
class Climb:
    rover: str
    profile: Staircase
    ds: float
    poses: list[PoseResult]

    def _worst(self, key) -> PoseResult:
        return max(self.poses, key=lambda p: (getattr(p, key), -p.x))

    @property
    def worst(self) -> PoseResult:
        return self._worst("ratio")

    @property
    def worst_equal(self) -> PoseResult:
        return self._worst("ratio_equal")

    @property
    def ratio(self) -> float:
        return self.worst.ratio

    @property
    def ratio_equal(self) -> float:
        return self.worst_equal.ratio_equal

    @property
    def torque(self) -> float:
        """The largest wheel torque over the poses at their optimal distributions (wedged poses left out: their
        torque is the force bound's; nan where every pose is wedged or has no balance)."""
        finite = [p.torque for p in self.poses if math.isfinite(p.ratio) and not p.wedged]
        return max(finite) if finite else math.nan

    @property
    def wedged(self) -> bool:
        """Whether the worst pose is wedged (PoseResult.wedged): its ratio is a limit the rover reaches only by
        squeezing itself between the risers with unbounded internal forces."""
        return self.worst.wedged

    @property
    def clearance(self) -> float:
        return min(p.clearance for p in self.poses)


# ------------------------------------------------------------------------------------------- the programs

def _ratio(N, T) -> float:
    scale = max(1.0, float(np.max(np.abs(N), initial=0.0)))
    r = 0.0
    for n, t in zip(N, T):
        if n > 1e-12 * scale:
            r = max(r, abs(t) / n)
        elif abs(t) > 1e-9 * scale:
            return math.inf
    return r


class Balance:
    """The balance at one pose: A u = rhs, u = (N, T, stop reactions), and the wheels' torques."""

    def __init__(self, cols_n, cols_t, cols_s, rhs, groups, radius, equal):
        self.nc, self.ns = cols_n.shape[1], cols_s.shape[1]
        self.groups = list(groups)
        A = np.hstack([cols_n, cols_t, cols_s])
        rows, b = [A], [rhs]
        # each touching group's torque: R_w times its contacts' tractions
        touched = sorted(set(groups))
        self.torque_rows = np.zeros((len(touched), A.shape[1]))
        for i, g in enumerate(touched):
            for k, gk in enumerate(groups):
                if gk == g:
                    self.torque_rows[i, self.nc + k] = radius
        if equal and len(touched) > 1:
            rows.append(self.torque_rows[1:] - self.torque_rows[0])
            b.append(np.zeros(len(touched) - 1))
        self.A, self.b = np.vstack(rows), np.concatenate(b)
        self.big = big = FORCE_BOUND * max(1.0, float(np.max(np.abs(rhs), initial=0.0)))
        self.bounds = [(0, big)] * self.nc + [(-big, big)] * self.nc + [(0, big)] * self.ns

    def _solve(self, c, A_ub, b_ub, extra_bounds):
        pad = len(extra_bounds)
        A_eq = np.hstack([self.A, np.zeros((self.A.shape[0], pad))])
        res = linprog(c, A_ub=A_ub, b_ub=b_ub, A_eq=A_eq, b_eq=self.b, bounds=self.bounds + extra_bounds,
                      method="highs", options=HIGHS)
        return res if res.status == 0 else None

    def at_bound(self, u) -> bool:
        """Whether a balance u has a force at the programs' bound (a wedge: see PoseResult.wedged)."""
        return u is not None and bool(np.max(np.abs(u), initial=0.0) >= 0.999 * self.big)

    def _split(self, u):
        nc = self.nc
        return u[:nc], u[nc:2 * nc], u[2 * nc:2 * nc + self.ns]

    def least_ratio(self) -> tuple[float, np.ndarray | None]:
        """The least largest friction ratio and a balance that has it (None: no balance with N >= 0)."""
        nc, nu = self.nc, self.A.shape[1]
        if nc == 0:
            return math.inf, None
        # a first balance: the least summed |T| (auxiliary a_k >= |T_k|) among those within RATIO_BOUND
        A_ub = np.zeros((4 * nc, nu + nc))
        for k in range(nc):
            A_ub[4 * k, nc + k], A_ub[4 * k, nu + k] = 1, -1
            A_ub[4 * k + 1, nc + k], A_ub[4 * k + 1, nu + k] = -1, -1
            A_ub[4 * k + 2, nc + k], A_ub[4 * k + 2, k] = 1, -RATIO_BOUND
            A_ub[4 * k + 3, nc + k], A_ub[4 * k + 3, k] = -1, -RATIO_BOUND
        c = np.concatenate([np.zeros(nu), np.ones(nc)])
        res = self._solve(c, A_ub, np.zeros(4 * nc), [(0, None)] * nc)
        if res is None:
            return math.inf, None
        u = res.x[:nu]
        r = min(_ratio(*self._split(u)[:2]), RATIO_BOUND)
        for _ in range(ITERATIONS):
            N, T, _ = self._split(u)
            g = N / max(float(N.max()), 1e-300)     # the previous balance's loads, scaled
            A_ub = np.zeros((2 * nc, nu + 1))
            for k in range(nc):
                A_ub[2 * k, k], A_ub[2 * k, nc + k], A_ub[2 * k, nu] = -r, 1, -g[k]
                A_ub[2 * k + 1, k], A_ub[2 * k + 1, nc + k], A_ub[2 * k + 1, nu] = -r, -1, -g[k]
            c = np.zeros(nu + 1)
            c[-1] = 1
            res = self._solve(c, A_ub, np.zeros(2 * nc), [(None, 0)])
            if res is None or res.x[-1] > -1e-13:
                break
            u_new = res.x[:nu]
            r_new = _ratio(*self._split(u_new)[:2])
            if not r_new < r:
                break
            u, r = u_new, r_new
        return r, u

    def least_torque(self, ratio) -> tuple[float, np.ndarray]:
        """The least largest wheel torque among the balances whose ratios stay within `ratio`."""
        nc, nu = self.nc, self.A.shape[1]
        rho = ratio * (1 + 1e-9) + 1e-12
        nt = len(self.torque_rows)
        A_ub = np.zeros((2 * nc + 2 * nt, nu + 1))
        for k in range(nc):
            A_ub[2 * k, k], A_ub[2 * k, nc + k] = -rho, 1
            A_ub[2 * k + 1, k], A_ub[2 * k + 1, nc + k] = -rho, -1
        for i, row in enumerate(self.torque_rows):
            A_ub[2 * nc + 2 * i, :nu], A_ub[2 * nc + 2 * i, nu] = row, -1
            A_ub[2 * nc + 2 * i + 1, :nu], A_ub[2 * nc + 2 * i + 1, nu] = -row, -1
        c = np.zeros(nu + 1)
        c[-1] = 1
        res = self._solve(c, A_ub, np.zeros(len(A_ub)), [(0, None)])
        if res is None:
            raise RuntimeError("the least-torque program found no balance at the least ratio")
        return float(res.x[-1]), res.x[:nu]


# ------------------------------------------------------------------------------------------------ the climb

def _label(pose: Pose, profile: Staircase) -> str:
    parts = []
    for c in pose.contacts:
        if abs(c.normal[0]) <= 1e-9:
            continue                    # a tread
        edge = c.normal[1] > 1e-9       # the block's corner (the face's normal is horizontal)
        parts.append(f"wheel {c.wheel} at riser {c.block} ({'edge' if edge else 'face'})")
    return ", ".join(dict.fromkeys(parts))


def _evaluate(rover: PlanarRover, pose: Pose, profile: Staircase, phase) -> PoseResult:
    cols_n, cols_t, cols_s, rhs = rover.terms(pose)
    groups = [c.group for c in pose.contacts]
    out = {}
    for equal in (False, True):
        balance = Balance(cols_n, cols_t, cols_s, rhs, groups, rover.radius, equal)
        r, u_ratio = balance.least_ratio()
        if math.isfinite(r):
            torque, u = balance.least_torque(r)
        else:
            torque, u = math.nan, None
        out[equal] = (r, torque, u, balance, u_ratio)
    r, torque, u, balance, u_ratio = out[False]
    # the least ratio's balance with forces at the bound: the ratio falls further as the bound grows (a wedge's
    # internal forces); flagged rather than quoted as if the bound were the rover's
    wedged = math.isfinite(r) and balance.at_bound(u_ratio)
    loads, ratios = {}, {}
    if u is not None:
        N, T, _ = balance._split(u)
        for c, n, t in zip(pose.contacts, N, T):
            loads[c.wheel] = loads.get(c.wheel, 0.0) + float(n)
            ratios[c.wheel] = max(ratios.get(c.wheel, 0.0), abs(float(t)) / float(n) if n > 0 else 0.0)
    stops = tuple(f"{rover.free[j]} at its {'lower' if s > 0 else 'upper'} stop" for j, s in pose.stops)
    touching = {c.group for c in pose.contacts}
    hanging = tuple(g for k, g in enumerate(rover.groups) if k not in touching)
    return PoseResult(pose.x, _label(pose, profile), r, torque, out[True][0], out[True][1], loads, ratios,
                      pose.clearance, phase[:2], phase[2], stops, hanging, wedged)


def _settle(rover: PlanarRover, profile: Staircase, blocks, guess, phase, where) -> tuple[Pose, PoseResult]:
    """The pose with group k's wheel centre at `centre` climbing `riser` (phase = (k, riser, s, centre)) and its
    result: of the pose with every other wheel held down, those with one other wheel released (climb_pose: its
    joint settles where its spring and weight put it, the wheel hanging there carries nothing, or it rests on the
    ground) and the pose at the same body position with the climbing wheel released (the others carry it over the
    riser where it leaves it), the one that requires the least friction. The poses are geometric, so a sprung
    joint carries what its spring gives at the pose's angle: without these alternatives a fork wheel at its
    spring's rest angle could only be loaded through its own traction's moment. (Held down, a wheel whose spring pulls it up keeps its load only by the
    moment of its own traction about its joint.)"""
    k, riser, s, centre = phase

    def settle(released):
        v, _ = rover.pose(blocks, None, guess, pin=(k, centre), released=released, where=where)
        pose = rover.describe_pose(v, blocks, profile.height, k, riser)
        # the climbing wheel has left its tread: only the riser carries it (at the lift-off it touches both); a
        # released wheel its joint holds off the ground by any margin carries nothing
        pose.contacts = [c for c in pose.contacts if not (c.group == k and c.block == riser)
                         and not (c.group in released and pose.gaps[c.group] > HANGS)]
        return pose

    def evaluate(pose):
        return pose, _evaluate(rover, pose, profile, (rover.groups[k], riser + 1, s))

    best = evaluate(settle(()))
    # the climbing wheel carried by the others at the same body position, if it leaves the riser so
    try:
        v, _ = rover.pose(blocks, best[0].x, best[0].coords, released=(k,), where=where)
        carried = rover.describe_pose(v, blocks, profile.height, k, riser)
    except PoseError:
        carried = None              # it cannot be carried there: the pose that climbs stands
    if carried is not None and carried.gaps[k] > HANGS:
        candidate = evaluate(carried)
        if candidate[1].ratio < best[1].ratio:
            best = candidate
    for other in range(len(rover.groups)):
        if other == k:
            continue
        try:
            hung = settle((other,))
        except PoseError:
            continue                # that wheel cannot be released here: the pose held down stands
        # a released wheel that comes to rest on the ground leaves the pose held down, unless its joint settles
        # elsewhere (then it is another pose the rover can take)
        if hung.gaps[other] > HANGS or np.max(np.abs(hung.coords - best[0].coords)) > 1e-6:
            candidate = evaluate(hung)
            if candidate[1].ratio < best[1].ratio:
                best = candidate
    return best


def _rest_loads(rover: PlanarRover, blocks, design) -> np.ndarray:
    """Each group's wheel load at rest in the design pose over flat ground (no tractions)."""
    pose = rover.describe_pose(design, blocks[:1], lambda x: np.zeros_like(x))
    cols_n, cols_t, cols_s, rhs = rover.terms(pose)
    balance = Balance(cols_n, cols_t, cols_s, rhs, [c.group for c in pose.contacts], rover.radius, False)
    r, _ = balance.least_ratio()
    if not math.isfinite(r):
        raise PoseError(f"rover {rover.kind.name}: no balance holds it at rest in its design pose")
    _, u = balance.least_torque(r)
    loads = np.zeros(len(rover.groups))
    for c, n in zip(pose.contacts, u[:balance.nc]):
        loads[c.group] += n
    return loads


def _roll_to(rover: PlanarRover, blocks, v, k, target, ds, ix, iz) -> np.ndarray:
    """A guess for the pose with group k's wheel at `target` (its next lift-off): from the last pose, the wheel rolled
    there along its tread in steps of ds, the others held down (on stairs a pose shifted at once would put wheels
    inside the profile); the last pose moved by the wheel's offset where a step fails."""
    start = np.array(rover.geometry(v, rover.par)[0])[:, k]
    n = max(1, int(math.ceil(np.linalg.norm(target - start) / ds)))
    guess = v.copy()
    try:
        for t in np.linspace(0, 1, n + 1)[1:]:
            guess, _ = rover.pose(blocks, None, guess, pin=(k, start + t * (target - start)))
        return guess
    except PoseError:
        shifted = v.copy()
        shifted[ix] += target[0] - start[0]
        shifted[iz] += target[1] - start[1]
        return shifted


def required_friction(kind: RoverKind, profile: Staircase, params: dict | None = None, ds: float | None = None,
                      rover: PlanarRover | None = None) -> Climb:
    """The climb of `kind` (its parameters' defaults, updated by `params`) up `profile`: every pose's required
    friction and torques (see the module's docstring). ds: the spacing of the poses along each climbing wheel's
    path (default R_w / 8). rover: a PlanarRover of the same kind and parameters to reuse (its programs are formed
    once). Raises PoseError where the rover's geometry cannot form a pose, ValueError for a profile it cannot
    stand on."""
    rover = rover or PlanarRover(kind, params)
    R = rover.radius
    profile.check(R)
    ds = ds or R / 8
    blocks = profile.blocks()
    design = rover.check_design()
    rover.hold_weights(_rest_loads(rover, blocks, design))
    ix, iz = rover.free.index("x"), rover.free.index("z")
    offsets = np.array(rover.geometry(design, rover.par)[0])[0] - design[ix]
    # the phases in the order the rover meets them: the body's x when the wheel reaches the riser
    phases = sorted(((edge - offsets[k], k, riser) for k in range(len(rover.groups))
                     for riser, edge in enumerate(profile.edges()) if profile.rise > 0))
    results, v = [], design.copy()
    for _, k, riser in phases:
        path = profile.path(riser, R, ds)
        v = _roll_to(rover, blocks, v, k, path[0][1], ds, ix, iz)
        for s, centre in path:
            where = (f"on {_what(profile)} with wheel {rover.groups[k]} at riser {riser + 1}, {s:.4f} m "
                     f"from its lift-off (centre {centre[0]:.4f}, {centre[1]:.4f} m)")
            pose, result = _settle(rover, profile, blocks, v, (k, riser, s, centre), where)
            v = pose.coords
            results.append(result)
    return Climb(kind.name, profile, ds, results)


def step_curve(kind: RoverKind, heights, params: dict | None = None, steps: int = 1, run: float = math.inf,
               ds: float | None = None) -> list[Climb]:
    """required_friction over heights: a sharp step (steps = 1) or stairs (their run) of each rise."""
    rover = PlanarRover(kind, params)
    return [required_friction(kind, Staircase(float(h), steps, run), ds=ds, rover=rover) for h in heights]


def _what(profile: Staircase) -> str:
    if profile.steps == 1:
        return f"a step of h = {profile.rise:.4f} m"
    return f"{profile.steps} stairs of rise h = {profile.rise:.4f} m, run {profile.run:.4f} m"
