"""Pan/tilt of the cross and of each camera: the transform chain of eqs. 4.48–4.57.

World point → (G) the cross gimbal's origin → (R) pan θ about Z and tilt φ about X → (G_ci)
camera i's gimbal → (R_ci) its own pan and tilt → (C_ci) its lens centre → (T) perspective.
All 4 × 4 homogeneous, composed as C_hci = T C_ci R_ci G_ci R G P_h (eq. 4.55).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray


def translation(x: float, y: float, z: float) -> NDArray[np.float64]:
    """Moves the origin to (x, y, z): eqs. 4.48, 4.50, 4.52."""
    m = np.eye(4)
    m[:3, 3] = [-x, -y, -z]
    return m


def rotation(theta: float, phi: float) -> NDArray[np.float64]:
    """Pan θ about Z, then tilt φ about X [rad]: eqs. 4.49, 4.51."""
    ct, st, cp, sp = np.cos(theta), np.sin(theta), np.cos(phi), np.sin(phi)
    return np.array(
        [
            [ct, st, 0.0, 0.0],
            [-st * cp, ct * cp, sp, 0.0],
            [st * sp, -ct * sp, cp, 0.0],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )


def perspective(f: float) -> NDArray[np.float64]:
    """T of eq. 4.53: x = x_h/c_k = f x/(f − z) (eqs. 4.56–4.57), [Fayed 2013]'s image plane
    with the lens at z = f. (The service's pinhole convention is u = cx + f X/Z instead.)"""
    m = np.eye(4)
    m[3, 2] = -1.0 / f
    return m


@dataclass(frozen=True, slots=True)
class Mount:
    gimbal: tuple[float, float, float]
    """(X_g, Y_g, Z_g): the cross gimbal in world coordinates."""
    pan: float
    tilt: float
    camera_gimbal: tuple[float, float, float]
    """(X_cig, Y_cig, Z_cig): camera i's gimbal in the cross frame."""
    camera_pan: float
    camera_tilt: float
    lens: tuple[float, float, float]
    """(X_ci, Y_ci, Z_ci): the lens centre in camera i's gimbal frame."""

    def matrix(self) -> NDArray[np.float64]:
        """C_ci R_ci G_ci R G: world → camera i (eq. 4.55 without T)."""
        return (
            translation(*self.lens)
            @ rotation(self.camera_pan, self.camera_tilt)
            @ translation(*self.camera_gimbal)
            @ rotation(self.pan, self.tilt)
            @ translation(*self.gimbal)
        )


def apply(m: NDArray[np.float64], points: ArrayLike) -> NDArray[np.float64]:
    """(N, 3) points through a 4 × 4 affine transform."""
    p = np.asarray(points, dtype=np.float64)
    h = np.column_stack([p, np.ones(len(p))])
    out = h @ m.T
    return np.asarray(out[:, :3] / out[:, 3:4], dtype=np.float64)


def to_camera(mount: Mount, world: ArrayLike) -> NDArray[np.float64]:
    return apply(mount.matrix(), world)


def to_world(mount: Mount, camera: ArrayLike) -> NDArray[np.float64]:
    """The inverse chain: G⁻¹ R⁻¹ G_ci⁻¹ R_ci⁻¹ C_ci⁻¹ (rotations are orthonormal)."""
    return apply(np.asarray(np.linalg.inv(mount.matrix()), dtype=np.float64), camera)


def project_dissertation(mount: Mount, f: float, world: ArrayLike) -> NDArray[np.float64]:
    """Image-plane (x, y) by eqs. 4.55–4.57."""
    h = np.column_stack([np.asarray(world, dtype=np.float64), np.ones(len(np.asarray(world)))])
    c = h @ (perspective(f) @ mount.matrix()).T
    return np.asarray(c[:, :2] / c[:, 3:4], dtype=np.float64)


def head_pose(
    r0: ArrayLike, t0: ArrayLike, pivot: ArrayLike, pan: float, tilt: float
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The pose (R, t; x_cam = R X + t) of a camera on a pan/tilt head turned to pan θ, tilt φ
    [rad], from its pose (r0, t0) at θ = φ = 0 and the head's pivot (where its pan and tilt
    axes cross, world coordinates).

    The head turns the camera about the pivot: a world point X is seen by the turned camera as
    the unturned camera sees G⁻¹ R G X, G the move of the origin to the pivot (eq. 4.48), R the
    pan about Z then tilt about X (eq. 4.49): world → head frame, which at zero angles is the
    world's. Eq. 4.55's chain with the camera's own gimbal, pan/tilt and lens offset folded
    into (r0, t0), which a calibration measures directly."""
    g = np.asarray(pivot, dtype=np.float64).ravel()
    turned = translation(*(-g)) @ rotation(pan, tilt) @ translation(*g)
    camera = np.eye(4)
    camera[:3, :3] = np.asarray(r0, dtype=np.float64)
    camera[:3, 3] = np.asarray(t0, dtype=np.float64).ravel()
    m = camera @ turned
    return np.ascontiguousarray(m[:3, :3]), np.ascontiguousarray(m[:3, 3])
