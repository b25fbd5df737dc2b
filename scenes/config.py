"""The scenes' knobs, each with its reason. The scene files' limits live in ``scenes.loader``."""

# Seconds an animation lasts when its scene file gives no frame count (and no frame sequence
# sets one): the length of the built-in animations (120 frames at 30 fps).
DEFAULT_ANIMATION_SECONDS = 4

# A sphere's subdiv and a sheet's resolution where the scene gives none (3,968 and 8,192
# triangles): twice as many longitudes as latitudes, so that the sphere's facets span equal
# angles both ways (5.6 degrees), and as many columns as rows, so that the square sheet's
# cells are square.
SPHERE_SUBDIV = (32, 64)
SHEET_RESOLUTION = (64, 64)
