"""Motion-blur samples (`Settings.subframes`, `[output] subframes`): the states kept inside each
frame fall where free fall puts them at their own times, the frames themselves keep their bytes,
and USD holds them as time samples between the frames' time codes (read back by usd-core)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from factories import TOP_CORNERS, grid_cloth, write_grid
from typer.testing import CliRunner

from meshdeform.errors import MeshdeformError
from meshdeform.scene import Scene
from meshdeform.simulate import Settings, simulate
from meshdeform.solvers import solver_class
from pipeline.cli import app

G = 9.81


def test_subframes_fall_where_free_fall_puts_them_at_their_times() -> None:
    mesh, model, _ = grid_cloth(4, plane="xz")
    options = solver_class("xpbd").options_class(damping=0.0)
    settings = Settings(solver="xpbd", fps=24, frames=6, options=options, subframes=4)
    assert settings.subframe_substeps == tuple(round(j * settings.substeps / 4) for j in (1, 2, 3))
    previous = 0.0
    for frame in simulate(model, Scene(gravity=(0.0, -G, 0.0)), settings):
        times = [t for t, _ in frame.subframes]
        assert len(times) == 3 and previous < times[0] < times[1] < times[2] < frame.time
        # each is a substep's end: a whole number of steps of 1 / (fps * substeps)
        steps = np.asarray(times) * 24 * settings.substeps
        np.testing.assert_allclose(steps, np.round(steps), atol=1e-9)
        dt = settings.dt
        for t, positions in frame.subframes:
            drop = float(np.mean(mesh.positions[:, 1] - positions[:, 1]))
            # free fall, within the integrator's first-order error g t dt (and not a frame's drop off)
            assert drop == pytest.approx(0.5 * G * t * t, abs=G * t * dt)
        previous = frame.time


@pytest.mark.parametrize(("solver", "subframes"), [("implicit", 2), ("xpbd", 3)])
def test_the_frames_are_the_same_bytes_with_and_without_subframes(solver: str, subframes: int) -> None:
    """The in-between states change nothing: the frames are those of the run without them. (The
    default solver's calm steps, 2 a frame, hold 2 states a frame; asking it for more runs its 8
    steps instead: docs/recipes.md.)"""
    _, model, _ = grid_cloth(8, pins=TOP_CORNERS)
    plain = [f.positions for f in simulate(model, Scene(), Settings(solver=solver, frames=5))]
    blurred = list(simulate(model, Scene(), Settings(solver=solver, frames=5, subframes=subframes)))
    for a, b in zip(plain, blurred, strict=True):
        assert a.tobytes() == b.positions.tobytes()
    assert all(len(f.subframes) == subframes - 1 for f in blurred)


def test_subframes_beyond_the_substeps_are_refused() -> None:
    with pytest.raises(MeshdeformError, match="subframes"):
        Settings(substeps=4, subframes=5)


def test_usd_holds_the_subframes_as_time_samples_between_frames(tmp_path: Path) -> None:
    from pxr import Usd, UsdGeom

    mesh_path = write_grid(tmp_path / "cloth.obj", 6, 6, plane="xz")
    (tmp_path / "r.toml").write_text(
        '[simulation]\nframes = 3\nstart_frame = 10\n[[pins]]\nselect = { indices = [0] }\n'
        '[output]\nformats = ["usd", "npz"]\nsubframes = 2\n'
    )
    out = tmp_path / "out"
    done = CliRunner().invoke(app, ["simulate", str(mesh_path), "-r", str(tmp_path / "r.toml"), "-o", str(out), "-q"])
    assert done.exit_code == 0, done.output
    stage = Usd.Stage.Open(str(out / "scene.usdc"))
    geom = next(UsdGeom.Mesh(p) for p in stage.Traverse() if p.IsA(UsdGeom.Mesh))
    codes = geom.GetPointsAttr().GetTimeSamples()
    # the rest pose at 10, frames at 11, 12, 13, and one state half-way inside each frame
    assert [c for c in codes if c == int(c)] == [10.0, 11.0, 12.0, 13.0]
    inside = [c for c in codes if c != int(c)]
    # half-way, to within a substep (xpbd: 22 a frame)
    assert len(inside) == 3 and all(abs(c % 1.0 - 0.5) <= 1.0 / 22 for c in inside)
    whole = np.load(out / "positions.npz")["positions"]
    for k, code in enumerate((10.0, 11.0, 12.0, 13.0)):
        np.testing.assert_allclose(np.asarray(geom.GetPointsAttr().Get(Usd.TimeCode(code))), whole[k], atol=1e-6)
    for code in inside:  # a state between its two frames, not either of them
        mid = np.asarray(geom.GetPointsAttr().Get(Usd.TimeCode(code)))
        before, after = whole[int(np.floor(code)) - 10], whole[int(np.ceil(code)) - 10]
        assert np.abs(mid - before).max() > 0 and np.abs(mid - after).max() > 0
