"""Rigid transforms as 4x4 matrices and unit quaternions.

Conventions (see docs/architecture.md): a pose ``T_wc`` maps camera coordinates to world
coordinates; quaternions are stored ``(qx, qy, qz, qw)`` as in TUM files.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]


def quat_to_rot(q: ArrayLike) -> Array:
    """Rotation matrices from quaternions ``(..., 4)`` in ``(x, y, z, w)`` order.

    Quaternions are normalised first, as trajectory files carry rounding errors.
    """
    q = np.asarray(q, dtype=np.float64)
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(norm < 1e-12):
        raise ValueError("zero-length quaternion")
    x, y, z, w = np.moveaxis(q / norm, -1, 0)
    r = np.empty(q.shape[:-1] + (3, 3))
    r[..., 0, 0] = 1 - 2 * (y * y + z * z)
    r[..., 0, 1] = 2 * (x * y - z * w)
    r[..., 0, 2] = 2 * (x * z + y * w)
    r[..., 1, 0] = 2 * (x * y + z * w)
    r[..., 1, 1] = 1 - 2 * (x * x + z * z)
    r[..., 1, 2] = 2 * (y * z - x * w)
    r[..., 2, 0] = 2 * (x * z - y * w)
    r[..., 2, 1] = 2 * (y * z + x * w)
    r[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return r


def rot_to_quat(r: ArrayLike) -> Array:
    """Quaternions ``(..., 4)`` in ``(x, y, z, w)`` order with ``w >= 0`` from rotation matrices.

    Uses the numerically stable branch choice (largest diagonal term) of Shepperd's method.
    """
    r = np.asarray(r, dtype=np.float64)
    flat = r.reshape(-1, 3, 3)
    out = np.empty((flat.shape[0], 4))
    for i, m in enumerate(flat):
        tr = m[0, 0] + m[1, 1] + m[2, 2]
        if tr > 0:
            s = 2.0 * np.sqrt(tr + 1.0)
            q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s]
        elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
            s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
            q = [0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s]
        elif m[1, 1] > m[2, 2]:
            s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
            q = [(m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s]
        else:
            s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
            q = [(m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s, (m[1, 0] - m[0, 1]) / s]
        q = np.asarray(q)
        q /= np.linalg.norm(q)
        out[i] = -q if q[3] < 0 else q
    return out.reshape(r.shape[:-2] + (4,))


def make_pose(rot: ArrayLike, trans: ArrayLike) -> Array:
    """Stack ``(..., 3, 3)`` rotations and ``(..., 3)`` translations into ``(..., 4, 4)`` poses."""
    rot = np.asarray(rot, dtype=np.float64)
    trans = np.asarray(trans, dtype=np.float64)
    t = np.zeros(rot.shape[:-2] + (4, 4))
    t[..., :3, :3] = rot
    t[..., :3, 3] = trans
    t[..., 3, 3] = 1.0
    return t


def pose_from_tum(xyz_quat: ArrayLike) -> Array:
    """Poses ``(..., 4, 4)`` from TUM rows ``(..., 7)`` = ``tx ty tz qx qy qz qw``."""
    v = np.asarray(xyz_quat, dtype=np.float64)
    return make_pose(quat_to_rot(v[..., 3:7]), v[..., 0:3])


def pose_to_tum(poses: ArrayLike) -> Array:
    """TUM rows ``(..., 7)`` from poses ``(..., 4, 4)``."""
    p = np.asarray(poses, dtype=np.float64)
    return np.concatenate([p[..., :3, 3], rot_to_quat(p[..., :3, :3])], axis=-1)


def invert(poses: ArrayLike) -> Array:
    """Inverse of rigid transforms ``(..., 4, 4)`` without a general matrix inverse."""
    p = np.asarray(poses, dtype=np.float64)
    rt = np.swapaxes(p[..., :3, :3], -1, -2)
    return make_pose(rt, -np.einsum("...ij,...j->...i", rt, p[..., :3, 3]))


def rotation_angle(rot: ArrayLike) -> Array:
    """Rotation angle in radians of ``(..., 3, 3)`` rotation matrices (clipped for safety)."""
    r = np.asarray(rot, dtype=np.float64)
    cos = (np.trace(r, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.arccos(np.clip(cos, -1.0, 1.0))


def so3_exp(w: ArrayLike) -> Array:
    """Rotation matrix from an axis-angle vector (Rodrigues)."""
    w = np.asarray(w, dtype=np.float64)
    theta = float(np.linalg.norm(w))
    if theta < 1e-12:
        return np.eye(3)
    k = w / theta
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(theta) * kx + (1 - np.cos(theta)) * kx @ kx


def look_at(eye: ArrayLike, target: ArrayLike, up: ArrayLike = (0.0, 0.0, 1.0)) -> Array:
    """Camera-to-world pose at ``eye`` looking at ``target`` (camera x right, y down, z forward)."""
    eye = np.asarray(eye, dtype=np.float64)
    z = np.asarray(target, dtype=np.float64) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, dtype=np.float64))
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("look_at: view direction parallel to up vector")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return make_pose(np.stack([x, y, z], axis=1), eye)


def orthonormalize(pose: ArrayLike) -> Array:
    """Project the rotation block of a 4x4 pose back onto SO(3) (nearest, via SVD).

    Products of poses accumulate rounding; a motion model that composes them every frame
    amplifies it unless it is removed.
    """
    p = np.array(pose, dtype=np.float64)
    u, _, vt = np.linalg.svd(p[:3, :3])
    r = u @ vt
    if np.linalg.det(r) < 0:
        u[:, -1] *= -1
        r = u @ vt
    p[:3, :3] = r
    return p
