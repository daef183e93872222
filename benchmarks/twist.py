"""Strips twisted by turning pins, self-collision on, each solver at its defaults, through the
recipe path.

    PYTHONPATH=. python benchmarks/twist.py [--solvers implicit xpbd verlet] [--degrees 720 1080]

The scene is `tests/factories.twisted_strip`: a 0.4 x 1 m strip of 20 x 20 vertices (diagonals
alternating), its top row pinned still and its bottom row pinned to a turn about the vertical
axis while rising 0.3 m over 2 s, no gravity, 24 fps; built as `meshdeform simulate` builds it
(`pipeline.build.build_simulation`, then `meshdeform.simulate`). The strip winds into a rope and
its impact zones hold turning pins (docs/performance.md, "Zones turned with their pins").

Printed per solver and turn: the largest count over frames of intersecting triangle pairs that
share no vertex (tests/intersections.py, decided by ipctk: an oracle meshdeform did not write) and
the first frame with one, the worst structural stretch, self-collision's work summed over the
frames (pairs flagged by the continuous check, impact-zone rounds, the largest zone) and the
seconds the frames took, or the error where a run stopped. Not run in CI.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tests"))  # the tests' helpers and their intersection oracle (no package)

from factories import twisted_strip  # noqa: E402
from intersections import intersecting_pairs  # noqa: E402

from meshdeform.errors import MeshdeformError  # noqa: E402
from meshdeform.simulate import simulate  # noqa: E402
from pipeline.build import build_simulation  # noqa: E402
from pipeline.recipe import parse_recipe  # noqa: E402


def line(solver: str, degrees: float) -> str:
    """One run's figures (the module docstring)."""
    mesh, text = twisted_strip(solver, degrees)
    built = build_simulation(parse_recipe(text), mesh)
    pairs, stretch = [], []
    flagged = rounds = largest = 0
    seconds = 0.0
    tick = time.perf_counter()
    try:
        for frame in simulate(built.model, built.scene, built.settings):
            seconds += time.perf_counter() - tick
            pairs.append(intersecting_pairs(frame.welded_positions, frame.model.triangles))
            stretch.append(frame.max_stretch)
            if frame.contact is not None:
                flagged += frame.contact.flagged_pairs
                rounds += frame.contact.zone_rounds
                largest = max(largest, frame.contact.largest_zone)
            tick = time.perf_counter()
    except MeshdeformError as error:
        return f"stopped: {str(error)[:100]}"
    first = next((k + 1 for k, count in enumerate(pairs) if count), None)
    return (
        f"{max(pairs):5d} {first or '-'!s:>5} {max(stretch):7.3f} {flagged:8d} {rounds:6d} {largest:7d} "
        f"{seconds:7.2f}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--solvers", nargs="+", default=["implicit", "xpbd", "verlet"])
    parser.add_argument("--degrees", nargs="+", type=float, default=[720.0, 1080.0])
    args = parser.parse_args()
    print(f"{'solver':<9} {'turn':>6} pairs first stretch  flagged rounds largest    secs")
    for solver in args.solvers:
        for degrees in args.degrees:
            print(f"{solver:<9} {degrees:6g} {line(solver, degrees)}", flush=True)


if __name__ == "__main__":
    main()
