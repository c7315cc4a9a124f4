"""Global alignment: every keyframe's homography onto the facade plane, refined together by least squares.

Unknowns: one homography G_k (image-normalised -> plane metres, 8 dof) per keyframe. Residuals: matched
inliers of every accepted pair, carried from one image through G_a then G_b^-1, must land on their match
(symmetric transfer error, measured in the images so that shrinking the whole map earns nothing), and
(where telemetry exists) each image must stay near where its pose puts it (a soft prior, ``sigma_prior_m``).
Solved by Levenberg-Marquardt with Huber weights on dense normal equations (8 N unknowns: 200 keyframes is a
1600x1600 system), so adding keyframes never makes the adjustment fail the way a chained panorama does;
drift between chained pairs is spread out.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from companion.stitch.geometry import apply_h
from companion.stitch.pairs import PairResult


@dataclass
class Alignment:
    G: list[np.ndarray | None]  # image-normalised -> plane, None for keyframes that could not be placed
    dropped: dict[int, str]  # keyframe position -> reason
    initial_rms: float  # symmetric transfer error, image-normalised units (x focal = px)
    final_rms: float
    iterations: int


def _to_params(H: np.ndarray) -> np.ndarray:
    H = H / H[2, 2]
    return H.ravel()[:8].copy()


def _to_h(p: np.ndarray) -> np.ndarray:
    return np.append(p, 1.0).reshape(3, 3)


def _jac(p: np.ndarray, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mapped points (N, 2) and d(mapped)/d(params) (N, 2, 8)."""
    x, y = pts[:, 0], pts[:, 1]
    w = p[6] * x + p[7] * y + 1.0
    u = (p[0] * x + p[1] * y + p[2]) / w
    v = (p[3] * x + p[4] * y + p[5]) / w
    J = np.zeros((len(pts), 2, 8))
    J[:, 0, 0], J[:, 0, 1], J[:, 0, 2] = x / w, y / w, 1.0 / w
    J[:, 1, 3], J[:, 1, 4], J[:, 1, 5] = x / w, y / w, 1.0 / w
    J[:, 0, 6], J[:, 0, 7] = -u * x / w, -u * y / w
    J[:, 1, 6], J[:, 1, 7] = -v * x / w, -v * y / w
    return np.column_stack((u, v)), J


def _spanning_init(n: int, edges: list[tuple[int, int, np.ndarray, int]], seeds: dict[int, np.ndarray]):
    """Places keyframes by chaining pairwise homographies outward from seeds, strongest pairs first."""
    G: list[np.ndarray | None] = [None] * n
    for k, H in seeds.items():
        G[k] = H
    adj: dict[int, list[tuple[int, np.ndarray, int]]] = {}
    for i, j, Hn, inl in edges:  # Hn: normalised i -> normalised j
        adj.setdefault(i, []).append((j, np.linalg.inv(Hn), inl))  # from placed i to j: G_j = G_i @ inv(Hn)
        adj.setdefault(j, []).append((i, Hn, inl))  # from placed j to i: G_i = G_j @ Hn
    queue = deque(sorted(seeds))
    while queue:
        a = queue.popleft()
        for b, T, _ in sorted(adj.get(a, []), key=lambda e: -e[2]):
            if G[b] is None:
                Gb = G[a] @ T
                G[b] = Gb / Gb[2, 2]
                queue.append(b)
    return G


