"""The unsupervised EV-FlowNet of thesis §4.3.7, trained with multicm's objective.

* :mod:`.voxel` -- voxel-grid input (numpy only);
* :mod:`.network` -- EV-FlowNet with a width multiplier (torch);
* :mod:`.numpynet` -- its trained finest flow in numpy (inference on the CPU, no torch);
* :mod:`.loss` -- the training loss: multicm's (4.9) as a ``torch.autograd.Function``;
* :mod:`.data`, :mod:`.train` -- simulated / recorded windows and the training loop
  (``evmotion train``);
* :mod:`.model` -- checkpoint files, the shipped default; :mod:`.folder` -- what a
  training folder holds;
* :mod:`.infer` -- :func:`estimate_flow_dnn` (``estimate_flow(..., method="dnn")``);
* :mod:`.planar`, :mod:`.tiles` -- what replaces the network's flow where multicm's
  objective prefers it: a plane's motion, or the flow refined on multicm's finest tiles;
  :mod:`.focus` (numpy twins of multicm's focus) and :mod:`.bfgs` serve both.

torch is an optional dependency (``pip install evmotion[dnn]``), for training, torch
checkpoints and GPUs; only the submodules that need it import it, and a window's flow on
the CPU with the shipped network needs none of them.
"""

from evmotion.catalog import MAX_CROP_SIDE, MAX_WIDTH, MIN_CROP_SIDE
from evmotion.methods.dnn.voxel import voxel_grid


def require_torch(feature: str = "the network (method 'dnn')") -> None:
    """Raise :class:`~evmotion.errors.MissingDependencyError` (one line: how to install)
    when PyTorch is absent; call it before importing a submodule that needs torch."""
    import importlib.util

    from evmotion.errors import MissingDependencyError

    if importlib.util.find_spec("torch") is None:
        raise MissingDependencyError("torch", feature, "dnn")


def estimate_flow_dnn(*args, **kwargs):
    """See :func:`evmotion.methods.dnn.infer.estimate_flow_dnn` (imports torch lazily)."""
    from evmotion.methods.dnn.infer import estimate_flow_dnn as fn

    return fn(*args, **kwargs)


__all__ = ["MAX_CROP_SIDE", "MAX_WIDTH", "MIN_CROP_SIDE", "estimate_flow_dnn", "require_torch",
           "voxel_grid"]
