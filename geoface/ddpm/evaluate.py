"""Metrics for generated geometry images (``bench/eval_ddpm.py``): validity, text control,
diversity and memorisation.

* :func:`mesh_validity` — does a geometry image reconstruct (:func:`geoface.gimage.reconstruct`)
  to a clean manifold head: finite positions, edge-manifold, one connected component, the
  topology of a disk (Euler characteristic 1, one boundary loop — what real items give), no
  zero-area faces, and a surface that is not crumpled: few faces folded against the image's own
  normals and few faces that cross another face.  A geometry image of a head covers the whole
  square, so the topology alone says little (any image with unit normals passes); the fold and
  self-intersection checks are what a noisy, creased or tangled sample fails.  Their default
  limits (2 % of the faces each) sit well above real heads: ICT-FaceKit heads at 64² fold
  0.1–0.6 % of their faces (lips and ears, under-sampled) and cross 0–0.3 %.
* :func:`vendi_score` — exp of the Shannon entropy of the eigenvalues of ``K / n`` (Friedman &
  Dieng 2023) for a PSD similarity matrix ``K`` with unit diagonal; :func:`cosine_similarity`
  builds one from feature vectors.
* :func:`masked_rms_distances` / :func:`nearest_neighbour` — RMS distance over the position
  channels, restricted to the pixels both images cover; nearest training neighbour per sample.
* :class:`ExpressionClassifier` + :func:`train_classifier` / :func:`predict` — a small seeded CNN
  over ``[B, C, N, N]`` geometry images (the text-control judge).

Arrays are numpy ``float64`` unless stated; images are ``[B, 9, N, N]`` in [-1, 1] space (the
:class:`geoface.ddpm.data.GImageDataset` convention) with a ``[B, N, N]`` bool mask.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from geoface.errors import GeofaceError

__all__ = ["Validity", "mesh_validity", "folded_faces", "self_intersecting_faces", "vendi_score", "cosine_similarity", "masked_rms_distances", "aligned_rms_distances",
           "nearest_neighbour", "ExpressionClassifier", "train_classifier", "predict", "stratified_split"]


# ---------------------------------------------------------------- validity
@dataclass(frozen=True)
class Validity:
    """Checks on one reconstructed geometry image; ``valid`` is their conjunction."""
    valid: bool
    finite: bool
    reconstructs: bool
    edge_manifold: bool
    components: int
    euler: int
    boundary_loops: int
    zero_area_faces: int
    vertices: int
    faces: int
    folded_faces: int = 0            # faces whose orientation opposes the image's normals (-1: no normals)
    self_intersecting_faces: int = 0  # faces crossing a non-adjacent face (-1: not checked)
    reason: str = ""


def _components(F: np.ndarray, n: int) -> int:
    from scipy.sparse.csgraph import connected_components

    from geoface.mesh.core import vertex_adjacency
    return int(connected_components(vertex_adjacency(F, n), directed=False)[0])


def mesh_validity(gi, *, expect_euler: int = 1, expect_loops: int = 1, area_rel: float = 1e-12,
                  max_folded: float = 0.02, max_self_intersecting: float = 0.02, mesh=None) -> Validity:
    """Reconstruct ``gi`` (a :class:`geoface.gimage.GeometryImage`) and check it is a clean disk.

    Parameters
    ----------
    gi : GeometryImage
    expect_euler, expect_loops : the topology real items reconstruct to (a disk: 1 and 1)
    area_rel : a face is degenerate when its area < ``area_rel * bbox_diagonal**2``
    max_folded : largest share of faces whose geometric normal points against the normal
        channel (the mean of its corners' normals); ignored when the image has no normals
    max_self_intersecting : largest share of faces that intersect a face they do not share a
        vertex with (pymeshlab's exact test); None skips the check
    mesh : ``reconstruct(gi)`` when the caller has it already (it is not rebuilt)

    Examples
    --------
    >>> mesh_validity(load_gimage("data/head_0000/aug0")).valid  # doctest: +SKIP
    True
    """
    from geoface.errors import InvalidGeometryImageError
    from geoface.gimage import reconstruct
    from geoface.mesh.core import edge_topology, face_areas

    bad = dict(valid=False, finite=True, reconstructs=False, edge_manifold=False, components=0, euler=0,
               boundary_loops=0, zero_area_faces=0, vertices=0, faces=0, folded_faces=-1, self_intersecting_faces=-1)
    img = np.asarray(gi.image)
    if not np.isfinite(img).all():
        return Validity(**{**bad, "finite": False}, reason="non-finite values")
    if mesh is None:
        try:
            mesh = reconstruct(gi)
        except InvalidGeometryImageError as e:
            return Validity(**bad, reason=str(e))
    V, F = np.asarray(mesh.V, np.float64), np.asarray(mesh.F, np.int64)
    et = edge_topology(F)
    manifold = len(et.nonmanifold_edges) == 0
    comps = _components(F, len(V))
    euler = len(V) - len(et.E) + len(F)
    loops = _boundary_loop_count(et, len(V))
    diag2 = float(np.sum((V.max(0) - V.min(0)) ** 2))
    zero = int(np.sum(face_areas(V, F) <= area_rel * max(diag2, 1e-300)))
    finite = bool(np.isfinite(V).all())
    folded = folded_faces(gi, mesh) if finite else -1
    crossing = self_intersecting_faces(V, F) if finite and max_self_intersecting is not None else -1
    m = max(len(F), 1)
    reasons = [r for ok, r in ((finite, "non-finite vertices"), (manifold, "non-manifold edges"),
                               (comps == 1, f"{comps} components"), (euler == expect_euler, f"Euler characteristic {euler}"),
                               (loops == expect_loops, f"{loops} boundary loops"), (zero == 0, f"{zero} zero-area faces"),
                               (folded <= max_folded * m, f"{folded / m:.1%} of faces folded"),
                               (max_self_intersecting is None or crossing <= max_self_intersecting * m,
                                f"{crossing / m:.1%} of faces self-intersecting"))
               if not ok]
    return Validity(valid=not reasons, finite=finite, reconstructs=True, edge_manifold=manifold,
                    components=comps, euler=int(euler), boundary_loops=loops, zero_area_faces=zero,
                    vertices=len(V), faces=len(F), folded_faces=int(folded), self_intersecting_faces=int(crossing),
                    reason="; ".join(reasons))


def folded_faces(gi, mesh) -> int:
    """Faces of ``mesh = reconstruct(gi)`` whose geometric normal makes an obtuse angle with the
    mean of its corners' normals from the image (-1 when ``gi`` has no normal channel).

    A vertex of the reconstruction sits at the centre of its pixel in UV, which finds its normal."""
    if not gi.has("normal"):
        return -1
    N = gi.resolution
    UV = np.asarray(mesh.UV, np.float64)
    j = np.clip(np.rint(UV[:, 0] * N - 0.5).astype(np.int64), 0, N - 1)
    i = np.clip(np.rint((1.0 - UV[:, 1]) * N - 0.5).astype(np.int64), 0, N - 1)
    n = np.asarray(gi.modality("normal"), np.float64)[:, i, j].T * 2.0 - 1.0
    V, F = np.asarray(mesh.V, np.float64), np.asarray(mesh.F, np.int64)
    fn = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    return int(np.sum(np.einsum("ij,ij->i", fn, n[F].mean(axis=1)) < 0))


def self_intersecting_faces(V: np.ndarray, F: np.ndarray) -> int:
    """Faces that intersect another face of the mesh (pymeshlab's per-face test)."""
    from geoface._lazy import lazy_import

    pymeshlab = lazy_import("pymeshlab", "the self-intersection check")
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(np.ascontiguousarray(V, np.float64), np.ascontiguousarray(F, np.int32)))
    ms.compute_selection_by_self_intersections_per_face()
    return int(ms.current_mesh().selected_face_number())


def _boundary_loop_count(et, n: int) -> int:
    """Connected components of the boundary-edge graph (= boundary loops on an edge-manifold disk)."""
    b = np.flatnonzero(et.edge_faces == 1)
    if len(b) == 0:
        return 0
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components
    E = et.E[b]
    used, inv = np.unique(E.ravel(), return_inverse=True)
    inv = inv.reshape(-1, 2)
    A = sp.coo_matrix((np.ones(len(E)), (inv[:, 0], inv[:, 1])), shape=(len(used), len(used)))
    return int(connected_components(A, directed=False)[0])


# ---------------------------------------------------------------- diversity
def cosine_similarity(X) -> np.ndarray:
    """``(n, n)`` cosine similarity of the rows of ``X (n, d)``; a zero row gets similarity 1 with itself only."""
    X = np.asarray(X, np.float64).reshape(len(X), -1)
    L = np.linalg.norm(X, axis=1, keepdims=True)
    Y = np.divide(X, L, out=np.zeros_like(X), where=L > 0)
    K = Y @ Y.T
    np.fill_diagonal(K, 1.0)
    return K


def vendi_score(K) -> float:
    """Vendi score ``exp(-sum_i l_i log l_i)``, ``l`` the eigenvalues of ``K / n``.

    ``K (n, n)`` must be symmetric PSD with unit diagonal.  n identical items give 1, n mutually
    orthogonal items give n.

    Examples
    --------
    >>> vendi_score(np.eye(4))
    4.0
    """
    K = np.asarray(K, np.float64)
    if K.ndim != 2 or K.shape[0] != K.shape[1] or K.shape[0] == 0:
        raise GeofaceError(f"K must be a non-empty square matrix; got shape {K.shape}")
    if not np.allclose(np.diag(K), 1.0, atol=1e-6):
        raise GeofaceError("K must have a unit diagonal")
    lam = np.linalg.eigvalsh((K + K.T) / (2 * len(K)))
    lam = lam[lam > 1e-12]
    return float(np.exp(-np.sum(lam * np.log(lam))))


# ---------------------------------------------------------------- memorisation
def _flat_images(A, mA, B, mB):
    """``(a, C, P)`` / ``(a, P)`` float arrays of images and masks, checked to pair up."""
    A = np.asarray(A, np.float64).reshape(len(A), A.shape[1], -1)
    B = np.asarray(B, np.float64).reshape(len(B), B.shape[1], -1)
    ma = np.asarray(mA, np.float64).reshape(len(A), -1)
    mb = np.asarray(mB, np.float64).reshape(len(B), -1)
    for name, m, X in (("mA", ma, A), ("mB", mb, B)):
        if m.shape != (X.shape[0], X.shape[2]):
            raise GeofaceError(f"{name} must have one (N, N) mask per image; got {m.shape[0]} masks for {X.shape[0]} images")
    return A, ma, B, mb


def masked_rms_distances(A, mA, B, mB) -> np.ndarray:
    """``(a, b)`` RMS distance between position images ``A (a, 3, N, N)`` and ``B (b, 3, N, N)``
    over the pixels both cover (``mA (a, N, N)``, ``mB (b, N, N)`` bool); ``inf`` where none."""
    A, ma, B, mb = _flat_images(A, mA, B, mB)
    C = A.shape[1]
    # sum_{p in both} |a_p - b_p|^2 = (m_a |a|^2)·m_b + m_a·(m_b |b|^2) - 2 sum_c (m_a a_c)·(m_b b_c)
    sq = (ma * (A ** 2).sum(1)) @ mb.T + ma @ (mb * (B ** 2).sum(1)).T
    cross = sum((ma * A[:, c]) @ (mb * B[:, c]).T for c in range(C))
    cnt = ma @ mb.T
    d2 = np.maximum(sq - 2 * cross, 0.0) / np.maximum(cnt * C, 1)
    return np.where(cnt > 0, np.sqrt(d2), np.inf)


def aligned_rms_distances(A, mA, B, mB, *, scale: bool = True) -> np.ndarray:
    """Like :func:`masked_rms_distances`, after the best similarity transform (rotation,
    translation and, with ``scale``, uniform scale) of each ``A`` item onto each ``B`` item
    over their common pixels (Umeyama 1991).  Geometry images share their parameterization, so
    pixels correspond and the alignment is closed-form: this is the distance that rigid
    augmentation (a rotated, shifted, scaled copy of a training head) does not hide."""
    A, ma, B, mb = _flat_images(A, mA, B, mB)
    D = np.full((len(A), len(B)), np.inf)
    for i in range(len(A)):
        m = ma[i][None] * mb  # (b, P)
        cnt = m.sum(1)
        ok = cnt >= 3
        c = np.maximum(cnt, 1)[:, None]
        mu_a = (m @ A[i].T) / c  # (b, 3)
        mu_b = np.einsum("bp,bcp->bc", m, B) / c
        a0 = A[i][None] - mu_a[:, :, None]  # (b, 3, P)
        b0 = B - mu_b[:, :, None]
        var_a = np.einsum("bp,bcp->b", m, a0 ** 2) / c[:, 0]
        var_b = np.einsum("bp,bcp->b", m, b0 ** 2) / c[:, 0]
        S = np.einsum("bp,bip,bjp->bij", m, b0, a0) / c[:, :, None]  # cov(b, a)
        U, d, Vt = np.linalg.svd(S)
        sgn = np.sign(np.linalg.det(U) * np.linalg.det(Vt))
        tr = d[:, 0] + d[:, 1] + sgn * d[:, 2]
        if scale:
            res = var_b - tr ** 2 / np.maximum(var_a, 1e-300)
        else:
            res = var_a + var_b - 2 * tr
        D[i] = np.where(ok, np.sqrt(np.maximum(res, 0.0) / 3), np.inf)
    return D


def nearest_neighbour(A, mA, B, mB, *, aligned: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Distance to and index of the nearest item of ``B`` for every item of ``A`` (see above);
    ``aligned``: after the best similarity transform (:func:`aligned_rms_distances`)."""
    D = aligned_rms_distances(A, mA, B, mB) if aligned else masked_rms_distances(A, mA, B, mB)
    j = np.argmin(D, axis=1)
    return D[np.arange(len(D)), j], j


# ---------------------------------------------------------------- text control
def stratified_split(labels, holdout: float = 0.2, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Indices ``(train, held_out)``: ``holdout`` of every class (at least one when the class has
    two or more items), chosen by a seeded permutation."""
    labels = np.asarray(labels)
    rng = np.random.default_rng(seed)
    test = []
    for c in sorted(set(labels.tolist())):
        idx = np.flatnonzero(labels == c)
        k = int(round(holdout * len(idx)))
        k = max(k, 1) if len(idx) >= 2 else 0
        test.extend(rng.permutation(idx)[:k].tolist())
    test = np.sort(np.asarray(test, np.int64))
    train = np.setdiff1d(np.arange(len(labels)), test)
    return train, test


def _torch():
    from geoface._lazy import lazy_import
    return lazy_import("torch", "the expression classifier")



def ExpressionClassifier(in_channels: int, n_classes: int, width: int = 16, res: int = 64, mean=None):
    """A small CNN: subtract ``mean [C, N, N]`` (the shared head shape), 4 × (conv3×3 → GroupNorm →
    SiLU → 2× average pool), flatten the ``N/16 × N/16`` map (keeps *where* a feature is: left vs.
    right eye), dropout, linear."""
    torch = _torch()
    nn = torch.nn

    class Center(nn.Module):
        def __init__(self, m):
            super().__init__()
            self.register_buffer("mean", torch.zeros(in_channels, res, res) if m is None else torch.as_tensor(m).float())

        def forward(self, x):  # [B, C, N, N]
            return x - self.mean

    layers, c = [Center(mean)], in_channels
    for k in range(4):
        w = width * 2 ** min(k, 2)
        layers += [nn.Conv2d(c, w, 3, padding=1), nn.GroupNorm(4, w), nn.SiLU(), nn.AvgPool2d(2)]
        c = w
    side = max(1, res // 16)
    return nn.Sequential(*layers, nn.Flatten(), nn.Dropout(0.2), nn.Linear(c * side * side, n_classes))


def train_classifier(X, y, *, n_classes: int | None = None, epochs: int = 60, batch_size: int = 32, lr: float = 2e-3,
                     width: int = 16, seed: int = 0, augment_shift: int = 1):
    """Train :func:`ExpressionClassifier` on ``X [n, C, N, N]`` (float32) with integer labels ``y (n,)``.

    The training mean image is subtracted inside the model.  Deterministic for a seed (CPU).
    ``augment_shift``: random integer image shifts up to this many pixels against over-fitting a
    small set.  Returns the model in eval mode.
    """
    torch = _torch()
    X = torch.as_tensor(np.asarray(X, np.float32))
    y = torch.as_tensor(np.asarray(y, np.int64))
    if X.ndim != 4 or len(X) != len(y) or len(X) == 0 or X.shape[2] != X.shape[3]:
        raise GeofaceError(f"X must be [n, C, N, N] with one label per item; got {tuple(X.shape)} and {tuple(y.shape)}")
    n_classes = int(n_classes or int(y.max()) + 1)
    g = torch.Generator().manual_seed(int(seed))
    torch.manual_seed(int(seed))
    model = ExpressionClassifier(X.shape[1], n_classes, width, res=X.shape[2], mean=X.mean(0))
    opt = torch.optim.AdamW(model.parameters(), lr=lr, weight_decay=1e-2)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=max(1, epochs))
    model.train()
    for _ in range(int(epochs)):
        perm = torch.randperm(len(X), generator=g)
        for s in range(0, len(X), batch_size):
            idx = perm[s:s + batch_size]
            xb = X[idx]
            if augment_shift:
                dx, dy = torch.randint(-augment_shift, augment_shift + 1, (2,), generator=g).tolist()
                xb = torch.roll(xb, (dy, dx), dims=(2, 3))
            loss = torch.nn.functional.cross_entropy(model(xb), y[idx])
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
        sched.step()
    return model.eval()


def predict(model, X, batch_size: int = 64) -> np.ndarray:
    """Class index per item of ``X [n, C, N, N]``."""
    torch = _torch()
    X = torch.as_tensor(np.asarray(X, np.float32))
    with torch.no_grad():
        out = [model(X[s:s + batch_size]).argmax(1) for s in range(0, len(X), batch_size)]
    return torch.cat(out).numpy() if out else np.zeros(0, np.int64)
