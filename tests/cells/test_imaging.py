"""Chapter 3 and chapter 4 §II: known answers, synthetic renders with exact ground truth."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from app.cells.core.imaging import (
    PART_SIDE,
    CannyParams,
    Gradient,
    OutlineNotFound,
    OutlineParams,
    canny,
    collinear,
    corners_from_segments,
    crop,
    equalize,
    join_fragments,
    luma,
    outline,
    part_is_light,
    shift,
    signed_area,
    stretch,
)
from app.cells.core.imaging import _on_outline as on_outline
from app.cells.core.imaging import _prune as prune
from tests.cells.scenes import (
    CYLINDER,
    PRISM_OUTLINE,
    box_scene,
    cylinder_scene,
    light_prism_scene,
    prism_scene,
)
from tests.factories.cells import corner_error

# Table 3.2 of the dissertation: Hough segments of Prism06.jpg

# Table 3.2 of the dissertation: Hough segments of Prism06.jpg
TABLE_3_2 = [
    (45, 68, 180, 36),
    (117, 148, 231, 117),
    (42, 70, 42, 114),
    (240, 108, 244, 63),
    (45, 135, 75, 157),
    (204, 32, 240, 47),
]


# Table 3.3: the corners, counter-clockwise, as printed (5 significant figures)
TABLE_3_3 = np.array(
    [
        [42, 68.711],
        [42, 132.8],
        [77.408, 158.77],
        [239.4, 114.71],
        [245.23, 49.179],
        [201.42, 30.924],
    ]
)


class TestCornersFromSegments:
    def test_table_3_2_gives_table_3_3(self) -> None:
        corners = corners_from_segments([tuple(map(float, s)) for s in TABLE_3_2])
        np.testing.assert_allclose(corners, TABLE_3_3, atol=0.01)

    def test_order_and_direction_of_the_input_do_not_matter(self) -> None:
        rng = np.random.default_rng(3)
        segs = [tuple(map(float, s)) for s in TABLE_3_2]
        for _ in range(10):
            shuffled = [segs[i] for i in rng.permutation(6)]
            shuffled = [(s[2], s[3], s[0], s[1]) if rng.random() < 0.5 else s for s in shuffled]
            corners = corners_from_segments(shuffled)
            assert signed_area(corners) < 0  # counter-clockwise as seen (y down)
            assert corner_error(corners, TABLE_3_3) < 0.01

    def test_needs_three_sides(self) -> None:
        with pytest.raises(ValueError, match="at least 3"):
            corners_from_segments([(0, 0, 1, 1), (1, 1, 2, 0)])


class TestJoining:
    def test_collinear_fragments_become_one_line(self) -> None:
        # the two fragments of one side (Prism03, Figure 3.21): a 1 px offset, a 12 px gap
        [joined] = join_fragments([(100, 50, 160, 51), (172, 51.5, 240, 53)])
        assert sorted([joined[:2], joined[2:]]) == [(100, 50), (240, 53)]

    def test_criteria_3_2_and_3_3(self) -> None:
        base = (0.0, 0.0, 100.0, 0.0)
        assert collinear(base, (110.0, 1.5, 200.0, 1.5))  # 1.5 px lateral
        assert not collinear(base, (110.0, 3.0, 200.0, 3.0))  # 3 px > 2 px (3.3)
        t = np.radians(6.0)
        assert not collinear(base, (110.0, 0.0, 110 + 90 * np.cos(t), 90 * np.sin(t)))  # 6° (3.2)

    def test_different_sides_stay_apart(self) -> None:
        segs = [tuple(map(float, s)) for s in TABLE_3_2]
        assert sorted(join_fragments(segs)) == sorted(segs)


class TestConditioning:
    def test_luma(self) -> None:
        image = np.array([[[255, 0, 0], [0, 255, 0], [0, 0, 255], [100, 150, 200]]], np.uint8)
        np.testing.assert_array_equal(luma(image), [[76, 150, 29, 141]])  # 0.299·255 = 76.2 …

    def test_stretch_spans_0_to_255(self) -> None:
        image = np.array([[103, 120, 170]], np.uint8)  # the range of Figure 4.1
        np.testing.assert_array_equal(stretch(image), [[0, 65, 255]])  # (120−103)/67·255 = 64.7
        with pytest.raises(ValueError, match="constant"):
            stretch(np.full((4, 4), 9, np.uint8))

    def test_equalize_is_255_times_the_cdf(self) -> None:
        rng = np.random.default_rng(1)
        image = rng.integers(103, 171, (50, 60), dtype=np.uint8)
        cdf = np.array([(image <= v).mean() for v in range(256)])
        np.testing.assert_array_equal(equalize(image), np.rint(255 * cdf[image]).astype(np.uint8))

    def test_shift(self) -> None:
        image = np.array([[0, 100, 200]], np.uint8)
        np.testing.assert_array_equal(shift(image, 1.5, 20), [[20, 170, 255]])

    def test_canny_thresholds_follow_matlab_scale(self) -> None:
        image = prism_scene()
        edges, low, high = canny(image, CannyParams(sigma=1.5, high=0.5))
        blurred = cv2.GaussianBlur(image, (0, 0), 1.5)
        mag = np.hypot(cv2.Sobel(blurred, cv2.CV_64F, 1, 0), cv2.Sobel(blurred, cv2.CV_64F, 0, 1))
        assert high == pytest.approx(0.5 * mag.max(), rel=1e-4)
        assert low == pytest.approx(0.2 * mag.max(), rel=1e-4)  # 40 % of the high threshold
        assert edges.dtype == np.uint8
        assert edges.any()

    def test_crop_remembers_its_offset(self) -> None:
        image = np.zeros((10, 20), np.uint8)
        region, offset = crop(image, (5, 2, 10, 6))
        assert region.shape == (6, 10)
        assert offset == (5, 2)
        with pytest.raises(ValueError, match="does not lie inside"):
            crop(image, (15, 0, 10, 5))


class TestPrism:
    """A matt box under a narrow dynamic range (103–170), with a cast shadow, noise and blur."""

    def test_scene_has_the_narrow_range(self) -> None:
        image = prism_scene()
        assert 100 <= image.min()
        assert image.max() <= 173

    @pytest.mark.parametrize("shadow", [0.45, 0.3, 0.0])
    @pytest.mark.parametrize("seed", [0, 1, 2])
    def test_corners_within_2_px(self, shadow: float, seed: int) -> None:
        o = outline(prism_scene(shadow=shadow, seed=seed))
        assert o.shape == "polygon"
        assert corner_error(o.corners, PRISM_OUTLINE) <= 2.0
        assert signed_area(o.corners) < 0

    def test_automatic_canny_thresholds(self) -> None:
        o = outline(prism_scene(), OutlineParams(canny=CannyParams(high=None)))
        assert corner_error(o.corners, PRISM_OUTLINE) <= 2.0

    def test_without_the_shadow_step_the_shadow_makes_a_false_edge(self) -> None:
        # the dissertation's Prism08 case
        image = prism_scene(shadow=0.45)
        naive = outline(image, OutlineParams(shadow=False))
        # the shadow's far border (x ≈ 560, y 215–345) is no edge of the part
        band = (slice(225, 335), slice(552, 568))
        assert naive.edges is not None
        assert np.count_nonzero(naive.edges[band]) > 50  # the false edge
        fixed = outline(image)
        assert fixed.edges is not None
        assert np.count_nonzero(fixed.edges[band]) == 0
        assert corner_error(fixed.corners, PRISM_OUTLINE) <= 2.0

    @pytest.mark.parametrize("seed", range(5))
    def test_more_noise(self, seed: int) -> None:
        # σ = 2 levels in a 67-level range: σ ≈ 7.6 levels once stretched to 0–255
        o = outline(prism_scene(noise=2.0, blur=1.0, seed=seed))
        assert corner_error(o.corners, PRISM_OUTLINE) <= 2.0


class TestLightPart:
    """A light part on a dark table: the dissertation's scenes are all dark on light."""

    @pytest.mark.parametrize("shadow", [True, False])
    @pytest.mark.parametrize("seed", [0, 1, 2])
    def test_corners_within_2_px(self, shadow: bool, seed: int) -> None:
        o = outline(light_prism_scene(shadow=shadow, seed=seed))
        assert o.part == "light"
        assert o.shape == "polygon"
        assert corner_error(o.corners, PRISM_OUTLINE) <= 2.0
        assert signed_area(o.corners) < 0

    def test_the_part_can_be_named(self) -> None:
        image = light_prism_scene()
        o = outline(image, OutlineParams(part="light"))
        assert o.part == "light"
        assert corner_error(o.corners, PRISM_OUTLINE) <= 2.0
        # taken for a dark part, nothing convex stands out: no outline is claimed
        with pytest.raises(OutlineNotFound):
            outline(image, OutlineParams(part="dark"))

    def test_a_dark_part_is_still_found_as_one(self) -> None:
        assert outline(prism_scene()).part == "dark"
        assert part_is_light(light_prism_scene())
        assert not part_is_light(prism_scene(shadow=0.6))


