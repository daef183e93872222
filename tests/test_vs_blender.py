"""benchmarks/vs_blender.py's meshdeform side and its quality-adjusted choice (no timings asserted;
the Blender side needs `bpy` and is not run here)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from meshdeform.simulate import Scene, Settings, simulate

_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "vs_blender.py"
_SPEC = importlib.util.spec_from_file_location("vs_blender", _PATH)
vs_blender = importlib.util.module_from_spec(_SPEC)
sys.modules.setdefault("vs_blender", vs_blender)  # its dataclasses look their module up there
_SPEC.loader.exec_module(vs_blender)


@pytest.mark.parametrize("scene", ["flat", "hanging"])
def test_every_simulated_frame_is_counted_and_its_stretch_measured(scene: str) -> None:
    """The run counts the frames asked for and reports the worst of every frame's stretch, which the
    simulation loop's own per-frame figure (its divergence guard's spring pass) confirms."""
    run = vs_blender.run_meshdeform("xpbd:substeps=4", 6, 5, scene)
    settings = Settings(solver="xpbd", frames=5, substeps=4)
    frames = list(simulate(vs_blender.meshdeform_inputs(6, scene), Scene(), settings))
    assert run.frames == 5
    assert run.max_stretch == pytest.approx(max(f.max_stretch for f in frames), rel=1e-12)
    assert run.last_stretch == pytest.approx(frames[-1].max_stretch, rel=1e-12)
    assert run.max_stretch > 1.0  # the cloth moved: gravity stretches it


def test_the_pinned_corners_are_those_of_the_far_or_top_edge() -> None:
    """Flat: the pinned edge is at z = 1 with the grid at y = 0; hanging: the top edge, y = 1."""
    for scene, axis in (("flat", 2), ("hanging", 1)):
        model = vs_blender.meshdeform_inputs(5, scene)
        pinned = model.rest_positions[model.inv_mass == 0.0]
        assert len(pinned) == 2
        np.testing.assert_array_equal(pinned[:, axis], [1.0, 1.0])
        np.testing.assert_array_equal(sorted(pinned[:, 0]), [0.0, 1.0])


def test_parse_config_reads_substeps_and_options() -> None:
    assert vs_blender.parse_config("xpbd") == ("xpbd", None, {})
    assert vs_blender.parse_config("implicit:substeps=16:iterations=6") == ("implicit", 16, {"iterations": 6})
    assert vs_blender.parse_config("springs:strain_limit=1.05:stable_substeps=false") == (
        "springs",
        None,
        {"strain_limit": 1.05, "stable_substeps": False},
    )


def test_fastest_within_takes_the_fastest_setting_under_the_bound_per_side() -> None:
    def row(side: str, setting: str, seconds: float, stretch: float):
        r = vs_blender.Row(side, setting)
        r.runs.append(vs_blender.Run(side, setting, 10, seconds, stretch, stretch))
        return r

    rows = [
        row("blender", "quality 5", 1.0, 1.3),
        row("blender", "quality 10", 2.0, 1.2),
        row("xpbd", "2 x 22", 0.1, 1.12),
        row("xpbd", "2 x 44", 0.2, 1.06),
        row("xpbd", "2 x 88", 0.4, 1.04),
    ]
    within_110 = vs_blender.fastest_within(rows, 1.10)
    assert within_110["blender"] is None
    assert within_110["xpbd"].setting == "2 x 44"
    assert vs_blender.fastest_within(rows, 1.05)["xpbd"].setting == "2 x 88"
    assert vs_blender.fastest_within(rows, 1.5)["blender"].setting == "quality 5"


def test_a_stiffer_material_stretches_less_and_an_unknown_option_is_refused() -> None:
    soft = vs_blender.run_meshdeform("implicit:stretch_modulus=1000", 6, 5, "hanging")
    stiff = vs_blender.run_meshdeform("implicit", 6, 5, "hanging")  # the default, 10 000 N/m
    assert 1.0 < stiff.max_stretch < soft.max_stretch
    with pytest.raises(SystemExit, match="no option"):
        vs_blender.run_meshdeform("implicit:tethers=1.0", 6, 5, "flat")
