"""The air-quality services: calibration, grading, readings, maps and alerts, over the
sky cameras' shared queries (``cameras``); the routers call these, these call ``core``."""
