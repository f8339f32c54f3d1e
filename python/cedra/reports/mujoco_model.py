"""A MuJoCo model of CEDRA for side-by-side benchmarks, generated from the project's own numbers.

    xml = mjcf(load_shipped("bump3d"), terrain="hfield")     # MJCF text
    r = run(load_shipped("bump3d"), terrain="hfield", dt=1e-3, stop_time=15.0)   # the paper's run

Every number comes from the scene (`Scene.parameters`, `Scene.inputs`, heightmap file) over the defaults of
`cedra.rover.parameters` and the input table; the four-bar's closure (theta5) is
`cedra.rover.mechanism.four_bar`, evaluated on those numbers: one source of truth, nothing typed twice. `mujoco` is
an optional dependency (`pip install .[bench]`, which ./build.sh does); importing this module does not need it, the
functions that build or run a model import it.

The mechanism (docs/model.md): a free body (m_B, diag(I_Bxx, I_Byy, I_Bzz) at the frame origin = mass
center); two bogies on hinges about the body's y axis at P_L, P_R with wheels at +-bogie_half; the rear wheel 5
on the body at (rear_x, 0, rear_z); the front four-bar as links: lower link A-C (hinge theta4 with the fork spring
fork_k, fork_d about fork_theta4_ref), the coupler at C (hinge, carrying m_F with I_F at C + fork_mass_at e(theta5)
and wheel 6 at C - fork_wheel e(theta5)), the upper link at B, the loop closed at D by an equality `connect`;
wheels of radius R_w, mass m_w, spin inertia 0.5 m_w R_w^2, diametral 0.25 m_w R_w^2; six torque motors on the
spin joints (gear 1, ctrlrange +-4 N.m, the controller's clip); friction mu on wheel-ground pairs only. Hinges
turn about -y so that a positive joint angle is the model's positive angle; all joint angles are 0 in the design
pose (MuJoCo's qpos0), so the fork spring's reference is 0 and the fork stops are offset by fork_theta4_ref.

What differs from the FMU's model (so the two are not expected to agree beyond a few %):
  * contact: MuJoCo's soft constraints (default solref 0.02 s / damping ratio 1, solimp (0.9, 0.95, 0.001),
    pyramidal friction cone with condim 3, no rolling/torsional friction effect) instead of the model's
    penalty ground (ground_k = 1e5 N/m, ground_d = 600 N.s/m, regularized Coulomb with v_eps). ground_k,
    ground_d and v_eps have no counterpart here; MuJoCo's contact stiffness is in acceleration units and
    cannot be set to N/m.
  * wheels are cylinders of half width WHEEL_HALF_WIDTH (2 cm), not thin disks: on a plane the contact is a
    line (MuJoCo puts points at both rims), on a height field a general convex-hfield collision (several points
    per wheel); the reported normal force of a wheel is the sum of its contacts' normal components.
  * terrain: a height field is piecewise linear (two triangles per cell) through the grid heights; the FMU uses
    the analytic Gaussian (bump) or the natural bicubic spline through the same grid (heightmap). The bump's
    grid is the Gaussian sampled at 1 cm (default); hills3d uses its own 5 cm grid as is.
  * the model's massless links (bogies, fork links) get LINK_MASS = 0.01 kg each (MuJoCo needs mass on moving
    bodies): 0.04 kg on a 24 kg rover.
  * joint stops are MuJoCo joint limits (soft constraints, default solreflimit), not the model's clipped
    spring-damper stop_k = 500 N.m/rad, stop_d = 5 N.m.s/rad.
  * steps and stairs ('boxes'): sharp boxes on the plane, where the model's edges are smoothed over terrain_s;
    MuJoCo's box-cylinder contact is its general convex collision, with multi-point contact (multiccd, its default)
    or without.
  * drives (scenes with drives): the command is clipped to the drive's torque-speed envelope every step in Python
    (Rover.step) and the gear's viscous loss is the spin joint's damping; without drives the motors are pure torque
    sources, as the model's are.
  * steering: no steering joints. Scenes with steering (flat3d) hold it at 0 with the servo; here it is welded.
  * the four-bar is closed by a soft equality constraint (drift ~1e-5 m), not in closed form; theta5 is a
    coordinate of MuJoCo's model.
  * start: the design pose with every wheel touching, then SETTLE s with zero torque before the timed run (the
    FMU settles statically in fmi2ExitInitializationMode); integrator Euler (MuJoCo's default, implicit in joint
    damping), fixed step dt, no adaptivity.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import casadi as ca
import numpy as np

from cedra.mechanics import heightmap
from cedra.models.plant import input_table, param_table
from cedra.rover.parameters import DEFAULTS
from cedra.rover.mechanism import four_bar
from cedra.models.scene import Scene
from cedra.run.simulate import SAMPLE, TAU_MAX, SpeedController

WHEEL_HALF_WIDTH = 0.02     # m
LINK_MASS = 0.01            # kg, on each of the model's massless links
SETTLE = 1.0                # s of zero torque before the timed run
BUMP_CELL = 0.01            # m, the bump's height-field cells
BUMP_X = (-1.0, 4.0)        # m, extent of the bump's height field
BUMP_Y = (-0.4, 0.4)
TERRAINS = ("plane", "hfield", "boxes")
LANDING = 2.0               # m: the top box reaches this far past the last edge; the boxes reach as far to the sides


def mujoco():
    """The optional dependency, imported on use (ImportError says how to get it)."""
    try:
        import mujoco as mj
    except ImportError as e:        # pragma: no cover - depends on the environment
        raise ImportError("the MuJoCo peer needs the optional dependency mujoco: pip install -e '.[bench]' "
                          "(./build.sh installs it)") from e
    return mj


def available() -> bool:
    try:
        mujoco()
        return True
    except ImportError:
        return False


def numbers(scene: Scene) -> dict:
    """The scene's parameters and inputs over the project's defaults (cedra.rover.parameters, the input table)."""
    p = {q.name: float(q.start) for q in param_table(scene.options) + input_table(scene.options)}
    p = {**DEFAULTS, **p}
    p.update(scene.parameters)
    p.update(scene.inputs)
    return p


def geometry(p: dict) -> dict:
    """Design-pose points in the body frame (docs/model.md), the four-bar closed by cedra.rover.mechanism.four_bar."""
    th4 = p["fork_theta4_ref"]
    C, th5, closure = (np.array(ca.evalf(v), dtype=float) for v in four_bar(th4, p))   # constant expressions
    C, th5, closure = C.ravel(), th5.item(), closure.item()
    e5 = np.array([math.cos(th5), 0.0, math.sin(th5)])
    return dict(A=np.array([p["fork_ax"], 0.0, p["fork_az"]]), B=np.array([p["fork_bx"], 0.0, p["fork_bz"]]),
                C=C, D=C + p["fork_c"] * e5, c6=C - p["fork_wheel"] * e5, mF=C + p["fork_mass_at"] * e5,
                th4=th4, th5=th5, closure=closure)


@dataclass
class Grid:
    """Heights Z[j, i] at X = x0 + i dx, Y = y0 + j dy."""
    Z: np.ndarray
    x0: float
    y0: float
    dx: float
    dy: float

    @property
    def x1(self):
        return self.x0 + (self.Z.shape[1] - 1) * self.dx

    @property
    def y1(self):
        return self.y0 + (self.Z.shape[0] - 1) * self.dy


def bump_grid(p: dict, cell=BUMP_CELL, xlim=BUMP_X, ylim=BUMP_Y) -> Grid:
    """The `bump` terrain (docs/model.md, Terrain: h exp(-((X - x0)/w)^2), constant in Y) sampled on a grid."""
    nx = int(round((xlim[1] - xlim[0]) / cell)) + 1
    ny = int(round((ylim[1] - ylim[0]) / cell)) + 1
    X = xlim[0] + cell * np.arange(nx)
    row = p["terrain_h"] * np.exp(-((X - p["terrain_x0"]) / p["terrain_w"]) ** 2)
    return Grid(np.tile(row, (ny, 1)), xlim[0], ylim[0], cell, cell)


def heightmap_grid(path) -> Grid:
    """A heightmap scene's grid file (format: fmu_src/heightmap.h). The FMU's own C reader checks it first
    (cedra.mechanics.heightmap.load); this only reads the numbers it already accepted."""
    heightmap.load(path)
    rows = []
    for line in Path(path).read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            rows.append(line.split())
    assert rows[0][0] == "cedra-heightmap"
    nx, ny = int(rows[1][0]), int(rows[1][1])
    x0, y0, dx, dy = (float(v) for v in rows[1][2:6])
    Z = np.array([[float(v) for v in r] for r in rows[2:2 + ny]])
    assert Z.shape == (ny, nx)
    return Grid(Z, x0, y0, dx, dy)


def scene_grid(scene: Scene, cell=BUMP_CELL) -> Grid:
    kind = scene.options.terrain
    if kind == "bump":
        return bump_grid(numbers(scene), cell)
    if kind == "heightmap":
        return heightmap_grid(scene.options.heightmap)
    raise ValueError(f"no height field for terrain kind {kind!r} (bump and heightmap have one; use 'plane')")


@dataclass
class Box:
    center: np.ndarray      # world, m
    half: np.ndarray        # half sizes along the box's own axes, m
    yaw: float              # about Z, rad


def scene_boxes(scene: Scene) -> list[Box]:
    """A step or stairs scene's terrain as sharp boxes on the ground plane (docs/model.md, Terrain): step j's top
    at (j + 1) terrain_h from its edge at u = j terrain_w to LANDING past the last edge, u measured across the edges
    from (terrain_x0, terrain_y0) along yaw terrain_yaw (a step: one box at terrain_x0). The model's edges are
    smoothed over terrain_s (tanh); a box's edge is where the smoothed profile is at half the rise."""
    kind = scene.options.terrain
    if kind not in ("step", "stairs"):
        raise ValueError(f"no boxes for terrain kind {kind!r} (step and stairs have them)")
    p = numbers(scene)
    steps = scene.options.stairs_steps if kind == "stairs" else 1
    run = p["terrain_w"] if kind == "stairs" else 0.0
    yaw = p.get("terrain_yaw", 0.0) if kind == "stairs" else 0.0
    origin = np.array([p["terrain_x0"], p.get("terrain_y0", 0.0) if kind == "stairs" else 0.0])
    along = np.array([math.cos(yaw), math.sin(yaw)])
    end = (steps - 1) * run + LANDING
    boxes = []
    for j in range(steps):
        top = (j + 1) * p["terrain_h"]
        u0 = j * run
        xy = origin + along * 0.5 * (u0 + end)
        boxes.append(Box(np.array([xy[0], xy[1], 0.5 * top]), np.array([0.5 * (end - u0), LANDING + end, 0.5 * top]),
                         yaw))
    return boxes


