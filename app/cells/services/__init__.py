"""The robot-cell services: camera calibrations, rigs and their laser grids, outlines; the
routers call these, these call ``core``."""