class TestCylinder:
    def test_contour_and_ellipses_not_a_polygon(self) -> None:
        o = outline(cylinder_scene())
        assert o.shape == "curved"
        assert len(o.corners) == 0
        assert len(o.contour) > 10
        c = CYLINDER
        xs = sorted((x1 + x2) / 2 for x1, _, x2, _ in o.lines)
        np.testing.assert_allclose(xs, [c["cx"] - c["a"], c["cx"] + c["a"]], atol=2)
        centres = sorted(e.center[1] for e in o.ellipses)
        np.testing.assert_allclose(centres, [c["top"], c["bottom"]], atol=3)
        for e in o.ellipses:
            assert e.center[0] == pytest.approx(c["cx"], abs=2)
            # each arc is half an ellipse, which pins its size less well than a whole one
            np.testing.assert_allclose(sorted(e.axes), [2 * c["b"], 2 * c["a"]], rtol=0.12)


class TestFamily:
    """Boxes under random pose, light, contrast, range, noise and blur (``box_scene``)."""

    def test_the_truth_is_well_posed(self) -> None:
        for seed in range(20):
            scene = box_scene(seed)
            assert scene.min_turn >= 10.0
            assert scene.min_side >= 25.0
            assert signed_area(scene.corners) < 0
            assert scene.image.shape == (480, 640)

    @pytest.mark.slow
    def test_most_scenes_of_a_block_come_out_within_2_px(self) -> None:
        # seeds 3000–3099: no threshold was chosen on them; bench/outline.py holds the figures
        # (95.1 % within 2 px on 3,000 scenes never studied, 92–98 % by block of 200); the
        # bounds leave room for a block's spread.
        verdicts = []
        for seed in range(3000, 3100):
            scene = box_scene(seed)
            try:
                found = outline(scene.image)
            except OutlineNotFound:
                verdicts.append("none")
                continue
            within = corner_error(found.corners, scene.corners) <= 2.0
            verdicts.append("ok" if within else "wrong")
        assert verdicts.count("ok") >= 0.88 * len(verdicts)
        assert verdicts.count("wrong") <= 0.08 * len(verdicts)

    @pytest.mark.parametrize("seed", [3, 4, 7, 12])
    def test_sides_are_sub_pixel(self, seed: int) -> None:
        scene = box_scene(seed)
        found = outline(scene.image)
        assert found.shape == "polygon"
        assert corner_error(found.corners, scene.corners) <= 1.0
        assert found.residual < 0.5
        assert found.support > 0.9


