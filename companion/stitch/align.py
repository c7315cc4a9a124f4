"""Global alignment: every keyframe's homography onto the facade plane, refined together by least squares.

Unknowns: one homography G_k (image-normalised -> plane metres, 8 dof) per keyframe. Residuals: matched
inliers of every accepted pair, carried from one image through G_a then G_b^-1, must land on their match
(symmetric transfer error, measured in the images so that shrinking the whole map earns nothing), and
(where telemetry exists) each image should stay near where its pose puts it: a weak, robust prior (Cauchy on the
image centre, ``sigma_prior_m``), so GNSS noise only decides where the map as a whole sits and a GNSS jump on a
few keyframes is outvoted by the images. Images first: the keyframes are placed by chaining the pairwise
homographies, and each connected part is then moved onto the telemetry as one piece (the median offset); the
residual between the two after the adjustment is how well the map is anchored (``Anchoring``).
Solved by Levenberg-Marquardt with Huber weights on dense normal equations (8 N unknowns: 200 keyframes is a
1600x1600 system), so adding keyframes never makes the adjustment fail the way a chained panorama does;
drift between chained pairs is spread out.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, replace

import numpy as np

from companion.stitch.config import StitchConfig
from companion.stitch.geometry import apply_h
from companion.stitch.inputs import CameraModel
from companion.stitch.pairs import PairResult, RegisteredPairs
from companion.stitch.priors import PlanePriors


@dataclass(frozen=True)
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


_ANCHOR_PTS = np.array([[-0.5, -0.3], [0.5, -0.3], [0.5, 0.3], [-0.5, 0.3], [0.0, 0.0]])
# prior residuals: the image centre (where the camera was: GNSS, metres off) and the corners relative to the
# centre (how the camera was turned: attitude, far better known). Keeping them apart stops position noise from
# tilting or keystoning the whole map.
_CENTRE_RELATIVE = np.eye(5)
_CENTRE_RELATIVE[:4, 4] = -1.0
_HUBER = 3.0
_ROW, _COL = np.divmod(np.arange(8), 3)  # the 8 parameters' places in the 3x3 homography
_CAUCHY = 1.0  # the centre prior's scale in units of sigma_prior_m: weight 1/2 at one sigma, 1/10 at three


@dataclass(frozen=True)
class _Observation:
    """Inlier matches of an accepted pair, image-normalised, in keyframe positions a and b."""

    a: int
    b: int
    xa: np.ndarray
    xb: np.ndarray


@dataclass(frozen=True)
class _Anchor:
    """Where a keyframe's prior (or the gauge seed) puts the anchor points on the plane, and how firmly."""

    k: int
    target: np.ndarray  # (5, 2) plane points of _ANCHOR_PTS
    sigma: np.ndarray  # (5,)
    robust: bool = True  # the centre term is Cauchy (telemetry), not Gaussian (the gauge seed)


def chained_layouts(n: int, edges, priors: list[np.ndarray | None]):
    """Each connected part of the pair graph laid out by its images alone: (root, part, homographies), chained
    from the keyframe with telemetry and the most inliers, which its telemetry places (so the layout's scale is
    that keyframe's footprint). Parts without telemetry are not laid out."""
    strength = np.zeros(n)
    for i, j, _, inl in edges:
        strength[i] += inl
        strength[j] += inl
    for comp in _components(n, [(e[0], e[1]) for e in edges]):
        told = [k for k in comp if priors[k] is not None]
        if not told:
            continue
        root = max(told, key=lambda k: (strength[k], -k))
        yield root, comp, _spanning_init(n, edges, {root: priors[root]})


