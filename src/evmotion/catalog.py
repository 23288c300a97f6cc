"""Names of the library's choices, for command-line parsers and documentation.

Importing this module loads nothing beyond the standard library (no numpy, numba or
scipy), so that a parser offering these choices (``evmotion egomotion --help``) does not
load the numerical core. The registries named below are the truth; ``tests/test_catalog.py``
checks each tuple against its registry, so a warp or objective added there and not here
fails the suite.

Examples
--------
>>> "rotation" in WARP_NAMES
True
"""

from __future__ import annotations

__all__ = ["FORMAT_NAMES", "HOT_NEIGHBOUR_RATIO", "MAX_CROP_SIDE", "MAX_EPOCHS", "MAX_LR",
           "MAX_MISMATCH", "MAX_PIXEL_RATE", "MAX_REFRACTORY_US", "MAX_SIM_DURATION_S",
           "MAX_SIM_SIDE", "MAX_TRAIN_SEED", "MIN_EVENT_PHOTONS", "MIN_SIM_SIDE",
           "MIN_THRESHOLD", "MAX_WIDTH", "VAL_SEED_BASE",
           "MIN_CROP_SIDE", "OBJECTIVE_NAMES", "WARP_NAMES", "WEIGHT_DATASETS"]

#: Event formats the readers know, in detection order (names of
#: :func:`evmotion.io.registry.all_formats`).
FORMAT_NAMES: tuple[str, ...] = ("h5", "mvsec", "dsec", "ecd", "ccs", "npy", "mat", "aedat4",
                                 "aedat2", "aedat3", "evt3", "evt2", "evt21", "dat", "rosbag",
                                 "h5generic")

#: Warps :func:`evmotion.core.warps.make_warp` builds (keys of
#: :data:`evmotion.core.warps.WARPS`).
WARP_NAMES: tuple[str, ...] = ("zoom", "translation", "rotation", "se2", "inplane",
                               "similarity", "affine", "homography")

#: Focus objectives (keys of :data:`evmotion.core.objectives.OBJECTIVES`).
OBJECTIVE_NAMES: tuple[str, ...] = ("variance", "gradient_magnitude", "avg_timestamp",
                                    "avg_timestamp_norm")

#: Data sets with thesis regularizer weights, Sec. 3.6.1 (keys of
#: :data:`evmotion.core.collapse.DEFAULT_WEIGHTS`).
WEIGHT_DATASETS: tuple[str, ...] = ("mvsec", "dsec", "ecd")

#: The widest network :class:`evmotion.methods.dnn.network.EVFlowNet` builds: 4x the
#: paper's EV-FlowNet (~225 M parameters); a wider one only exhausts the memory.
MAX_WIDTH = 4.0
#: Largest side of a simulated sensor, px (``evmotion simulate --size``): the simulator
#: renders float64 frames of this size.
MAX_SIM_SIDE = 4096
#: Smallest side of a simulated sensor, px (the motion simulator's; schlieren scenes need 8).
MIN_SIM_SIDE = 2
#: Longest simulated recording, s (``evmotion simulate --duration``).
MAX_SIM_DURATION_S = 3600.0
#: Largest side of a training crop, px: the simulator renders each training window at the
#: crop's size.
MAX_CROP_SIDE = MAX_SIM_SIDE
#: Smallest side of a training crop, px: a 16-px crop is 1 px at the network's coarsest
#: level and rarely keeps the events a training window needs.
MIN_CROP_SIDE = 32
#: The most events a simulated pixel fires per second: one a microsecond (the timestamps'
#: unit).
MAX_PIXEL_RATE = 1e6
#: The largest learning rate a training of the network takes.
MAX_LR = 1.0
#: Smallest contrast threshold the simulators take, log intensity (0.1 % contrast, 100x
#: below any sensor's): each crossing is an event and each sample moves at most half a
#: threshold, so 1e-30 never ended (probe OPT).
MIN_THRESHOLD = 1e-3
#: Largest relative std of the simulators' per-pixel thresholds.
MAX_MISMATCH = 1.0
#: Longest refractory period the simulators take, µs (10 s).
MAX_REFRACTORY_US = 10_000_000
#: Fewest photons of a white event pixel per time constant (the schlieren simulator's
#: low light): 0.1 already makes about 20,000 noise events per pixel and second; 1e-30
#: never ended (probe OPT).
MIN_EVENT_PHOTONS = 0.1
#: Seeds of the network's validation windows start here; its training windows' seeds are
#: ``seed * 1e6 + epoch * 1e4 + i`` (``i`` < 1e4) and stay below.
VAL_SEED_BASE = 2_000_000_000
#: Training seeds below this keep the training windows' seeds under VAL_SEED_BASE.
MAX_TRAIN_SEED = VAL_SEED_BASE // 1_000_000
#: Most training epochs: with more, epoch 100's windows would be the next seed's epoch 0
#: (and the last seed's the validation windows).
MAX_EPOCHS = 100
#: Most time bins of multicm's time-aware flow: the thesis uses 5 (40 from 640 px wide);
#: each bin holds a flow field and an IWE per reference, so memory grows with them.
MAX_TIME_BINS = 200
#: Most worker processes a command starts (``--workers``); no more than it has windows.
MAX_WORKERS = 256

#: A hot pixel, for the commands and the network (:func:`evmotion.filters.hot_pixel_mask`'s
#: ``neighbour_ratio``): more than this many times the events of each of its neighbours.
HOT_NEIGHBOUR_RATIO = 4.0
#: Largest sensor side (pixels) a header may declare: today's largest event sensors are
#: 1280x720 (Prophesee IMX636) and 1920x1080 (Samsung); 16384 leaves room while keeping a
#: per-pixel float32 image of a corrupt header's sensor under 1 GiB.
MAX_SENSOR_SIDE = 16384

#: Integer times above this, read as µs, lie past the year 5000: they are nanoseconds since
#: the epoch (1e17 ns is 1973), as ROS, Metavision exports and event_utils write them.
NS_EPOCH_US = 10 ** 17
