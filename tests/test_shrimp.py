"""The shrimp-faithful CEDRA geometry (cedra.rover.shrimp): its rules hold on the rover's own description, and a
broken geometry is refused before any pose or code (cedra.rover.assembly)."""
import math

import numpy as np
import pytest

from cedra.rover import shrimp
from cedra.rover.assembly import assembly_failure
from cedra.rover.climb_pose import PlanarRover
from cedra.rover.mechanism import CEDRA
from cedra.rover.profile import Staircase
from cedra.rover.required_friction import _rest_loads
from cedra.rover.virtual_centres import virtual_centres

VALUES = shrimp.SHRIMP.values


def _fork_centre(values):
    return next(vc for vc in virtual_centres(CEDRA, values) if vc.joint == "theta4")


def test_the_fork_turns_about_the_centre_it_is_built_about():
    """The fork's virtual centre from the description's kinematics (wheel 6's velocity and its coupler's angular
    velocity) is the point four_bar_about builds the links' lines through, to 1e-9 m: FORK_BEHIND behind and
    FORK_BELOW below the wheel's axle. The default fork's centre is ahead of its wheel."""
    vc = _fork_centre(VALUES)
    z0 = shrimp.R_W - shrimp.AXLE_Z                      # the body's height at the design pose
    assert vc.wheel_centre == pytest.approx((shrimp.FORK_WHEEL_X, shrimp.R_W), abs=1e-12)
    assert vc.centre[0] == pytest.approx(shrimp.FORK_WHEEL_X - shrimp.FORK_BEHIND, abs=1e-9)
    assert vc.centre[1] == pytest.approx(z0 + shrimp.AXLE_Z - shrimp.FORK_BELOW, abs=1e-9)
    assert vc.centre[0] < vc.wheel_centre[0] and vc.below_axle > 0          # behind and below the axle
    default = _fork_centre({})
    assert default.centre[0] > default.wheel_centre[0] + 1.0


def test_a_face_pushing_the_fork_wheel_back_lifts_it():
    """A backward force at the wheel's axle height (a step's face) does positive work on the fork's upward motion:
    the virtual work of (-1, 0) on the wheel centre's velocity, per unit rate of lifting it, is positive for the
    shrimp fork (the centre below the axle) and negative for the default's."""
    for values, sign in ((VALUES, 1), ({}, -1)):
        vc = _fork_centre(values)
        (px, pz), (cx, cz) = vc.centre, vc.wheel_centre
        # about the centre, a rotation w moves the wheel centre by w (-(cz - pz), cx - px); lifting it: w (cx - px) > 0
        w = 1.0 / (cx - px)
        vx = -w * (cz - pz)
        assert sign * (-vx) > 0, (values, vc)


def test_the_four_bar_closes_over_its_stops_and_the_design_pose_stands_on_flat_ground():
    assert assembly_failure(CEDRA, VALUES) is None
    rover = PlanarRover(CEDRA, VALUES)
    centres = np.array(rover.geometry(rover.check_design(), rover.par)[0])
    assert np.allclose(centres[1], shrimp.R_W, atol=1e-12)          # every wheel centre R_w above the ground


def test_the_bogie_reaches_over_two_wheel_diameters():
    assert 2 * VALUES["bogie_half"] * math.sin(VALUES["bogie_stop"]) >= 4 * shrimp.R_W
    assert VALUES["bogie_z"] == VALUES["rear_z"]                    # its pivot at the axles' height


def test_the_rear_wheel_carries_a_bogie_wheels_load():
    """At rest on flat ground (the rover's own balance, from its description) the fork wheel carries the fork's and
    its own weight (the spring at rest), and with bogie_x = -rear_x / 4 the rear wheel carries what a bogie wheel
    does: each its own weight and a fifth of the body's (by hand, to 1e-9). The default's rear wheel carries less
    than half of a bogie wheel's load."""
    from cedra.rover.parameters import DEFAULTS as p
    g = p["g"]
    rover = PlanarRover(CEDRA, VALUES)
    loads = dict(zip(rover.groups, _rest_loads(rover, Staircase(0.0).blocks(), rover.check_design())))
    share = p["m_w"] * g + p["m_B"] * g / 5
    assert VALUES["bogie_x"] == pytest.approx(-VALUES["rear_x"] / 4, abs=1e-15)
    for wheel in (1, 2, 5):
        assert loads[wheel] == pytest.approx(share, rel=1e-9), loads
    assert loads[6] == pytest.approx((p["m_F"] + p["m_w"]) * g, rel=1e-9), loads
    default = PlanarRover(CEDRA)
    loads = dict(zip(default.groups, _rest_loads(default, Staircase(0.0).blocks(), default.check_design())))
    assert loads[5] < 0.5 * loads[1], loads


def test_a_four_bar_that_closes_at_its_design_but_not_at_a_stop_is_found():
    """The default four-bar with its lower stop moved past the angle where its links fall in line (theta4 = -0.92
    rad): the check names theta4, an angle within the stops beyond it, and the parameters the chain depends on."""
    assert assembly_failure(CEDRA, {}) is None
    failure = assembly_failure(CEDRA, {"fork_stop_lo": -1.2})
    assert failure is not None and failure.joint == "theta4"
    assert -1.2 <= failure.angle < -0.9 and abs(failure.closure) >= 1 - 1e-6
    assert {"fork_b", "fork_stop_lo"} <= set(failure.parameters)
    assert "fork_k" not in failure.parameters


def test_the_example_scene_and_step_map_name_the_variant():
    """examples/scenes/shrimp_step2d.toml names the variant (CEDRA's model with its values as start values) and
    examples/sweeps/rovers/step_shrimp.toml maps it over step_cedra's grid up to two wheel diameters."""
    from pathlib import Path

    from cedra.models.scene import load
    from cedra.sweep.definition import load as load_sweep
    repo = Path(__file__).resolve().parents[1]
    scene = load(repo / "examples" / "scenes" / "shrimp_step2d.toml")
    assert scene.options.rover == "cedra" and scene.variant is shrimp.SHRIMP
    assert scene.parameters["bogie_half"] == VALUES["bogie_half"] and scene.inputs["terrain_h"] == 4 * shrimp.R_W
    sweep = load_sweep(repo / "examples" / "sweeps" / "rovers" / "step_shrimp.toml")
    assert sweep.target.scene.variant is shrimp.SHRIMP
    assert max(r["terrain_h"] for r in sweep.runs()) == pytest.approx(4 * shrimp.R_W)
