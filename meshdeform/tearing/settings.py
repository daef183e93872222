"""Where and when the cloth tears: break thresholds per spring kind and vertex, the averaging
window, and the budget of topology updates.

A recipe's `[[tears]]` tables become `TearRegion`s over the model's welded vertices;
`TearSettings.from_regions` turns them into per-vertex arrays (later regions win, hard-pinned
vertices never tear), which the detector reads per spring (the lower threshold and the longer
window of its two ends).

Topology updates are budgeted like a token bucket (`interval`, `burst`) because every update
hands the solver a new model, which it prepares from scratch: a crack running through the cloth
is applied on the substeps it happens, heavy sustained tearing waits (failures collect and are
applied together) so that it costs at most about one preparation per `interval`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from meshdeform.model import SpringModel
from meshdeform.topology import KIND_NAMES, SpringKind

_INF = np.inf

#: topology updates are budgeted like a token bucket: up to DEFAULT_BURST of them run on the
#: substeps their springs break, after which one more is allowed per DEFAULT_INTERVAL seconds
#: (failures in between wait and are applied together). A crack running through the cloth fits
#: in the burst, and heavy sustained tearing (a cloth shredding) costs at most about one solver
#: preparation per frame at 24 fps (measurements: docs/performance.md, "Tearing").
DEFAULT_INTERVAL = 1.0 / 24.0
DEFAULT_BURST = 32
#: a crack runs on in the same update through tips whose springs across it reach this fraction
#: of their threshold (the load concentrates at a crack tip), at most this many vertices deep
DEFAULT_TIP = 0.9
DEFAULT_LOOKAHEAD = 8


def kind_thresholds(max_stretch: float | Mapping[str, float] | None) -> np.ndarray:
    """(3,) break stretch per spring kind from a number (structural springs only) or a per-kind
    table {"structural": 1.5, "shear": 2.0, "bending": 2.5}; kinds not given never break (inf)."""
    out = np.full(3, _INF)
    if max_stretch is None:
        return out
    if isinstance(max_stretch, Mapping):
        for name, value in max_stretch.items():
            if name not in KIND_NAMES:
                raise ValueError(f"unknown spring kind {name!r}; choose from {', '.join(KIND_NAMES)}")
            out[KIND_NAMES.index(name)] = float(value)
    else:
        out[SpringKind.STRUCTURAL] = float(max_stretch)
    if np.any(out <= 1.0):
        raise ValueError("a break stretch must be greater than 1 (1 is the rest length)")
    return out


@dataclass(frozen=True)
class TearRegion:
    """Where and when the cloth tears.

    mask: (W,) bool over the model's welded vertices that may tear (None: all of them).
    max_stretch: break stretch ratio: a number applies to structural springs (shear and bending
        then only go where the mesh opens), a table {kind: ratio} sets each kind.
    vertex_max_stretch: optional (W,) per-vertex break stretch of structural springs (a painted
        map), replacing the structural value of `max_stretch`; vertices whose value is not above
        1 (or not finite) do not tear.
    average: a spring breaks when its stretch averaged over this many substeps exceeds the
        threshold (1: the current substep alone).
    """

    mask: np.ndarray | None = None
    max_stretch: float | Mapping[str, float] | None = 1.5
    vertex_max_stretch: np.ndarray | None = None
    average: int = 1


@dataclass(frozen=True, eq=False)
class TearSettings:
    """Per welded vertex: break thresholds per kind (3, W) (inf: never), tearable (W,) bool,
    averaging window (W,) int. A spring is tested when either end tears; its threshold is the
    lower of its two ends' and its window the longer; only a tearable end is ever split.

    interval, burst: the budget of topology updates (see DEFAULT_INTERVAL); tip, lookahead: how
    a crack runs on within one update (see DEFAULT_TIP and `meshdeform.tearing.crack`)."""

    thresholds: np.ndarray
    tearable: np.ndarray
    window: np.ndarray
    interval: float = DEFAULT_INTERVAL
    burst: int = DEFAULT_BURST
    tip: float = DEFAULT_TIP
    lookahead: int = DEFAULT_LOOKAHEAD

    @classmethod
    def from_regions(
        cls,
        model: SpringModel,
        regions: Sequence[TearRegion],
        interval: float = DEFAULT_INTERVAL,
        burst: int = DEFAULT_BURST,
    ) -> TearSettings:
        """Later regions win where they overlap (as pins do). Hard-pinned vertices never tear.

        interval, burst: the budget of topology updates (see DEFAULT_INTERVAL): up to `burst`
        updates on the substeps springs break, then one per `interval` seconds of simulated time
        (interval 0: no limit, every failure is applied on its substep)."""
        n = model.vertex_count
        thresholds = np.full((3, n), _INF)
        window = np.ones(n, dtype=np.int64)
        tearable = np.zeros(n, dtype=bool)
        for region in regions:
            mask = np.ones(n, dtype=bool) if region.mask is None else np.asarray(region.mask, dtype=bool)
            if mask.shape != (n,):
                raise ValueError(f"tear mask has shape {mask.shape}, expected ({n},)")
            if int(region.average) < 1:
                raise ValueError("average must be at least 1 substep")
            per_kind = kind_thresholds(region.max_stretch)
            values = np.repeat(per_kind[:, None], n, axis=1)
            if region.vertex_max_stretch is not None:
                vm = np.asarray(region.vertex_max_stretch, dtype=np.float64)
                if vm.shape != (n,):
                    raise ValueError(f"vertex_max_stretch has shape {vm.shape}, expected ({n},)")
                values[SpringKind.STRUCTURAL] = np.where(np.isfinite(vm) & (vm > 1.0), vm, _INF)
            thresholds[:, mask] = values[:, mask]
            window[mask] = int(region.average)
            tearable[mask] = True
        tearable &= ~np.asarray(model.pinned)
        tearable &= np.isfinite(thresholds).any(axis=0)
        thresholds[:, ~tearable] = _INF
        if not interval >= 0:
            raise ValueError("the tear update interval must be 0 or more seconds")
        if int(burst) < 1:
            raise ValueError("the tear update burst must be at least 1")
        return cls(thresholds, tearable, window, float(interval), int(burst), DEFAULT_TIP, DEFAULT_LOOKAHEAD)

    def take(self, index_map: np.ndarray) -> TearSettings:
        """The settings for a grown vertex set (copies inherit their original's values)."""
        return replace(
            self,
            thresholds=self.thresholds[:, index_map],
            tearable=self.tearable[index_map],
            window=self.window[index_map],
        )
