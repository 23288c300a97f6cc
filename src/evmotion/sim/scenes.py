"""Named scenes: a texture and one or two moving layers with default motion parameters.

Every scene uses a warp of :mod:`evmotion.core.warps` referenced at ``t = 0`` (the start of
the recording); parameters are the warp's, in its units. The defaults give speeds of a few
hundred px/s at the border of a DAVIS346 (346x260) image:

============ =========== ==============================================================
scene        warp        parameters (``params=`` keys) and units
============ =========== ==============================================================
translation  translation ``vx, vy`` image velocity, px/s
rotation     rotation    ``wx, wy, wz`` (or ``omega``) camera angular velocity, rad/s,
                         camera frame x right, y down, z forward; through ``K``
zoom         zoom        ``hz`` = forward speed / depth, 1/s (time to contact 1/hz; the
                         thesis' (3.7) ``b_z = hz * T`` for a window of T s); ``foe``
                         focus of expansion (x, y) px (default image centre)
se2          se2         ``vx, vy`` px/s, ``wz`` rad/s (A.11; ``wz`` with the rotation
                         warp's sign: the camera's rate about z, minus A.11's ``w_z``)
inplane      inplane     ``vx, vy`` px/s, ``phi`` rad/s, ``hz`` 1/s (A.22)
similarity   similarity  ``vx, vy`` px/s, ``wz`` rad/s, ``s`` 1/s (A.36)
affine       affine      ``vx, vy`` px/s, ``g11, g12, g21, g22`` 1/s (A.47)
homography   homography  ``g11, g12, g21, g22`` 1/s, ``g13, g23`` px/s,
                         ``g31, g32`` 1/(px s) (A.1)
object       translation background ``bg_vx, bg_vy`` px/s; object (a textured disc
             + se2       occluding it, SE(2) about its own centre): ``fg_vx, fg_vy``
                         px/s, ``fg_wz`` rad/s, ``radius`` px, ``fg_x, fg_y`` start px
============ =========== ==============================================================
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evmotion.errors import ParameterError

__all__ = ["BOS_SCENES", "SCENES", "SceneSpec", "default_K"]

# The background-oriented schlieren scenes of :func:`evmotion.sim.schlieren.simulate_schlieren`
# and what each shows.
BOS_SCENES = {
    "plume": "rising thermal plume from a hot plate at the bottom (natural convection)",
    "jet": "turbulent hot-air jet from a hair dryer at the left (forced convection)",
    "breath": "pulsed breath from a mouth at the left: eddies decelerating and spreading",
    "ice": "cold air stream falling from crushed ice at the top (negative density)",
}


@dataclass(frozen=True)
class SceneSpec:
    """A named scene: its warp(s) and default parameters."""

    name: str
    warp: str
    defaults: dict
    description: str


SCENES: dict[str, SceneSpec] = {s.name: s for s in (
    SceneSpec("translation", "translation", {"vx": 220.0, "vy": -130.0},
              "constant image translation (feature flow, 3.5.1)"),
    SceneSpec("rotation", "rotation", {"wx": 0.5, "wy": -0.7, "wz": 1.2},
              "camera rotation through the intrinsics (3.22)"),
    SceneSpec("zoom", "zoom", {"hz": 1.5},
              "forward motion towards a fronto-parallel plane, focus of expansion (3.7)"),
    SceneSpec("se2", "se2", {"vx": 150.0, "vy": -90.0, "wz": 0.9}, "planar SE(2) (A.11)"),
    SceneSpec("inplane", "inplane", {"vx": 120.0, "vy": 60.0, "phi": 0.5, "hz": 0.3},
              "4-DOF in-plane approximation (A.22)"),
    SceneSpec("similarity", "similarity", {"vx": 120.0, "vy": -60.0, "wz": 0.8, "s": 0.8},
              "4-DOF similarity (A.36)"),
    SceneSpec("affine", "affine",
              {"vx": 100.0, "vy": 50.0, "g11": 0.6, "g12": 0.3, "g21": -0.4, "g22": -0.5},
              "6-DOF affine (A.47)"),
    SceneSpec("homography", "homography",
              {"g11": 0.4, "g12": 0.3, "g13": 120.0, "g21": -0.3, "g22": -0.5, "g23": -60.0,
               "g31": 8e-4, "g32": -6e-4}, "8-DOF homography (A.1)"),
    SceneSpec("object", "translation+se2",
              {"bg_vx": -80.0, "bg_vy": 40.0, "fg_vx": 300.0, "fg_vy": 60.0, "fg_wz": 1.0,
               "radius": None, "fg_x": None, "fg_y": None},
              "independently moving textured disc occluding a translating background"),
)}


def default_K(sensor_size: tuple[int, int]) -> np.ndarray:
    """Pinhole intrinsics used by the simulator: ``f = 0.75 W`` px (about 75 deg horizontal
    field of view, like a DAVIS346 with a 4.5 mm lens), principal point at the centre."""
    h, w = sensor_size
    f = 0.75 * w
    return np.array([[f, 0.0, (w - 1) / 2.0], [0.0, f, (h - 1) / 2.0], [0.0, 0.0, 1.0]])


def resolve_params(scene: str, params: dict | None, sensor_size) -> dict:
    """Scene defaults updated by ``params`` (aliases: ``omega``, ``theta``, ``foe``)."""
    if scene not in SCENES:
        raise ParameterError(f"unknown scene '{scene}'; choose one of {sorted(SCENES)}")
    spec = SCENES[scene]
    out = dict(spec.defaults)
    names = list(spec.defaults)
    h, w = sensor_size
    if scene == "zoom":
        out["foe"] = [(w - 1) / 2.0, (h - 1) / 2.0]
    if scene == "object":
        out.update(radius=0.2 * min(h, w), fg_x=0.3 * w, fg_y=0.5 * h)
    for key, val in (params or {}).items():
        if key == "omega" and scene == "rotation":
            vals = _vector(key, val, 3)
            out.update(wx=vals[0], wy=vals[1], wz=vals[2])
        elif key == "theta" and scene != "object":
            vals = _vector(key, val, len(names))
            out.update(dict(zip(names, vals, strict=True)))
        elif key == "foe" and scene == "zoom":
            out["foe"] = list(_vector(key, val, 2))
        elif key in out:
            out[key] = float(_vector(key, val, 1)[0])
        else:
            extra = {"rotation": ", omega", "zoom": ", foe"}.get(scene, "")
            raise ParameterError(f"scene '{scene}' has no parameter '{key}'; its parameters "
                                 f"are {', '.join(names)}{extra}"
                                 + ("" if scene == "object" else ", theta"))
    if scene == "object":
        _check_object(out, sensor_size)
    return out


#: How far outside the sensor, in its larger side, the object's disc may start or reach.
OBJECT_REACH = 10


def _check_object(p: dict, sensor_size) -> None:
    """Refuse a disc of no size or one far off the sensor (probe OPT: fg_x=1e30 never
    ended, radius -5 or 0 simulated a scene with no object, unsaid)."""
    h, w = sensor_size
    far = OBJECT_REACH * max(h, w)
    if not 0.5 <= p["radius"] <= far:
        raise ParameterError(f"scene 'object': radius must be in [0.5, {far:g}] px "
                             f"({OBJECT_REACH}x the sensor's larger side), got {p['radius']:g}")
    for key, side in (("fg_x", w), ("fg_y", h)):
        if not -far <= p[key] <= side + far:
            raise ParameterError(f"scene 'object': {key} must be in [{-far:g}, {side + far:g}] "
                                 f"px (the disc's start, within {OBJECT_REACH}x the sensor's "
                                 f"larger side of it), got {p[key]:g}")


def _vector(key, val, n) -> np.ndarray:
    try:
        arr = np.atleast_1d(np.asarray(val, dtype=np.float64))
    except (TypeError, ValueError):
        raise ParameterError(f"parameter '{key}' must be numeric, got {val!r}") from None
    if arr.shape != (n,) or not np.all(np.isfinite(arr)):
        raise ParameterError(f"parameter '{key}' must be {n} finite number(s), got {val!r}")
    return arr
