"""Camera/CCD sensor model: scene radiance to digital numbers.

The model turns a float radiance image ``(H, W)`` or a stack ``(T, H, W)``
into the unsigned-integer frame a camera would record: photon shot noise,
full-well saturation, Gaussian read noise, a dark offset, analogue-to-digital
gain and quantisation to ``bits`` bits. :class:`IntensityScale` names the
grey-level scale frames are in (bit depth, and the exposure and gain a user
states), so that a calibration can tell frames of another scale.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from optitact._validate import check_keys, finite, integer, positive, real_array, seed_value
from optitact.errors import InputError, ShapeError

__all__ = ["CCD", "IntensityScale", "check_bit_depth", "dn_ratio"]

_BITS = (8, 10, 12, 16)
#: Bit depths a frame's grey levels may be stated in (integer frames up to uint16).
MAX_FRAME_BITS = 16
#: Largest full well (electrons): numpy's Poisson sampler takes means up to about 9e18, and
#: :meth:`CCD.expose` draws at most ``2 full_well + 1000``.
MAX_FULL_WELL = 1e18


@dataclass(frozen=True)
class CCD:
    r"""A CCD/CMOS camera that converts radiance to digital numbers (DN).

    Parameters
    ----------
    exposure : float, default 25000.0
        Photo-electrons per unit radiance per frame (exposure time, lens
        throughput and quantum efficiency folded into one factor), in
        electrons / radiance unit. Finite and > 0.
    full_well : float, default 20000.0
        Full-well capacity in electrons; the collected charge clips here
        before readout. Finite and > 0.
    read_noise : float, default 10.0
        Gaussian read noise in electrons rms. Finite and >= 0 (0 gives an
        ideal readout).
    dark_offset : float, default 4.0
        Bias added to every pixel, in DN. Finite and within
        ``[0, 2**bits - 1]``.
    bits : int, default 8
        ADC depth, one of 8, 10, 12, 16. Frames are ``uint8`` for 8 bits and
        ``uint16`` otherwise.
    gain : float or None, default None
        Conversion gain in DN per electron. ``None`` maps the full well onto
        the top of the ADC range, ``(2**bits - 1 - dark_offset) / full_well``
        (see `dn_per_electron`). Finite and > 0 when given.

    Raises
    ------
    TypeError
        If a field has the wrong kind (a bool, a string, a float ``bits``...).
    InputError
        If a field is not finite, not positive, ``bits`` is not one of
        8, 10, 12, 16, ``dark_offset`` lies outside ``[0, 2**bits - 1]``,
        ``full_well`` exceeds ``MAX_FULL_WELL`` (1e18), or the conversion
        gain, the largest DN or the DN variance of the model would overflow
        float64.

    See Also
    --------
    CCD.expose : Draw a noisy frame.
    CCD.mean_dn, CCD.variance_dn : The model's expected DN and its variance.

    Notes
    -----
    For a pixel with radiance :math:`L` the model draws, in electrons,

    .. math::

        n_e &\sim \mathrm{Poisson}(\kappa L), \\
        e &= \min(n_e, W) + \epsilon, \qquad
            \epsilon \sim \mathcal{N}(0, \sigma_r^2),

    with :math:`\kappa` = ``exposure``, :math:`W` = ``full_well`` and
    :math:`\sigma_r` = ``read_noise``, and records

    .. math::

        \mathrm{DN} = \mathrm{clip}\big(\mathrm{rint}(g\,e + o),\;
            0,\; 2^b - 1\big),

    with :math:`g` = `dn_per_electron`, :math:`o` = ``dark_offset`` and
    :math:`b` = ``bits``. With the default gain, :math:`g W + o = 2^b - 1`,
    so a saturated pixel reads :math:`2^b - 1` plus read noise, clipped from
    above: about half of saturated pixels read below the top code (by
    :math:`g \sigma_r` DN rms). A gain above the default leaves headroom so
    saturated pixels read exactly :math:`2^b - 1`.

    Examples
    --------
    >>> import numpy as np
    >>> from optitact.optics.ccd import CCD
    >>> ccd = CCD(bits=12)
    >>> frame = ccd.expose(np.full((4, 5), 0.2), seed=0)
    >>> frame.dtype, frame.shape
    (dtype('uint16'), (4, 5))
    >>> print(round(float(ccd.mean_dn(np.full((1, 1), 0.2))[0, 0]), 3))
    1026.75
    """

    exposure: float = 25000.0
    full_well: float = 20000.0
    read_noise: float = 10.0
    dark_offset: float = 4.0
    bits: int = 8
    gain: float | None = None

    def __post_init__(self) -> None:
        bits = integer(self.bits, "bits")
        if bits not in _BITS:
            raise InputError(f"bits must be one of {_BITS}, got {bits}")
        top = 2**bits - 1
        exposure = positive(self.exposure, "exposure")
        full_well = positive(self.full_well, "full_well")
        read_noise = positive(self.read_noise, "read_noise", allow_zero=True)
        dark_offset = positive(self.dark_offset, "dark_offset", allow_zero=True)
        if dark_offset > top:
            raise InputError(
                f"dark_offset must be in [0, {top}] DN for bits={bits}, got {self.dark_offset!r}"
            )
        gain = None if self.gain is None else positive(self.gain, "gain")
        if full_well > MAX_FULL_WELL:
            raise InputError(f"full_well must be at most {MAX_FULL_WELL:g} electrons, got {self.full_well!r}")
        g = (top - dark_offset) / full_well if gain is None else gain
        with np.errstate(over="ignore"):
            g64 = np.float64(g)
            extreme = (g64, g64 * (full_well + 10.0 * read_noise) + dark_offset,
                       g64 * g64 * (full_well + np.float64(read_noise) ** 2))
        if not all(np.isfinite(v) for v in extreme):
            raise InputError(
                f"gain {g!r} DN/electron with full_well={full_well!r} and read_noise={read_noise!r} "
                f"overflows float64 (the largest DN or its variance); use a smaller gain or full well"
            )
        # Store plain Python numbers so the config compares, hashes and
        # serialises the same whatever numeric types came in.
        for name, value in (
            ("exposure", exposure),
            ("full_well", full_well),
            ("read_noise", read_noise),
            ("dark_offset", dark_offset),
            ("bits", bits),
            ("gain", gain),
        ):
            object.__setattr__(self, name, value)

    # ------------------------------------------------------------------ #
    # Derived quantities
    # ------------------------------------------------------------------ #
    @property
    def dn_per_electron(self) -> float:
        """Effective conversion gain in DN per electron.

        ``gain`` when it was given, otherwise
        ``(2**bits - 1 - dark_offset) / full_well``, which maps the full well
        onto the top of the ADC range.
        """
        if self.gain is not None:
            return self.gain
        return (self._max_dn - self.dark_offset) / self.full_well

    @property
    def radiance_at_saturation(self) -> float:
        """Radiance at which the mean charge reaches the full well.

        Equal to ``full_well / exposure``, in the scene's radiance units.
        """
        return self.full_well / self.exposure

    @property
    def _max_dn(self) -> int:
        return 2**self.bits - 1

    @property
    def _dtype(self) -> type[np.unsignedinteger]:
        return np.uint8 if self.bits == 8 else np.uint16

    # ------------------------------------------------------------------ #
    # Model
    # ------------------------------------------------------------------ #
    def expose(self, radiance, *, seed: int | None = None) -> np.ndarray:
        r"""Draw a noisy frame for a radiance image or stack.

        Parameters
        ----------
        radiance : array_like, shape (H, W) or (T, H, W)
            Non-negative, finite scene radiance (real float or integer
            dtype). Not modified.
        seed : int or None, optional
            Seed for ``np.random.default_rng``; the same seed gives a
            bit-identical frame. ``None`` draws fresh entropy.

        Returns
        -------
        numpy.ndarray, shape like ``radiance``
            Digital numbers, ``uint8`` for 8 bits, ``uint16`` otherwise.

        Raises
        ------
        TypeError
            If ``radiance`` has a bool, complex, object or other non-real
            dtype, or ``seed`` is not an integer.
        ShapeError
            If ``radiance`` is not 2-D or 3-D.
        InputError
            If ``radiance`` holds NaN, infinity or a negative value, or
            ``seed`` is negative.

        Notes
        -----
        Per pixel, with the symbols of `CCD`:

        .. math::

            n_e \sim \mathrm{Poisson}(\kappa L), \quad
            e = \min(n_e, W) + \mathcal{N}(0, \sigma_r^2), \quad
            \mathrm{DN} = \mathrm{clip}(\mathrm{rint}(g e + o), 0, 2^b - 1).

        ``rint`` rounds half to even. A stack draws all its noise from one
        generator, so its frames are independent draws but are not equal to
        the frames one would get by exposing each slice with the same seed.

        Mean charges above :math:`2W + 1000` electrons are lowered to that
        value before the Poisson draw. Such a pixel saturates either way
        (the chance that it would fall below the full well is below
        :math:`e^{-790}`); the cap keeps numpy's sampler in range for any
        finite radiance.

        Examples
        --------
        >>> import numpy as np
        >>> ccd = CCD(bits=16)
        >>> a = ccd.expose(np.full((2, 3), 0.5), seed=1)
        >>> b = ccd.expose(np.full((2, 3), 0.5), seed=1)
        >>> bool(np.array_equal(a, b))
        True
        """
        lum = self._radiance(radiance)
        rng = np.random.default_rng(seed_value(seed))
        cap = 2.0 * self.full_well + 1000.0
        mean_e = np.minimum(lum, cap / self.exposure) * self.exposure
        electrons = rng.poisson(mean_e).astype(np.float64)
        np.minimum(electrons, self.full_well, out=electrons)
        electrons += rng.normal(0.0, self.read_noise, size=electrons.shape)
        dn = np.rint(self.dn_per_electron * electrons + self.dark_offset)
        np.clip(dn, 0, self._max_dn, out=dn)
        return dn.astype(self._dtype)

    def mean_dn(self, radiance) -> np.ndarray:
        r"""Expected DN of the model, ignoring ADC clipping and quantisation.

        Parameters
        ----------
        radiance : array_like, shape (H, W) or (T, H, W)
            Non-negative, finite scene radiance. Not modified.

        Returns
        -------
        numpy.ndarray of float64, shape like ``radiance``
            Expected digital number per pixel.

        Raises
        ------
        TypeError
            If ``radiance`` has a bool, complex, object or other non-real
            dtype.
        ShapeError
            If ``radiance`` is not 2-D or 3-D.
        InputError
            If ``radiance`` holds NaN, infinity or a negative value.

        Notes
        -----
        .. math::

            \mu_\mathrm{DN} = g \min(\kappa L, W) + o.

        This treats the full well as a hard limit on the mean and leaves out
        the clip of the ADC range and rounding. It is exact in the mean
        (up to rounding bias well below 1 DN) while the charge stays several
        :math:`\sqrt{\kappa L}` below the full well and the DN distribution
        stays clear of 0 and :math:`2^b - 1`; near saturation and where the
        read noise reaches 0 DN the recorded mean departs from it.

        Examples
        --------
        >>> import numpy as np
        >>> ccd = CCD(exposure=1000.0, full_well=10000.0, dark_offset=5.0, gain=0.01)
        >>> ccd.mean_dn(np.array([[0.0, 2.0, 50.0]]))
        array([[  5.,  25., 105.]])
        """
        lum = self._radiance(radiance)
        charge = np.minimum(lum, self.radiance_at_saturation) * self.exposure
        return self.dn_per_electron * charge + self.dark_offset

    def variance_dn(self, radiance) -> np.ndarray:
        r"""Variance of the recorded DN for pixels below saturation.

        Parameters
        ----------
        radiance : array_like, shape (H, W) or (T, H, W)
            Non-negative, finite scene radiance. Not modified.

        Returns
        -------
        numpy.ndarray of float64, shape like ``radiance``
            Variance per pixel, in DN squared.

        Raises
        ------
        TypeError
            If ``radiance`` has a bool, complex, object or other non-real
            dtype.
        ShapeError
            If ``radiance`` is not 2-D or 3-D.
        InputError
            If ``radiance`` holds NaN, infinity or a negative value.

        Notes
        -----
        Below saturation (:math:`\kappa L < W`):

        .. math::

            \sigma^2_\mathrm{DN} = g^2 (\kappa L + \sigma_r^2) + \tfrac{1}{12},

        shot noise plus read noise, scaled by the gain, plus the variance of
        uniform rounding error. The rounding term holds when the noise spans
        more than about 1 DN; the formula holds while the charge stays
        several :math:`\sqrt{\kappa L}` below the full well and the DN
        distribution stays clear of 0 and :math:`2^b - 1`.

        At and above saturation (:math:`\kappa L \ge W`) the full-well clip
        removes the shot noise and this returns
        :math:`g^2 \sigma_r^2 + 1/12`; the clip at the top of the ADC range,
        which the default gain reaches there, lowers the recorded variance
        further.

        Examples
        --------
        >>> import numpy as np
        >>> ccd = CCD(exposure=1000.0, read_noise=10.0, gain=0.5, bits=16)
        >>> print(round(float(ccd.variance_dn(np.array([[1.0]]))[0, 0]), 4))
        275.0833
        """
        lum = self._radiance(radiance)
        charge = np.minimum(lum, self.radiance_at_saturation) * self.exposure
        shot = np.where(charge < self.full_well, charge, 0.0)
        return self.dn_per_electron**2 * (shot + self.read_noise**2) + 1.0 / 12.0

    # ------------------------------------------------------------------ #
    # Serialisation
    # ------------------------------------------------------------------ #
    def to_dict(self) -> dict[str, Any]:
        """Return the configuration as a JSON-friendly dict.

        Returns
        -------
        dict
            One entry per field; ``gain`` is ``None`` when the default gain
            is in use, so ``CCD.from_dict(ccd.to_dict()) == ccd``.

        Examples
        --------
        >>> CCD(bits=12).to_dict()["bits"]
        12
        """
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> CCD:
        """Build a `CCD` from a dict such as the one `to_dict` returns.

        Parameters
        ----------
        d : Mapping
            Field names to values; missing fields take their defaults.

        Returns
        -------
        CCD
            The validated configuration.

        Raises
        ------
        TypeError
            If ``d`` is not a mapping, or a value has the wrong kind.
        InputError
            If ``d`` has a key that is not a field (the message lists the
            valid ones), or a value is out of range.

        Examples
        --------
        >>> CCD.from_dict({"bits": 10, "read_noise": 5.0}).bits
        10
        """
        return cls(**check_keys(d, [f.name for f in fields(cls)], "d (CCD fields)", noun="field"))

    # ------------------------------------------------------------------ #
    # Input checks
    # ------------------------------------------------------------------ #
    @staticmethod
    def _radiance(radiance) -> np.ndarray:
        """Validate a radiance image or stack and return it as float64."""
        arr = real_array(radiance, "radiance")
        if arr.ndim not in (2, 3):
            raise ShapeError(f"radiance must have shape (H, W) or (T, H, W), got shape {arr.shape}")
        finite(arr, "radiance")
        if arr.size and arr.min() < 0:
            low = float(arr.min())
            where = tuple(int(i) for i in np.unravel_index(np.argmin(arr), arr.shape))
            raise InputError(f"radiance must be >= 0, got minimum {low!r} at index {where}")
        return arr


# ---------------------------------------------------------------------------- intensity scale
def check_bit_depth(value, name: str) -> int:
    """A frame bit depth, checked: an integer from 1 to ``MAX_FRAME_BITS`` (16).

    Parameters
    ----------
    value : int
        The bit depth of a frame's grey levels (12 for 12-bit data in ``uint16`` frames).
    name : str
        What the value is called in the error message (e.g. ``"bits"``).

    Returns
    -------
    int
        ``value`` as an ``int``.

    Raises
    ------
    TypeError, InputError
        ``value`` is not an integer, or not from 1 to ``MAX_FRAME_BITS``.

    Examples
    --------
    >>> check_bit_depth(12, "bits")
    12
    """
    bits = integer(value, name)
    if not 1 <= bits <= MAX_FRAME_BITS:
        raise InputError(f"{name} must be a bit depth from 1 to {MAX_FRAME_BITS}, got {bits}")
    return bits


@dataclass(frozen=True)
class IntensityScale:
    """The grey-level scale of a camera's frames: bit depth, and the exposure and gain stated.

    Parameters
    ----------
    bits : int, default 8
        Bit depth of the frames' grey levels (1 to 16): they run from 0 to
        the full scale ``2**bits - 1``. 12-bit data stored in ``uint16``
        files is 12 here, not 16.
    exposure, gain : float, default 1.0
        The exposure and gain the frames were taken at, in the user's own
        units (e.g. milliseconds, a linear gain factor); finite and > 0. optitact
        only compares them: frames at another exposure or gain than a
        calibration's are refused, since the camera's response to them
        (offset, noise, saturation) is not known.

    Examples
    --------
    >>> IntensityScale(bits=12).full_scale
    4095
    >>> str(IntensityScale())
    '8-bit (full scale 255), exposure 1, gain 1'
    """

    bits: int = 8
    exposure: float = 1.0
    gain: float = 1.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "bits", check_bit_depth(self.bits, "bits"))
        object.__setattr__(self, "exposure", positive(self.exposure, "exposure"))
        object.__setattr__(self, "gain", positive(self.gain, "gain"))

    @property
    def full_scale(self) -> int:
        """The largest grey level, ``2**bits - 1``."""
        return 2**self.bits - 1

    def __str__(self) -> str:
        return (f"{self.bits}-bit (full scale {self.full_scale}), exposure {self.exposure:g}, "
                f"gain {self.gain:g}")

    def to_dict(self) -> dict[str, Any]:
        """The fields as a JSON-friendly dict."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> IntensityScale:
        """Build from :meth:`to_dict` output; missing fields take their defaults."""
        return cls(**check_keys(d, [f.name for f in fields(cls)], "intensity scale", noun="field"))