def _v(x):
    return " ".join(f"{float(t):.15g}" for t in np.atleast_1d(x))


def _wheel(name, pos, p, indent):
    m, R = p["m_w"], p["R_w"]
    s = " " * indent
    inertia = _v([0.25 * m * R * R, 0.5 * m * R * R, 0.25 * m * R * R])
    damping = f' damping="{p["drive_viscous"]!r}"' if p["drives"] else ""     # the gear's viscous loss
    return (f'{s}<body name="{name}" pos="{_v(pos)}">\n'
            f'{s}  <joint name="{name}_spin" type="hinge" axis="0 1 0"{damping}/>\n'
            f'{s}  <inertial pos="0 0 0" mass="{m!r}" diaginertia="{inertia}"/>\n'
            f'{s}  <geom name="{name}_geom" class="wheel" type="cylinder" size="{R!r} {WHEEL_HALF_WIDTH}" '
            f'zaxis="0 1 0"/>\n'
            f'{s}</body>\n')


def _link(mid, length, indent):
    i = LINK_MASS * length ** 2 / 12 + 1e-7
    return f'{" " * indent}<inertial pos="{_v(mid)}" mass="{LINK_MASS}" diaginertia="{_v([i, i, i])}"/>\n'


def _terrain_xml(grid: Grid | None):
    """(asset, geom) of the ground: a plane, or a height field through the grid's heights."""
    if grid is None:
        return "", '    <geom name="ground" type="plane" size="50 50 0.1" class="ground"/>\n'
    Z = grid.Z
    zmin, zmax = float(Z.min()), float(Z.max())
    span = max(zmax - zmin, 1e-9)
    ny, nx = Z.shape
    # MuJoCo scales the elevation data to [0, 1] (min -> 0, max -> 1), then by size[2]; its text's first row is
    # the +Y edge (like an image), so rows go from Y = y1 down to y0
    elev = " ".join(f"{v:.12g}" for v in ((Z[::-1] - zmin) / span).ravel())
    rx, ry = (grid.x1 - grid.x0) / 2, (grid.y1 - grid.y0) / 2
    asset = (f'  <asset>\n    <hfield name="terrain" nrow="{ny}" ncol="{nx}" size="{rx!r} {ry!r} {span!r} 0.1" '
             f'elevation="{elev}"/>\n  </asset>\n')
    geom = (f'    <geom name="ground" type="hfield" hfield="terrain" '
            f'pos="{_v([grid.x0 + rx, grid.y0 + ry, zmin])}" class="ground"/>\n')
    return asset, geom


