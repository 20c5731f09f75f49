"""Laser grid accuracy and time on ray-traced scenes with exact ground truth.

Each scene is a box or an upright cylinder on a table at 1 m, seen by the 4-camera cross
(f = 1000 px, ax = 0.30, ay = 0.20 m, 640 × 480), the grid (1.2 cm cells at 1 m) projected from
the cross's centre, pixel noise σ = 2 grey levels (renders: tests/cells/laser_scenes.py). For
each: the errors of volume, measured surface area (the part's top) and side area against the
part's own dimensions, and the time of each stage. Then the first box at other grid pitches,
and at other exposures (every channel scaled, clipped at 255) and JPEG qualities, as a camera
delivers its photos: the laser dot's error against its exact point, and the grid's errors.

    python bench/laser_grid.py
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.cells.core import laser, laser_grid
from app.cells.core.triangulation import CrossRig  # noqa: E402
from tests.cells.laser_scenes import RIG, Part, Scene, photographed, render  # noqa: E402

SCENES = [
    # shape, dims [m], centre [m], yaw, table tilt, grid rotation [rad]
    ("box", (0.20, 0.14, 0.08), (0.01, -0.02), 0.15, 0.05, 0.10),
    ("box", (0.16, 0.12, 0.12), (-0.02, 0.01), 0.50, -0.08, 0.20),
    ("box", (0.22, 0.10, 0.05), (0.03, 0.02), -0.30, 0.03, -0.15),
    ("box", (0.12, 0.12, 0.03), (0.0, 0.03), 0.70, 0.0, 0.12),
    ("cylinder", (0.08, 0.10), (0.01, -0.02), 0.0, 0.05, 0.10),
    ("cylinder", (0.05, 0.14), (-0.03, 0.0), 0.0, 0.02, -0.2),
    ("cylinder", (0.09, 0.06), (0.02, 0.0), 0.0, -0.06, 0.25),
    ("box", (0.20, 0.14, 0.08), (0.01, -0.02), 0.15, 0.0, 0.0),
    ("cylinder", (0.06, 0.15), (-0.02, 0.02), 0.0, 0.0, 0.0),
]


def measured(
    images: list, dots: list, geo: laser_grid.Geometry
) -> tuple[laser.Dot, list[laser_grid.Nodes], laser_grid.Labelled, laser_grid.Measurement]:
    """Dot, nodes, labels and measurement from one grid and one dot image per camera."""
    dot = laser.locate([laser.find_spots(d) for d in dots], geo.triangulate)
    nodes = [laser_grid.detect(im) for im in images]
    grid = laser_grid.label(
        nodes, laser_grid.match(nodes, geo, origin=dot.point), geo, origin=dot.point
    )
    return dot, nodes, grid, laser_grid.measure(grid, nodes, geo)


def main() -> None:
    geo = laser_grid.cross_geometry(RIG)
    print(
        "| part | dims [m] | tilt | grid rot. | volume | surface | side | nodes | detect | "
        "match | label | measure | notes |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for shape, dims, centre, yaw, tilt, rot in SCENES:
        part = Part(shape, dims, centre, yaw)
        scene = Scene(part, table_tilt=tilt, grid_rotation=rot)
        images = render(scene, seed=1)
        dots = render(scene, mode="dot", seed=2)
        t0 = time.perf_counter()
        nodes = [laser_grid.detect(im) for im in images]
        t1 = time.perf_counter()
        dot = laser.locate([laser.find_spots(d) for d in dots], geo.triangulate)
        matches = laser_grid.match(nodes, geo, origin=dot.point)
        t2 = time.perf_counter()
        grid = laser_grid.label(nodes, matches, geo, origin=dot.point)
        t3 = time.perf_counter()
        notes = "; ".join(w.split(":")[0] for w in grid.warnings)
        try:
            m = laser_grid.measure(grid, nodes, geo)
        except ValueError as exc:
            print(
                f"| {shape} | {dims} | {tilt:+.2f} | {rot:+.2f} | – | – | – | "
                f"{len(grid.points)} | | | | | failed: {exc}; {notes} |"
            )
            continue
        t4 = time.perf_counter()

        def pct(x: float, truth: float) -> str:
            return f"{100 * (x / truth - 1):+.1f} %"

        print(
            f"| {shape} | {dims} | {tilt:+.2f} | {rot:+.2f} | {pct(m.volume, part.volume)} | "
            f"{pct(m.surface_area, part.top_area)} | {pct(m.side_area, part.side_area)} | "
            f"{len(grid.points)} | {1000 * (t1 - t0):.0f} ms | {1000 * (t2 - t1):.0f} ms | "
            f"{1000 * (t3 - t2):.0f} ms | {1000 * (t4 - t3):.0f} ms | {notes} |"
        )

    print("\nGrid pitch (the first box):\n")
    print("| cell at 1 m [mm] | cell [px] | nodes | volume | surface | side |")
    print("|---|---|---|---|---|---|")
    part = Part(*SCENES[0][:4])
    for pitch, lines in ((0.009, 33), (0.012, 25), (0.016, 19), (0.020, 15)):
        scene = Scene(part, table_tilt=0.05, grid_rotation=0.1, pitch=pitch, lines=lines)
        _, _, grid, m = measured(render(scene, seed=1), render(scene, mode="dot", seed=2), geo)
        print(
            f"| {1000 * pitch:.0f} | {RIG.f * pitch:.0f} | {len(grid.points)} | "
            f"{100 * (m.volume / part.volume - 1):+.1f} % | "
            f"{100 * (m.surface_area / part.top_area - 1):+.1f} % | "
            f"{100 * (m.side_area / part.side_area - 1):+.1f} % |"
        )

    print("\nExposure and JPEG quality (the first box; the dot is at (0, 0, 0.92) exactly):\n")
    print("| exposure | format | dot error [mm] | dot RMS [px] | nodes | volume | surface | side |")
    print("|---|---|---|---|---|---|---|---|")
    scene = Scene(part, table_tilt=0.05, grid_rotation=0.1)
    images, dots = render(scene, seed=1), render(scene, mode="dot", seed=2)
    for gain in (0.5, 0.7, 1.0, 1.4, 1.6, 2.0):
        for quality in (0, 95, 80):
            grid_ims, dot_ims = (
                [photographed(im, gain, quality) for im in ims] for ims in (images, dots)
            )
            fmt = f"JPEG {quality}" if quality else "PNG"
            try:
                dot, _, grid, m = measured(grid_ims, dot_ims, geo)
            except ValueError as exc:  # the dot not found
                print(f"| {gain} | {fmt} | {str(exc).split(':')[0]} | | | | | |")
                continue
            error = 1000 * float(np.linalg.norm(dot.point - [0.0, 0.0, 0.92]))
            print(
                f"| {gain} | {fmt} | {error:.2f} | {dot.reprojection_rms:.2f} | "
                f"{len(grid.points)} | {100 * (m.volume / part.volume - 1):+.1f} % | "
                f"{100 * (m.surface_area / part.top_area - 1):+.1f} % | "
                f"{100 * (m.side_area / part.side_area - 1):+.1f} % |"
            )

    print("\nCamera resolution (the first box; focal length and sensor scaled together):\n")
    print("| f [px] | image | cell [px] | reduced by | nodes | volume | surface | time |")
    print("|---|---|---|---|---|---|---|---|")
    for f, size in (
        (1000, (640, 480)),
        (2000, (1280, 960)),
        (3000, (1920, 1440)),
        (4000, (2560, 1920)),
        (6000, (3840, 2880)),
    ):
        rig = CrossRig(f=float(f), ax=RIG.ax, ay=RIG.ay, cx=size[0] / 2, cy=size[1] / 2)
        cam = laser_grid.cross_geometry(rig)
        images = render(scene, rig=rig, size=size, seed=1)
        dots = render(scene, mode="dot", rig=rig, size=size, seed=2)
        t0 = time.perf_counter()
        _, nodes, grid, m = measured(images, dots, cam)
        print(
            f"| {f} | {size[0]} × {size[1]} | {f * scene.pitch:.0f} | "
            f"{max(n.scale for n in nodes)} | {len(grid.points)} | "
            f"{100 * (m.volume / part.volume - 1):+.1f} % | "
            f"{100 * (m.surface_area / part.top_area - 1):+.1f} % | "
            f"{time.perf_counter() - t0:.1f} s |"
        )


if __name__ == "__main__":
    main()