def dn_ratio(frame_bits: int, readings_bits: int) -> float:
    """Grey levels of ``frame_bits``-bit frames per grey level of ``readings_bits``-bit ones.

    The ratio of the full scales, ``(2**frame_bits - 1) / (2**readings_bits - 1)``,
    accepted only when one full scale is a whole multiple of the other: 1 for
    equal depths, 257 for 16-bit frames of an 8-bit scale (``65535 = 257 x
    255``, how 8-bit images are widened to 16 bits) and 1/257 the other way.
    Any other pair (12-bit frames for 8-bit readings: 4095 / 255 = 16.06)
    depends on how the camera's ADC maps its charge and is refused.

    Raises
    ------
    InputError
        When the two full scales are not whole multiples of each other; the
        message names both.

    Examples
    --------
    >>> dn_ratio(16, 8), dn_ratio(12, 12)
    (257.0, 1.0)
    """
    hi, lo = 2**check_bit_depth(frame_bits, "frame bits") - 1, 2**check_bit_depth(readings_bits, "bits") - 1
    if hi % lo == 0:
        return float(hi // lo)
    if lo % hi == 0:
        return 1.0 / (lo // hi)
    raise InputError(
        f"{frame_bits}-bit frames (full scale {hi}) cannot be mapped exactly onto the {readings_bits}-bit "
        f"scale (full scale {lo}) the readings must be in: their ratio {hi / lo:.4g} is not a whole "
        f"number, and how the camera's ADC maps charge at either depth is not known. Use frames of "
        f"{readings_bits} bits, or a calibration made for {frame_bits}-bit frames")
