"""`python -m cedra report rovers --quick`: the paper's run for both rovers and the three controllers (the climbing
maps, nine sweeps of 20 to 112 runs each, are the full report's: `python -m cedra report rovers`)."""
import argparse
from pathlib import Path

import numpy as np
import pytest

from cedra.reports import rovers as R
from fmu_harness import shipped_fmu


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    build = tmp_path_factory.mktemp("rovers_build")
    for name in ("bump2d", "rb_bump2d", "drive2d", "rb_drive2d"):       # the shipped FMUs, where the report finds them
        (build / f"{name}.fmu").symlink_to(shipped_fmu(name, tmp_path_factory))
    out = tmp_path_factory.mktemp("rovers_out")
    args = argparse.Namespace(build=str(build), out=str(out), quick=True, quiet=True)
    assert R.main(args) == 0
    return out


def table_rows(out: Path, first: str) -> list[dict]:
    """The rows of the table of rovers.md whose header line starts with first, each as {column: cell}."""
    lines = (out / "rovers.md").read_text().splitlines()
    head = next(k for k, line in enumerate(lines) if line.startswith(first))
    names = [c.strip() for c in lines[head].strip("|").split("|")]
    rows = []
    for line in lines[head + 2:]:
        if not line.startswith("|"):
            break
        rows.append(dict(zip(names, (c.strip() for c in line.strip("|").split("|")))))
    return rows


def rows_of(out: Path) -> dict:
    """The measures table of rovers.md as {(rover, controller, terrain): row}."""
    return {(c["rover"], c["controller"], c["terrain"]): c for c in table_rows(out, "| rover | controller")}


def test_both_rovers_over_the_paper_bump_with_every_controller(report):
    rows = rows_of(report)
    assert len(rows) == 2 * len(R.CONTROLLERS) * 2 == 12
    for rover in R.ROVERS:
        for controller in R.CONTROLLERS:
            over = rows[(rover, controller, "bump")]["last wheel past the bump"]
            assert over.endswith(" s") and 5.0 < float(over[:-2]) < 15.0, (rover, controller, over)


def test_the_rocker_bogie_spreads_its_load_evenly_and_cedra_does_not(report):
    """On flat ground the rocker-bogie's lever arms give six equal loads (max / min 1 to 1 %); CEDRA's design
    puts less on its front and rear wheels (5, 6) than on the bogies'."""
    rows = rows_of(report)
    for controller in R.CONTROLLERS:
        assert float(rows[("rocker-bogie", controller, "flat")]["load spread max/min (5-15 s)"]) < 1.01
        assert float(rows[("CEDRA", controller, "flat")]["load spread max/min (5-15 s)"]) > 2.0


def test_over_the_bump_the_rocker_bogie_loads_its_wheels_less(report):
    rows = rows_of(report)
    for controller in R.CONTROLLERS:
        rb, cedra = rows[("rocker-bogie", controller, "bump")], rows[("CEDRA", controller, "bump")]
        assert float(rb["peak Fn (N)"]) < 0.5 * float(cedra["peak Fn (N)"])
    # the inverse kinematics cuts CEDRA's slip on the bump (its light wheels spin under equal torques)
    assert float(rows[("CEDRA", "inverse kinematics", "bump")]["mean slip (m/s)"]) < \
        0.2 * float(rows[("CEDRA", "equal torques", "bump")]["mean slip (m/s)"])


def test_highest_over_per_friction():
    rows = [dict(mu="0.8", terrain_h=str(h), verdict=v) for h, v in
            ((0.0, "over"), (0.065, "over"), (0.13, "stuck"), (0.195, "over"), (0.26, "hung up"))]
    rows += [dict(mu="0.4", terrain_h=str(h), verdict="stuck") for h in (0.0, 0.065)]
    best = R.highest_over(rows)
    assert best[0.8] == (0.195, False)          # 3 R_w over, but 2 R_w below it is not
    assert np.isnan(best[0.4][0])



