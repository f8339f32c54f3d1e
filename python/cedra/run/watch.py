"""Runs a person can watch: `animation.gif` (a 2D side view) and `view.html` (a 3D replay) of a
run, from its recorded outputs.

    paths = watch(out_dir, names, rows, fmu_path)      # names: "time" + outputs, rows: one per sample
    python -m cedra watch out/turn_flat/turn_flat.csv --fmu build/flat3d.fmu      # from a run's CSV

* `animation.gif` (or `animation.mp4` when ffmpeg is on PATH): the rover in the X-Z plane (body box, its links as
  lines: CEDRA's bogies, four-bar and struts, the rocker-bogie's rockers and bogies; wheels as circles with a spoke
  turning at the wheel's spin angle, the ground force on each wheel as an arrow, 1 cm per 10 N) over the terrain
  under Y = 0, the camera following the body, FPS frames per simulated second, so the GIF plays in real time. For 2D runs (CEDRA's wheels 3, 4 are 1, 2; the
  rocker-bogie's 4, 5, 6 are 1, 2, 3).
* `view.html`: one self-contained page (no network: the renderer, `view.html` next to this module, is ~300 lines
  of canvas-2D projection and the data is inline JSON): the terrain surface sampled from the FMU's own terrain
  (kind and numbers from its model description, a heightmap from its resources, heights from
  `cedra.mechanics.terrain`), the body box, links, wheels as discs with a spoke, ground forces; a time slider,
  play/pause, speed, follow camera, mouse orbit and zoom. A 2D run is shown at Y = 0 with its terrain extruded in Y.
  Page options after `#`: `follow=0` (fixed camera on the whole path), `play=0`, `t=<s>`, `speed=<x>`.

Geometry comes from `cedra.rover.skeleton` (the chains of docs/model.md, checked against the FMU's wheel centers),
so a run records what WATCHED names and nothing is recomputed from a second copy of the kinematics.
"""
from __future__ import annotations

import importlib
import json
import shutil
import tempfile
import time
import zipfile
from pathlib import Path

import casadi as ca
import numpy as np

from cedra.rover.parameters import DEFAULTS
from cedra.rover.skeleton import BOX_FACES, skeleton

# a heightmap run's terrain is drawn with cedra.mechanics' heightmap library, whose builder cedra.models hands it
importlib.import_module("cedra.models")

FPS = 10                    # animation frames per simulated second (GIF frame times are in 10 ms: 100 ms)
VIEW_FPS = 15               # samples per simulated second embedded in view.html (the page interpolates)
FORCE_SCALE = 0.01 / 10.0   # m of arrow per N (1 cm per 10 N)
WINDOW = (2.0, 0.75)        # m, the animation's view: width (following the body), height
WHEELS = range(1, 7)
WATCHED = (["body.x", "body.y", "body.z", "body.yaw", "body.pitch", "body.roll", "bogie.theta[1]", "bogie.theta[2]",
            "fork.theta4", "steer.theta[1]", "steer.theta[2]", "rocker.rho", "bogie.beta[1]", "bogie.beta[2]"] +
           [f"wheel[{i}].{q}" for q in ("omega", "Fn", "Fx", "Fy", "px", "py", "pz") for i in WHEELS])
TEMPLATE = Path(__file__).with_name("view.html")


def plus_watched(names) -> list[str]:
    """names, then what WATCHED adds to them (a run's record list)."""
    return list(names) + [n for n in WATCHED if n not in names]


# ---------------------------------------------------------------- the run's numbers and terrain
def fmu_numbers(fmu_path) -> dict:
    """Float start values of the FMU's variables over the project's defaults (parameters and terrain inputs)."""
    from fmpy import read_model_description
    md = read_model_description(str(fmu_path))
    p = dict(DEFAULTS)
    for v in md.modelVariables:
        if v.start is not None and v.type == "Real":
            p[v.name] = float(v.start)
    p["_model"] = md.modelName
    return p