class TestHonestAnswers:
    """Where no polygon is supported, none is claimed."""

    def test_a_smooth_gradient_has_no_outline(self) -> None:
        ramp = np.tile(np.linspace(0, 255, 640), (480, 1)).astype(np.uint8)
        with pytest.raises(OutlineNotFound, match="no part stands out"):
            outline(ramp)

    @pytest.mark.parametrize("seed", [0, 1, 2])
    def test_a_textured_background_has_no_outline(self, seed: int) -> None:
        rng = np.random.default_rng(seed)
        texture = cv2.GaussianBlur(rng.normal(128, 60, (480, 640)), (0, 0), 3)
        with pytest.raises(OutlineNotFound):
            outline(np.clip(texture, 0, 255).astype(np.uint8))

    @pytest.mark.parametrize("seed", [0, 1, 2])
    def test_a_disc_is_curved_not_a_polygon_of_chords(self, seed: int) -> None:
        rng = np.random.default_rng(seed)
        image = np.full((480, 640), 220.0)
        centre = (320 + 10 * seed, 240)
        cv2.circle(image, centre, 90, 60, -1, cv2.LINE_AA)
        image = cv2.GaussianBlur(image, (0, 0), 1.0) + rng.normal(0, 1.5, image.shape)
        found = outline(np.clip(image, 0, 255).astype(np.uint8))
        assert found.shape == "curved"
        assert len(found.corners) == 0
        [ellipse] = found.ellipses
        np.testing.assert_allclose(ellipse.center, centre, atol=0.5)
        np.testing.assert_allclose(ellipse.axes, [180, 180], atol=1.0)  # full axes, r = 90
        assert found.residual < 0.3

    def test_a_polygon_answer_says_how_well_it_fits(self) -> None:
        found = outline(prism_scene())
        assert 0 < found.residual < 0.5
        assert found.support > 0.9


