"""Knobs of the commands' own work, each with its reason. The builder's, the traversal's and
the renderer's live in ``hwbvh.config``, ``traversal.config`` and ``raytracer.config``; the
scene files' limits in ``scenes.loader``."""

# The adaptive strategy rebuilds once the refitted tree's SAH cost exceeds this multiple of the
# cost right after the last rebuild. The SAH cost estimates traversal work per ray, so this
# bounds what refitting may add to a frame's render at about half again of a fresh tree's.
ADAPTIVE_THRESHOLD = 1.5
