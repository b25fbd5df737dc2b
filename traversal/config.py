"""Every tolerance and knob of the traversal, in one place, each with its reason.

Numba compiles these into the kernels as constants; an edit here compiles every kernel once
more, as an edit to any source file of the kernel packages does (``hwbvh.kernel_cache``).
"""

# --- AABB unit (aabb_unit) --------------------------------------------------------------
# gamma(3) = 3u / (1 - 3u), u the unit roundoff: the bound on the relative rounding error of
# the plane-distance chain. The far distance is widened by 1 + 2*gamma(3) (pbrt-v4's slab
# test), so float rounding cannot turn a grazing hit on a flat box into a miss; the widening
# can only add a box visit, never lose a hit.
GAMMA3_F32 = 3 * 2.0**-24 / (1 - 3 * 2.0**-24)
GAMMA3_F64 = 3 * 2.0**-53 / (1 - 3 * 2.0**-53)

# --- Moller-Trumbore unit (triangle_unit) -----------------------------------------------
# The parallel band is relative: det^2 <= (BAND_K*eps)^2 |e1|^2 |e2|^2 |d|^2, eps the machine
# epsilon (2^-23 float32, 2^-52 float64). det = -d.(e1 x e2) = |d||e1||e2| sin(a) sin(theta), a
# the ray's angle to the plane and theta the triangle's angle at v0, and |d||e1||e2| eps is the
# rounding noise of det itself. So the band rejects rays with sin(a) sin(theta) <= BAND_K*eps:
# ~4.8e-7 rad (float32) / ~8.9e-16 rad (float64) for well-shaped triangles, whatever their size
# (an absolute epsilon would drop every hit on a 1e-4-sized triangle), and k eps / sin(theta) for
# slivers, where a det below that noise floor could not be told from zero. Measuring against
# |e1 x e2| instead would let that noise through as hits with t and barycentrics of any size.
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
# The largest slack a tracer takes (``Tracer(edge_eps=...)``): a thousandth of the triangle, some
# 250 times the float32 default and far past any rounding of a barycentric coordinate. A wider
# triangle takes hits that belong to its neighbours (at 1, most hits on a random soup are
# another triangle's).
MAX_EDGE_EPS = 1e-3

# --- Secondary-ray origins (offset) -----------------------------------------------------
# Offset along the geometric normal, relative to the largest coordinate magnitude of the hit
# point and its triangle: ~3.8e-6 = 32 float32 ulps (2^-23 each) of that magnitude, a bound on
# the float32 error of a point on the triangle's plane and of that plane (the renderer puts hit
# points on it: the float32 unit's t alone is off by more on slivers).
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
# An answer's own triangle may be missed, in float64, by the float32 unit's rounding, which
# grows as the ray grazes the triangle and as its origin lies farther than the triangle is
# large: the barycentrics' error is about eps * |o - v0| * max|e| / (|e1 x e2| cos), with eps
# float32's unit roundoff and cos the ray's angle to the normal (the numerator's rounding over
# det). An answer's triangle is accepted within BARY_ERR_K times that (or BARY_TOL, whichever
# is larger); on a bunny seen at grazing angles, 2^26 primary rays met at most 0.6 times it on
# both Embree's answers and ours (rays through a shared edge, each tracer taking one side).
# Never beyond BARY_TOL_MAX: a ray nearly in a triangle's plane does not make any answer right.
# The hits that make an answer wrong (a triangle entered by more than BARY_TOL, closer) keep
# the fixed tolerance: a ray that passes through both triangles of an edge is a hole in a
# closed surface, however grazing.
BARY_ERR_K = 4.0
BARY_TOL_MAX = 1e-2
# A right answer's t may lie off its triangle's plane by the float32 unit's rounding of it,
# which T_TOL_REL bounds on well-shaped triangles but not on slivers: t's numerator and the
# determinant are triple products of e1, e2 and o - v0 (or d), each rounded by about
# eps |e1| |e2| |o - v0| (or |d|) while their values shrink with |e1 x e2|, so the point at t
# lies off the plane by about eps (|o - v0| + t |d|) |e1| |e2| / |e1 x e2|, eps float32's unit
# roundoff: 1 / sin of the triangle's angle at v0 times what a well-shaped triangle shows. On
# the staircase mesh (slivers down to sin 2e-4), float32 answers lie up to 0.4 times that
# bound off the plane and up to 1.7 times T_TOL_REL. A t is accepted within T_ERR_K times it
# (or T_TOL_REL, whichever is larger), never beyond T_TOL_MAX_REL of t + |o|_max / |d| (as
# BARY_TOL_MAX: a triangle so thin that its rounding passes 1% of the distance leaves no answer
# on it right), and the reported t itself must lie in the ray's interval.
T_ERR_K = 4.0
T_TOL_MAX_REL = 1e-2
# Before the start of a ray's interval, a hit counts as a right answer only within
# BEHIND_TOL_REL (4 float32 ulps) of t + |o|_max/|d|, far less than T_TOL_REL: a secondary ray
# starts 2^-18 (32 ulps) of the coordinate magnitude off its own surface (OFFSET_REL), and
# that surface, just behind the origin, must never pass as a hit.
BEHIND_TOL_REL = 2.0**-21