def start_height(p: dict, grid: Grid | None, x: float, y: float) -> float:
    """Body mass-center height of the design pose with every wheel touching the ground under (x, y): the design
    height R_w - rear_z above the highest ground point under the wheels' centers."""
    base = p["R_w"] - p["rear_z"]
    if grid is None:
        return base
    g = geometry(p)
    pts = [(p["bogie_x"] + s * p["bogie_half"], side * p["bogie_y"]) for s in (1, -1) for side in (1, -1)]
    pts += [(p["rear_x"], 0.0), (g["c6"][0], 0.0)]
    X = np.array([x + a for a, _ in pts])
    Y = np.array([y + b for _, b in pts])
    i = np.clip(np.round((X - grid.x0) / grid.dx).astype(int), 0, grid.Z.shape[1] - 1)
    j = np.clip(np.round((Y - grid.y0) / grid.dy).astype(int), 0, grid.Z.shape[0] - 1)
    return base + float(np.max(grid.Z[j, i]))


def _boxes_xml(boxes: list[Box]) -> str:
    return "".join(f'    <geom name="step{j}" type="box" size="{_v(b.half)}" pos="{_v(b.center)}" '
                   f'euler="0 0 {b.yaw!r}" class="ground"/>\n' for j, b in enumerate(boxes))


