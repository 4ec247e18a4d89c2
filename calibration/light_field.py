"""Uneven light across a chart: a smooth gain field per frame, fitted jointly with the curves.

Public objects
--------------
- :data:`FIELD_TERMS`: the field's terms.
- :func:`field_basis`: the terms at the patches' places, zero mean over each frame's chart.
- :func:`fit_frame_fields`: each frame's field given the curves (Gauss–Newton on the patch means).

The model
---------
A patch mean is ``m_pc = g_f(x_p) · (A c)_pc``: the chart's light is not the same everywhere — a
lens's falloff toward the corners (cos⁴, vignetting), an LED's spot, a lamp to one side — and
``g_f`` multiplies the three channels alike (it is the light's power at the patch, not its
colour). ``log g`` is a polynomial of total degree :data:`FIELD_DEGREE` in the patch's place
``(u, v)`` on the chart, scaled to [−1, 1] across it (no power of an axis beyond what the chart's
places along it determine: v³ at most on 4 rows), each term less its mean over the chart's
patches, so the field has no overall level: each frame's power stays what the LED spectra (or
the light's unknown scale) say. One field per sequence: a lens's falloff and the booth's geometry
light all its frames alike (why this form: ``docs/decisions/docstring-history.md``,
``docs/calibration.md``).
"""

from __future__ import annotations

import numpy as np

FIELD_DEGREE = 4
"""Highest total power of ``log g``'s polynomial in the patch's place (see the module notes)."""
GAUSS_NEWTON_STEPS = 3
"""Steps per frame and alternation: the alternation refines further."""
MAX_LOG_GAIN = 1.5
"""The field is clipped to ``exp(±1.5)``: a wilder fit is no light field but a misfit."""


def field_terms(positions: np.ndarray) -> list[tuple[int, int]]:
    """The powers ``(i, j)`` of ``u^i v^j`` in the field: ``0 < i + j ≤`` :data:`FIELD_DEGREE`, and no power of an
    axis beyond what the chart's distinct places along it determine (4 rows: v³ at most)."""
    positions = np.asarray(positions, dtype=float)
    distinct = [len(np.unique(np.round(positions[:, a], 6))) for a in (0, 1)]
    return [
        (i, j)
        for total in range(1, FIELD_DEGREE + 1)
        for i in range(total, -1, -1)
        for j in (total - i,)
        if i < distinct[0] and j < distinct[1]
    ]


def field_basis(positions: np.ndarray, frame: np.ndarray) -> np.ndarray:
    """The field's terms at each row's patch, (rows, terms), zero mean over each field's patches.

    Parameters
    ----------
    positions
        (rows, 2) each row's patch place (column, row) in pitches.
    frame
        (rows,) the field each row belongs to: the mean is taken per field, over its rows.
    """
    positions = np.asarray(positions, dtype=float)
    low, high = positions.min(axis=0), positions.max(axis=0)
    scaled = (2 * (positions - low) / np.where(high > low, high - low, 1.0)) - 1.0
    u, v = scaled[:, 0], scaled[:, 1]
    basis = np.column_stack([u**i * v**j for i, j in field_terms(positions)])
    for f in np.unique(frame):
        rows = frame == f
        basis[rows] -= basis[rows].mean(axis=0)
    return basis


def fit_frame_fields(
    predicted: np.ndarray,
    data: np.ndarray,
    std: np.ndarray,
    basis: np.ndarray,
    frame: np.ndarray,
    theta: np.ndarray,
) -> np.ndarray:
    """Each frame's field coefficients given the predicted patch means, (n_frames, 5).

    Minimises ``Σ ((m − g·p) / σ)²`` over the frame's rows and channels, ``g = exp(basis · θ_f)``,
    by :data:`GAUSS_NEWTON_STEPS` Gauss–Newton steps from ``theta``.

    Parameters
    ----------
    predicted, data, std
        (rows, 3): the curves' prediction without the field, the patch means, their standard errors.
    basis
        (rows, 5) from :func:`field_basis`.
    frame
        (rows,) frame of each row.
    theta
        (n_frames, 5) the current coefficients.
    """
    theta = np.array(theta, dtype=float)
    for f in range(theta.shape[0]):
        rows = frame == f
        if np.count_nonzero(rows) <= basis.shape[1]:
            continue
        b, p, m, s = basis[rows], predicted[rows], data[rows], std[rows]
        for _ in range(GAUSS_NEWTON_STEPS):
            gain = np.exp(np.clip(b @ theta[f], -MAX_LOG_GAIN, MAX_LOG_GAIN))
            model = gain[:, None] * p
            residual = ((m - model) / s).ravel()
            jacobian = ((model / s)[:, :, None] * b[:, None, :]).reshape(-1, b.shape[1])
            normal = jacobian.T @ jacobian + 1e-9 * np.eye(b.shape[1])
            step = np.linalg.solve(normal, jacobian.T @ residual)
            theta[f] += step
            if np.max(np.abs(step)) < 1e-6:
                break
    return theta


def frame_gains(basis: np.ndarray, frame: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """The gain ``g`` of every row, (rows,)."""
    return np.exp(np.clip(np.sum(basis * theta[frame], axis=1), -MAX_LOG_GAIN, MAX_LOG_GAIN))