# --- Work scheduling (not part of the units: answers do not depend on these) -------------
# Rays per packet. The lane masks are read 8 lanes at a time through a uint64 view, so this is
# a multiple of 8; 16 float32 lanes fill one AVX-512 register (two AVX2 registers).
PACKET_RAYS = 16
# Rays per parallel work item of a batch (each work item allocates one traversal stack). A
# multiple of PACKET_RAYS, so that a batch's packets are its aligned groups of PACKET_RAYS rays
# whichever chunk they fall in (``packet.packet_rays`` relies on it).
CHUNK_RAYS = 64
if CHUNK_RAYS % PACKET_RAYS:
    raise ValueError("CHUNK_RAYS must be a multiple of PACKET_RAYS")
# Chunks a batch hands the threads at least per range (``hwbvh.parallel.run_ranges``'
# ``min_items``): 1,024 rays. Handing a range to another thread costs hundreds of
# microseconds on a virtual machine (a sleeping core's wake-up, the interpreter's lock passed
# back and forth), more than tracing a small batch: on a 2-core EPYC, 1,024 coherent rays on
# the bunny took 454 us in 16 ranges over two threads and 183 us in one, 4,096 incoherent
# rays 2.1 ms in 16 ranges and 1.7 ms in 4; from 16,384 rays on, the split does not change.
MIN_RANGE_CHUNKS = 16
# Scalar ray bounds (0, inf, ...) become one kept array per value, sliced for each batch, so
# a query does not fill new ones (``api._filled``). Batches longer than this get their own:
# a render's queries are a band's rays (16k camera rays, a few times that in shadow rays), so
# the kept arrays stay at a megabyte or two each.
KEPT_BOUND_RAYS = 1 << 18
# The most rays of one generated query set (``verify_mesh``, ``hwrt verify --rays``, ``hwrt bench
# trace --rays``): the sets are made and verified a slice at a time (MAKE_CHUNK,
# VERIFY_CHUNK), and ``hwrt verify`` of 2^26 rays on a 70k-triangle scene peaked at
# 4.2 GB (primary, random), 8.5 GB (shadow) and 10.0 GB (bounces, whose first rays mostly miss),
# and ``hwrt bench trace`` (one set alive at a time) at 10.3 GB; more would only exhaust memory.
MAX_RAYS = 1 << 26
# Rays made at a time (``raysets``): a set of up to 2^26 rays (and the first rays a hit-based
# set draws, up to HIT_GROWTH^HIT_ROUNDS times more) is made a slice at a time, so that its
# float64 working arrays stay small; whole, they took several times the set's own size.
MAKE_CHUNK = 1 << 20
# Hit-based sets (``raysets``) draw n first rays, then (from the hit rate seen) more, growing
# at most HIT_GROWTH-fold per round for HIT_ROUNDS rounds: enough for any mesh that one first
# ray in 16 hits, while memory stays bounded (n = 10^6 shadow rays never needs more than 1.6e7
# first rays).
HIT_GROWTH = 4
HIT_ROUNDS = 2
# Rays verified at a time (``verify``): each slice is traced by both tracers and classified
# before the next, so that the working arrays of a large set (the answers, the float64 copies
# the re-test takes) stay those of one slice.
VERIFY_CHUNK = 1 << 20

