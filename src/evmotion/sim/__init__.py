"""Event simulator with exact ground truth (ESIM-like).

Model
-----
* A scene is one or two layers (background, and an occluding object with an opacity
  mask), each a periodic texture of log intensity (:mod:`~evmotion.sim.textures`) moved
  by a parametric warp of chapter 3 (:mod:`~evmotion.sim.motions`, the warps of
  :mod:`evmotion.core.warps`, so the ground-truth parameters are in the estimators' own
  parametrization). Named scenes and their parameters: :mod:`~evmotion.sim.scenes`.
* Time advances in steps in which no texture point moves by more than about one pixel;
  inside a step every pixel whose log intensity changed by more than
  ``max_step_fraction * threshold`` is re-sampled on a finer grid (up to 64 samples), so
  between consecutive samples of a pixel its log intensity changes by about that fraction
  or less. Between samples log intensity is linear, and an event fires at each crossing of
  the pixel's threshold (per-pixel ON/OFF mismatch) at the interpolated time, rounded up
  to the next microsecond. A refractory period suppresses crossings (the pixel is reset);
  background-activity noise and hot pixels are Poisson processes added afterwards.
* Ground truth (:class:`GroundTruth`): flow in px/s at any time, displacement over any
  interval (exact along trajectories), parameters at any time, angular velocity, event
  masks; saved beside the events as ``<stem>_gt.h5`` (:mod:`~evmotion.sim.gtio`).

* Options (:mod:`~evmotion.sim.options`): :class:`SimOptions`, :class:`EventOptions` and
  :class:`SchlierenOptions` gather the tuning of the three simulators as one checked,
  frozen value (``simulate(scene, options=opts)``); their fields are also keywords.

* Schlieren (:mod:`~evmotion.sim.schlieren`): events and frames of a random-dot
  background seen through moving air (thesis ch. 6), with the exact flow between frames;
  its events come from :func:`~evmotion.sim.simulator.simulate_log_function`, the same
  event model for a log intensity given as a function of time.

Speed (one core, 346x260, ``benchmarks/results/sim.md``): 2.9-4.1 M events/s on the
single-layer scenes with the dots or checker textures (16x16 tiles where the texture is
locally constant are skipped), 1.7-1.9 M events/s on the noise and shapes textures and on
the two-layer ``object`` scene; 33-56x the plain-numpy reference of the kernel.

>>> from evmotion.sim import simulate, SCENES
>>> res = simulate("rotation", duration_s=0.01, sensor_size=(60, 80), seed=0)
>>> res.gt.params(0)["omega"]
[0.5, -0.7, 1.2]
"""

import importlib

# Names are imported from their module on first use (PEP 562), so that importing a light
# module such as evmotion.sim.scenes (the CLI's parser does, for its choices) does not
# import the simulator, the warps and numba.
_HOME = {
    "BOS_SCENES": "scenes",
    "SCENES": "scenes",
    "default_K": "scenes",
    "TEXTURES": "textures",
    "Texture": "textures",
    "make_texture": "textures",
    "texture_from_image": "textures",
    "GroundTruth": "groundtruth",
    "Layer": "groundtruth",
    "Motion": "motions",
    "make_motion": "motions",
    "gt_path_for": "gtio",
    "read_ground_truth": "gtio",
    "sim_calibration": "gtio",
    "write_ground_truth": "gtio",
    "SchlierenGT": "schlieren",
    "SchlierenSim": "schlieren",
    "read_schlieren_gt": "schlieren",
    "simulate_schlieren": "schlieren",
    "write_schlieren": "schlieren",
    "EventOptions": "options",
    "SchlierenOptions": "options",
    "SimOptions": "options",
    "LogSimResult": "simulator",
    "SimResult": "simulator",
    "simulate": "simulator",
    "simulate_log_function": "simulator",
}

__all__ = [
    "BOS_SCENES",
    "SCENES",
    "TEXTURES",
    "EventOptions",
    "GroundTruth",
    "Layer",
    "LogSimResult",
    "Motion",
    "SchlierenGT",
    "SchlierenOptions",
    "SchlierenSim",
    "SimOptions",
    "SimResult",
    "Texture",
    "default_K",
    "gt_path_for",
    "make_motion",
    "make_texture",
    "read_ground_truth",
    "read_schlieren_gt",
    "sim_calibration",
    "simulate",
    "simulate_log_function",
    "simulate_schlieren",
    "texture_from_image",
    "write_ground_truth",
    "write_schlieren",
]


def __getattr__(name: str):
    if name in _HOME:
        value = getattr(importlib.import_module(f"evmotion.sim.{_HOME[name]}"), name)
        globals()[name] = value
        return value
    if name in set(_HOME.values()) | {"photoreceptor", "render"}:
        # the submodules too, as evmotion.methods' (evmotion.sim.schlieren was an
        # AttributeError until imported, probe CB)
        return importlib.import_module(f"evmotion.sim.{name}")
    raise AttributeError(f"module 'evmotion.sim' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
