"""Make ``sky.jpg``, the sample frame of the README's first session: a 640 × 360 street
camera's view, a hazy sky over a row of buildings. Run from the repository's root:
``.venv/bin/python docs/examples/make_sky.py``."""

from pathlib import Path

import cv2
import numpy as np

WIDTH, HEIGHT, SKY = 640, 360, 200
"""The frame's size [px] and the sky's height [px]: the README registers the camera with
``roi = [0, 0, 640, 200]``."""


def sky_frame(seed: int = 0) -> np.ndarray:
    """The frame, BGR: a vertical gradient of pale blue haze, buildings of random heights
    below it, and a little sensor noise (seeded)."""
    rng = np.random.default_rng(seed)
    rows = np.linspace(0.0, 1.0, HEIGHT)[:, None]
    top, horizon = np.array([205.0, 170.0, 140.0]), np.array([215.0, 205.0, 195.0])  # BGR
    image = (top + (horizon - top) * rows)[:, None, :].repeat(WIDTH, axis=1)
    x = 0
    while x < WIDTH:
        width = int(rng.integers(30, 90))
        roof = int(rng.integers(SKY, SKY + 60))
        shade = float(rng.uniform(70, 120))
        image[roof:, x : x + width] = (shade, shade * 0.95, shade * 0.9)
        x += width
    image[SKY + 100 :] = (60.0, 62.0, 65.0)  # the street
    image += rng.normal(0.0, 2.0, image.shape)
    return np.clip(image, 0, 255).astype(np.uint8)


if __name__ == "__main__":
    out = Path(__file__).with_name("sky.jpg")
    ok, data = cv2.imencode(".jpg", sky_frame(), [cv2.IMWRITE_JPEG_QUALITY, 85])
    assert ok
    out.write_bytes(data.tobytes())
    print(f"{out}: {len(data)} bytes")
