"""The result every repair step returns, and how steps compose."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..mesh.core import triple_keys


@dataclass(frozen=True)
class StepResult:
    """Output of one repair step.

    Attributes
    ----------
    V : (n', 3) float64
    F : (m', 3) int64
    vertex_map : (n',) int64, input vertex each output vertex comes from (-1: created)
    face_map : (m',) int64, input face each output face comes from (-1: created)
    changes : list of dict, one entry per change made (``{"step": ..., ...}``)
    """

    V: np.ndarray
    F: np.ndarray
    vertex_map: np.ndarray
    face_map: np.ndarray
    changes: list = field(default_factory=list)

    @classmethod
    def identity(cls, V: np.ndarray, F: np.ndarray, changes: list | None = None) -> "StepResult":
        return cls(V, F, np.arange(len(V), dtype=np.int64), np.arange(len(F), dtype=np.int64), list(changes or []))

    def then(self, nxt: "StepResult") -> "StepResult":
        """Compose: ``self`` followed by ``nxt`` (maps chained back to ``self``'s input)."""
        vm = np.where(nxt.vertex_map >= 0, self.vertex_map[np.maximum(nxt.vertex_map, 0)], -1)
        fm = np.where(nxt.face_map >= 0, self.face_map[np.maximum(nxt.face_map, 0)], -1)
        return StepResult(nxt.V, nxt.F, vm.astype(np.int64), fm.astype(np.int64), self.changes + nxt.changes)


def select_faces(V: np.ndarray, F: np.ndarray, keep: np.ndarray, changes: list | None = None) -> StepResult:
    """Keep faces where ``keep`` is True and drop vertices no longer used."""
    F2 = F[keep]
    used = np.zeros(len(V), bool)
    used[F2.ravel()] = True
    kept_v = np.flatnonzero(used)
    remap = -np.ones(len(V), np.int64)
    remap[kept_v] = np.arange(len(kept_v))
    return StepResult(V[kept_v], remap[F2], kept_v.astype(np.int64), np.flatnonzero(keep).astype(np.int64), list(changes or []))


def match_provenance(V0: np.ndarray, F0: np.ndarray, V1: np.ndarray, F1: np.ndarray, changes: list | None = None) -> StepResult:
    """Provenance for a step done by an external tool: vertices of ``V1`` that coincide
    exactly with a vertex of ``V0`` map to it, faces whose corners all map and form a face
    of ``F0`` map to it; everything else is marked created (-1)."""
    from scipy.spatial import cKDTree

    d, idx = cKDTree(V0).query(V1)
    vmap = np.where(d == 0.0, idx, -1).astype(np.int64)
    fmap = -np.ones(len(F1), np.int64)
    mapped = vmap[F1]
    ok = (mapped >= 0).all(1)
    if ok.any() and len(F0):
        key0, key1 = triple_keys(np.sort(F0, 1), np.sort(mapped[ok], 1), n=len(V0))
        order = np.argsort(key0)
        pos = np.clip(np.searchsorted(key0[order], key1), 0, len(order) - 1)
        hit = key0[order][pos] == key1
        fmap[np.flatnonzero(ok)[hit]] = order[pos[hit]]
    return StepResult(V1, F1, vmap, fmap, list(changes or []))
