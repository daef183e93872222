"""Start-up of `meshdeform simulate MESH --out DIR --frames 1`, cold (empty Numba cache) and warm.

    PYTHONPATH=<tree> python benchmarks/startup.py [--repeat 3] [--cases grid8,grid40,fold]
        [--cold | --warm]

Every run is a fresh process, the command line tool as a user starts it:

    python -c "from pipeline.cli import app; app()" simulate MESH --out DIR --frames 1 [-r RECIPE]

(the console script `meshdeform` runs the same `app`), in its own empty output folder. Cold: a
new, empty NUMBA_CACHE_DIR for each run, so every kernel the run uses is compiled (a fresh CI
runner, container or Dask worker). Warm: one NUMBA_CACHE_DIR, filled by a first run that is not
counted. The runs of one case take turns (cold, warm, cold, ...) so that a change in the
machine's load touches both. PYTHONDONTWRITEBYTECODE is removed from the children's environment
and one uncounted run comes first: the modules' .pyc files exist, as in an installed package.

Cases (the meshes are written into a temporary folder: the grids here, the samples by
samples/make_samples.py; the recipes are this repository's samples/recipes):
- grid8, grid40, grid256: an N x N quad grid in the XY plane, 1 m square, the default recipe
  (grid256: 65 536 vertices, issue 16's production resolution);
- curtain, flag_mesh, sheet, icosphere, rope: the sample meshes with the default recipe;
- flag: samples/meshes/flag.obj with samples/recipes/flag.toml (wind, turbulence, tethers);
- fold: samples/meshes/sheet.obj with samples/recipes/fold.toml (a capsule, the ground and
  self-collision);
- sill: samples/meshes/curtain.obj with samples/recipes/curtain.toml (wind and a box collider);
- cape: samples/meshes/cape.obj with samples/recipes/cape.toml (a body mesh following a point cache).

Prints per case and kind the median, minimum and maximum over the repetitions of the wall
seconds and of the CPU seconds (user + system of the child: less sensitive to other jobs on a
shared machine), then the command, then the load average at the start and at the end.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RECIPES = ROOT / "samples" / "recipes"
#: case -> (mesh file name in the case folder, recipe path or None for the default)
CASES: dict[str, tuple[str, Path | None]] = {
    "grid8": ("grid8.obj", None),
    "grid40": ("grid40.obj", None),
    "grid256": ("grid256.obj", None),
    "curtain": ("curtain.obj", None),
    "flag_mesh": ("flag.obj", None),
    "sheet": ("sheet.obj", None),
    "icosphere": ("icosphere.ply", None),
    "rope": ("rope.obj", None),
    "flag": ("flag.obj", RECIPES / "flag.toml"),
    "fold": ("sheet.obj", RECIPES / "fold.toml"),
    "sill": ("curtain.obj", RECIPES / "curtain.toml"),
    "cape": ("cape.obj", RECIPES / "cape.toml"),
}
DEFAULT_CASES = ("grid8", "grid40", "curtain", "flag", "fold")
#: the tool started as a user starts it (the console script runs the same `app`)
TOOL = [sys.executable, "-c", "from pipeline.cli import app; app()"]


def make_meshes(folder: Path) -> None:
    """The grids and the sample meshes, into `folder`."""
    from meshdeform.io import write_obj
    from meshdeform.mesh import grid_mesh

    for n in (8, 40, 256):
        write_obj(folder / f"grid{n}.obj", grid_mesh(n, n, plane="xy"))
    subprocess.run(
        [sys.executable, str(ROOT / "samples" / "make_samples.py"), str(folder)], check=True, stdout=subprocess.DEVNULL
    )


def command(folder: Path, case: str, out: Path) -> list[str]:
    mesh, recipe = CASES[case]
    args = [*TOOL, "simulate", str(folder / mesh), "--out", str(out), "--frames", "1", "--quiet"]
    return args + (["--recipe", str(recipe)] if recipe is not None else [])


def timed(args: list[str], cache: Path) -> tuple[float, float]:
    """(wall seconds, CPU seconds of the child) of one run with Numba's cache in `cache`, started
    in the cache's folder: `python -c` puts its working folder first on `sys.path`, so a run
    started in a source tree would import that tree's code, not the one PYTHONPATH names."""
    env = {key: value for key, value in os.environ.items() if key != "PYTHONDONTWRITEBYTECODE"}
    env["NUMBA_CACHE_DIR"] = str(cache)
    if env.get("PYTHONPATH"):  # its folders as this process reads them (the child starts elsewhere)
        env["PYTHONPATH"] = os.pathsep.join(str(Path(p).resolve()) for p in env["PYTHONPATH"].split(os.pathsep) if p)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run(
        args, env=env, cwd=cache.parent, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
    )
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(args)} failed ({done.returncode}): {done.stderr.strip()}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def figures(values: list[float]) -> str:
    return f"{statistics.median(values):6.2f} ({min(values):.2f}-{max(values):.2f})"


def load() -> str:
    return " ".join(f"{v:.2f}" for v in os.getloadavg())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3, help="counted runs of each kind (median quoted)")
    parser.add_argument("--cases", default=",".join(DEFAULT_CASES), help=f"comma-separated, of {', '.join(CASES)}")
    kinds = parser.add_mutually_exclusive_group()
    kinds.add_argument("--cold", action="store_true", help="cold runs only")
    kinds.add_argument("--warm", action="store_true", help="warm runs only")
    args = parser.parse_args()
    cases = [c.strip() for c in args.cases.split(",") if c.strip()]
    unknown = [c for c in cases if c not in CASES]
    if unknown:
        parser.error(f"unknown cases {unknown}; known: {', '.join(CASES)}")
    wanted = ["cold"] * (not args.warm) + ["warm"] * (not args.cold)
    print(f"load average {load()}", flush=True)
    with tempfile.TemporaryDirectory(prefix="meshdeform-startup-") as tmp:
        root = Path(tmp)
        meshes = root / "meshes"
        meshes.mkdir()
        make_meshes(meshes)
        runs = iter(range(10**9))
        for case in cases:
            warm_cache = root / f"warm-{case}"
            timed(command(meshes, case, root / f"out-{next(runs)}"), warm_cache)  # .pyc files, the warm cache
            results: dict[str, list[tuple[float, float]]] = {kind: [] for kind in wanted}
            for _ in range(args.repeat):
                for kind in wanted:
                    cache = warm_cache if kind == "warm" else root / f"cold-{next(runs)}"
                    results[kind].append(timed(command(meshes, case, root / f"out-{next(runs)}"), cache))
            for kind in wanted:
                walls = [wall for wall, _ in results[kind]]
                cpus = [cpu for _, cpu in results[kind]]
                print(
                    f"{case:10s} {kind}: wall {figures(walls)} s, cpu {figures(cpus)} s "
                    f"(median (min-max) of {args.repeat})",
                    flush=True,
                )
            mesh, recipe = CASES[case]
            shown = f"meshdeform simulate {mesh} --out DIR --frames 1" + (f" -r {recipe.name}" if recipe else "")
            print(f"{'':10s} command: {shown}", flush=True)
    print(f"load average {load()}", flush=True)


if __name__ == "__main__":
    main()