def _image_first_init(n: int, edges, priors: list[np.ndarray | None]) -> list[np.ndarray | None]:
    """Each connected part of the pair graph placed by its images (``chained_layouts``), then moved as one
    piece by the median offset between its image centres and where telemetry puts them: one bad pose cannot
    bend the map, a jump cannot move it far. Keyframes in no accepted pair stand where telemetry puts them;
    parts without any telemetry are not placed."""
    G: list[np.ndarray | None] = [None] * n
    centre = np.zeros((1, 2))
    for _root, comp, chained in chained_layouts(n, edges, priors):
        told = [k for k in comp if priors[k] is not None]
        offsets = np.array([apply_h(priors[k], centre)[0] - apply_h(chained[k], centre)[0] for k in told])
        shift = np.median(offsets, axis=0)
        T = np.array([[1.0, 0.0, shift[0]], [0.0, 1.0, shift[1]], [0.0, 0.0, 1.0]])
        for k in comp:
            Gk = T @ chained[k]
            G[k] = Gk / Gk[2, 2]
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
    edges, obs = _pair_observations(pairs, to_norm)
    seeds = _seeds(n, priors, edges, reference)
    G = _image_first_init(n, edges, priors) if any(P is not None for P in priors) else _spanning_init(n, edges, seeds)
    dropped = {k: "not connected to the map (no accepted pair) and no telemetry pose" for k in range(n) if G[k] is None}
    placed = [k for k in range(n) if G[k] is not None]
    problem = _Problem(
        col={k: c for c, k in enumerate(placed)},
        obs=[o for o in obs if G[o.a] is not None and G[o.b] is not None],
        anchors=_anchors(placed, priors, seeds, sigma_prior_m, sigma_shape_m),
        sigma_match=sigma_match,
    )
    params = np.concatenate([_to_params(G[k]) for k in placed]) if placed else np.zeros(0)
    params, it, rms0 = _levenberg_marquardt(problem, params, iterations)
    _, _, _, rms1 = problem.evaluate(params, False)
    out: list[np.ndarray | None] = [None] * n
    for k in placed:
        c = problem.col[k]
        out[k] = _to_h(params[8 * c : 8 * c + 8])
    return Alignment(out, dropped, rms0, rms1, it)


def pair_graph(pairs, to_norm: np.ndarray) -> list[tuple[int, int, np.ndarray, int]]:
    """Accepted pairs as graph edges: (i, j, homography image-normalised i -> j, inliers)."""
    from_norm = np.linalg.inv(to_norm)
    edges = []
    for r in pairs:
        if r.accepted:
            Hn = to_norm @ r.H @ from_norm
            edges.append((r.i, r.j, Hn / Hn[2, 2], r.inliers))
    return edges


def _pair_observations(pairs: list[PairResult], to_norm: np.ndarray):
    """Accepted pairs as graph edges (``pair_graph``) and as matched point sets."""
    obs = [_Observation(r.i, r.j, apply_h(to_norm, r.pts_i), apply_h(to_norm, r.pts_j)) for r in pairs if r.accepted]
    return pair_graph(pairs, to_norm), obs


def _seeds(n: int, priors, edges, reference: np.ndarray) -> dict[int, np.ndarray]:
    """Telemetry places every keyframe with a prior; without any, the largest connected component is seeded at
    its first keyframe by ``reference``."""
    if any(P is not None for P in priors):
        return {k: priors[k] for k in range(n) if priors[k] is not None}
    best = max(_components(n, [(e[0], e[1]) for e in edges]), key=len)
    return {min(best): reference}


def _anchors(placed: list[int], priors, seeds, sigma_prior_m: float, sigma_shape_m: float) -> list[_Anchor]:
    anchors = []
    for k in placed:
        if priors[k] is not None:
            sig = np.array([sigma_shape_m] * 4 + [sigma_prior_m])
            anchors.append(_Anchor(k, apply_h(priors[k], _ANCHOR_PTS), sig))
        elif k in seeds:
            anchors.append(_Anchor(k, apply_h(seeds[k], _ANCHOR_PTS), np.full(5, 1e-6), robust=False))  # gauge
    return anchors


