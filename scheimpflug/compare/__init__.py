"""Real frames against a twin's: image-level figures per region, stripe positions, detectors' figures.

No Mitsuba: pure numpy on frame folders (:mod:`scheimpflug.compare.figures`).
"""
