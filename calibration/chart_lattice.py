"""Chart detection, step 3 (:mod:`calibration.chart_detection`): the affine lattice through the patch candidates'
centres, its largest connected block of sites and its coarsest well-filled sub-lattice."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from msflash.calibration.chart_regions import _Candidates, _size_groups

MAX_SIZE_GROUPS = 8
"""Most size groups (largest first) searched for a lattice."""
SUBLATTICE_GAIN = 1.25
"""A sub-lattice (every 2nd or 3rd site) replaces a lattice it fills this many times better."""
SITE_TOLERANCE = 0.2
"""A centre belongs to a lattice site if within 0.2 pitch of it (both lattice coordinates)."""


# -- 3. the lattice ---------------------------------------------------------------------------
def _folded(vectors: np.ndarray) -> np.ndarray:
    """Vectors flipped into the upper half plane (a lattice direction and its opposite are one)."""
    flip = (vectors[:, 1] < 0) | ((vectors[:, 1] == 0) & (vectors[:, 0] < 0))
    return np.where(flip[:, None], -vectors, vectors)


def _dominant(vectors: np.ndarray) -> np.ndarray | None:
    """The most common direction and length among folded displacement vectors (their median)."""
    if len(vectors) == 0:
        return None
    angles = np.arctan2(vectors[:, 1], vectors[:, 0])
    lengths = np.hypot(vectors[:, 0], vectors[:, 1])
    turn = np.abs((angles[:, None] - angles[None] + np.pi / 2) % np.pi - np.pi / 2)
    alike = (turn < math.radians(12)) & (np.abs(np.log(lengths[:, None] / lengths[None])) < math.log(1.25))
    best = int(np.argmax(alike.sum(axis=1)))
    members = vectors[alike[best]]
    aligned = np.where((members @ vectors[best] < 0)[:, None], -members, members)
    return np.median(aligned, axis=0)


def _reduced(u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lagrange–Gauss reduction: the shortest basis of the lattice spanned by ``u`` and ``v``."""
    for _ in range(32):
        if u @ u > v @ v:
            u, v = v, u
        step = round(float(u @ v) / float(u @ u))
        if step == 0:
            break
        v = v - step * u
    return u, v


@dataclass(frozen=True)
class _Lattice:
    origin: np.ndarray
    basis: np.ndarray
    """(2, 2), columns u and v (detection pixels)."""
    sites: np.ndarray
    """(m, 2) integer sites of the members."""
    members: np.ndarray
    """Indices (into the points given) on the lattice."""


def _lattice(points: np.ndarray, minimum: int) -> _Lattice | None:
    """The affine lattice through most of ``points`` (and the largest connected block of its sites).

    Of lattices holding at least ``minimum`` points, the coarsest: small regions between the
    patches (edge pixels of a mosaic) must not halve the pitch.
    """
    if len(points) < 4:
        return None
    distance = np.hypot(*(points[:, None] - points[None]).transpose(2, 0, 1))
    np.fill_diagonal(distance, np.inf)
    nearest = np.argmin(distance, axis=1)
    u = _dominant(_folded(points[nearest] - points))
    if u is None or not np.hypot(*u) > 0:
        return None
    displacement = points[None] - points[:, None]
    cosine = np.abs(displacement @ u) / (np.hypot(*u) * np.maximum(distance, 1e-12))
    off_axis = np.where(cosine < math.cos(math.radians(30)), distance, np.inf)
    second = np.argmin(off_axis, axis=1)
    has_second = np.isfinite(off_axis[np.arange(len(points)), second])
    v = _dominant(_folded(displacement[np.arange(len(points)), second][has_second]))
    if v is None:
        return None
    u, v = _reduced(u, v)
    basis = np.column_stack([u, v])
    if abs(np.linalg.det(basis)) < 0.1 * (u @ u):
        return None
    anchor = points[int(np.argmin(np.hypot(*(points - np.median(points, axis=0)).T)))]
    origin = anchor
    members = np.arange(len(points))
    sites = np.zeros((0, 2), dtype=np.int64)
    for _ in range(3):
        coordinates = np.linalg.solve(basis, (points - origin).T).T
        rounded = np.rint(coordinates)
        error = np.abs(coordinates - rounded).max(axis=1)
        on_lattice = error < SITE_TOLERANCE
        # One point per site: the closest.
        order = np.lexsort((error, rounded[:, 1], rounded[:, 0]))
        first = np.ones(len(order), dtype=bool)
        first[1:] = np.any(np.diff(rounded[order], axis=0) != 0, axis=1)
        unique = np.zeros(len(points), dtype=bool)
        unique[order[first]] = True
        members = np.flatnonzero(on_lattice & unique)
        if members.size < 4:
            return None
        members = members[_largest_block(rounded[members].astype(np.int64))]
        sites = rounded[members].astype(np.int64)
        keep, sites = _coarsest(sites, minimum)
        members = members[keep]
        design = np.column_stack([np.ones(len(members)), sites])
        solution, *_ = np.linalg.lstsq(design, points[members], rcond=None)
        origin, basis = solution[0], solution[1:].T
        if not abs(np.linalg.det(basis)) > 0.1 * min(basis[:, 0] @ basis[:, 0], basis[:, 1] @ basis[:, 1]):
            return None  # the sites lie on a line: no two-dimensional grid
    if members.size < 4:
        return None
    shift = sites.min(axis=0)  # sites from (0, 0), the origin at site (0, 0)
    return _Lattice(origin + basis @ shift, basis, sites - shift, members)


