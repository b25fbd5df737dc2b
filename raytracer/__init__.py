"""raytracer: the Whitted renderer (compiled stages, film, EXR output) over any tracer."""
import hwbvh.kernel_cache  # noqa: F401  (before any kernel: cached kernels stay fresh)
