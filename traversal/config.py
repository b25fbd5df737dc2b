"""Every tolerance and knob of the traversal, in one place, each with its reason.

Numba compiles these into the kernels as constants, and its on-disk cache does not notice an
edit here (it checks only the kernel's own source file): after changing a value, delete the
cached kernels (``traversal/__pycache__/*.nbi`` and ``*.nbc``).
"""

# --- AABB unit (aabb_unit) --------------------------------------------------------------
# gamma(3) = 3u / (1 - 3u), u the unit roundoff: the bound on the relative rounding error of
# the plane-distance chain. The far distance is widened by 1 + 2*gamma(3) (pbrt-v4's slab
# test), so float rounding cannot turn a grazing hit on a flat box into a miss; the widening
# can only add a box visit, never lose a hit.
GAMMA3_F32 = 3 * 2.0**-24 / (1 - 3 * 2.0**-24)
GAMMA3_F64 = 3 * 2.0**-53 / (1 - 3 * 2.0**-53)

# --- Moller-Trumbore unit (triangle_unit) -----------------------------------------------
# The parallel band is relative: det^2 <= (BAND_K*eps)^2 |e1|^2 |e2|^2 |d|^2 rejects rays
# closer than ~2.4e-7 rad (float32) / ~4.4e-16 rad (float64) to the triangle's plane, whatever
# the triangle's size (an absolute epsilon would drop every hit on a 1e-4-sized triangle).
# The unit evaluates it on terms scaled by powers of two (triangle_unit), so it holds wherever
# the datapath's own values stay in the float range, not only where those squares do.
BAND_K = 4.0

# Barycentric slack of the valid check, in units of the triangle. The float32 Moller-Trumbore
# unit computes u and v from different edge vectors in the two triangles sharing an edge, so a
# ray exactly through the edge can fail both strict checks (a leak). A slack of 2^-18 (~4e-6,
# tens of float32 ulps of a barycentric coordinate) closes those cracks; it dilates each
# triangle by that fraction of its size, far below a pixel. Set to 0 for the strict unit.
EDGE_EPS_F32 = 2.0**-18
EDGE_EPS_F64 = 2.0**-40

# --- Secondary-ray origins (offset) -----------------------------------------------------
# Offset along the geometric normal, relative to the largest coordinate magnitude of the hit
# point and its triangle: ~3.8e-6 = 32 float32 ulps (2^-23 each) of that magnitude, a bound on
# the float32 error of the point and of the triangle's plane.
OFFSET_REL = 2.0**-18
# The "fixed epsilon" strategy, for the accuracy study only (it breaks at other scene scales).
FIXED_EPS = 1e-4

# --- Verification against Embree (verify) -----------------------------------------------
# float32 hit distances carry about eps * (|o| + t|d|) / |d| of rounding per operation; 1e-5
# (~80 ulps) of t + |o|_max/|d| bounds the unit's error chain while staying far below any real
# gap between surfaces.
T_TOL_REL = 1e-5
# float32 Moller-Trumbore barycentrics are off by a few 1e-7 for well-conditioned rays but by up
# to ~2e-5 on slivers (cancellation in s.p / det), and the valid check accepts EDGE_EPS_F32
# (~3.8e-6) of slack to close cracks. A wrong triangle is off by far more than that, and a
# closer strict hit still makes any answer a mismatch.
BARY_TOL = 1e-4

# --- Work scheduling (not part of the units: answers do not depend on these) -------------
# Rays per packet. The lane masks are read 8 lanes at a time through a uint64 view, so this is
# a multiple of 8; 16 float32 lanes fill one AVX-512 register (two AVX2 registers).
PACKET_RAYS = 16
# Rays per parallel work item of a batch (each work item allocates one traversal stack).
CHUNK_RAYS = 64