@dataclass(frozen=True)
class _Problem:
    """The least-squares problem over the placed keyframes' parameters (8 per keyframe, column ``col[k]``)."""

    col: dict[int, int]
    obs: list[_Observation]
    anchors: list[_Anchor]
    sigma_match: float

    def evaluate(self, p: np.ndarray, want_jac: bool):
        """Huber cost, normal equations (J^T J, J^T r) when wanted, and the matches' rms transfer error."""
        m = len(self.col)
        JTJ = np.zeros((8 * m, 8 * m)) if want_jac else None
        JTr = np.zeros(8 * m) if want_jac else None
        cost, sq_match = 0.0, []
        for o in self.obs:
            for s_, t_, xs, xt in ((o.a, o.b, o.xa, o.xb), (o.b, o.a, o.xb, o.xa)):  # both directions: symmetric
                cost += self._add_pair(p, s_, t_, xs, xt, JTJ, JTr, sq_match)
        for anchor in self.anchors:
            cost += self._add_anchor(p, anchor, JTJ, JTr)
        rms = float(np.sqrt(np.mean(np.concatenate(sq_match)))) if sq_match else 0.0
        return cost, JTJ, JTr, rms

    def _add_pair(self, p, s_, t_, xs, xt, JTJ, JTr, sq_match) -> float:
        cs, ct = self.col[s_], self.col[t_]
        ps_, pt_ = p[8 * cs : 8 * cs + 8], p[8 * ct : 8 * ct + 8]
        r, J = self._pair_terms(ps_, pt_, xs, JTJ is not None)
        r = (r - xt / self.sigma_match).reshape(-1)  # (2N,): x0, y0, x1, y1, ...
        nr = np.hypot(r[0::2], r[1::2])
        wgt = np.where(nr <= _HUBER, 1.0, _HUBER / np.maximum(nr, 1e-12))
        cost = float(np.sum(np.where(nr <= _HUBER, nr**2, 2 * _HUBER * nr - _HUBER**2)))
        sq_match.append((nr * self.sigma_match) ** 2)
        if JTJ is None:
            return cost
        J = J.reshape(-1, 16)  # one row per residual component, matching r
        Jw = J * np.repeat(wgt, 2)[:, None]
        JJ = Jw.T @ J
        Jr = Jw.T @ r
        ss, st = slice(8 * cs, 8 * cs + 8), slice(8 * ct, 8 * ct + 8)
        JTJ[ss, ss] += JJ[:8, :8]
        JTJ[st, st] += JJ[8:, 8:]
        JTJ[ss, st] += JJ[:8, 8:]
        JTJ[st, ss] += JJ[8:, :8]
        JTr[ss] += Jr[:8]
        JTr[st] += Jr[8:]
        return cost

    def _pair_terms(self, ps_, pt_, xs, want_jac: bool) -> tuple[np.ndarray, np.ndarray | None]:
        """The points of s carried into t, over ``sigma_match`` (the pair's residual is their distance from their
        matches: a transfer error in image t, invariant to any common change of all G, so no collapse towards a
        smaller map, which a residual measured on the plane would reward), and the analytic Jacobian of that
        transfer with respect to both keyframes' parameters (N, 2, 16). With z = G_t^-1 G_s x (homogeneous), the
        parameter (r, c) of G_s moves z by G_t^-1[:, r] x_c, that of G_t by -G_t^-1[:, r] z_c, and the image
        point u = z[:2] / z[2] by du/dz. (It was a numerical Jacobian, 16 transfers per pair direction: most of
        the alignment's time on a 300-keyframe spool.)"""
        Ginv = np.linalg.inv(_to_h(pt_))
        xh = np.column_stack((xs, np.ones(len(xs))))
        z = xh @ (Ginv @ _to_h(ps_)).T
        iz = 1.0 / z[:, 2]
        u = z[:, :2] * iz[:, None]
        if not want_jac:
            return u / self.sigma_match, None
        du_dz = np.zeros((len(xs), 2, 3))
        du_dz[:, 0, 0] = iz
        du_dz[:, 1, 1] = iz
        du_dz[:, :, 2] = -u * iz[:, None]
        D = du_dz @ Ginv  # (N, 2, 3): column r is du/dz . G_t^-1[:, r]
        J = np.empty((len(xs), 2, 16))
        J[:, :, :8] = D[:, :, _ROW] * xh[:, None, _COL]
        J[:, :, 8:] = -D[:, :, _ROW] * z[:, None, _COL]
        return u / self.sigma_match, J / self.sigma_match

    def _add_anchor(self, p, anchor: _Anchor, JTJ, JTr) -> float:
        """The telemetry prior: shape (corners relative to the centre) Gaussian, the centre Cauchy-robust (a
        pinned gauge seed stays Gaussian)."""
        ck = self.col[anchor.k]
        u, J = _jac(p[8 * ck : 8 * ck + 8], _ANCHOR_PTS)
        r = (_CENTRE_RELATIVE @ (u - anchor.target)) / anchor.sigma[:, None]
        wgt = np.ones(len(r))
        cost = np.sum(r**2, axis=1)
        if anchor.robust:
            s_ = cost[4]
            wgt[4] = 1.0 / (1.0 + s_ / _CAUCHY**2)
            cost[4] = _CAUCHY**2 * np.log1p(s_ / _CAUCHY**2)
        if JTJ is not None:
            J = np.einsum("ab,bpi->api", _CENTRE_RELATIVE, J) / anchor.sigma[:, None, None]
            s = slice(8 * ck, 8 * ck + 8)
            JTJ[s, s] += np.einsum("n,npi,npj->ij", wgt, J, J)
            JTr[s] += np.einsum("n,npi,np->i", wgt, J, r)
        return float(np.sum(cost))