def mjcf(scene: Scene, terrain: str = "hfield", dt: float = 1e-3, cell: float = BUMP_CELL, multiccd: bool = True,
         energy: bool = False) -> str:
    """MJCF text of CEDRA with the scene's numbers. terrain: 'hfield' (the scene's bump or heightmap grid as a
    height field), 'plane', or 'boxes' (a step or stairs scene's steps as boxes on the plane, scene_boxes).
    multiccd: MuJoCo's multi-point convex collision (its default: on); energy: MuJoCo computes data.energy."""
    if terrain not in TERRAINS:
        raise ValueError(f"terrain must be one of {TERRAINS}, got {terrain!r}")
    p = {**numbers(scene), "drives": scene.options.drives}
    grid = scene_grid(scene, cell) if terrain == "hfield" else None
    flags = ("" if multiccd else ' multiccd="disable"') + (' energy="enable"' if energy else "")
    flags = f"<flag{flags}/>" if flags else ""
    g = geometry(p)
    A, B, C, D, c6, mF = g["A"], g["B"], g["C"], g["D"], g["c6"], g["mF"]
    th4 = g["th4"]
    x0, y0 = scene.start.get("x", 0.0), scene.start.get("y", 0.0)
    yaw = scene.start.get("yaw", 0.0)
    z0 = start_height(p, grid, x0, y0)
    asset, ground = _terrain_xml(grid)
    if terrain == "boxes":
        ground += _boxes_xml(scene_boxes(scene))
    mu = p["mu"]
    stop = p["bogie_stop"]
    IF = p["I_F"]
    half = p["bogie_half"]
    x = f'''<mujoco model="cedra_{scene.name}_{terrain}">
  <!-- generated by cedra.reports.mujoco_model from the scene {scene.name} and cedra.rover.parameters -->
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{dt!r}" integrator="Euler" gravity="0 0 {-p['g']!r}">{flags}</option>
  <size memory="16M"/>
  <default>
    <geom contype="0" conaffinity="0" rgba="0.6 0.6 0.7 1"/>
    <default class="wheel">
      <geom contype="1" conaffinity="0" condim="3" friction="{mu!r} 0.005 0.0001" rgba="0.2 0.2 0.2 1"/>
    </default>
    <default class="ground">
      <geom contype="0" conaffinity="1" condim="3" friction="{mu!r} 0.005 0.0001" rgba="0.5 0.45 0.4 1"/>
    </default>
  </default>
{asset}  <worldbody>
{ground}    <body name="body" pos="{_v([x0, y0, z0])}" euler="0 0 {yaw!r}">
      <freejoint name="root"/>
      <inertial pos="0 0 0" mass="{p['m_B']!r}" diaginertia="{_v([p['I_Bxx'], p['I_Byy'], p['I_Bzz']])}"/>
      <body name="bogie_L" pos="{_v([p['bogie_x'], p['bogie_y'], p['bogie_z']])}">
        <joint name="theta1" type="hinge" axis="0 -1 0" range="{-stop!r} {stop!r}"/>
{_link([0, 0, 0], 2 * half, 8)}{_wheel('wheel1', [half, 0, 0], p, 8)}{_wheel('wheel2', [-half, 0, 0], p, 8)}      </body>
      <body name="bogie_R" pos="{_v([p['bogie_x'], -p['bogie_y'], p['bogie_z']])}">
        <joint name="theta2" type="hinge" axis="0 -1 0" range="{-stop!r} {stop!r}"/>
{_link([0, 0, 0], 2 * half, 8)}{_wheel('wheel3', [half, 0, 0], p, 8)}{_wheel('wheel4', [-half, 0, 0], p, 8)}      </body>
{_wheel('wheel5', [p['rear_x'], 0, p['rear_z']], p, 6)}      <body name="fork_lower" pos="{_v(A)}">
        <joint name="theta4" type="hinge" axis="0 -1 0" stiffness="{p['fork_k']!r}" damping="{p['fork_d']!r}"
               springref="0" range="{p['fork_stop_lo'] - th4!r} {p['fork_stop_hi'] - th4!r}"/>
{_link((C - A) / 2, p['fork_a'], 8)}        <body name="coupler" pos="{_v(C - A)}">
          <joint name="theta5" type="hinge" axis="0 -1 0"/>
          <inertial pos="{_v(mF - C)}" mass="{p['m_F']!r}" diaginertia="{_v([IF, IF, IF])}"/>
{_wheel('wheel6', c6 - C, p, 10)}        </body>
      </body>
      <body name="fork_upper" pos="{_v(B)}">
        <joint name="theta_upper" type="hinge" axis="0 -1 0"/>
{_link((D - B) / 2, p['fork_b'], 8)}      </body>
    </body>
  </worldbody>
  <equality>
    <connect name="fourbar" body1="coupler" body2="fork_upper" anchor="{_v(D - C)}"/>
  </equality>
  <actuator>
'''
    for i in range(1, 7):
        x += f'    <motor name="tau{i}" joint="wheel{i}_spin" gear="1" ctrlrange="{-TAU_MAX!r} {TAU_MAX!r}"/>\n'
    return x + "  </actuator>\n</mujoco>\n"


