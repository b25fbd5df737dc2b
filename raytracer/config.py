"""The renderer's knobs, each with its reason."""
import numpy as np

# Rays per shading block: the shading kernel works a block at a time in passes over a
# structure-of-arrays scratch, so that its arithmetic runs in SIMD lanes; 256 keeps that
# scratch (73 rows of 256 doubles, 150 KB) in the L2 cache beside the rays it reads.
BLOCK = 256

# The type of the wavefronts' pixel and row indices: every ray carries its pixel through the
# stages (and every secondary wavefront a row index per ray), so 32 bits instead of 64 take
# 3-5% off the shading's time on the default scene, in memory traffic; unsigned, because
# Numba wraps a negative index around the array's end, so an index of a signed type costs a
# test at every access, which LLVM drops for an index it knows is not negative (2-3% more).
# It bounds a frame to MAX_PIXELS pixels (a film of that many takes 100 GB for its radiance
# sums alone), and a wavefront to as many rows (a secondary wavefront's refractions start at
# the row of the last queue's length; arrays of that many rows, 100 bytes and more a ray,
# would not be allocated).
PIXEL = np.uint32
MAX_PIXELS = np.iinfo(PIXEL).max

# Pixels per band, and the fewest bands a frame is cut into. A frame is rendered in bands of
# whole rows (a multiple of the 4-row camera tiles), each band through every sample pass and
# bounce on one thread, the threads taking bands as they finish: so a band's wavefronts stay
# in the caches between stages, and the threads meet once per frame instead of at every
# stage, which is what a busy machine punishes. Large enough that the ray queries of a band (a
# few per bounce) spend their time tracing, not in their Python call; small enough, and at
# least MIN_BANDS of them, that the threads share a frame out evenly (a thread idles only
# while the last band ends). The default scene (640x480, 4 spp) rendered 7-13% slower in
# 8k-pixel bands than in 16k, 18-23% slower in 64k (five bands), and within 5% either way in
# 32k, run to run.
BAND_PIXELS = 16384
MIN_BANDS = 8

# Copies of the PCG64 generator stepped side by side in SIMD lanes (``pcg64``), each started one
# draw further on: any count draws the same numbers, and from 16 on the lanes run at full speed
# (on a 2-core EPYC with AVX2, a band's 15k draws took 70 us with 8 lanes, 28 us with 16 to 128).
LANES = 64

# Seconds a first render waits for the child process that compiles the traversal kernel beside
# it (``render._compile_traversal_beside``); a child that takes longer is stuck, and is killed
# (the render compiles the kernel itself).
CHILD_COMPILE_TIMEOUT = 600