class TerrainMap:
    """The FMU's terrain as numpy: `height(X, Y)`, `normal(X, Y)` on arrays. The kind is the one whose inputs are
    exactly the FMU's terrain_* variables (each kind has its own set); no inputs: a heightmap when the FMU ships
    resources/heightmap.txt, else flat. `values` overrides the FMU's start values (a run that set other inputs)."""

    def __init__(self, fmu_path, values: dict | None = None):
        from fmpy import read_model_description
        from cedra.mechanics.terrain import KINDS, Terrain, terrain_inputs
        md = read_model_description(str(fmu_path))
        names = {v.name for v in md.modelVariables if v.name.startswith("terrain_")}
        self.extent = None              # (x0, x1, y0, y1) where the terrain exists (a heightmap's grid)
        hm = ""
        with zipfile.ZipFile(fmu_path) as z:
            if not names and "resources/heightmap.txt" in z.namelist():
                self._dir = tempfile.mkdtemp(prefix="cedra-watch-")
                hm = z.extract("resources/heightmap.txt", self._dir)
        if hm:
            kind = "heightmap"
            nx, ny, x0, y0, dx, dy = _grid_header(hm)
            self.extent = (x0, x0 + (nx - 1) * dx, y0, y0 + (ny - 1) * dy)
        else:
            kinds = [k for k in KINDS if k != "heightmap"
                     and any(set(terrain_inputs(k, d)) == names for d in ("2d", "3d"))]
            if len(kinds) != 1:
                raise ValueError(f"{fmu_path}: cannot tell the terrain kind from its inputs {sorted(names)}")
            kind = kinds[0]
        self.kind = kind
        start = {v.name: float(v.start) for v in md.modelVariables if v.name in names}
        start.update({k: float(v) for k, v in (values or {}).items() if k in names})
        self.values = start
        syms = {n: ca.SX.sym(n) for n in sorted(names)}
        terrain = Terrain(kind, syms, hm)
        X, Y = ca.SX.sym("X"), ca.SX.sym("Y")
        h, g, _ = terrain.local(X, Y)
        self._f = ca.Function("terrain", [X, Y] + list(syms.values()), [h, g])
        self._t = [start[n] for n in syms]

    def _eval(self, X, Y):
        X, Y = np.broadcast_arrays(np.asarray(X, dtype=float), np.asarray(Y, dtype=float))
        flat_x, flat_y = X.ravel(), Y.ravel()
        if self.extent:                 # the grid's terrain ends at its edge: sample inside it
            flat_x = np.clip(flat_x, self.extent[0], self.extent[1])
            flat_y = np.clip(flat_y, self.extent[2], self.extent[3])
        n = flat_x.size
        h, g = self._f.map(n)(flat_x[None, :], flat_y[None, :], *[np.full((1, n), t) for t in self._t])
        return np.array(h).reshape(X.shape), np.array(g).T.reshape(X.shape + (2,))

    def height(self, X, Y=0.0) -> np.ndarray:
        return self._eval(X, Y)[0]

    def normal(self, X, Y=0.0) -> np.ndarray:
        g = self._eval(X, Y)[1]
        n = np.concatenate([-g, np.ones(g.shape[:-1] + (1,))], axis=-1)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)


def _grid_header(path):
    rows = [ln.split("#", 1)[0].split() for ln in Path(path).read_text().splitlines()]
    rows = [r for r in rows if r]
    nx, ny = int(rows[1][0]), int(rows[1][1])
    return (nx, ny) + tuple(float(v) for v in rows[1][2:6])


def ground_forces(cols: dict, axles: np.ndarray, terrain: TerrainMap, frames) -> tuple[np.ndarray, np.ndarray]:
    """Contact points (frames, 6, 3) and the ground's force on each wheel (frames, 6, 3), world: Fn along the
    terrain normal at the contact point, Fx along the contact frame's x = unit(axle x n), Fy along n x x."""
    idx = np.asarray(frames)
    n = len(idx)
    zeros = np.zeros(len(cols["time"]))
    P = np.stack([np.stack([np.asarray(cols.get(f"wheel[{i}].p{a}", zeros))[idx] for a in "xyz"], axis=-1)
                  for i in WHEELS], axis=1)
    F = np.stack([np.stack([np.asarray(cols.get(f"wheel[{i}].F{a}", zeros))[idx] for a in ("n", "x", "y")], axis=-1)
                  for i in WHEELS], axis=1)
    normal = terrain.normal(P[..., 0], P[..., 1])
    x = np.cross(axles[:n], normal)
    x /= np.maximum(np.linalg.norm(x, axis=-1, keepdims=True), 1e-12)
    y = np.cross(normal, x)
    force = F[..., :1] * normal + F[..., 1:2] * x + F[..., 2:3] * y
    return P, force