class Rover:
    """A compiled MuJoCo model of the scene and its data, with the FMU's output names where they exist."""

    def __init__(self, scene: Scene, terrain: str = "hfield", dt: float = 1e-3, cell: float = BUMP_CELL,
                 multiccd: bool = True, energy: bool = False):
        mj = mujoco()
        self.mj = mj
        self.scene, self.terrain, self.dt = scene, terrain, dt
        self.xml = mjcf(scene, terrain, dt, cell, multiccd, energy)
        self.model = mj.MjModel.from_xml_string(self.xml)
        self.data = mj.MjData(self.model)
        self.wheel_of_geom = {mj.mj_name2id(self.model, mj.mjtObj.mjOBJ_GEOM, f"wheel{i}_geom"): i - 1
                              for i in range(1, 7)}
        self._f6 = np.zeros(6)
        self.spin_dofs = np.array([self.model.jnt_dofadr[mj.mj_name2id(self.model, mj.mjtObj.mjOBJ_JOINT,
                                                                        f"wheel{i}_spin")] for i in range(1, 7)])
        p = numbers(scene)
        self.drives = scene.options.drives
        self._cmd = np.zeros(6)
        self.stall, self.noload = p["drive_stall_torque"], p["drive_noload_speed"]
        mj.mj_forward(self.model, self.data)

    def step(self, n=1):
        """n steps of dt with the torques set by set_torques; with the scene's drives, every step first clips the
        commands to each drive's torque-speed envelope at the wheel's present spin rate (docs/model.md, Drives:
        the FMU's drive_torque; the gear's viscous loss is the spin joint's damping), as a 1/dt drive would."""
        if not self.drives:
            self.mj.mj_step(self.model, self.data, nstep=n)
            return
        for _ in range(n):
            w = self.data.qvel[self.spin_dofs]
            self.data.ctrl[:] = np.minimum(np.maximum(self._cmd, -self.stall * (1 + w / self.noload)),
                                           self.stall * (1 - w / self.noload))
            self.mj.mj_step(self.model, self.data)

    @property
    def time(self):
        return self.data.time

    def vx(self):
        return float(self.data.qvel[0])     # free joint: world-frame linear velocity of the body's origin

    def pose(self):
        """body x, y, z and ZYX Euler (yaw, pitch, roll) as the FMU's body.* outputs."""
        q = self.data.qpos
        w, x, y, z = q[3:7]
        yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
        pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
        roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
        return dict(x=float(q[0]), y=float(q[1]), z=float(q[2]), yaw=yaw, pitch=pitch, roll=roll)

    def normal_forces(self) -> np.ndarray:
        """Per wheel (1..6), the sum of the normal components of its ground contacts, N."""
        F = np.zeros(6)
        d = self.data
        for k in range(d.ncon):
            c = d.contact[k]
            w = self.wheel_of_geom.get(c.geom1, self.wheel_of_geom.get(c.geom2))
            if w is None:
                continue
            self.mj.mj_contactForce(self.model, d, k, self._f6)
            F[w] += self._f6[0]
        return F

    def unstable(self) -> bool:
        """MuJoCo met non-finite or huge accelerations (it then resets the state to the model's start by itself)."""
        return self.data.warning[self.mj.mjtWarning.mjWARN_BADQACC].number > 0

    def energy(self) -> float:
        """Kinetic + potential energy (gravity, joint springs), J; the model must be made with energy=True."""
        self.mj.mj_energyPos(self.model, self.data)
        self.mj.mj_energyVel(self.model, self.data)
        return float(self.data.energy[0] + self.data.energy[1])

    def motor_power(self) -> float:
        """The power the six motors put into the wheels now, W."""
        return float(np.dot(self.data.actuator_force, self.data.actuator_velocity))

    def set_torques(self, tau):
        """The six torque commands (with drives: what each drive is asked for, clipped in step)."""
        self._cmd = np.asarray(tau, dtype=float) * np.ones(6)
        self.data.ctrl[:] = self._cmd


