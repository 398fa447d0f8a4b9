"""Optional temporal smoothing of solved poses: a zero-phase low-pass over the take.

Each frame of :func:`skincap.solve.ik.solve_poses` is its own least-squares fit, so
marker noise and soft-tissue jitter pass into the poses. :func:`smooth_poses` filters
the root origin and every segment's world rotation with a second-order Butterworth
low-pass run forwards and backwards (``scipy.signal.sosfiltfilt``: no lag, the cut-off
attenuated to -6 dB). Rotations are filtered as unit quaternions made sign-continuous
over time, then renormalised (accurate while a segment turns less than ~90 deg per
cut-off period, which any body motion does at a cut-off of a few hertz); bone lengths
stay exact because the segment origins still follow the tree.
"""

from __future__ import annotations

import numpy as np

from skincap.errors import ValidationError
from skincap.geometry.rotations import matrix_to_quat, quat_to_matrix

__all__ = ["smooth_poses"]

#: Fewest frames the filter runs on (``sosfiltfilt``'s padding needs more than this).
MIN_SMOOTH_FRAMES = 16


def smooth_poses(
    rotations: np.ndarray, root: np.ndarray, rate: float, cutoff_hz: float
) -> tuple[np.ndarray, np.ndarray]:
    """Low-pass filter solved poses over time.

    Parameters
    ----------
    rotations : (T, S, 3, 3) float
        World rotations of the segments, finite.
    root : (T, 3) float, metres
        Root origin per frame, finite.
    rate : float
        Frame rate, Hz.
    cutoff_hz : float
        Cut-off frequency, Hz, above 0 and below the Nyquist frequency ``rate / 2``.

    Returns
    -------
    rotations : (T, S, 3, 3) float64
    root : (T, 3) float64, metres
        The inputs unchanged when the take has fewer than
        :data:`MIN_SMOOTH_FRAMES` frames.

    Raises
    ------
    ValidationError
        A cut-off outside (0, rate / 2), or non-finite poses.
    """
    rot = np.asarray(rotations, dtype=np.float64)
    org = np.asarray(root, dtype=np.float64)
    if rot.ndim != 4 or rot.shape[2:] != (3, 3) or org.shape != (rot.shape[0], 3):
        raise ValidationError(
            f"rotations/root: expected (T, S, 3, 3) and (T, 3), got {rot.shape} and {org.shape}"
        )
    nyquist = 0.5 * float(rate)
    if not (0.0 < cutoff_hz < nyquist):
        raise ValidationError(
            f"smoothing cut-off: expected between 0 and {nyquist:g} Hz (half the {rate:g} Hz "
            f"frame rate), got {cutoff_hz:g}"
        )
    if not (np.isfinite(rot).all() and np.isfinite(org).all()):
        raise ValidationError("rotations/root: must be finite to be smoothed")
    t = rot.shape[0]
    if t < MIN_SMOOTH_FRAMES:
        return rot.copy(), org.copy()
    # imported here: scipy.signal costs ~0.9 s of CPU, and a solve smooths only on request
    from scipy.signal import butter, sosfiltfilt

    sos = butter(2, cutoff_hz / nyquist, output="sos")
    q = matrix_to_quat(rot)  # (T, S, 4)
    # q and -q are the same rotation: flip each frame to the side of the previous one
    flip = np.einsum("tsi,tsi->ts", q[1:], q[:-1]) < 0
    sign = np.concatenate([np.ones((1, q.shape[1])), np.where(flip, -1.0, 1.0)])
    q = q * np.cumprod(sign, axis=0)[..., None]
    q = sosfiltfilt(sos, q, axis=0)
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    return quat_to_matrix(q), sosfiltfilt(sos, org, axis=0)