def _levenberg_marquardt(problem: _Problem, params: np.ndarray, iterations: int) -> tuple[np.ndarray, int, float]:
    """Damped Gauss-Newton on the problem's normal equations; returns the parameters, the iterations run and
    the rms transfer error before the first step."""
    cost, JTJ, JTr, rms0 = problem.evaluate(params, True)
    lam, it = 1e-3, 0
    for it in range(1, iterations + 1):  # noqa: B007
        if len(problem.col) == 0:
            break
        A = JTJ + lam * np.diag(np.maximum(np.diag(JTJ), 1e-9))
        try:
            step = np.linalg.solve(A, -JTr)
        except np.linalg.LinAlgError:
            lam *= 10
            continue
        new = params + step
        new_cost, nJTJ, nJTr, _ = problem.evaluate(new, True)
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
    return params, it, rms0


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


@dataclass(frozen=True)
class AlignmentRound:
    """One pass of the global alignment: each aligned pair's median residual and the pairs it rejected."""

    transfer_rms_px: float
    iterations: int
    pair_residual_px: dict[tuple[int, int], float]  # (position i, position j) -> median transfer error
    limit_px: float | None
    rejected: tuple[tuple[int, int], ...]


@dataclass(frozen=True)
class Anchoring:
    """How well the map is anchored on the wall: after the adjustment, the offset (plane metres) between where
    the images put each keyframe's centre and where its telemetry does. Keyframes whose telemetry is more than
    ``outvoted_sigmas`` prior sigmas off (a GNSS jump) were outvoted by the images; the rest decide where the
    map sits, to about ``placement_sigma_m`` (their robust spread over the square root of their number)."""

    keyframes: int  # keyframes with telemetry that were placed
    offsets_m: tuple[float, ...]  # per such keyframe (in ``positions`` order): |telemetry centre - image centre|
    positions: tuple[int, ...]
    outvoted: tuple[int, ...]  # keyframe positions
    placement_sigma_m: float
    mean_offset_m: tuple[float, float]  # (along, up) mean over the keyframes not outvoted
    # the images against the telemetry alone (``placement_sigma_m`` before the wall's edges or GNSS's absolute
    # error are counted: ``with_absolute``)
    relative_sigma_m: float | None = None

    def with_absolute(self, sigma_m: tuple[float, float]) -> Anchoring:
        """This anchoring with the map's absolute placement uncertainty (along, up) counted in
        ``placement_sigma_m``: GNSS's bias, or the wall's edges where the keyframes show them."""
        relative = self.placement_sigma_m if self.relative_sigma_m is None else self.relative_sigma_m
        total = math.sqrt(relative**2 + sigma_m[0] ** 2 + sigma_m[1] ** 2)
        return replace(self, placement_sigma_m=total, relative_sigma_m=relative)

    def summary(self) -> dict:
        d = np.asarray(self.offsets_m)
        return {
            "keyframes": self.keyframes,
            "offset_m": {
                "median": round(float(np.median(d)), 3),
                "p95": round(float(np.percentile(d, 95)), 3),
                "max": round(float(d.max()), 3),
            },
            "mean_offset_m": [round(v, 3) for v in self.mean_offset_m],
            "placement_sigma_m": round(self.placement_sigma_m, 3),
            "relative_sigma_m": round(self.placement_sigma_m if self.relative_sigma_m is None
                                      else self.relative_sigma_m, 3),
        }


