"""Every knob and constant of the hardware builder, in one place, each with its source.

Sources are Doyle 2014 (``../shared/seed/doyle-2014-hwbvh-thesis.txt``) and ``../shared/SPEC.md``.
"""

# --- Primitive records (thesis 3.3, SPEC 1) ---------------------------------------------
PRIMITIVE_INDEX_BITS = 24                 # 24-bit primitive index in the 216-bit record
MAX_PRIMITIVES = 1 << PRIMITIVE_INDEX_BITS  # 16,777,216 primitives per build
PRIMITIVE_RECORD_BYTES = 27               # 192-bit float32 AABB + 24-bit index = 216 bits

# Coordinates beyond this magnitude are rejected: float32 surface areas (extent^2, up to
# 2e30 * 3) times a primitive count (<= 2^24) must stay finite for the SAH comparisons of
# Eq. 3.3 to mean anything.
MAX_COORDINATE = 1.0e15

# The coarsest float32 rounding, as a fraction of a mesh's size, that the builder accepts
# from triangles given in a wider type, and that a scene accepts from a placement (a
# translation, a shape far from the origin): past it float32 spaces the coordinates more
# than an eighth of the mesh's size apart, and the mesh keeps at most a few positions
# across, flattened or rounded to a point, which every ray would then miss without a word
# (a unit mesh moved 1e9 along x keeps its y-z areas).
MAX_FLOAT32_ROUNDING = 1 / 16

# --- Binned SAH (thesis 3.3.3-3.3.4, SPEC 2) --------------------------------------------
DEFAULT_BINS = 16        # Table 4.1: both instantiations use 16 bins (hardware maximum)
MIN_BINS = 2             # a split needs two bins to fall between
MAX_HARDWARE_BINS = 16   # the hardware supports at most 16 bins
MAX_SOFTWARE_BINS = 64   # software allows more, for the accuracy studies
DEFAULT_LEAF_SIZE = 4    # Table 4.1: leaf size 4
MAX_LEAF_SIZE = 255      # leaves are fixed-size termination; 255 keeps the studies bounded

# --- Upper builder / subtree builders (thesis 3.4, SPEC 3) ------------------------------
DEFAULT_CAPACITY = 8192  # subtree capacity w * Psize (Table 4.1: 8192)
DEFAULT_BLOCK_NODES = 256  # nodes per block handed out by the upper builder's pool (3.3.5)

# Ranges of the layout knobs of ``hwbvh.build`` (checked before any allocation). A capacity at
# or above the primitive count puts the whole tree in one subtree, so only the layout kernel's
# int64 bounds it. A block never holds more nodes than a tree of MAX_PRIMITIVES has (2N - 1).
# The subtree builders only place nodes (the layout keeps a few words per builder), so their
# range is generous, far beyond any hardware instance (KNOB_RANGES); ``build`` also keeps every
# node slot, at most (1 + builders) * block_nodes + 2N - 1, below the format's 32-bit pointers.
LAYOUT_KNOB_RANGES = {
    "capacity": (1, 2**63 - 1),
    "subtree_builders": (1, 1 << 16),
    "block_nodes": (1, 2 * MAX_PRIMITIVES),
}
MAX_NODE_SLOTS = 2**32 - 1

# --- Output format (thesis 3.3.5, SPEC 4) -----------------------------------------------
NODE_BYTES = 48          # 384 bits = two 192-bit words
WORD_BYTES = 24          # one 192-bit memory word
INDEX_BYTES = 3          # 24-bit index entries
INDICES_PER_WORD = 8     # 8 x 24 bits = 192 bits
INDEX_PAD = 0xFFFFFF     # tail padding of the last index word
LEAF_FLAG = 1            # flags bit 0

# --- Reference sweep builder (thesis 4.3.3, SPEC 5) -------------------------------------
SWEEP_MAX_LEAF = 64      # forced split above this, so a pile of identical triangles stays bounded