@dataclass
class Result:
    """One closed-loop run: samples every SAMPLE s of the timed part."""
    label: str
    cpu: float                      # time.process_time of the timed part, s
    simulated: float
    steps: int
    t: np.ndarray = field(repr=False)
    x: np.ndarray = field(repr=False)
    Fn: np.ndarray = field(repr=False)      # samples x 6
    ok: bool = True
    message: str = ""
    extra: dict = field(default_factory=dict)

    def x_at(self, t):
        return float(np.interp(t, self.t, self.x)) if self.t[-1] >= t - 1e-9 else float("nan")

    @property
    def peak_fn(self):
        return float(np.max(self.Fn))


def settle(rover: Rover, seconds=SETTLE):
    """Zero torque for `seconds`: the rover comes to rest on the ground (not timed by run)."""
    rover.set_torques(np.zeros(6))
    rover.step(int(round(seconds / rover.dt)))


def run(scene: Scene, terrain: str = "hfield", dt: float = 1e-3, stop_time: float = 15.0, cell: float = BUMP_CELL,
        label: str = "", multiccd: bool = True) -> Result:
    """The paper's run (docs/model.md) on MuJoCo: settle, then every SAMPLE s read body.vx, the speed controller
    (cedra.run.simulate.SpeedController) sets all six torques, MuJoCo steps SAMPLE/dt times (zero-order hold).
    The CPU time counts the controlled part only (the model compile and the settle are not timed)."""
    rover = Rover(scene, terrain, dt, cell, multiccd)
    settle(rover)
    nsub = int(round(SAMPLE / dt))
    if abs(nsub * dt - SAMPLE) > 1e-12:
        raise ValueError(f"dt = {dt} does not divide the controller's period {SAMPLE}")
    n = int(round(stop_time / SAMPLE))
    ctrl = SpeedController()
    t, x, F = np.empty(n + 1), np.empty(n + 1), np.empty((n + 1, 6))
    ok, msg = True, ""
    cpu = time.process_time()
    for k in range(n + 1):
        t[k] = k * SAMPLE
        x[k] = rover.data.qpos[0]
        F[k] = rover.normal_forces()
        if k == n:
            break
        rover.set_torques(np.full(6, ctrl(rover.vx())))
        rover.step(nsub)
        if not np.all(np.isfinite(rover.data.qpos)) or rover.unstable():
            ok, msg = False, f"unstable at t = {t[k] + SAMPLE:g} (non-finite or huge accelerations)"
            t, x, F = t[:k + 1], x[:k + 1], F[:k + 1]
            break
    cpu = time.process_time() - cpu
    return Result(label or f"MuJoCo {terrain} dt {dt * 1e3:g} ms", cpu, float(t[-1]), (len(t) - 1) * nsub,
                  t, x, F, ok, msg, extra=dict(y_end=float(rover.data.qpos[1])))


def static_loads(scene: Scene, terrain: str = "plane", dt: float = 1e-3, seconds: float = 2.0,
                 average: float = 0.1) -> np.ndarray:
    """Wheel loads (N, wheels 1..6) at rest: settle `seconds` with zero torque, then the mean over `average` s."""
    rover = Rover(scene, terrain, dt)
    settle(rover, seconds)
    n = max(1, int(round(average / dt)))
    acc = np.zeros(6)
    for _ in range(n):
        rover.step()
        acc += rover.normal_forces()
    return acc / n