def frame_indices(t: np.ndarray, fps: float) -> np.ndarray:
    """Sample indices nearest to every 1/fps s of the run (the last sample included)."""
    t = np.asarray(t, dtype=float)
    want = np.arange(t[0], t[-1] + 1e-9, 1.0 / fps)
    idx = np.unique(np.clip(np.searchsorted(t, want - 1e-9), 0, len(t) - 1))
    return idx if idx[-1] == len(t) - 1 else np.append(idx, len(t) - 1)


# ---------------------------------------------------------------- the 2D animation
def video_format() -> str:
    from matplotlib import animation
    return "mp4" if shutil.which("ffmpeg") and animation.writers.is_available("ffmpeg") else "gif"


def animation(cols: dict, p: dict, terrain: TerrainMap, path, fps: float = FPS, title: str = "",
              fmt: str | None = None) -> Path:
    """The side view (X-Z) of the run as a GIF (or MP4: fmt "mp4", default when ffmpeg is present); returns the
    file written (its suffix is the format's)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle, Polygon
    fmt = fmt or video_format()
    path = Path(path).with_suffix("." + fmt)
    path.parent.mkdir(parents=True, exist_ok=True)
    t = np.asarray(cols["time"], dtype=float)
    idx = frame_indices(t, fps)
    sk = skeleton(cols, p, idx)
    P, F = ground_forces(cols, sk.axles, terrain, idx)
    R = sk.R_w
    fig = plt.figure(figsize=(9, 3.4), dpi=80)
    ax = fig.add_axes((0, 0, 1, 1))
    w, h = WINDOW
    xs = sk.points[..., 0]
    X = np.linspace(xs.min() - w, xs.max() + w, 1200)
    ground = terrain.height(X, 0.0)
    ax.fill_between(X, ground, ground.min() - 1.0, color="#c9bca8", lw=0)
    ax.plot(X, ground, color="#7a6a55", lw=1)
    z_lo = ground.min() - 0.12
    # a ruler on the ground instead of axis ticks (ticks relaid out every frame cost most of the drawing time)
    marks = np.round(np.arange(np.floor(X[0] * 10) / 10, X[-1], 0.1), 6)
    ax.vlines(marks, z_lo + 0.02, z_lo + np.where(np.isclose(marks % 0.5, 0) | np.isclose(marks % 0.5, 0.5),
                                                  0.06, 0.04), color="#6b5b47", lw=1)
    ruler = [ax.text(m + 0.01, z_lo + 0.045, f"{m:g} m", fontsize=8, color="#4b3b27", clip_on=True)
             for m in marks[np.isclose(np.abs(marks) % 0.5, 0) | np.isclose(np.abs(marks) % 0.5, 0.5)]]
    ax.set_aspect("equal", adjustable="box")
    ax.set_ylim(z_lo, z_lo + h)
    ax.set_axis_off()
    box = Polygon(np.zeros((4, 2)), closed=True, fc="#e8892b", ec="#5a3000", lw=1.2, zorder=3)
    ax.add_patch(box)
    links = [ax.plot([], [], color="#333333", lw=2.2, solid_capstyle="round", zorder=4)[0] for _ in sk.links]
    # 2D: the wheels whose spins the planar run keeps (their twins on the right coincide with them)
    planar_wheels = [1, 2, 3] if sk.rover == "the rocker-bogie" else [1, 2, 5, 6]
    shown = planar_wheels if "body.y" not in cols else list(WHEELS)
    circles = {i: ax.add_patch(Circle((0, 0), R, fc="#4a4a4a", ec="#111111", lw=1, alpha=0.92, zorder=5))
               for i in shown}
    spokes = {i: ax.plot([], [], color="#ffd24a", lw=2, zorder=6)[0] for i in shown}
    arrows = ax.quiver(np.zeros(len(shown)), np.zeros(len(shown)), np.zeros(len(shown)), np.zeros(len(shown)),
                       angles="xy", scale_units="xy", scale=1 / FORCE_SCALE, color="#e0102a", width=0.005,
                       zorder=7)
    label = ax.text(0.01, 0.97, "", transform=ax.transAxes, va="top", fontsize=9, family="monospace")
    legend = ax.text(0.99, 0.97, f"{title or sk.rover}\narrows: ground force on a wheel, 1 cm per "
                     f"{0.01 / FORCE_SCALE:g} N", transform=ax.transAxes, va="top", ha="right", fontsize=8,
                     color="#7a0010", zorder=10, bbox=dict(fc="white", ec="#7a0010", lw=0.6, alpha=1.0))
    k_box = [sk.names.index(f"box{k}") for k in BOX_FACES[2]]      # the y- face, seen from the side
    k_links = [[sk.names.index(n) for n in line] for line in sk.links]
    k_w = [i - 1 for i in shown]
    body_x = np.asarray(cols["body.x"], dtype=float)
    frames = []
    for f, k in enumerate(idx):
        pts = sk.points[f]
        box.set_xy(pts[k_box][:, [0, 2]])
        for line, ks in zip(links, k_links):
            line.set_data(pts[ks, 0], pts[ks, 2])
        for i in shown:
            c = pts[sk.names.index(f"c{i}")]
            circles[i].set_center((c[0], c[2]))
            s = c + R * sk.spokes[f, i - 1]
            spokes[i].set_data([c[0], s[0]], [c[2], s[2]])
        arrows.set_offsets(P[f, k_w][:, [0, 2]])
        arrows.set_UVC(F[f, k_w, 0], F[f, k_w, 2])
        xc = body_x[k] + 0.1
        ax.set_xlim(xc - w / 2, xc + w / 2)
        for r in ruler:                 # only the labels in view are drawn
            r.set_visible(abs(r.get_position()[0] - xc) < w / 2 + 0.2)
        label.set_text(f"t = {t[k]:5.2f} s  body.x = {body_x[k]:5.3f} m")
        fig.canvas.draw()
        frame = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
        if f == 0:      # the legend is a fixed, opaque label: drawn once, its pixels pasted into later frames
            b = legend.get_bbox_patch().get_window_extent()
            hgt = frame.shape[0]
            ys = slice(max(0, int(hgt - b.y1) - 1), min(hgt, int(np.ceil(hgt - b.y0)) + 1))
            xs_ = slice(max(0, int(b.x0) - 1), min(frame.shape[1], int(np.ceil(b.x1)) + 1))
            patch = frame[ys, xs_].copy()
            legend.set_visible(False)
        else:
            frame[ys, xs_] = patch
        frames.append(frame)
    plt.close(fig)
    _write_video(frames, path, fps, fmt)
    return path


def _write_video(frames, path, fps, fmt):
    """GIF through Pillow (one palette per frame, 'duration' in ms), MP4 through ffmpeg (H.264) on a pipe."""
    if fmt == "mp4":
        import subprocess
        hgt, wid = frames[0].shape[:2]
        cmd = ["ffmpeg", "-y", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{wid}x{hgt}",
               "-r", f"{fps:g}", "-i", "-", "-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-c:v", "libx264",
               "-pix_fmt", "yuv420p", str(path)]
        subprocess.run(cmd, input=b"".join(f.tobytes() for f in frames), check=True)
        return
    from PIL import Image
    images = [Image.fromarray(f).quantize(colors=64, method=Image.Quantize.FASTOCTREE) for f in frames]
    images[0].save(path, save_all=True, append_images=images[1:], duration=round(1000 / fps), loop=0,
                   optimize=False, disposal=1)


# ---------------------------------------------------------------- the 3D page
def view_data(cols: dict, p: dict, terrain: TerrainMap, fps: float = VIEW_FPS, title: str = "",
              planar: bool | None = None) -> dict:
    """What view.html draws, as plain lists: terrain grid, per-frame points, axles, spokes, contacts, forces."""
    t = np.asarray(cols["time"], dtype=float)
    idx = frame_indices(t, fps)
    sk = skeleton(cols, p, idx)
    P, F = ground_forces(cols, sk.axles, terrain, idx)
    pts = sk.points
    planar = ("body.y" not in cols) if planar is None else planar
    lo, hi = pts[..., :2].reshape(-1, 2).min(axis=0), pts[..., :2].reshape(-1, 2).max(axis=0)
    x0, x1 = lo[0] - 1.0, hi[0] + 1.0
    y0, y1 = (-0.6, 0.6) if planar else (lo[1] - 0.8, hi[1] + 0.8)
    if terrain.extent:
        x0, x1 = max(x0, terrain.extent[0]), min(x1, terrain.extent[1])
        y0, y1 = max(y0, terrain.extent[2]), min(y1, terrain.extent[3])
    cell = max((x1 - x0) / 90, (y1 - y0) / 90, 0.02)
    nx, ny = int(np.ceil((x1 - x0) / cell)) + 1, int(np.ceil((y1 - y0) / cell)) + 1
    GX, GY = np.meshgrid(np.linspace(x0, x1, nx), np.linspace(y0, y1, ny))
    Z = terrain.height(GX, GY)

    def r(a, d=4):
        return np.round(np.asarray(a, dtype=float), d).tolist()
    return dict(
        title=title, planar=planar, R_w=sk.R_w, force_scale=FORCE_SCALE,
        points=sk.names, links=sk.links, box_faces=BOX_FACES, rover=sk.rover,
        terrain=dict(x0=x0, x1=x1, y0=y0, y1=y1, nx=nx, ny=ny, z=r(Z.ravel())),
        t=r(t[idx], 3), p=r(pts), axle=r(sk.axles, 3), spoke=r(sk.spokes, 3), contact=r(P),
        force=r(F, 1), fn=r(np.array([np.asarray(cols.get(f"wheel[{i}].Fn", np.zeros(len(t))))[idx]
                                         for i in WHEELS]).T, 1))


def view_html(data: dict, path) -> Path:
    """view.html with `data` inline (the page needs nothing else)."""
    text = TEMPLATE.read_text()
    blob = json.dumps(data, separators=(",", ":")).replace("</", "<\\/")
    assert "/*DATA*/null" in text
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text.replace("/*DATA*/null", blob, 1).replace("{{TITLE}}", _html_escape(data["title"])))
    return path


def _html_escape(s: str) -> str:
    return s.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


# ---------------------------------------------------------------- both, from a run
def columns(names, rows) -> dict:
    rows = np.asarray(rows, dtype=float)
    return {n: rows[:, k] for k, n in enumerate(names)}


def watch(out_dir, names, rows, fmu_path, title: str = "", video: bool | None = None, page: bool = True,
          stem: str = "", values: dict | None = None) -> dict:
    """Write the run's animation (default: 2D runs only) and view.html into out_dir; returns {"animation": path,
    "view": path, "seconds": {"animation": s, "view": s}}. stem prefixes the file names (several runs in one
    directory); values: terrain inputs the run set (else the FMU's start values)."""
    cols = columns(names, rows)
    p = fmu_numbers(fmu_path)
    terrain = TerrainMap(fmu_path, values)
    planar = "body.y" not in cols
    video = planar if video is None else video
    title = title or p["_model"]
    out = {"seconds": {}}
    out_dir = Path(out_dir)
    if video:
        t0 = time.perf_counter()
        out["animation"] = animation(cols, p, terrain, out_dir / f"{stem}animation", title=title)
        out["seconds"]["animation"] = time.perf_counter() - t0
    if page:
        t0 = time.perf_counter()
        out["view"] = view_html(view_data(cols, p, terrain, title=title, planar=planar), out_dir / f"{stem}view.html")
        out["seconds"]["view"] = time.perf_counter() - t0
    return out


# ---------------------------------------------------------------- from a CSV: python -m cedra watch
def read_csv(path) -> tuple[list[str], np.ndarray]:
    """A run's CSV (a header of names, then one row of numbers per sample, as the runs write them)."""
    import csv
    with open(path, newline="") as fh:
        reader = csv.reader(fh)
        names = next(reader)
        rows = np.array([[float(v) for v in r] for r in reader if r])
    return names, rows


def add_parser(sub):
    p = sub.add_parser("watch", help="animation.gif and view.html of a run's CSV (the runs write them already)")
    p.add_argument("csv", help="a run's CSV with time and the outputs in cedra.run.watch.WATCHED")
    p.add_argument("--fmu", default="build/bump2d.fmu", help="the plant FMU that made it (its parameters and "
                   "terrain; default build/bump2d.fmu)")
    p.add_argument("--out", help="directory (default: the CSV's)")
    p.add_argument("--title", default="")
    p.add_argument("--video", choices=["auto", "yes", "no"], default="auto",
                   help="the side-view animation: auto = for 2D runs")


def main(args) -> int:
    import sys
    names, rows = read_csv(args.csv)
    video = None if args.video == "auto" else args.video == "yes"
    try:
        w = watch(args.out or Path(args.csv).parent, names, rows, args.fmu, title=args.title or Path(args.csv).stem,
                  video=video)
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    for key in ("animation", "view"):
        if key in w:
            print(f"wrote {w[key]} ({w[key].stat().st_size / 1e6:.2f} MB, {w['seconds'][key]:.1f} s)")
    return 0