# --- Timing model (thesis 3.5, Tables 3.1-3.3; SPEC 6) ---------------------------------
LAT_PRIM_BUFFER = 2      # Table 3.3: primitive buffer latency
LAT_PARTITION = 36       # Table 3.3: partitioning unit latency
LAT_BINNING = 32         # Table 3.3: binning unit latency
LAT_SAH = 73             # Table 3.3: SAH calculator latency, and one node per 73 cycles
THREAD_SWITCH = 2        # 3.3.2: "within two cycles" the partitioning unit switches thread
AABB_BYTES = 24          # a float32 AABB alone: the initial scene-AABB pass reads one per primitive
# Control latency per split that the RTL spends and Table 3.3 does not list (bin-collector dump
# and merge, READY/GO hand-shakes, FIFOs, thread-context reads). Not derived from the text:
# fitted (hwbvh.calibration.fit_control_latency, `hwrt bench model` on the meshes of
# ../shared/meshes) so that subtrees of FIT_SUBTREE_MIN..FIT_SUBTREE_MAX primitives take the
# 14.6 cycles per primitive that the thesis' Marbles build implies (Table 4.11 energies / Table
# 4.10 powers, Marbles' size from Table 4.2). Bunny and Sponza are then predictions, not fits.
# 0 gives the text-only model.
CONTROL_LATENCY = 129
# The fit's subtrees (hwbvh.calibration.fit_subtrees): those the upper builder hands off with
# 3.5k-5.5k primitives, around the half of Marbles' 8,642-8,835 triangles that each of its two
# subtrees holds (calibration.marbles_rate); at most FIT_SUBTREES_PER_MESH of them from each
# mesh, so that no mesh outweighs the others in the mean rate.
FIT_SUBTREE_MIN = 3500
FIT_SUBTREE_MAX = 5500
FIT_SUBTREES_PER_MESH = 6

# --- Resources per unit (thesis 4.3.4, Tables 4.5-4.8) ------------------------------------
# Floating-point cores of one unit, by type (the columns of Tables 4.5-4.7; the same in the
# subtree builders and the upper builder). A "binning unit" is a group of three, one per axis.
FP_TYPES = ("add", "sub", "mul", "div", "cmp", "fxd_flt", "flt_fxd")
FP_CORES_PER_UNIT = {
    "partitioning_unit": {"add": 1, "sub": 3, "mul": 1, "div": 1, "flt_fxd": 1},
    "binning_unit": {"add": 3, "sub": 9, "mul": 3, "div": 3, "flt_fxd": 3},
    # per axis: the surface area (3 sub, 3 mul, 2 add), times the count (1 mul, 1 fxd-flt) and
    # the final sum of both sides (1 add)
    "sah_calculator": {"add": 9, "sub": 9, "mul": 12, "fxd_flt": 3},
    "tree_output": {},
}
# Comparators are the AABB unions (6 each) of an SAH calculator fed by g binning-unit groups:
# one bin collector per group (3 axes x 6), a merge tree of g - 1 unions per axis, and the cost
# evaluator's sweep union per axis: 18g + 18(g - 1) + 18 = 36g. Table 4.5: 144 at g = w = 4;
# Tables 4.6/4.7: 36 and 72 at g = 1 and 2 RAM pairs.
SAH_CMP_PER_GROUP = 36
# The upper builder's partitioning units have 6 comparators per RAM pair each (Table 4.6: 6 at
# one pair; Table 4.7: 12 at two); the subtree builder's have none.
UPPER_PU_CMP_PER_RAM_PAIR = 6
COMPARATOR_GATES = 235   # 4.3.4: the synthesised comparator, given to InCyte as 235 gates

