"""scenes: scene dicts (Mitsuba style), built-in scenes generated in code, loaders (trimesh)."""
import hwbvh.kernel_cache  # noqa: F401  (before any kernel: cached kernels stay fresh)
from .animation import ANIMATIONS, Animation, load_animation
from .builtin import BUILTIN
from .loader import (CompiledScene, compile_scene, is_scene, load_scene, load_scene_geometry,
                     mesh_scene, save_scene, transform_scene, with_frame)

__all__ = ["ANIMATIONS", "Animation", "load_animation", "BUILTIN", "CompiledScene", "compile_scene",
           "is_scene", "load_scene", "load_scene_geometry", "mesh_scene", "save_scene",
           "transform_scene", "with_frame"]