def global_alignment(
    n: int,
    pairs: list[PairResult],
    to_norm: np.ndarray,
    priors: list[np.ndarray | None],
    reference: np.ndarray,
    *,
    sigma_match: float,
    sigma_prior_m: float = 0.5,
    sigma_shape_m: float = 0.05,
    iterations: int = 30,
) -> Alignment:
    """``to_norm`` maps pixels to image-normalised coordinates; ``reference`` places keyframe 0 when no
    keyframe has a telemetry prior (it fixes the gauge)."""
    from_norm = np.linalg.inv(to_norm)
    edges, obs = [], []
    for r in pairs:
        if not r.accepted:
            continue
        Hn = to_norm @ r.H @ from_norm
        edges.append((r.i, r.j, Hn / Hn[2, 2], r.inliers))
        obs.append((r.i, r.j, apply_h(to_norm, r.pts_i), apply_h(to_norm, r.pts_j)))
    has_prior = [P is not None for P in priors]
    dropped: dict[int, str] = {}
    if any(has_prior):
        seeds = {k: priors[k] for k in range(n) if has_prior[k]}
    else:
        # largest connected component, seeded at its first keyframe
        comp = _components(n, [(e[0], e[1]) for e in edges])
        best = max(comp, key=len)
        seeds = {min(best): reference}
    G = _spanning_init(n, edges, seeds)
    for k in range(n):
        if G[k] is None:
            dropped[k] = "not connected to the map (no accepted pair) and no telemetry pose"
    placed = [k for k in range(n) if G[k] is not None]
    col = {k: c for c, k in enumerate(placed)}
    obs = [o for o in obs if o[0] in col and o[1] in col]
    anchor_pts = np.array([[-0.5, -0.3], [0.5, -0.3], [0.5, 0.3], [-0.5, 0.3], [0.0, 0.0]])
    # prior residuals: the image centre (where the camera was: GNSS, metres off) and the corners relative to
    # the centre (how the camera was turned: attitude, far better known). Keeping them apart stops position
    # noise from tilting or keystoning the whole map.
    D = np.eye(5)
    D[:4, 4] = -1.0
    anchors = []
    for k in placed:
        if has_prior[k]:
            sig = np.array([sigma_shape_m] * 4 + [sigma_prior_m])
            anchors.append((k, apply_h(priors[k], anchor_pts), sig))
        elif k in seeds:
            anchors.append((k, apply_h(seeds[k], anchor_pts), np.full(5, 1e-6)))  # gauge: pin the seed
    params = np.concatenate([_to_params(G[k]) for k in placed]) if placed else np.zeros(0)
    m = len(placed)

    def pair_res(pa, pb, xa, xb):
        """Transfer error in image b (normalised units): invariant to any common change of all G (no collapse
        towards a smaller map, which a residual measured on the plane would reward)."""
        M = np.linalg.inv(_to_h(pb)) @ _to_h(pa)
        return (apply_h(M, xa) - xb) / sigma_match

    def evaluate(p, want_jac, huber):
        cost = 0.0
        JTJ = np.zeros((8 * m, 8 * m)) if want_jac else None
        JTr = np.zeros(8 * m) if want_jac else None
        sq_match = []
        for a, b, xa, xb in obs:
            for s_, t_, xs, xt in ((a, b, xa, xb), (b, a, xb, xa)):  # both directions: symmetric
                cs, ct = col[s_], col[t_]
                ps_, pt_ = p[8 * cs : 8 * cs + 8], p[8 * ct : 8 * ct + 8]
                r = pair_res(ps_, pt_, xs, xt)
                nr = np.linalg.norm(r, axis=1)
                wgt = np.where(nr <= huber, 1.0, huber / np.maximum(nr, 1e-12))
                cost += float(np.sum(np.where(nr <= huber, nr**2, 2 * huber * nr - huber**2)))
                sq_match.append((nr * sigma_match) ** 2)
                if not want_jac:
                    continue
                J = np.zeros((len(xs), 2, 16))
                for q in range(8):  # numerical Jacobian: 16 cheap evaluations per pair direction
                    e = 1e-6 * max(abs(ps_[q]), 1e-3)
                    d = ps_.copy()
                    d[q] += e
                    J[:, :, q] = (pair_res(d, pt_, xs, xt) - r) / e
                    e = 1e-6 * max(abs(pt_[q]), 1e-3)
                    d = pt_.copy()
                    d[q] += e
                    J[:, :, 8 + q] = (pair_res(ps_, d, xs, xt) - r) / e
                JJ = np.einsum("n,npi,npj->ij", wgt, J, J)
                Jr = np.einsum("n,npi,np->i", wgt, J, r)
                ss, st = slice(8 * cs, 8 * cs + 8), slice(8 * ct, 8 * ct + 8)
                JTJ[ss, ss] += JJ[:8, :8]
                JTJ[st, st] += JJ[8:, 8:]
                JTJ[ss, st] += JJ[:8, 8:]
                JTJ[st, ss] += JJ[8:, :8]
                JTr[ss] += Jr[:8]
                JTr[st] += Jr[8:]
        for k, target, sigma in anchors:
            ck = col[k]
            u, J = _jac(p[8 * ck : 8 * ck + 8], anchor_pts)
            r = (D @ (u - target)) / sigma[:, None]
            cost += float(np.sum(r**2))
            if want_jac:
                J = np.einsum("ab,bpi->api", D, J) / sigma[:, None, None]
                s = slice(8 * ck, 8 * ck + 8)
                JTJ[s, s] += np.einsum("npi,npj->ij", J, J)
                JTr[s] += np.einsum("npi,np->i", J, r)
        rms = float(np.sqrt(np.mean(np.concatenate(sq_match)))) if sq_match else 0.0
        return cost, JTJ, JTr, rms

    huber = 3.0
    cost, JTJ, JTr, rms0 = evaluate(params, True, huber)
    lam, it = 1e-3, 0
    for it in range(1, iterations + 1):  # noqa: B007
        if m == 0:
            break
        A = JTJ + lam * np.diag(np.maximum(np.diag(JTJ), 1e-9))
        try:
            step = np.linalg.solve(A, -JTr)
        except np.linalg.LinAlgError:
            lam *= 10
            continue
        new = params + step
        new_cost, nJTJ, nJTr, _ = evaluate(new, True, huber)
        if new_cost < cost:
            converged = (cost - new_cost) < 1e-7 * cost
            params, cost, JTJ, JTr = new, new_cost, nJTJ, nJTr
            lam = max(lam / 3.0, 1e-9)
            if converged:
                break
        else:
            lam *= 5.0
            if lam > 1e8:
                break
    _, _, _, rms1 = evaluate(params, False, huber)
    out: list[np.ndarray | None] = [None] * n
    for k in placed:
        out[k] = _to_h(params[8 * col[k] : 8 * col[k] + 8])
    return Alignment(out, dropped, rms0, rms1, it)


def _components(n: int, edges: list[tuple[int, int]]) -> list[set[int]]:
    parent = list(range(n))

    def find(a):
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    for a, b in edges:
        parent[find(a)] = find(b)
    comps: dict[int, set[int]] = {}
    for k in range(n):
        comps.setdefault(find(k), set()).add(k)
    return list(comps.values())