# Register space (bytes). What the text describes is modelled from the parameters; the rest is
# a constant per unit. Table 4.5 prints 422 KB for the subtree builder and Table 4.6 164 KB for
# HWBVH-C's upper builder, yet Table 4.8 has 587 KB, which Table 4.9's 4,808,704 register-file
# bits confirm to the bit: the only split that rounds (half to even) to both is 422.5 + 164.5.
# HWBVH-HP then leaves 1161 - 2 x 422.5 = 316 KB for its upper builder, Table 4.7's figure.
THREAD_CONTEXT_BYTES = 48    # 3.3.1: a thread context without its stack is "< 50 bytes"
PARTITIONING_UNIT_REG_BYTES = 2048 - 8 * THREAD_CONTEXT_BYTES  # Table 4.5: 2 KB at Tsize = 8
BINNING_GROUP_REG_BYTES = 4096   # Tables 4.5-4.7: 4 KB (the pipeline's AABB FIFOs, status)
BIN_RECORD_BYTES = 27        # Fig. 3.10: a 216-bit bin record (AABB + 24-bit count) per bin
SAH_TERM_BYTES = 4           # Fig. 3.11: float32 SA*N terms in the evaluator's FIFO and LIFO
INDEX_FIFO_ENTRY_BYTES = 4   # 3.3.5: index + valid + last bits in a 32-bit entry; w * Tsize
                             # FIFOs of Psize entries are Table 4.5's 256 KB tree output
UPPER_TREE_OUTPUT_REG_BYTES = 4096   # Tables 4.6/4.7: 4 KB
# Not itemised in the text, solved from the three totals above (422.5, 164.5 and 316 KB):
SAH_CALC_OTHER_REG_BYTES = 2256          # subtree SAH calculator: 9120 B in all (Table 4.5: 9 KB)
UPPER_SAH_CALC_OTHER_REG_BYTES = 2928    # upper: 5904 / 7200 B at 1 / 2 pairs (6 / 7 KB)
UPPER_PU_REG_BYTES = 148_448             # DRAM burst buffers: 145.0 KB (the tables print 147)

# --- Area and power (thesis 4.3.4, Tables 4.9-4.10: InCyte, 90 nm) -----------------------
# Table 4.10, the two InCyte data points: total equivalent gates, die area, active power
THESIS_TOTAL_GATES = {"HWBVH-C": 13_479_356, "HWBVH-HP": 26_359_541}
THESIS_AREA_MM2 = {"HWBVH-C": 55.947, "HWBVH-HP": 105.787}
THESIS_ACTIVE_POWER_W = {"HWBVH-C": 5.902, "HWBVH-HP": 25.179}
MISC_LOGIC_SHARE = 0.20  # 4.3.4: miscellaneous logic "to consume 20% of the core area"
# Gates of a configuration: the comparators at their 235 gates, every other floating-point core
# at one gate count, every register or SRAM bit at another. The two unknowns are solved from
# InCyte's total equivalent gates of the two presets (Table 4.10), which the model therefore
# reproduces; the presets' resources differ by about one factor of two throughout, so two points
# cannot separate more kinds (an area or a power per kind solved from them comes out negative
# for one kind). Then one constant maps gates to area (least squares in log space over the two
# presets, which it meets within +-1.7%), and active power is gates x clock x a price per gate
# and hertz that grows with the clock, (f / POWER_REFERENCE_MHZ) ** POWER_CLOCK_EXPONENT:
# HWBVH-HP (500 MHz) spends 9% more per gate and hertz than HWBVH-C (250 MHz), as a faster
# design does in stronger cells. One price for both would miss each preset's power by 4.4% and
# turn the presets' energy per build (power x time) the wrong way round against Table 4.11
# (Bunny: HWBVH-C 0.0356 J, HWBVH-HP 0.0367 J); so fitted, both presets draw exactly Table
# 4.10's active power. hwbvh.calibration.fit_cost_model computes all five constants.
GATES_PER_FP_CORE = 6210.3
GATES_PER_STORAGE_BIT = 0.67868
AREA_MM2_PER_GATE = 4.0813e-6
ACTIVE_W_PER_GATE_HZ = 1.75142e-15       # at POWER_REFERENCE_MHZ
POWER_REFERENCE_MHZ = 250.0
POWER_CLOCK_EXPONENT = 0.125371

