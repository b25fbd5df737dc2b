"""The scenes' knobs, each with its reason. The scene files' limits live in ``scenes.loader``."""

# Seconds an animation lasts when its scene file gives no frame count (and no frame sequence
# sets one): the length of the built-in animations (120 frames at 30 fps).
DEFAULT_ANIMATION_SECONDS = 4
# Frames per second where the scene file gives none: the built-in animations' rate (120 frames
# in DEFAULT_ANIMATION_SECONDS).
DEFAULT_FPS = 30.0
# Frame rates an animation may have: an animation without a frame count lasts
# DEFAULT_ANIMATION_SECONDS, which at these bounds is 1 to 4000 frames (beyond them: no frame,
# or frame times too fine for the motions' clocks).
MIN_FPS = 0.25
MAX_FPS = 1000.0
GENERATED_TRIANGLES = 20_000     # the built-in cloth and generated sphere: a mid-size mesh

# A sphere's subdiv and a sheet's resolution where the scene gives none (3,968 and 8,192
# triangles): twice as many longitudes as latitudes, so that the sphere's facets span equal
# angles both ways (5.6 degrees), and as many columns as rows, so that the square sheet's
# cells are square.
SPHERE_SUBDIV = (32, 64)
SHEET_RESOLUTION = (64, 64)