def _occupancy(sites: np.ndarray) -> float:
    """Fraction of the sites' bounding block that they fill."""
    return len(sites) / float(np.prod(np.ptp(sites, axis=0) + 1))


def _coarsest(sites: np.ndarray, minimum: int) -> tuple[np.ndarray, np.ndarray]:
    """Sites of the coarsest well-filled sub-lattice (every 2nd or 3rd site along a vector).

    A sub-lattice replaces the lattice if it keeps ``minimum`` sites and fills its block at least
    :data:`SUBLATTICE_GAIN` times better (a full grid of patches stays whole; patches with small
    regions between them drop the in-between sites). Returns the sites kept (bool) and their
    coordinates on the sub-lattice.
    """
    keep = np.ones(len(sites), dtype=bool)
    sites = sites.copy()
    while True:
        options = []
        filled = _occupancy(sites[keep])
        for axis in (0, 1):
            if np.ptp(sites[keep, axis]) == 0:
                continue
            for step in (2, 3):
                for residue in range(step):
                    subset = keep & (sites[:, axis] % step == residue)
                    if subset.sum() < minimum:
                        continue
                    coarse = sites[subset].copy()
                    coarse[:, axis] = (coarse[:, axis] - residue) // step
                    if _occupancy(coarse) >= SUBLATTICE_GAIN * filled:
                        options.append((int(subset.sum()), step, axis, residue, subset))
        if not options:
            return keep, sites[keep]
        _, step, axis, residue, keep = max(options, key=lambda o: o[:2])
        sites[:, axis] = (sites[:, axis] - residue) // step


def _largest_block(sites: np.ndarray) -> np.ndarray:
    """Indices of the largest group of sites connected through gaps of at most one missing site."""
    from scipy import sparse
    from scipy.sparse.csgraph import connected_components

    near = np.abs(sites[:, None] - sites[None]).max(axis=2) <= 2
    _, component = connected_components(sparse.csr_matrix(near), directed=False)
    return np.flatnonzero(component == np.bincount(component).argmax())


def _lattices(candidates: _Candidates, minimum: int) -> list[tuple[_Lattice, np.ndarray]]:
    """Lattices of at least ``minimum`` candidates of one size, with the candidates on each (no overlaps)."""
    lattices: list[tuple[_Lattice, np.ndarray]] = []
    for group in _size_groups(candidates, minimum)[:MAX_SIZE_GROUPS]:
        remaining = group
        while remaining.size >= minimum:
            lattice = _lattice(candidates.centres[remaining], minimum)
            if lattice is None:
                break
            members = remaining[lattice.members]
            if members.size >= minimum and not any(np.intersect1d(members, known).size for _, known in lattices):
                lattices.append((lattice, members))
            remaining = np.delete(remaining, lattice.members)
    return lattices
