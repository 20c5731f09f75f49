"""The pan/tilt chain (eqs. 4.48–4.57): known answers and round trips."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from app.cells.core.pantilt import (
    Mount,
    head_pose,
    perspective,
    project_dissertation,
    rotation,
    to_camera,
    to_world,
    translation,
)

RNG = np.random.default_rng(11)


def test_rotation_is_orthonormal_and_pans_about_z() -> None:
    r = rotation(0.7, -0.3)[:3, :3]
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0)
    # pan 90°, no tilt: the X axis maps to −Y in the rotated frame (eq. 4.49's first column)
    np.testing.assert_allclose(rotation(np.pi / 2, 0.0)[:3, :3] @ [1, 0, 0], [0, -1, 0], atol=1e-12)
    # tilt 90°, no pan: Y maps to −Z
    np.testing.assert_allclose(rotation(0.0, np.pi / 2)[:3, :3] @ [0, 1, 0], [0, 0, -1], atol=1e-12)


def test_translation_moves_the_origin() -> None:
    np.testing.assert_allclose(translation(1, 2, 3) @ [1, 2, 3, 1], [0, 0, 0, 1])


@pytest.mark.parametrize("seed", range(5))
def test_round_trip(seed: int) -> None:
    rng = np.random.default_rng(seed)
    mount = Mount(
        gimbal=tuple(rng.normal(0, 1, 3)),  # type: ignore[arg-type]
        pan=rng.uniform(-np.pi, np.pi),
        tilt=rng.uniform(-1, 1),
        camera_gimbal=tuple(rng.normal(0, 0.2, 3)),  # type: ignore[arg-type]
        camera_pan=rng.uniform(-0.5, 0.5),
        camera_tilt=rng.uniform(-0.5, 0.5),
        lens=tuple(rng.normal(0, 0.05, 3)),  # type: ignore[arg-type]
    )
    world = rng.normal(0, 3, (100, 3))
    np.testing.assert_allclose(to_world(mount, to_camera(mount, world)), world, atol=1e-10)
    # distances survive: the chain is rigid
    cam = to_camera(mount, world)
    np.testing.assert_allclose(
        np.linalg.norm(cam[1:] - cam[:-1], axis=1),
        np.linalg.norm(world[1:] - world[:-1], axis=1),
        rtol=1e-12,
    )


def test_perspective_is_eq_4_4() -> None:
    mount = Mount((0, 0, 0), 0.0, 0.0, (0, 0, 0), 0.0, 0.0, (0, 0, 0))
    f = 0.05
    p = np.array([[0.3, -0.2, -2.0]])
    # eq. 4.4: x = fX/(f − Z), y = fY/(f − Z)
    np.testing.assert_allclose(
        project_dissertation(mount, f, p), [[f * 0.3 / (f + 2.0), f * -0.2 / (f + 2.0)]], rtol=1e-12
    )
    assert perspective(f)[3, 2] == pytest.approx(-1 / f)


@pytest.mark.parametrize("seed", range(5))
def test_a_head_turns_the_camera_about_its_pivot(seed: int) -> None:
    """head_pose against the same move built by hand: the lens centre swings about the pivot
    by the head's rotation, the camera's axes turn with it."""
    rng = np.random.default_rng(seed)
    r0 = Rotation.from_rotvec(rng.normal(0, 0.3, 3)).as_matrix()
    centre0 = rng.normal(0, 0.5, 3)
    t0 = -r0 @ centre0
    pivot = centre0 + rng.normal(0, 0.05, 3)
    pan, tilt = rng.uniform(-1, 1), rng.uniform(-0.5, 0.5)
    r, t = head_pose(r0, t0, pivot, pan, tilt)
    turn = rotation(pan, tilt)[:3, :3]  # world → head frame (eq. 4.49)
    centre = pivot + turn.T @ (centre0 - pivot)
    np.testing.assert_allclose(r, r0 @ turn, atol=1e-12)
    np.testing.assert_allclose(-r.T @ t, centre, atol=1e-12)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    r_zero, t_zero = head_pose(r0, t0, pivot, 0.0, 0.0)
    np.testing.assert_allclose(r_zero, r0, atol=1e-15)
    np.testing.assert_allclose(t_zero, t0, atol=1e-15)