def test_blank_image_is_refused() -> None:
    with pytest.raises(ValueError, match="no gradient|constant"):
        outline(np.full((100, 100), 128, np.uint8))


class TestOutlineEdges:
    """Which edge pixels a side is fitted to: the part on one side, not on both."""

    def test_an_edge_between_two_faces_is_not_the_outline(self) -> None:
        # a part of two faces (40 and 90) on a table of 220; the part's level is 150
        image = np.full((100, 100), 220, np.uint8)
        image[20:80, 20:50] = 40
        image[20:80, 50:80] = 90
        outer = np.array([[19.5, 50.0], [79.5, 40.0], [60.0, 79.5]])  # left, right, bottom
        inner = np.array([[49.5, 30.0], [49.5, 50.0], [49.5, 70.0]])  # the faces' boundary
        np.testing.assert_array_equal(
            on_outline(Gradient.of(image, 0.8), np.vstack([outer, inner]), 150),
            [True] * 3 + [False] * 3,
        )

    def test_a_part_beside_its_shadow_keeps_its_edge(self) -> None:
        # a shadow 3 px wide at 160 (above the part's level) along the part: the part's edge
        # with it has the shadow PART_SIDE px beyond it, not part, and is outline; so is the
        # shadow's own edge with the table, which levels cannot tell from it
        assert PART_SIDE < 3
        image = np.full((60, 60), 220, np.uint8)
        image[10:50, 10:30] = 40
        image[10:50, 30:33] = 160
        edges = np.array([[29.5, 30.0], [32.5, 30.0]])
        np.testing.assert_array_equal(on_outline(Gradient.of(image, 0.8), edges, 150), [True, True])

    def test_no_points(self) -> None:
        assert on_outline(
            Gradient.of(np.zeros((10, 10), np.uint8), 0.8), np.empty((0, 2)), 100
        ).shape == (0,)


def square_outline() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A square's outline drawn as edges (100 px sides from (50, 50)): the distance to the
    nearest edge pixel, the edge pixels (n, 2), and the square's corners."""
    edges = np.zeros((200, 200), np.uint8)
    cv2.rectangle(edges, (50, 50), (150, 150), 255, 1)
    near = cv2.distanceTransform(cv2.bitwise_not(edges), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    ys, xs = np.nonzero(edges)
    points = np.column_stack([xs, ys]).astype(np.float64)
    square = np.array([[50.0, 50.0], [50.0, 150.0], [150.0, 150.0], [150.0, 50.0]])
    return near, points, square


class TestUnbackedSides:
    def test_a_spike_with_no_edge_along_it_is_dropped(self) -> None:
        """A polygon with a sixth corner spiking 30 px out from the middle of the square's
        right side: the spike's two sides have no edge along them, and go; the square's four
        corners come back, to the edges' sub-pixel line."""
        near, points, square = square_outline()
        spiked = np.insert(square, 3, [[150.0, 110.0], [180.0, 100.0], [150.0, 90.0]], axis=0)
        found = prune(spiked, near, points)
        assert len(found) == 4
        assert corner_error(found, square) < 0.5

    def test_a_polygon_its_edges_back_is_kept(self) -> None:
        near, points, square = square_outline()
        np.testing.assert_array_equal(prune(square, near, points), square)


def test_sampling_more_points_than_remap_takes_in_a_column() -> None:
    """40,000 points (``cv2.remap`` asserts fewer than 32,767 rows a map): each the bilinear
    blend of its four neighbours, computed here by hand."""
    from app.cells.core.imaging import _sample

    rng = np.random.default_rng(3)
    image = rng.uniform(0, 255, (100, 120)).astype(np.float32)
    at = np.column_stack([rng.uniform(0, 118, 40_000), rng.uniform(0, 98, 40_000)])
    x0, y0 = np.floor(at[:, 0]).astype(int), np.floor(at[:, 1]).astype(int)
    fx, fy = at[:, 0] - x0, at[:, 1] - y0
    expected = (
        image[y0, x0] * (1 - fx) * (1 - fy)
        + image[y0, x0 + 1] * fx * (1 - fy)
        + image[y0 + 1, x0] * (1 - fx) * fy
        + image[y0 + 1, x0 + 1] * fx * fy
    )
    got = _sample(image, at)
    assert got.shape == (40_000,)
    # remap's bilinear weights are fixed-point (1/32 of a pixel): within 255/32
    np.testing.assert_allclose(got, expected, atol=255 / 32)