def statics_rows(out: Path, terrain: str) -> dict:
    """The quasi-static table of rovers.md for the step or the stairs as {(rover, h / R_w): row}."""
    column = "h / R_w" if terrain == "step" else "rise / R_w"
    return {(c["rover"], float(c[column])): c for c in table_rows(out, f"| rover | {column} |")}


def test_the_quick_report_draws_the_required_friction_and_the_virtual_centres(report):
    """The quick form has the quasi-static curve for both rovers: finite on the step up to 2 R_w, rising with h up
    to the wheel radius (the edge's contact steepens), and both figures."""
    assert (report / "rovers_statics.png").stat().st_size > 10_000
    assert (report / "rovers_centres.png").stat().st_size > 10_000
    rows = statics_rows(report, "step")
    for rover in R.ROVERS:
        ratios = [float(rows[(rover, h)]["required friction"]) for h in (0.5, 1.0, 1.5, 2.0)]
        assert all(np.isfinite(ratios)) and all(r > 0 for r in ratios), (rover, ratios)
        assert ratios[1] > ratios[0], (rover, ratios)
    text = (report / "rovers.md").read_text()
    assert "| CEDRA | theta4 | 6 |" in text        # the fork's virtual centre is in the table


def test_the_shrimp_variant_climbs_two_wheel_diameters_below_unit_friction(report):
    """The quick form's step curve goes to two wheel diameters (4 R_w) for the three rovers; the shrimp-faithful
    CEDRA's is solved at every height and requires less than 1 at 4 R_w, and less than the default CEDRA wherever
    the default's is solved; the stairs are solved for every rover; its fork's virtual centre is behind and below
    the wheel axle, the default's ahead."""
    rows = statics_rows(report, "step")
    heights = (0.5, 1.0, 1.5, 2.0, 4.0)
    shrimp = [float(rows[("CEDRA shrimp", h)]["required friction"]) for h in heights]
    assert shrimp[-1] < 1.0, shrimp
    for h, s in zip(heights, shrimp):
        default = rows[("CEDRA", h)]["required friction"]
        assert default == "not solved" or s < float(default), (h, s, default)
    assert rows[("rocker-bogie", 4.0)]["required friction"] != "not solved"
    for rover in ("CEDRA", "CEDRA shrimp", "rocker-bogie"):
        stairs = statics_rows(report, "stairs")[(rover, 1.5)]
        assert stairs["required friction"] != "not solved" and np.isfinite(float(stairs["required friction"]))
    centres = {r["rover"]: r for r in table_rows(report, "| rover | joint |") if r["joint"] == "theta4"}
    for rover, behind in (("CEDRA shrimp", True), ("CEDRA", False)):
        (cx, cz), (wx, wz) = (tuple(map(float, centres[rover][k].split(", ")))
                              for k in ("virtual centre x, z (m)", "wheel centre x, z (m)"))
        assert (cx < wx) == behind and cz < wz, centres[rover]


def test_the_maps_table_lists_a_variants_map_after_the_rovers():
    """A variant's map (VARIANT_MAPS) gets its own row after the rovers' on its terrain, its highest step per mu."""
    rows = [dict(mu=str(mu), terrain_h=str(h), verdict="over" if h <= top else "stuck")
            for mu, top in ((0.4, 0.0325), (0.8, 0.1625)) for h in (0.0, 0.0325, 0.1625, 0.26)]
    sw = type("Sweep", (), {"grid": {"terrain_h": [0.0, 0.0325, 0.1625, 0.26], "mu": [0.4, 0.8]}})()
    maps = {("step", "CEDRA"): (sw, rows), ("step", "CEDRA shrimp"): (sw, rows)}
    lines = R.maps_table(maps)
    assert [ln.split("|")[2].strip() for ln in lines[2:]] == ["CEDRA", "CEDRA shrimp"]
    assert lines[-1].split("|")[3:5] == [" 0.5 R_w ", " 2.5 R_w "], lines[-1]
    assert set(R.VARIANT_MAPS) <= set(R.map_sweeps())
