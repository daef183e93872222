"""Headless previews of a deformed mesh sequence with PyVista: PNG frames, a contact sheet, GIF, MP4.

One reused off-screen Plotter renders every frame (`render.FrameRenderer`): the mesh's points,
normals and scalars are updated in place (no new window per frame). The camera is fixed for the
whole sequence, framed on the union of all frames' bounds from a chosen view (iso, front, side,
top; `camera`); in a torn frame only its main pieces count (`framing`: pieces that fall away leave the
view; `framing = "all"` frames everything). The colour range is fixed for the sequence too, from every
frame, so nothing jumps between frames. That needs one pass over the frames before rendering:
`render_previews` (`sequence`) takes the frames as a sequence (a (F, V, 3) array, a list, or any lazy
object with `__len__`/`__getitem__`, such as `open_result`'s loader, which reads a result folder's files
on demand through the readers beside their writers in `meshdeform.export`; `results`).

Colouring (`scalars`): a flat material, per-vertex strain (the largest stretch ratio, current /
rest length, of the edges at a vertex; from 1, no stretch, pale, to the largest stretch of any frame,
dark red; compression shows as no stretch) or the displacement from rest (0 to the largest). The frame
label and the colour bar (its ends the colour map's, the range labelled) are drawn over the view with
Pillow at sizes legible at the image's (`overlay`); the contact sheet labels each tile in a band above it
and has one colour bar. Pinned vertices and torn edges
(boundary edges the rest mesh did not have) can be highlighted, with an optional wireframe overlay.
The scene's colliders, when given (`colliders`: a run's scene, or the one `meshdeform preview` rebuilds
from the run's recipe), are drawn in neutral greys at each frame's time (seconds since the rest pose:
(frame number - start frame) / fps), planes as a floor under the cloth; the camera stays framed on the cloth.

Frame numbers are scene frames, as the result's files number them (the rest pose at the run's start
frame, 1 by default); `every` counts from the sequence's first frame.

Files (inside `out_dir`; `media`): `preview/0001.png` ... (frame numbers, 4 digits),
`preview/contact_sheet.png`, `preview.mp4` / `preview.gif`. Every file is written atomically.
"""

from meshdeform.export.results import FrameItem
from meshdeform.preview.camera import CameraSetup, frame_camera
from meshdeform.preview.media import contact_sheet
from meshdeform.preview.options import (
    COLORS,
    CONTACT_SHEET_NAME,
    PREVIEW_FOLDER,
    VIDEOS,
    VIEWS,
    PreviewOptions,
    PreviewResult,
)
from meshdeform.preview.render import FrameRenderer, boundary_edges
from meshdeform.preview.results import ResultSequence, open_result, render_result, render_result_previews
from meshdeform.preview.scalars import EdgeStrain
from meshdeform.preview.sequence import render_previews

__all__ = [
    "COLORS",
    "CONTACT_SHEET_NAME",
    "PREVIEW_FOLDER",
    "VIDEOS",
    "VIEWS",
    "CameraSetup",
    "EdgeStrain",
    "FrameItem",
    "FrameRenderer",
    "PreviewOptions",
    "PreviewResult",
    "ResultSequence",
    "boundary_edges",
    "contact_sheet",
    "frame_camera",
    "open_result",
    "render_previews",
    "render_result",
    "render_result_previews",
]
