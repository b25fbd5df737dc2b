"""Robust origins for secondary rays.

A hit point computed in float32 is off the true surface by a few ulps of its coordinates, so a
secondary ray started exactly there can re-hit its own triangle (shadow acne, speckled
reflections). A fixed epsilon breaks at other scene scales. We offset along the geometric
normal, to the side the new ray leaves on, by ``OFFSET_REL`` times the largest coordinate
magnitude of the hit point and its triangle: a bound on the float32 error of the point and of
the triangle's plane (pbrt-v4 offsets by a propagated error bound in the same way,
``OffsetRayOrigin``). It scales with the scene, so scaling a scene by 1e-3 or 1e3 scales the
offset with it, and translating by 1e5 grows it to the float32 resolution there.
"""
import numpy as np

OFFSET_REL = 2.0**-18    # ~3.8e-6: 32 float32 ulps (2^-23 each) of the coordinate magnitude


STRATEGIES = ("relative", "fixed", "none")
FIXED_EPS = 1e-4         # the "fixed epsilon" strategy, for the accuracy study only


def offset_origins(points, ng, dirs, tri_mag, strategy="relative"):
    """points (n,3), ng (n,3) geometric normals (any length), dirs (n,3) outgoing directions,
    tri_mag (n,) largest |coordinate| of each hit triangle. Returns float64 origins.
    ``strategy``: "relative" (the default, above), "fixed" (1e-4 along the normal, what breaks
    at other scales) or "none" (start on the surface), the last two for comparison."""
    if strategy == "none":
        return np.asarray(points, np.float64).copy()
    p = np.asarray(points, np.float64)
    n = np.asarray(ng, np.float64)
    n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    side = np.sign(np.einsum("ij,ij->i", n, dirs))
    side[side == 0] = 1.0
    if strategy == "fixed":
        return p + n * (side * FIXED_EPS)[:, None]
    mag = np.maximum(np.abs(p).max(axis=1), tri_mag)
    return p + n * (side * OFFSET_REL * np.maximum(mag, 1e-30))[:, None]
