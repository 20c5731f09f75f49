"""Vantage: ordinary cameras as measuring instruments."""

import os

__version__ = "0.1.0"

# OpenCV reads its own pixel cap once, when it loads: set here, before any module imports cv2,
# to the service's pixel limit, so that no path decodes past it (app.platform.frames.jpeg)
os.environ.setdefault(
    "OPENCV_IO_MAX_IMAGE_PIXELS", os.environ.get("VANTAGE_MAX_PIXELS", "50000000").strip()
)