# --- Uniform grid (grid) -------------------------------------------------------------------
# Cells per triangle of the density heuristic (cells ~ GRID_DENSITY * N, cubic where the mesh's
# bounds allow). Fewer cells test more triangles per cell; more cells step through more empty
# ones and insert each triangle into more of them (memory). Packets walk one slice of cells after
# another and test a rectangle of cells per slice, so they favour larger cells: on bunny,
# dragon_res2, sponza and classroom, density 1 traces camera and shadow packets 5-30% faster
# than 4 (0.5 no faster), single random rays up to ~10% slower; 1 keeps ~2.2 references per
# triangle.
GRID_DENSITY = 1.0
# The cell count never exceeds this (int64 cell offsets: 8 bytes per cell, 128 MiB at the cap).
GRID_MAX_CELLS = 2**24
# References (triangle ids in cells, 4 bytes each) never exceed GRID_MAX_REFS_PER_TRI * N. A
# triangle is inserted into every cell its bounding box overlaps, so one huge triangle alone
# could reach every cell, and N of them N * cells; above the cap the resolution is coarsened
# until the references fit (one cell holds exactly N, so it always ends).
GRID_MAX_REFS_PER_TRI = 16
# Each triangle's box is padded before insertion, so that every point at which the triangle unit
# can report a hit lies in a cell that lists it: by GRID_PAD_TRI of the triangle's extent (the
# unit's barycentric slack, EDGE_EPS_F32 = 2^-18, twice over) and GRID_PAD_COORD of its largest
# coordinate magnitude (16 float32 ulps: the rounding of a float32 hit point).
GRID_PAD_TRI = 2.0**-17
GRID_PAD_COORD = 2.0**-19
# Traversal stops once the current cell ends beyond the closest hit by this much, relative to
# t + |o|/|d| (a few times the float32 unit's rounding of t, ~1e-6 relative): a hit at the same
# t, or rounded nearer, in the next cell is still found and ties go to the lower index.
GRID_STOP_SLACK = 2.0**-16
# Per-ray mailbox entries (direct-mapped on the triangle id; a power of two): a triangle spanning
# several cells is tested once per ray while its id stays in the mailbox; a forgotten id is only
# tested again, with the same answer.
GRID_MAILBOX = 32
# Packet mailbox entries (direct-mapped, a power of two): a packet's rectangle of cells per
# slice holds more triangles than one ray's cell, and a forgotten id costs a whole packet's
# lane loop again (same answers).
GRID_PACKET_MAILBOX = 128
# A packet bounds its lanes' ray segments in each slice of cells in float64 and widens the bounds
# by this much of the lane's coordinate magnitude (|o| + |t d| + the grid's): far above the
# float64 rounding of a segment's ends (a few 2^-53) and far below the triangles' padding
# (GRID_PAD_COORD, 2^-19), so a cell is added only where a segment ends that close to its plane.
GRID_PACKET_WIDEN = 2.0**-40

