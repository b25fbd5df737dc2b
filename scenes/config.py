"""The scenes' knobs, each with its reason. The scene files' limits live in ``scenes.loader``."""

# Seconds an animation lasts when its scene file gives no frame count (and no frame sequence
# sets one): the length of the built-in animations (120 frames at 30 fps).
DEFAULT_ANIMATION_SECONDS = 4