def anchoring_of(G: list[np.ndarray | None], priors, sigma_prior_m: float, outvoted_sigmas: float = 3.0):
    """The :class:`Anchoring` of aligned homographies ``G`` against the telemetry ``priors`` (None when no
    placed keyframe has telemetry)."""
    told = [k for k in range(len(G)) if G[k] is not None and priors[k] is not None]
    if not told:
        return None
    centre = np.zeros((1, 2))
    d = np.array([apply_h(priors[k], centre)[0] - apply_h(G[k], centre)[0] for k in told])
    norm = np.linalg.norm(d, axis=1)
    bad = norm > outvoted_sigmas * sigma_prior_m
    good = d[~bad] if (~bad).any() else d
    spread = 1.4826 * np.median(np.abs(good - np.median(good, axis=0)), axis=0)
    spread = np.maximum(spread, np.std(good, axis=0) if len(good) > 1 else spread)
    sigma = float(np.linalg.norm(spread) / np.sqrt(len(good)))
    return Anchoring(
        len(told),
        tuple(float(v) for v in norm),
        tuple(told),
        tuple(k for k, b in zip(told, bad, strict=True) if b),
        sigma,
        (float(good[:, 0].mean()), float(good[:, 1].mean())),
    )


@dataclass(frozen=True)
class AlignedKeyframes:
    """The alignment stage's output: each keyframe's homography onto the plane (``alignment.G``) and the pairs
    after outlier rejection (pairs inconsistent with all the others are marked not accepted, with the reason)."""

    alignment: Alignment
    pairs: tuple[PairResult, ...]
    rounds: tuple[AlignmentRound, ...]
    anchoring: Anchoring | None = None  # None without telemetry

    @property
    def placed(self) -> list[int]:
        return [k for k, G in enumerate(self.alignment.G) if G is not None]

    @property
    def accepted(self) -> list[PairResult]:
        return [r for r in self.pairs if r.accepted]


def align_keyframes(
    pairs: RegisteredPairs, priors: PlanePriors, camera: CameraModel, cfg: StitchConfig, *, max_rounds: int = 4
) -> AlignedKeyframes:
    """Global alignment onto the plane; pairs that disagree with all the others after it are dropped and it is
    re-run (at most ``max_rounds`` alignments; the last round's rejections are reported, not re-aligned)."""
    to_norm = np.linalg.inv(camera.K)
    n = len(priors.priors)
    results = list(pairs.results)
    rounds = []
    for _round in range(max_rounds):
        al = global_alignment(
            n,
            results,
            to_norm,
            list(priors.priors),
            priors.reference,
            sigma_match=pairs.settings.ransac_px / camera.focal_px,
            sigma_prior_m=cfg.sigma_prior_m,
            sigma_shape_m=cfg.sigma_shape_m,
        )
        errs = _pair_residuals_px(al, results, to_norm, camera.focal_px)
        limit = max(cfg.max_pair_residual_px, 6.0 * float(np.median(list(errs.values())))) if errs else None
        bad = [k for k, e in errs.items() if e > limit] if errs else []
        rounds.append(
            AlignmentRound(
                al.final_rms * camera.focal_px,
                al.iterations,
                {(results[k].i, results[k].j): e for k, e in errs.items()},
                limit,
                tuple((results[k].i, results[k].j) for k in bad),
            )
        )
        if not bad:
            break
        for k in bad:
            why = f"inconsistent with the other pairs after global alignment ({errs[k]:.1f} px)"
            results[k] = replace(results[k], accepted=False, reason=why)
    anchoring = anchoring_of(al.G, priors.priors, cfg.sigma_prior_m) if priors.use_poses else None
    return AlignedKeyframes(al, tuple(results), tuple(rounds), anchoring)


def _pair_residuals_px(al: Alignment, results: list[PairResult], to_norm: np.ndarray, focal_px: float):
    """Median transfer error (px) of every accepted pair whose keyframes were both placed, by list position."""
    errs = {}
    for k, r in enumerate(results):
        if r.accepted and al.G[r.i] is not None and al.G[r.j] is not None:
            M = np.linalg.inv(al.G[r.j]) @ al.G[r.i]
            e = apply_h(M, apply_h(to_norm, r.pts_i)) - apply_h(to_norm, r.pts_j)
            errs[k] = float(np.median(np.linalg.norm(e, axis=1))) * focal_px
    return errs
