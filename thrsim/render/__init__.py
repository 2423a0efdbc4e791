"""Offscreen pictures of the bone being reamed (ModernGL on EGL): ``BoneRenderer``, ``save_png``."""

from thrsim.render.bone import BoneRenderer, ReamerView, save_png
from thrsim.render.camera import Camera, framing_camera

__all__ = ["BoneRenderer", "Camera", "ReamerView", "framing_camera", "save_png"]
