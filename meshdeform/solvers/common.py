"""Per-model data the solvers derive once: spring constants, damping coefficients, layouts."""

from __future__ import annotations

import weakref
from collections.abc import Callable
from typing import ClassVar, NamedTuple

import numpy as np

from meshdeform.model import SpringModel, State
from meshdeform.solvers.base import Control
from meshdeform.solvers.dispatch import SubstepPicker, substep_picker
from meshdeform.solvers.layout import SpringLayout, inherited_layout, kernel_chunks, spring_layout
from meshdeform.solvers.options import SweepOptions
from meshdeform.solvers.sweep_kernels import PLANE, VERTEX


def spring_constants(model: SpringModel) -> tuple[np.ndarray, np.ndarray]:
    """(k_tension, k_compression) per spring in N/m: stiffness * material.stretch_modulus."""
    modulus = float(model.material.stretch_modulus)
    kt = np.maximum(np.asarray(model.stiffness, dtype=np.float64), 0.0) * modulus
    kc = np.maximum(np.asarray(model.compression, dtype=np.float64), 0.0) * modulus
    return kt, kc


def reduced_mass(model: SpringModel) -> np.ndarray:
    """Reduced mass 1 / (w_a + w_b) of each spring's ends (0 when both are pinned)."""
    w = model.inv_mass[model.springs[:, 0]] + model.inv_mass[model.springs[:, 1]]
    return np.where(w > 0.0, 1.0 / np.where(w > 0.0, w, 1.0), 0.0)


def damping_coefficients(model: SpringModel, k: np.ndarray) -> np.ndarray:
    """Spring damping c = 2 z sqrt(k m_reduced) in Ns/m from the damping ratio z per spring."""
    z = np.maximum(np.asarray(model.damping, dtype=np.float64), 0.0)
    return 2.0 * z * np.sqrt(k * reduced_mass(model))


def structural_mask(model: SpringModel) -> np.ndarray:
    from meshdeform.topology import SpringKind

    return np.asarray(model.kinds) == SpringKind.STRUCTURAL


class ModelCache:
    """Mixin: `self._prepared(model)` rebuilds per-model data when the model changes."""

    _model: SpringModel | None = None

    def _prepared(self, model: SpringModel) -> bool:
        """True when the cache is for this model; otherwise remember it and return False."""
        if self._model is model:
            return True
        self._model = model
        return False


