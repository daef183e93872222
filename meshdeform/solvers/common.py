"""Per-model data the solvers derive once: spring constants, damping coefficients, layouts."""

from __future__ import annotations

import numpy as np

from meshdeform.model import SpringModel


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
