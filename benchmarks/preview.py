"""Preview speed: seconds per 800x600 frame, and a 120-frame MP4 of a 64 x 64 cloth.

    .venv/bin/python benchmarks/preview.py [--frames 120] [--size 800x600] [--grid 64] [--no-aa-mp4]

Synthetic motion (a sagging, waving sheet pinned along its top), so only previewing is measured:
per frame the strain, normals, render and read-back; for the MP4 also the bounds pass and the
H.264 encoding (a separate ffmpeg process). Rendering is software OpenGL (Mesa llvmpipe through
EGL) on machines without a GPU, so wall times depend on the cores free at the time: the CPU
seconds of this process (all its threads) are printed too, and so is the load average.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from meshdeform.mesh import Mesh, grid_mesh
from meshdeform.preview import EdgeStrain, FrameRenderer, PreviewOptions, render_previews


def cloth_frames(n: int, frames: int) -> tuple[Mesh, list[np.ndarray], np.ndarray]:
    """A sheet pinned along its top that sags (stretching most at the pins) and waves."""
    mesh = grid_mesh(n, n)
    rest = mesh.positions
    u = 1.0 - rest[:, 1]
    out = []
    for i in range(1, frames + 1):
        s = 0.3 * i / frames
        pos = rest.copy()
        pos[:, 1] = 1.0 - (u + s * (2 * u - u * u) / 2)
        pos[:, 2] = 0.1 * np.sin(3 * rest[:, 0] + 0.25 * i) * u
        out.append(pos)
    return mesh, out, np.flatnonzero(rest[:, 1] > 1 - 1e-9)


def per_frame(mesh: Mesh, frames: list[np.ndarray], pinned: np.ndarray, options: PreviewOptions) -> tuple[float, ...]:
    """(set-up seconds, wall seconds per frame, CPU seconds per frame) of the reused renderer."""
    stack = np.stack(frames)
    bounds = np.stack([stack.min(axis=(0, 1)), stack.max(axis=(0, 1))])
    strain = EdgeStrain(mesh, mesh.positions)
    started = time.perf_counter()
    renderer = FrameRenderer(mesh, options, bounds, (0.7, 1.3), pinned)
    renderer.overlay.decorate(renderer.render(frames[0], strain(frames[0])), 1)  # the first frame compiles shaders
    setup = time.perf_counter() - started
    count = min(40, len(frames))
    started, cpu = time.perf_counter(), time.process_time()
    for k in range(count):
        renderer.overlay.decorate(renderer.render(frames[k], strain(frames[k])), k + 1)
    wall = (time.perf_counter() - started) / count
    cpu_time = (time.process_time() - cpu) / count
    renderer.close()
    return setup, wall, cpu_time


def mp4(mesh: Mesh, frames: list[np.ndarray], pinned: np.ndarray, options: PreviewOptions) -> tuple[float, float]:
    """(seconds, MB) for `render_previews` writing an MP4 of every frame (and one PNG)."""
    with tempfile.TemporaryDirectory() as tmp:
        started = time.perf_counter()
        result = render_previews(mesh, frames, Path(tmp), options, pinned=pinned, fps=24)
        total = time.perf_counter() - started
        size = result.video.stat().st_size if result.video else 0
    return total, size / 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=120)
    parser.add_argument("--size", default="800x600")
    parser.add_argument("--grid", type=int, default=64)
    parser.add_argument("--no-aa-mp4", action="store_true", help="also time the MP4 without anti-aliasing")
    args = parser.parse_args()
    size = tuple(int(v) for v in args.size.lower().split("x"))
    mesh, frames, pinned = cloth_frames(args.grid, args.frames)
    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    what = f"{size[0]}x{size[1]} frame of the {args.grid}x{args.grid} cloth (strain colours, colour bar, pins, label)"
    for aa in (True, False):
        setup, wall, cpu = per_frame(mesh, frames, pinned, PreviewOptions(size=size, anti_aliasing=aa))
        print(
            f"one {what}, {'4x MSAA' if aa else 'no anti-aliasing'}: {wall:.3f} s ({1 / wall:.1f} frames/s; "
            f"{cpu:.3f} CPU s); renderer set-up and first frame {setup:.2f} s"
        )
    for aa in (True, False) if args.no_aa_mp4 else (True,):
        options = PreviewOptions(size=size, video="mp4", frames=(1,), anti_aliasing=aa)
        total, mb = mp4(mesh, frames, pinned, options)
        print(
            f"{args.frames}-frame MP4 of the {args.grid}x{args.grid} cloth at {size[0]}x{size[1]}, "
            f"{'4x MSAA' if aa else 'no anti-aliasing'}: {total:.2f} s ({total / args.frames:.3f} s per frame, "
            f"{mb:.2f} MB)"
        )
    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")


if __name__ == "__main__":
    main()
