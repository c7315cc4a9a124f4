"""Location-dependent homographies on a Cx x Cy mesh (APAP; paper Eq. 4).

For keyframe k the globally adjusted homography G_k puts its matched points p_i = G_k(x_i) on the wall, while
the partner keyframes put the same features at r_i. Each keyframe warps its matches to the midpoint
q_i = (p_i + r_i) / 2, so two overlapping keyframes meet exactly at their shared features (no ghosting of
non-planar detail). At every mesh vertex X* a correction C* (plane -> plane) is fitted by Gaussian-weighted DLT,
w_i = max(exp(-|X* - x_i|^2 / rho^2), gamma): near features it follows them, far from any feature the weights
become uniform (the offset gamma) and C* tends to the best single correction, i.e. back to the global G_k.
The local homography is H* = C* G_k. Vertices (not cell centres) carry H*, so neighbouring cells share edges
and the warped mesh has no cracks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from companion.stitch.geometry import apply_h


@dataclass
class WarpedMesh:
    src_px: np.ndarray  # (Cy+1, Cx+1, 2) vertex positions in the keyframe, full-resolution pixels
    dst_plane: np.ndarray  # (Cy+1, Cx+1, 2) the same vertices on the wall plane (along_m, up_m)
    local: bool  # False when too few matches: the mesh is just the global homography


def _hartley(pts: np.ndarray) -> np.ndarray:
    c = pts.mean(axis=0)
    d = np.sqrt(np.mean(np.sum((pts - c) ** 2, axis=1)))
    s = np.sqrt(2.0) / max(d, 1e-12)
    return np.array([[s, 0.0, -s * c[0]], [0.0, s, -s * c[1]], [0.0, 0.0, 1.0]])


def weighted_dlt(src: np.ndarray, dst: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Homographies src -> dst for each row of ``weights`` (V, N) at once: the weighted Eq. 4 DLT.

    Solves min ||diag(w) A h|| per row by the smallest eigenvector of A^T W A (9x9), all rows batched.
    Returns (V, 3, 3).
    """
    T = _hartley(np.vstack((src, dst)))
    s = apply_h(T, src)
    d = apply_h(T, dst)
    x, y, u, v = s[:, 0], s[:, 1], d[:, 0], d[:, 1]
    z, o = np.zeros_like(x), np.ones_like(x)
    a1 = np.column_stack((z, z, z, -x, -y, -o, v * x, v * y, v))
    a2 = np.column_stack((x, y, o, z, z, z, -u * x, -u * y, -u))
    M = (a1[:, :, None] * a1[:, None, :] + a2[:, :, None] * a2[:, None, :]).reshape(len(x), 81)
    A = (weights @ M).reshape(-1, 9, 9)
    _, vecs = np.linalg.eigh(A)
    Hn = vecs[:, :, 0].reshape(-1, 3, 3)
    Tinv = np.linalg.inv(T)
    H = Tinv[None] @ Hn @ T[None]
    return H / H[:, 2:3, 2:3]


def mesh_for_keyframe(
    G: np.ndarray,
    to_norm: np.ndarray,
    width: int,
    height: int,
    pts_px: np.ndarray,
    targets_plane: np.ndarray,
    *,
    cells: tuple[int, int] = (16, 9),
    rho_px: float | None = None,
    gamma: float = 0.01,
    max_shift_m: float = 0.25,
    min_points: int = 12,
) -> WarpedMesh:
    """Vertex positions of keyframe k's mesh on the wall. ``pts_px``/``targets_plane``: its matched features
    and where they must land (the midpoints)."""
    cx, cy = cells
    xs = np.linspace(0.0, float(width), cx + 1)
    ys = np.linspace(0.0, float(height), cy + 1)
    src = np.stack(np.meshgrid(xs, ys), axis=-1)  # (cy+1, cx+1, 2)
    flat = src.reshape(-1, 2)
    Gpx = G @ to_norm
    base = apply_h(Gpx, flat)
    if len(pts_px) < min_points:
        return WarpedMesh(src, base.reshape(src.shape), False)
    rho = rho_px if rho_px is not None else 0.1 * width
    p = apply_h(Gpx, pts_px)
    d2 = np.sum((flat[:, None, :] - pts_px[None, :, :]) ** 2, axis=2)
    w = np.maximum(np.exp(-d2 / rho**2), gamma)
    C = weighted_dlt(p, targets_plane, w)
    hom = np.einsum("vij,vj->vi", C, np.column_stack((base, np.ones(len(base)))))
    with np.errstate(divide="ignore", invalid="ignore"):
        moved = hom[:, :2] / hom[:, 2:3]
    shift = np.linalg.norm(moved - base, axis=1)
    bad = ~np.isfinite(shift) | (shift > max_shift_m)
    moved[bad] = base[bad]  # a wild local fit falls back to the global homography at that vertex
    return WarpedMesh(src, moved.reshape(src.shape), True)
