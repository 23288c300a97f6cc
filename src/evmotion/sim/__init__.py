"""Event simulator with exact ground truth (ESIM-like).

>>> from evmotion.sim import simulate, SCENES
>>> res = simulate("rotation", duration_s=0.01, sensor_size=(60, 80), seed=0)
>>> res.gt.params(0)["omega"]
[0.5, -0.7, 1.2]
"""

from evmotion.sim.groundtruth import GroundTruth, Layer
from evmotion.sim.motions import Motion, make_motion
from evmotion.sim.scenes import SCENES, default_K
from evmotion.sim.simulator import SimResult, simulate
from evmotion.sim.textures import TEXTURES, Texture, make_texture, texture_from_image

__all__ = [
    "SCENES",
    "TEXTURES",
    "GroundTruth",
    "Layer",
    "Motion",
    "SimResult",
    "Texture",
    "default_K",
    "make_motion",
    "make_texture",
    "simulate",
    "texture_from_image",
]
