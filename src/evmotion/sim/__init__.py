"""Event simulator with exact ground truth (ESIM-like).

>>> from evmotion.sim import simulate, SCENES
>>> res = simulate("rotation", duration_s=0.01, sensor_size=(60, 80), seed=0)
>>> res.gt.params(0)["omega"]
[0.5, -0.7, 1.2]
"""

from evmotion.sim.groundtruth import GroundTruth, Layer
from evmotion.sim.gtio import gt_path_for, read_ground_truth, write_ground_truth
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
    "gt_path_for",
    "make_motion",
    "make_texture",
    "read_ground_truth",
    "simulate",
    "texture_from_image",
    "write_ground_truth",
]