class LayoutCache(ModelCache):
    """ModelCache of the solvers that sweep a `layout.SpringLayout` (verlet, xpbd).

    After a tear (`follow_tear`, called by `simulate`) the torn model's layout is derived from
    the current one (`layout.inherited_layout`) instead of being sorted afresh, which keeps
    frequent topology updates cheap. Either way the result depends only on the sequence of
    models, so runs stay reproducible.
    """

    layout: SpringLayout | None = None
    _successor: tuple[SpringModel, SpringLayout, np.ndarray, np.ndarray] | None = None
    _buffers: dict[str, np.ndarray] | None = None

    def follow_tear(self, previous: SpringModel, model: SpringModel, index_map: np.ndarray, parent: np.ndarray) -> None:
        """`model` replaces `previous` (index_map: new vertex -> previous one; parent: new spring
        -> previous one); used when `model` is prepared, if `previous` is the model prepared last."""
        if self._model is previous and self.layout is not None:
            self._successor = (model, self.layout, index_map, parent)

    def _buffer(self, name: str, count: int, dtype: type | np.dtype) -> np.ndarray:
        """A cache-line-aligned (count,) array of `dtype`, reused from one model to the next.

        Its contents are left from before (callers write every field before reading it): a
        torn model, a little larger or smaller than the last, then costs no fresh allocation
        and page faults; it grows with 1/8 to spare.
        """
        if self._buffers is None:
            self._buffers = {}
        buffers = self._buffers
        held = buffers.get(name)
        if held is None or held.dtype != np.dtype(dtype) or held.shape[0] < count:
            held = buffers[name] = aligned_zeros((count + count // 8,), dtype)
        return held[:count]

    def _layout_for(self, model: SpringModel, parts: int) -> SpringLayout:
        """The layout to prepare `model` with: inherited after a tear, else built afresh."""
        successor, self._successor = self._successor, None
        if successor is not None and successor[0] is model:
            inherited = inherited_layout(successor[1], model, successor[2], successor[3])
            if inherited is not None:
                return inherited
        return spring_layout(model, parts)


def aligned_zeros(shape: tuple[int, ...], dtype: type = np.float64, align: int = 64) -> np.ndarray:
    """A C-contiguous zero array whose data starts on an `align`-byte boundary (a cache line)."""
    dt = np.dtype(dtype)
    count = int(np.prod(shape))
    raw = np.zeros(count * dt.itemsize + align, dtype=np.uint8)
    start = (-raw.ctypes.data) % align
    return raw[start : start + count * dt.itemsize].view(dt).reshape(shape)


class TetherLinks(NamedTuple):
    """Kernel tethers (`sweep_kernels.TETHER` records) and, per record r, the records of the
    same pin group at its vertex's neighbours along the tether paths: links[offsets[r]:
    offsets[r + 1]] (record indices), each with gap = limit ratio x slack x the rest length
    between the two vertices (m). By the triangle inequality of the paths, a neighbour within
    its own limit is never further from the pins than r's limit plus that gap
    (`sweep_kernels.release_tethers`)."""

    records: np.ndarray
    offsets: np.ndarray
    links: np.ndarray
    gaps: np.ndarray


def kernel_tethers(
    model: SpringModel,
    rank: np.ndarray,
    ratio: float | None,
    kinds: tuple[int, ...] | None = None,
    slack: float = 1.0,
) -> TetherLinks:
    """Tethers (see `layout.tethers`, paths over springs of `kinds`) as `sweep_kernels.TETHER`
    records with their links (`TetherLinks`).

    In a layout's kernel numbering (rank: model vertex -> kernel vertex); limits times `slack`.
    Sorted by kernel vertex (stably, so a vertex's tethers keep their order); empty when
    `ratio` is None or not positive.
    """
    from meshdeform.solvers.layout import TETHER_PATH_KINDS, tethers
    from meshdeform.solvers.sweep_kernels import TETHER

    if ratio is None or ratio <= 0:
        return TetherLinks(np.zeros(0, dtype=TETHER), np.zeros(1, np.int64), np.zeros(0, np.int64), np.zeros(0))
    kinds = TETHER_PATH_KINDS if kinds is None else kinds
    t = tethers(model, ratio, kinds=kinds)
    vertex = rank[t.vertex]
    order = np.argsort(vertex, kind="stable")
    out = np.zeros(order.shape[0], dtype=TETHER)
    out["v"] = vertex[order]
    out["p"] = rank[t.pin][order]
    out["lim"] = t.limit[order] * float(slack)
    offsets, links, gaps = _tether_links(model, kinds, t.vertex[order], t.group[order], float(ratio) * float(slack))
    return TetherLinks(out, offsets, links, gaps)


def _tether_links(
    model: SpringModel, kinds: tuple[int, ...], vertex: np.ndarray, group: np.ndarray, scale: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For tether records r of model vertices vertex (R,) and pin groups group (R,): each record's
    links, the records of the same group at the vertex's neighbours along springs of `kinds`,
    as (offsets (R + 1,), links (K,) record indices, gaps (K,) m: scale times the spring's rest
    length), in record order, then in the order of the vertex's springs. Vectorised: every
    record's neighbours looked up at once among the (vertex, group) keys."""
    along = np.isin(np.asarray(model.kinds), np.asarray(kinds, dtype=np.int64))
    ends = np.asarray(model.springs, dtype=np.int64)[along]
    length = np.asarray(model.rest_lengths, dtype=np.float64)[along]
    # the springs both ways, by their first end: vertex v's neighbours are b[first[v]:first[v + 1]]
    a = np.concatenate([ends[:, 0], ends[:, 1]])
    by = np.argsort(a, kind="stable")
    a = a[by]
    b = np.concatenate([ends[:, 1], ends[:, 0]])[by]
    both_lengths = np.concatenate([length, length])[by]
    first = np.searchsorted(a, np.arange(model.vertex_count + 1))
    groups = int(group.max()) + 1 if group.size else 1
    keys = vertex * groups + group
    key_order = np.argsort(keys, kind="stable")
    sorted_keys = keys[key_order]
    # one slot per (record, neighbour of its vertex)
    degree = first[vertex + 1] - first[vertex]
    owner = np.repeat(np.arange(vertex.shape[0], dtype=np.int64), degree)
    slot = np.arange(owner.shape[0], dtype=np.int64) - np.repeat(np.cumsum(degree) - degree, degree)
    edge = first[vertex[owner]] + slot
    wanted = b[edge] * groups + group[owner]
    at = np.minimum(np.searchsorted(sorted_keys, wanted), max(sorted_keys.shape[0] - 1, 0))
    found = sorted_keys[at] == wanted if sorted_keys.size else np.zeros(wanted.shape[0], dtype=bool)
    owner, edge = owner[found], edge[found]
    links = key_order[at[found]].astype(np.int64)
    offsets = np.searchsorted(owner, np.arange(vertex.shape[0] + 1)).astype(np.int64)
    return offsets, links, np.ascontiguousarray(scale * both_lengths[edge])


class SweepSolver(LayoutCache):
    """What verlet and xpbd share: a `SpringLayout` swept by one compiled substep kernel over a
    scratch copy of the vertices (`sweep_kernels.VERTEX`), tethers to the pins, and `step` as one
    substep of `advance`.

    Subclasses set `tether_kinds` / `tether_slack` (the springs tether paths run along and their
    slack, see `kernel_tethers`) and call `_prepare_sweeps` from their `_prepare` with their two
    builds of the substep kernel.
    """

    tether_kinds: ClassVar[tuple[int, ...] | None] = None
    tether_slack: ClassVar[float] = 1.0
    #: runs the substep kernel, the build `dispatch.SubstepPicker` finds faster (kept from one model to the next)
    substep: SubstepPicker | None = None

    def __init__(self, options: SweepOptions) -> None:
        super().__init__(options)
        self.iterations = options.iterations_for(self)
        self._dt = -1.0

    def _prepare_sweeps(
        self, model: SpringModel, serial: Callable[..., None], parallel: Callable[..., None]
    ) -> SpringLayout:
        """The layout, inverse masses, tethers, scratch, slab offsets, chunks and substep picker
        for `model`; returns the layout. Per-spring records are the subclass's."""
        lay = self.layout = self._layout_for(model, self.options.partitions)
        self.inv_mass = np.ascontiguousarray(model.inv_mass, dtype=np.float64)
        linked = kernel_tethers(
            model, lay.vertex_rank, self.options.tethers, self.tether_kinds, self.tether_slack
        )
        self.tethers = linked.records
        self.tether_links = linked
        # the tethers' limits in force (`sweep_kernels.release_tethers`), from the records' own
        self.tether_work = self.tethers.copy()
        self.tether_limits = np.empty(self.tethers.shape[0])
        self.tether_scaled = np.empty(self.tethers.shape[0])
        # a vertex tethered to pins of two groups: their separation may scale its limits
        vertices = self.tethers["v"]
        self.tethers_to_groups = bool(vertices.shape[0] > 1 and (vertices[1:] == vertices[:-1]).any())
        self.released = np.zeros(1, dtype=np.int64)
        self._run_state: weakref.ref[State] | None = None
        self.scratch = self._buffer("scratch", model.vertex_count, VERTEX)
        self.offsets = np.ascontiguousarray(lay.offsets, dtype=np.uint64)
        self.chunks = kernel_chunks(lay, self.tethers["v"])
        self.substep = substep_picker(serial, parallel, lay.parts, lay.a.shape[0] + model.vertex_count, self.substep)
        self._dt = -1.0
        return lay

    def step(self, model: SpringModel, state: State, dt: float, control: Control) -> None:
        self.advance(model, state, dt, control, 1)

    def _starts_run(self, state: State) -> bool:
        """Whether `state` is not the one this solver's last step advanced (a new run, or the
        first step on a newly prepared model): then its tethers are held again (the limits a
        run released are that run's)."""
        held = self._run_state() if self._run_state is not None else None
        if held is state:
            return False
        self._run_state = weakref.ref(state)
        self.tether_work["lim"] = self.tethers["lim"]
        self.released[0] = 0
        return True

    def _release(self, touched: np.ndarray | None) -> tuple[tuple[np.ndarray, ...], bool]:
        """The substep kernel's tether release arguments (`sweep_kernels.release_tethers`:
        offsets, links, gaps, contact mask, limits and scaled-limits scratch, released count) and
        whether to run it: where a vertex is tethered to pins of two groups (their separation
        scales its limits), a collider touches a vertex with a tether, or a tether is still
        released. touched: the model vertices a collider holds (indices), or None."""
        contact = NO_CONTACT
        if touched is not None and touched.shape[0] > 0 and self.tethers.shape[0] > 0:
            contact = np.zeros(self.layout.vertex_rank.shape[0], dtype=np.uint8)
            contact[self.layout.vertex_rank[touched]] = 1
        links = self.tether_links
        state = (
            links.offsets, links.links, links.gaps, contact, self.tether_limits, self.tether_scaled, self.released,
        )
        return state, self.tethers_to_groups or contact.shape[0] > 0 or bool(self.released[0])

    def _planes(self, control: Control, dt: float) -> np.ndarray:
        """`control.planes` as `sweep_kernels.PLANE` records in kernel numbering, each plane's
        level where its surface is at the end of a substep of dt (none: an empty array)."""
        planes = control.planes
        if planes is None or planes.offsets.shape[0] == 0:
            return NO_PLANES
        rank = self.layout.vertex_rank
        out = np.empty(planes.offsets.shape[0], dtype=PLANE)
        for j in range(3):
            out[f"v{j}"] = rank[planes.vertices[:, j]]
            out[f"w{j}"] = planes.weights[:, j]
        out["nx"], out["ny"], out["nz"] = planes.normals.T
        out["level"] = planes.offsets + np.einsum("ij,ij->i", planes.normals, planes.velocities) * dt
        out["ux"], out["uy"], out["uz"] = planes.velocities.T * dt
        out["mu"] = planes.friction
        out["push"] = 0.0
        return out


#: no contact planes: the substep kernels' empty `PLANE` array
NO_PLANES = np.zeros(0, dtype=PLANE)
#: no vertex touching a collider: the tether release's empty contact mask (`SweepSolver._release`)
NO_CONTACT = np.zeros(0, dtype=np.uint8)