# --- SAH kd-tree (kdtree) ------------------------------------------------------------------
# The surface area heuristic's costs (Wald & Havran 2006's form), in the units of one
# traversal step, as measured on the kd-tree's own kernel (bunny, dragon, buddha, incoherent
# rays): a step is a dependent load and a plane test (~17 ns), a triangle test is branch-free
# (~8 ns more per test), so a test costs about half a step. PBRT's 1 : 1.5 made ~2x the
# references at the same depth, built 1.5-2x slower and traced incoherent rays 0-15% slower.
KD_COST_TRAVERSAL = 1.0
KD_COST_INTERSECT = 0.5
# A split with one empty side has its cost multiplied by this (WH06's lambda): cutting empty
# space off lets rays skip it at the price of one traversal step, so it is favoured.
KD_EMPTY_FACTOR = 0.8
# Depth cap: KD_DEPTH_BASE + KD_DEPTH_LOG2 * log2(N), rounded (20 on the 69k-triangle bunny, 22
# on 262k triangles). Beyond it every node is a leaf, so no input (identical triangles, a clump)
# can deepen the tree without bound, and the traversal stack has a known size. With perfect
# splits the SAH keeps finding splits worth their cost on every mesh measured, so the cap, not
# the costs, ends most paths. PBRT's 8 + 1.3 log2(N) (29 on the bunny) gave 6-9 references per
# triangle, ~3x the build time and no faster rays (bunny, dragon_res2, buddha_100k, sponza,
# classroom: incoherent rays 0-20% slower, primary and shadow rays within the noise);
# 4 + log2(N) gives 2.3-2.9 references per triangle; 2 + log2(N) builds ~20% faster but leaves
# ~19 triangles in a leaf for no faster rays.
KD_DEPTH_BASE = 4
KD_DEPTH_LOG2 = 1.0
# Total references (triangle ids in leaves, 4 bytes each) never exceed KD_MAX_REFS_PER_TRI * N:
# a triangle is referenced by every leaf it crosses, so huge triangles could multiply the
# references; a split that would cross the cap makes a leaf instead.
KD_MAX_REFS_PER_TRI = 16
# A triangle is kept on each side of a split its box, clipped to the child and padded, reaches:
# padded like the grid's cells (GRID_PAD_TRI of the triangle's extent and GRID_PAD_COORD of its
# largest coordinate magnitude), so every point where the unit can report a hit lies in a leaf
# that lists the triangle, and a triangle in a split plane is referenced on both sides.
KD_PAD_TRI = GRID_PAD_TRI
KD_PAD_COORD = GRID_PAD_COORD
# A leaf accepts hits up to its exit distance plus this slack, relative to t + |o|/|d| (the
# grid's stop slack, for the same float32 rounding of t), and traversal stops once the closest
# hit lies that far before the leaf's exit: a hit at the same t just beyond a split plane is
# still found and ties go to the lower index.
KD_T_SLACK = GRID_STOP_SLACK
# The build's nodes down to this depth are built first; the up to 2^KD_PARALLEL_DEPTH subtrees
# below them are built independently, on as many threads as there are, and joined in a fixed
# order (each with its share of the reference cap), so the tree is the same on any thread count.
# Meshes below KD_PARALLEL_MIN_TRIS are built in one pass (threads would cost more than they save).
KD_PARALLEL_DEPTH = 5
KD_PARALLEL_MIN_TRIS = 4096
# Rays per chunk of a batch for Embree (``embree_ref``). embreex traces a call's rays one by one on the calling thread (it
# releases the GIL), so a batch is cut into chunks that ``run_ranges`` hands to the same
# threads our traversal uses (a range of chunks per embreex call): Embree and our traversal
# then trace on equal terms, down to the small queues of a render's later bounces. A call
# costs about 2 us (measured), a 1024-ray chunk some 40 us or more of tracing.
EMBREE_CHUNK_RAYS = 1 << 10
# The float32 Moller-Trumbore unit's largest intermediate is t's numerator
# e2 . ((o - v0) x e1), at most |e1| |e2| |o - v0| (each product and sum on the way is bounded by
# it too). Below this bound, a quarter of float32's largest number, rounding cannot carry it
# past the float32 range; beyond it a ray may miss or hit at t = inf (traversal.structure).
F32_UNIT_MAX_PRODUCT = 2.0**126
# The same bound for the float64 units (the accuracy study's precision), a quarter of float64's
# largest number: the builder's coordinates (at most 1e15) keep every product far below it, so
# only rays from origins beyond about 1e270 can reach it.
F64_UNIT_MAX_PRODUCT = 2.0**1022
# The same products lose bits below float32's normal range (2^-126: a product of 2^-140 keeps
# 10 of its 24), and t's numerator and det with them, so a scene too small is refused too: one
# whose triangles span (the diagonal of their box) less than this. The default scene scaled
# down renders as at scale 1 (0.2-0.4% of pixels off by float32 rounding of its coordinates)
# down to a span of 1e-11; below, the products of its smaller triangles near 2^-126: 1.2% of
# pixels are off at 3.5e-12, 25% at 3.5e-14, most below. 2^-33 (~1.2e-10) stays ten times
# above the smallest span that rendered cleanly.
F32_UNIT_MIN_SPAN = 2.0**-33
# A tracer's own floor, below the renderer's: the determinant of a ray of unit direction with
# a triangle is at most |e1| |e2|, and below float32's normal range (2^-126) it loses its bits
# and the ray its hit. A tracer whose largest triangle has |e1| |e2| below 2^-100 (triangles
# of about 1e-15) is refused, 26 bits above that range; meshes of 1e-12 keep tracing (their
# rays that start within rounding of a triangle lose t's bits first, as in Embree's unit).
F32_UNIT_MIN_EDGES = 2.0**-100

# A pinhole camera's vertical field of view, in degrees: it sees less than a half-space
FOV_RANGE = (1e-3, 179.0)

# verify_rays' check that an Embree scene holds the triangles it checks: rays toward the
# centres of SCENE_PROBES of the largest triangles (the least moved by float32 rounding),
# from PROBE_OFFSET of their size off their planes, and at least PROBE_STEPS float32 steps at
# their coordinates (so that the origin stays on the front side); at least half must reach
# their triangle. Another mesh, or the same one moved by a fraction of a triangle, reaches none.
SCENE_PROBES = 16
PROBE_OFFSET = 1e-3
PROBE_STEPS = 8
