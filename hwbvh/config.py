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

# --- Binned SAH (thesis 3.3.3-3.3.4, SPEC 2) --------------------------------------------
DEFAULT_BINS = 16        # Table 4.1: both instantiations use 16 bins (hardware maximum)
MAX_HARDWARE_BINS = 16   # the hardware supports at most 16 bins
MAX_SOFTWARE_BINS = 64   # software allows more, for the accuracy studies
DEFAULT_LEAF_SIZE = 4    # Table 4.1: leaf size 4
MAX_LEAF_SIZE = 255      # leaves are fixed-size termination; 255 keeps the studies bounded

# --- Upper builder / subtree builders (thesis 3.4, SPEC 3) ------------------------------
DEFAULT_CAPACITY = 8192  # subtree capacity w * Psize (Table 4.1: 8192)
DEFAULT_BLOCK_NODES = 256  # nodes per block handed out by the upper builder's pool (3.3.5)

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
# fitted (hwbvh.calibration.fit_control_latency) so that subtrees of ~4.4k primitives take the
# ~14.5 cycles per primitive that the thesis' Marbles build implies (Table 4.11 energies / Table
# 4.10 powers). Bunny and Sponza are then predictions, not fits. 0 gives the text-only model.
CONTROL_LATENCY = 148

# --- Power (Table 4.10, InCyte, 90 nm) ----------------------------------------------------
THESIS_ACTIVE_POWER_W = {"HWBVH-C": 5.902, "HWBVH-HP": 25.179}

# --- Software build scheduling (not a hardware parameter) -------------------------------
# Nodes with more primitives than this are split with data-parallel binning/partitioning;
# smaller ones become independent tasks built in parallel. The tree does not depend on it.
TASK_MIN_PRIMS = 2048
SEQUENTIAL_MAX_PRIMS = 10000   # below this one sequential subtree build is as fast, and needs
                               # no parallel kernels compiled (first-run time)
TASKS_PER_THREAD = 16
