"""Textures for the simulator: periodic rasters of log intensity.

A texture is a raster of **natural-log intensity** (float32, shape ``(Ht, Wt)``) that the
renderer samples bilinearly with periodic wrap-around, so a scene can move arbitrarily far
without running out of texture. Reference coordinates are sensor pixels at the scene's
reference time; the raster's pixel ``(0, 0)`` sits at reference pixel ``(-ox, -oy)``
(``origin``), leaving a margin around the sensor before the texture repeats.

Intensities are kept within ``[0.15, 1]`` (log in ``[-1.9, 0]``): real sensors clip dark
pixels, and the contrast range keeps event counts realistic.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from evmotion.errors import FormatError, ParameterError
from evmotion.io.pngfile import read_png
from evmotion.utils import whole_number

__all__ = ["TEXTURES", "Texture", "make_texture", "texture_from_image"]

I_MIN = 0.15  # darkest intensity (relative): log contrast up to ~1.9, as a real scene


@dataclass(frozen=True, eq=False)
class Texture:
    """A periodic log-intensity raster, optionally with an opacity (alpha) raster.

    Attributes
    ----------
    log_i : ndarray (Ht, Wt) float32
        Natural log of the intensity (relative units, max 0).
    alpha : ndarray (Ht, Wt) float32 or None
        Opacity in [0, 1] for layers drawn over others (None: opaque).
    origin : (float, float)
        Reference pixel ``(x, y)`` of raster pixel ``(0, 0)``.
    name : str
    """

    log_i: np.ndarray
    alpha: np.ndarray | None
    origin: tuple[float, float]
    name: str

    @property
    def shape(self) -> tuple[int, int]:
        return self.log_i.shape


def _to_log(img: np.ndarray) -> np.ndarray:
    """Map an image with values in [0, 1] to clipped log intensity."""
    img = np.clip(np.asarray(img, dtype=np.float64), 0.0, 1.0)
    return np.log(I_MIN + (1.0 - I_MIN) * img).astype(np.float32)


def _grid(shape):
    ys, xs = np.mgrid[0:shape[0], 0:shape[1]]
    return xs.astype(np.float64), ys.astype(np.float64)


def _blur121(img: np.ndarray) -> np.ndarray:
    """Periodic [1, 2, 1] / 4 blur along both axes: softens sharp edges for bilinear
    sampling and keeps constant regions exactly constant (the renderer skips those)."""
    for axis in (0, 1):
        img = 0.25 * np.roll(img, 1, axis=axis) + 0.5 * img + 0.25 * np.roll(img, -1, axis=axis)
    return img


def dots(shape, seed: int, density: float = 0.0008, radius=(1.5, 4.0)) -> np.ndarray:
    """Random bright dots on a dark background, values in [0, 1] (periodic)."""
    rng = np.random.default_rng(seed)
    h, w = shape
    n = max(1, int(density * h * w))
    cx = rng.uniform(0, w, n)
    cy = rng.uniform(0, h, n)
    r = rng.uniform(*radius, n)
    amp = rng.uniform(0.5, 1.0, n)
    img = np.zeros(shape)
    xs, ys = _grid(shape)
    for i in range(n):
        x0, x1 = int(cx[i] - r[i] - 2), int(cx[i] + r[i] + 3)
        y0, y1 = int(cy[i] - r[i] - 2), int(cy[i] + r[i] + 3)
        yy = np.arange(y0, y1) % h
        xx = np.arange(x0, x1) % w
        dx = np.arange(x0, x1)[None, :] - cx[i]
        dy = np.arange(y0, y1)[:, None] - cy[i]
        # soft edge of ~1 px: sharp enough to fire events, smooth enough to sample
        v = amp[i] * np.clip(r[i] + 0.5 - np.hypot(dx, dy), 0.0, 1.0)
        sub = img[np.ix_(yy, xx)]
        img[np.ix_(yy, xx)] = np.maximum(sub, v)
    return img


def shapes(shape, seed: int, n: int | None = None) -> np.ndarray:
    """Random rectangles and discs of random grey levels (edges), values in [0, 1]."""
    rng = np.random.default_rng(seed)
    h, w = shape
    n = n if n is not None else max(4, h * w // 2500)
    img = np.full(shape, 0.5)
    for _ in range(n):
        cx, cy = rng.uniform(0, w), rng.uniform(0, h)
        size = rng.uniform(8, 40)
        level = rng.uniform(0.0, 1.0)
        # draw within the bounding box only, wrapping around the periodic raster
        ext = int(size * 1.2) + 2
        xx = np.arange(int(cx) - ext, int(cx) + ext + 1)
        yy = np.arange(int(cy) - ext, int(cy) + ext + 1)
        dx = (xx - cx)[None, :]
        dy = (yy - cy)[:, None]
        if rng.random() < 0.5:
            ang = rng.uniform(0, np.pi)
            u = dx * np.cos(ang) + dy * np.sin(ang)
            v = -dx * np.sin(ang) + dy * np.cos(ang)
            inside = np.minimum(size - np.abs(u), 0.6 * size - np.abs(v))
        else:
            inside = size - np.hypot(dx, dy)
        a = np.clip(inside + 0.5, 0.0, 1.0)
        ix = np.ix_(yy % h, xx % w)
        img[ix] = a * level + (1 - a) * img[ix]
    return img


def noise(shape, seed: int, beta: float = 2.0) -> np.ndarray:
    """1/f^(beta/2) amplitude ("natural image") noise, periodic, values in [0, 1]."""
    rng = np.random.default_rng(seed)
    ky = np.fft.fftfreq(shape[0])[:, None]
    kx = np.fft.fftfreq(shape[1])[None, :]
    k = np.hypot(kx, ky)
    k[0, 0] = 1.0
    spec = (rng.normal(size=shape) + 1j * rng.normal(size=shape)) / k ** (beta / 2)
    spec[0, 0] = 0.0
    img = np.real(np.fft.ifft2(spec))
    img = (img - img.mean()) / (img.std() + 1e-12)
    return np.clip(0.5 + 0.1 * img, 0.0, 1.0)


def checker(shape, seed: int, square: int = 32) -> np.ndarray:
    """Checkerboard with ``square``-pixel squares (adjusted to tile the raster), random phase."""
    rng = np.random.default_rng(seed)
    h, w = shape
    sy = h / max(1, round(h / square))
    sx = w / max(1, round(w / square))
    xs, ys = _grid(shape)
    ph = rng.integers(0, 2)
    c = (np.floor(xs / sx) + np.floor(ys / sy) + ph) % 2
    return _blur121(0.3 + 0.4 * c)


TEXTURES = {"dots": dots, "shapes": shapes, "noise": noise, "checker": checker}


def _load_image(path: str | Path) -> np.ndarray:
    path = Path(path)
    if not path.is_file():
        raise FormatError(path, "image not found")
    suffix = path.suffix.lower()
    if suffix == ".npy":
        return _unit_range(np.load(path))
    if suffix == ".png":
        arr, info = read_png(path, what="cannot decode PNG")
        return arr.astype(np.float64) / (2 ** info["bitdepth"] - 1)
    try:
        import matplotlib.image as mpimg

        return np.asarray(mpimg.imread(path), dtype=np.float64)
    except Exception as exc:
        raise FormatError(path, f"cannot read image: {exc}",
                          hint="use a PNG, JPEG (with Pillow) or .npy array") from None


def _unit_range(image) -> np.ndarray:
    """An image array as float64, uint8 and uint16 divided by their type's range (a uint16
    image of 8-bit data, k * 257, reads as the uint8 one); others as they are."""
    arr = np.asarray(image)
    if arr.dtype.kind == "u" and arr.itemsize <= 2:
        return arr.astype(np.float64) / np.iinfo(arr.dtype).max
    return arr.astype(np.float64)


def texture_from_image(image, shape: tuple[int, int], origin: tuple[float, float],
                       name: str = "image") -> Texture:
    """Texture from a grey or RGB image (path or array).

    uint8 and uint16 arrays are read on their type's range (0-255, 0-65535); other
    arrays on [0, 1] or, beyond 1, as 8-bit levels when their values are whole numbers up
    to 255 and else as relative radiance (divided by their maximum). Negative values are refused. The image
    is resized (nearest-neighbour index mapping after a light blur) to the raster
    ``shape`` and made periodic by mirroring, so the wrap-around has no seam.

    Examples
    --------
    >>> a = np.array([[10, 200], [40, 90]], np.uint8)
    >>> b = texture_from_image(a, (4, 4), (0.0, 0.0))
    >>> c = texture_from_image(a.astype(np.uint16) * 257, (4, 4), (0.0, 0.0))
    >>> bool(np.array_equal(b.log_i, c.log_i))
    True
    """
    src = str(image) if isinstance(image, (str, Path)) else "array"
    arr = _load_image(image) if isinstance(image, (str, Path)) else _unit_range(image)
    if arr.ndim == 3:
        arr = arr[..., :3].mean(axis=-1) if arr.shape[-1] >= 3 else arr[..., 0]
    if arr.ndim != 2 or min(arr.shape) < 2:
        raise ParameterError(f"texture image {src} must be a 2-D grey or RGB image, "
                             f"got shape {np.shape(arr)}")
    if not np.all(np.isfinite(arr)):
        raise ParameterError(f"texture image {src} contains NaN or inf")
    if arr.min() < 0:
        raise ParameterError(f"texture image {src} holds negative values (down to "
                             f"{arr.min():.3g}): an image is a radiance, >= 0")
    if arr.max() > 1.0:
        # a float image beyond [0, 1]: 8-bit levels, or a radiance in its own unit (one in
        # [1.1, 8.1] divided by 255 lost its contrast in the log's dark floor, probe AU)
        whole = arr.max() <= 255 and np.all(arr == np.round(arr))
        arr = arr / 255.0 if whole else arr / arr.max()
    # mirror to a periodic image twice the size, then resample to the raster
    per = np.block([[arr, arr[:, ::-1]], [arr[::-1, :], arr[::-1, ::-1]]])
    h, w = shape
    iy = (np.arange(h) * per.shape[0] / h).astype(int)
    ix = (np.arange(w) * per.shape[1] / w).astype(int)
    img = per[np.ix_(iy, ix)]
    return Texture(_to_log(img), None, origin, name)


def make_texture(name: str, shape: tuple[int, int], origin: tuple[float, float],
                 seed: int = 0) -> Texture:
    """Build a named texture raster.

    Parameters
    ----------
    name : str
        One of :data:`TEXTURES`: ``dots`` (random dots), ``shapes`` (rectangles and discs,
        i.e. edges), ``noise`` (1/f natural-like), ``checker``.
    shape : (int, int)
        Raster ``(height, width)``.
    origin : (float, float)
        Reference pixel ``(x, y)`` of raster pixel (0, 0).
    seed : int
        Random seed (same seed, same texture).

    Examples
    --------
    >>> tex = make_texture("checker", (64, 96), origin=(-8.0, -8.0), seed=0)
    >>> tex.log_i.shape, tex.log_i.dtype.name
    ((64, 96), 'float32')
    """
    if name not in TEXTURES:
        raise ParameterError(f"unknown texture '{name}'; choose one of {sorted(TEXTURES)} "
                             "or pass an image (path or array)")
    seed = whole_number("seed", seed, lo=0)  # (1e30, NaN or -1 reached numpy; probe API)
    return Texture(_to_log(TEXTURES[name](tuple(shape), seed)), None, origin, name)