# --- Hardware ranges of the configuration knobs (checked before any simulation) ---------
# Thesis 3.3: w and Tsize are powers of two, Psize any positive integer. The studies of 4.2.1
# span 2..16; 64 bounds how far the cost model is asked to extrapolate. A split needs 2 bins.
# The clock fit rests on 250 and 500 MHz in 90 nm; 1 GHz bounds its extrapolation.
KNOB_RANGES = {
    "bins": (MIN_BINS, MAX_HARDWARE_BINS),
    "leaf_size": (1, MAX_LEAF_SIZE),
    "w": (1, 64),
    "tsize": (1, 64),
    "psize": (1, MAX_PRIMITIVES),
    "subtree_builders": (1, 64),
    "ram_pairs": (1, 16),
    "clock_mhz": (1.0, 1000.0),
}
POWER_OF_TWO_KNOBS = ("w", "tsize")
# Control latency (above) is a calibrated cycle count per split (129). A million cycles is far
# beyond any controller, and keeps cycle totals (at most 2^25 splits) well inside int64.
MAX_CONTROL_LATENCY = 1_000_000

# The most bytes of an existing PREFIX.json read to tell a tree's description (a few KB) from
# another file before a save would replace it (api.prefix_problem); a larger file is not one.
TREE_META_READ_BYTES = 1 << 20

# The most bytes of a PLY file read for its header (element counts, format, property types)
# before trimesh reads it (primitives._ply_header): far more than any header with its comments.
PLY_HEADER_BYTES = 1 << 16

# The bytes one file name may hold where the file system does not say (os.pathconf fails):
# ext4, XFS, Btrfs and tmpfs all allow 255, so an output name longer than this is refused
# before the work (files.check_outputs) instead of failing when the result is renamed into place.
DEFAULT_NAME_MAX = 255

# --- Threading (hwbvh.parallel) -----------------------------------------------------------
# The threading set-up (``parallel.THREADING_SETUPS``) unless HWRT_THREADING names another:
# OpenMP with sleeping idle threads, the fastest set-up alone and beside a busy competitor on
# every core (docs/contention.md), and, unlike workqueue, safe for several calling threads (a
# Dask worker's).
DEFAULT_THREADING = "omp-passive"

# --- Software build scheduling (not a hardware parameter) -------------------------------
# Nodes with more primitives than this are split with data-parallel binning/partitioning;
# smaller ones become independent tasks built in parallel. The tree does not depend on it.
TASK_MIN_PRIMS = 2048
SEQUENTIAL_MAX_PRIMS = 10000   # below this one sequential subtree build is as fast, and needs
                               # no parallel kernels compiled (first-run time)
TASKS_PER_THREAD = 16
# ``parallel.run_ranges`` cuts a batch into this many ranges per thread, taken as threads come
# free: enough to rebalance around a thread slowed by another program, few enough calls.
RANGES_PER_THREAD = 8

# Freed memory kept for the next build (``memory``): arrays below this size come from the heap
# instead of fresh pages (32 MiB, glibc's largest: a 260k-triangle build's largest array is
# 12.6 MB), and the heap's free top goes back to the system only beyond the trim threshold.
# The price is memory the process keeps after its peak; a build's page faults cost a quarter
# of its time on a virtual machine.
MALLOC_MMAP_THRESHOLD = 32 * 1024 * 1024
MALLOC_TRIM_THRESHOLD = 1024 * 1024 * 1024

# Below this size an OBJ file with a negative face index is rewritten by the line-by-line
# reader, which takes ~0.1 s per MB (~30 ms at this size): the compiled pass, though ~20x
# faster, is compiled on first use where Numba's cache is empty or unwritable (~3.5 s), and the
# small files where that would dominate (examples, tests, hand-written scenes) are the common
# ones; large files repay it.
OBJ_COMPILED_MIN_BYTES = 256 * 1024
