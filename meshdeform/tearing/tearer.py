"""The tearer: what `meshdeform.simulate` calls after every substep to tear and cut the cloth.

Per substep it applies the cuts that are due (`cuts`), tests the springs (`detect`) and, when
the update budget allows, turns the pending failures into splits (`crack`: which vertices, by
which planes), performs them (`surgery`: a new model and each spring's parent), grows the output
layout (`output`) and resizes the State in place (positions, previous positions and
velocities are copied to the new vertices). The result is a `TearEvent`: the new, frozen
`SpringModel` plus an index map (new vertex -> old vertex) and spring parents, which simulate
hands to the solver, forces and constraints. Several changes in one substep (a cut, then a
tear) are composed into one event.

Every update hands the solver a new model, which it prepares from scratch; updates are
therefore budgeted like a token bucket (`TearSettings.interval`, `burst`): a crack running
through the cloth is applied on the substeps it happens, heavy sustained tearing waits
(failures collect and are applied together) so that it costs at most about one preparation
per `interval` (a frame at 24 fps).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from meshdeform.mesh import Mesh
from meshdeform.model import SpringModel, State
from meshdeform.tearing.corners import Corners
from meshdeform.tearing.crack import choose_ends, crack_ahead, plane_sides
from meshdeform.tearing.cuts import Cut, cut_split
from meshdeform.tearing.detect import record_failures, spring_state
from meshdeform.tearing.output import OutputLayout
from meshdeform.tearing.settings import TearSettings
from meshdeform.tearing.surgery import mesh_pieces, rebuild, split_vertices
from meshdeform.topology import SpringKind


@dataclass(frozen=True, eq=False)
class TearEvent:
    """A topology change: the new model, index_map (W',) new vertex -> previous vertex, parent
    (S',) new spring -> the previous model's spring it descends from, and how many springs broke
    and vertices were added by it."""

    model: SpringModel
    index_map: np.ndarray
    parent: np.ndarray
    broken: int
    split: int


@dataclass
class _Counters:
    broken: int = 0
    split: int = 0
    changed: bool = False


class Tearer:
    """Breaks springs, splits vertices and applies scripted cuts during `meshdeform.simulate`.

    mesh: the input mesh the model was built from (its polygons are what opens); model: that
    model; settings: where and when springs break (None: only cuts); cuts: scripted cuts.
    The simulate loop calls `start(model)` once and `after_substep(model, state, time)` after
    every substep; a returned `TearEvent` carries the new model (the state has been resized in
    place). `mesh` is the current output mesh, `origin` the original welded vertex of every
    current vertex, `pieces` the current number of connected pieces.

    Springs are tested every substep; failures collect and the topology is updated at most
    every `settings.interval` seconds of simulated time (cuts at their own time), because every
    update hands the solver a new model to prepare, except where a waiting break is overdue
    (`SpringState.any_overdue`: its spring stretched `detect.OVERDUE_FACTOR` times as far past
    its rest length as its threshold allows), which updates at once.
    """

    def __init__(
        self,
        mesh: Mesh,
        model: SpringModel,
        settings: TearSettings | None = None,
        cuts: Sequence[Cut] = (),
    ) -> None:
        if np.asarray(model.vertex_map).shape != (mesh.vertex_count,):
            raise ValueError("the model was not built from this mesh (vertex counts differ)")
        if settings is not None and settings.tearable.shape != (model.vertex_count,):
            raise ValueError("tear settings are for another model (vertex counts differ)")
        self.input_mesh = mesh
        self.initial_model = model
        self.initial_settings = settings
        self.cuts = tuple(sorted(cuts, key=lambda c: c.time))
        for cut in self.cuts:
            if cut.mask is not None and np.asarray(cut.mask).shape != (model.vertex_count,):
                raise ValueError("cut mask is for another model (vertex counts differ)")
        self._corners = Corners.from_mesh(mesh)
        self._line_inputs = np.asarray(mesh.line_indices, dtype=np.int64)
        self._line_offsets = np.asarray(mesh.line_offsets, dtype=np.int64)
        self.reset()

    @property
    def enabled(self) -> bool:
        """Whether anything can ever tear or be cut."""
        return bool(self.cuts) or (self.initial_settings is not None and bool(self.initial_settings.tearable.any()))

    # -- state ------------------------------------------------------------------------------------
    def reset(self) -> None:
        """Back to the untorn input (a new run)."""
        model = self.initial_model
        self.model = model
        self.settings = self.initial_settings
        self.origin = np.arange(model.vertex_count, dtype=np.int64)
        self._cv = np.asarray(model.vertex_map, dtype=np.int64)[self.input_mesh.face_indices]
        self._layout = OutputLayout.of_input(self.input_mesh, model)
        self._pending_cuts = list(self.cuts)
        self._step = 0
        self._tokens = float(self.initial_settings.burst) if self.initial_settings is not None else 0.0
        self._token_time = 0.0
        self._mesh: Mesh | None = self.input_mesh
        self._pieces: int | None = None
        self._frame = _Counters()
        self.total_broken = 0
        self.total_split = 0
        self.updates = 0
        self._springs = spring_state(model, self.settings, None, None)

    def start(self, model: SpringModel) -> None:
        """Called by simulate before the first substep: a run from the initial model resets."""
        if model is self.initial_model:
            self.reset()
        elif model is not self.model:
            raise ValueError("Tearer: simulate was given a model this tearer did not build")

    @property
    def mesh(self) -> Mesh:
        """The output mesh of the current topology (the input mesh until something opens)."""
        if self._mesh is None:
            self._mesh = self._layout.mesh(self.input_mesh)
        return self._mesh

    @property
    def output_vertex_map(self) -> np.ndarray:
        """(V',) output vertex -> current simulation vertex (the model's vertex_map)."""
        return self._layout.sim

    @property
    def output_origin(self) -> np.ndarray:
        """(V',) output vertex -> the input vertex it was copied from."""
        return self._layout.source

    @property
    def pieces(self) -> int:
        """Connected pieces of the current mesh (polygons and polylines joined by shared vertices)."""
        if self._pieces is None:
            referenced = np.zeros(self.model.vertex_count, dtype=bool)
            referenced[self._cv] = True
            if self._line_inputs.size:
                referenced[self._layout.sim[self._line_inputs]] = True
            self._pieces = mesh_pieces(self.model, referenced)
        return self._pieces

    def frame_stats(self) -> tuple[int, int, bool]:
        """(springs broken, vertices added, topology changed) since the last call; resets them."""
        c = self._frame
        self._frame = _Counters()
        return c.broken, c.split, c.changed

    # -- the per-substep entry point -----------------------------------------------------------------
    def after_substep(self, model: SpringModel, state: State, time: float) -> TearEvent | None:
        """Apply due cuts, test the springs, split; None when the topology did not change."""
        if model is not self.model:
            raise ValueError("Tearer.after_substep: not the model of the last tear event")
        events: list[TearEvent] = []
        while self._pending_cuts and self._pending_cuts[0].time <= time + 1e-9:
            event = self._apply_cut(self._pending_cuts.pop(0), state)
            if event is not None:
                events.append(event)
        sp = self._springs
        if sp.index.shape[0]:
            record_failures(sp, state.positions, self._step)
            s = self.settings
            assert s is not None
            if s.interval > 0:  # refill the update budget
                self._tokens = min(float(s.burst), self._tokens + (time - self._token_time) / s.interval)
            self._token_time = time
            if sp.any_pending and (s.interval <= 0 or self._tokens >= 1.0 - 1e-9 or sp.any_overdue):
                event = self._tear(state)
                if event is not None:
                    self._tokens = max(self._tokens - 1.0, 0.0)
                    events.append(event)
        self._step += 1
        if not events:
            return None
        self.updates += 1
        if len(events) == 1:
            return events[0]
        index_map = events[0].index_map
        parent = events[0].parent
        for e in events[1:]:
            index_map = index_map[e.index_map]
            parent = parent[e.parent]
        return TearEvent(
            model=events[-1].model,
            index_map=index_map,
            parent=parent,
            broken=sum(e.broken for e in events),
            split=sum(e.split for e in events),
        )

    # -- tearing and cutting -------------------------------------------------------------------------
    def _tear(self, state: State) -> TearEvent | None:
        """Turn the pending failures into splits and removed springs, and apply them."""
        sp = self._springs
        local = np.flatnonzero(sp.pending > 0)
        ratio = sp.pending[local]
        sp.pending[:] = 0.0
        sp.any_pending = sp.any_overdue = False
        if local.size == 0:
            return None
        model = self.model
        settings = self.settings
        assert settings is not None
        x = state.positions
        spring = sp.index[local]
        structural = np.asarray(model.kinds)[spring] == SpringKind.STRUCTURAL
        remove = spring[~structural]  # failing shear / bending springs just go
        split_mask = np.zeros(model.vertex_count, dtype=bool)
        side = np.zeros(self._cv.shape[0], dtype=np.int8)
        acted = ~structural
        ahead = 0
        if structural.any():
            rows = np.flatnonzero(structural)
            chosen, vertices, normals = choose_ends(
                self._corners, self._cv, model, settings.tearable, x, spring[rows], ratio[rows]
            )
            ok = vertices >= 0
            # no end can split: not tested again until the topology changes
            sp.stuck[local[rows[chosen[~ok]]]] = True
            if ok.any():
                acted[rows[chosen[ok]]] = True
                v = vertices[ok]
                nrm = normals[ok]
                ahead_v, ahead_n = crack_ahead(model, settings, sp, x, v, nrm)
                ahead = int(ahead_v.shape[0])
                v = np.concatenate([v, ahead_v])
                nrm = np.concatenate([nrm, ahead_n])
                split_mask[v] = True
                _, corners, d = plane_sides(self._corners, self._cv, model.vertex_count, x, v, nrm)
                side[corners] = (d > 0).astype(np.int8)
        if not split_mask.any() and remove.size == 0:
            return None
        event = self._apply(state, split_mask, side, remove, int(np.count_nonzero(acted)) + ahead)
        if event is None:
            sp.stuck[local[acted]] = True
        return event

    def _apply_cut(self, cut: Cut, state: State) -> TearEvent | None:
        found = cut_split(cut, self._corners, self._cv, self.origin, state.positions)
        if found is None:
            return None
        near, side = found
        return self._apply(state, near, side, np.zeros(0, dtype=np.int64), 0)

    def _apply(
        self, state: State, split_mask: np.ndarray, side: np.ndarray, remove: np.ndarray, broken: int
    ) -> TearEvent | None:
        """Split, rebuild the model, grow the output layout and the state; None if nothing changed."""
        model = self.model
        n = model.vertex_count
        if split_mask.any():
            cv, index_map = split_vertices(self._cv, self._corners.nxt, n, split_mask, side)
        else:
            cv, index_map = self._cv, np.arange(n, dtype=np.int64)
        new_count = index_map.shape[0] - n
        if new_count == 0 and remove.size == 0:
            return None
        layout = self._layout
        new_model, parent = rebuild(
            model, self._corners, cv, index_map, remove, layout.sim[self._line_inputs], self._line_offsets
        )
        # springs the opening separated (no descendant left) count as broken too
        lost = np.bincount(parent, minlength=model.spring_count) == 0
        lost[remove] = False
        broken_total = broken + int(np.count_nonzero(lost))
        layout.grow(self.input_mesh, self._cv, cv)
        new_model = layout.attach(new_model, index_map.shape[0])
        self._cv = cv
        self.origin = self.origin[index_map]
        if new_count and self.settings is not None:
            self.settings = self.settings.take(index_map)
        state.positions = np.ascontiguousarray(state.positions[index_map])
        state.previous = np.ascontiguousarray(state.previous[index_map])
        state.velocities = np.ascontiguousarray(state.velocities[index_map])
        self._springs = spring_state(new_model, self.settings, parent, self._springs)
        self.model = new_model
        self._mesh = None
        self._pieces = None
        self._frame.broken += broken_total
        self._frame.split += new_count
        self._frame.changed = True
        self.total_broken += broken_total
        self.total_split += new_count
        return TearEvent(model=new_model, index_map=index_map, parent=parent, broken=broken_total, split=new_count)
