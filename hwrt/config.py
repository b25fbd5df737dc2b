"""Knobs of the commands' own work, each with its reason. The builder's, the traversal's, the
renderer's and the scenes' live in ``hwbvh.config``, ``traversal.config``, ``raytracer.config``
and ``scenes.config``; the scene files' limits in ``scenes.loader``."""

# The adaptive strategy rebuilds once the refitted tree's SAH cost exceeds this multiple of the
# cost right after the last rebuild. The SAH cost estimates traversal work per ray, so this
# bounds what refitting may add to a frame's render at about half again of a fresh tree's.
ADAPTIVE_THRESHOLD = 1.5

# The most characters of a file beside a handoff dump (F.json) read to tell whether it is such
# a dump's description before the dump replaces it: a description lists one size per handoff,
# at most a few per thousand primitives, so a file far past this is something else.
HANDOFF_DESCRIPTION_MAX_CHARS = 1 << 26

# --- Cells on Dask (cluster) ------------------------------------------------------------
CONNECT_TIMEOUT_S = 5      # an unreachable scheduler fails this fast instead of hanging
RETRIES = 2                # re-runs of a cell that raised (a killed worker is rescheduled anyway)
WORKER_WATCH_S = 10        # how often a run checks that its scheduler still has workers

# --- Design-space exploration (explore) -------------------------------------------------
# The most configurations one exploration takes: 23x the default grid's 4,320
# (DEFAULT_GRID), a few hours of simulation per mesh on a workstation's cores; a
# grid past it is refused before its configurations are made (each is a few kilobytes of
# parameters and results).
MAX_CONFIGURATIONS = 100_000
# The default grid: the thesis' w x Tsize study (4.2.1, Fig. 4.2) and leaf sizes (Fig. 4.3),
# half to twice the subtree capacity, one to four subtree builders and RAM pairs, and the two
# presets' clocks; 16 bins, the hardware's maximum and both presets' setting.
DEFAULT_GRID = {"w": [2, 4, 8, 16], "tsize": [2, 4, 8, 16], "psize": [1024, 2048, 4096],
                "subtree_builders": [1, 2, 4], "ram_pairs": [1, 2, 4], "clock_mhz": [250.0, 500.0],
                "leaf_size": [4, 8, 16, 32, 64]}
BATCH_CONFIGS = 96         # configurations per task: ~0.1-1 s of simulation, a fine progress bar
TREE_CACHE = 3             # trees a worker keeps (a 270k-triangle tree is ~50 MB)

# --- Accuracy study (study) -------------------------------------------------------------
# The reference renders follow paths this long: the deepest max_depth the study sets
# (``study.KNOBS``), so that no cell's paths are longer than the reference's.
REFERENCE_DEPTH = 8
REFERENCE_SPP_OF_SPP_KNOB = 16       # the spp knob's values converge toward this many samples
# random rays per cell checked against Embree: the mismatch and tie rates resolve 1e-5
# (--quick: 5e-5)
MISMATCH_RAYS = 100_000
MISMATCH_RAYS_QUICK = 20_000

# --- Animation benchmark (animate) ------------------------------------------------------
BENCH_FRAMES = 60            # bench animation: 2 s at 30 fps covers the explosion and the drape
# --quick: 12 frames (0.4 s at 30 fps) still pass the explosion's start (0.25 s,
# ``scenes.animation.EXPLODE_AT``), on a generated sphere and cloth of a fifth of their usual
# triangles (``scenes.config.GENERATED_TRIANGLES``), for a short run
BENCH_QUICK_FRAMES = 12
BENCH_QUICK_TRIANGLES = 4000

# --- Mitsuba 3 as a peer (mitsuba_peer) -------------------------------------------------
# A vertex normal further than this from its face normal (1 - cos) means the mesh is shaded
# smooth, which Mitsuba's mesh without vertex normals would not reproduce.
FLAT_NORMAL_TOLERANCE = 1e-4
# Seconds a child process may take to try a variant (the first LLVM run compiles its kernels).
PROBE_TIMEOUT_SECONDS = 300

# --- hwrt verify (cli) ------------------------------------------------------------------
# Rays traced when --rays is not given: one mismatching ray in them is a rate of 1e-5, the
# resolution of the accuracy study's check (MISMATCH_RAYS).
VERIFY_RAYS = 100_000
# The rays' kind when --kind is not given: rays from uniform points of the mesh's box in
# uniform directions reach every part of the tree from every angle, where a camera's rays see
# only what faces it.
VERIFY_KIND = "random"


# Environment switches (HWRT_PROGRESS, HWRT_DEBUG): the words that turn one on or off. An
# unset or empty variable is off; any other word is refused by the command line, as an
# unknown value of HWRT_THREADING is, rather than read as on.
FLAG_WORDS = {"1": True, "true": True, "yes": True, "on": True,
              "0": False, "false": False, "no": False, "off": False, "": False}


def env_flag(name):
    """Whether environment switch ``name`` is on (FLAG_WORDS); None for a word it does not
    know."""
    import os
    return FLAG_WORDS.get(os.environ.get(name, "").strip().lower())
