"""Knobs of the commands' own work, each with its reason. The builder's, the traversal's and
the renderer's live in ``hwbvh.config``, ``traversal.config`` and ``raytracer.config``; the
scene files' limits in ``scenes.loader``."""

# The adaptive strategy rebuilds once the refitted tree's SAH cost exceeds this multiple of the
# cost right after the last rebuild. The SAH cost estimates traversal work per ray, so this
# bounds what refitting may add to a frame's render at about half again of a fresh tree's.
ADAPTIVE_THRESHOLD = 1.5


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
