"""Fitted calibration curves: normal force g(G) and shear f(u) per element, saved as JSON.

Models
------
``"ohka"`` -- the sensor's published form, per element ``i``::

    Fz = g_i(G),   Fx = f_i(ux),   Fy = f_i(uy)

``"coupled"`` -- the shear curve depends on the normal load, and the normal
curve on where the light comes from::

    Fz = g_i(G) + s (p_i . u / u_scale),   (Fx, Fy) = (ux, uy) * Fz / (a_i + b_i sqrt(Fz))

with ``s = G / G_scale``. The second term is the brightness gradient across
the element: the dome is lit from its rim, so a cone nearer the rim gives a
brighter spot for the same load, and a tilted feeler (which moves load, and
the centroid, towards one side) changes G at equal Fz -- by up to +-10 % on
the 45-degree ring of the default sensor.

Why the coupled form: the columnar feeler is rigid, so moment balance on the
cones gives ``sum_k P_k r_k = h F_t`` (``h`` the lever arm), and a cone's
contact area, hence its grey value, is proportional to its load (Sneddon,
``A = 2 P tan(alpha) / E*``); the grey-value centroid of the tilted feeler
is therefore ``sum P_k r_k / sum P_k = h F_t / F_z``. The patches also slide
by ``F_t / sum k_k`` with Mindlin stiffness ``k = 8 G* a`` and ``a ~ sqrt(P)``,
i.e. by about ``c F_t / sqrt(F_z)``. Together ``u = F_t (h / F_z + c /
sqrt(F_z))``, which inverts to the form above with ``a ~ h`` and ``b ~ c``.
A curve ``f(u)`` alone cannot represent this: the same shift means twice the
shear at twice the normal load.

Both models use ``g_i(G) = c0 + c1 s + c2 s^2 + c3 s^3`` (``s = G / G_scale``)
with all ``c >= 0``, so g increases with G; ``f_i(u) = d1 t + d3 t^3``
(``t = u / u_scale``), ``d >= 0``, odd and increasing; ``a, b >= 0``. Fits are
bounded linear or non-linear least squares (SciPy) on scaled inputs.
Outside the fitted range (G above the largest fitted G, |u| beyond the
largest fitted shift) readings are clamped to the range and flagged.

Intensity scale
---------------
G is in the grey levels of the frames the curves were fitted on, so a
calibration records their :class:`~optitact.ccd.IntensityScale`: the bit
depth (``intensity.bits``; the set's CCD when fitted from a calibration set,
8 for files written before the field existed) and the exposure and gain the
user states (default 1). :meth:`Calibration.pipeline` maps frames of another
depth exactly (16-bit frames that widen 8-bit ones, x 257) or refuses them,
and refuses another exposure or gain.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from optitact.camera import FisheyeCamera
from optitact._validate import check_keys, check_type
from optitact.ccd import IntensityScale
from optitact.errors import InputError, ShapeError
from optitact.io import atomic_write_text, json_fingerprint
from optitact.readings import Readings
from optitact.sensor import DomeSensor

__all__ = ["MODELS", "Calibration", "CalibrationMismatchError", "fingerprint", "fit"]

MODELS = ("ohka", "coupled")
SCHEMA = "optitact.calibration"
SCHEMA_VERSION = 1
#: Largest calibration file read (bytes); a calibration of 41 elements is ~20 kB.
MAX_FILE_BYTES = 5_000_000
#: Smallest relative spread (``ptp / max |x|``) of G, u and Fz a fit accepts; a narrower range
#: leaves the cubic g(G) and the shear curve ill-conditioned.
MIN_RELATIVE_SPREAD = 1e-6
#: Pipeline options a calibration file may hold.
PIPELINE_KEYS = ("method", "filter", "filter_size", "noise_sigma", "k", "min_pixels", "saturation",
                 "radius", "grid_mm")
_G_TERMS = 4
_F_TERMS = {"ohka": 2, "coupled": 2}


class CalibrationMismatchError(InputError):
    """A calibration was made for another sensor, camera or pipeline."""


def fingerprint(sensor: DomeSensor, camera: FisheyeCamera, pipeline_options: dict,
                intensity: IntensityScale | None = None) -> str:
    """Short hash of the sensor, camera, pipeline options and intensity scale a calibration belongs to.

    The default scale (8-bit, exposure 1, gain 1) is left out of the hash, so
    that calibrations written before the scale was recorded keep their
    fingerprint.
    """
    check_type(sensor, DomeSensor, "sensor")
    check_type(camera, FisheyeCamera, "camera")
    doc = {"sensor": sensor.to_dict(), "camera": camera.to_dict(), "pipeline": _plain(pipeline_options)}
    if intensity is not None and check_type(intensity, IntensityScale, "intensity") != IntensityScale():
        doc["intensity"] = intensity.to_dict()
    return json_fingerprint(doc, 16)


def _plain(options: dict) -> dict:
    """Pipeline options as plain JSON values (drops None, which means 'default')."""
    return {k: v for k, v in sorted(options.items()) if v is not None and k != "baseline"}


def _resolved(sensor: DomeSensor, camera: FisheyeCamera, options: dict) -> dict:
    """Pipeline options with the region geometry made explicit.

    The default region radius and dewarp cell size are derived from the
    sensor and camera; storing the values used keeps a calibration valid
    even if a later version derives other defaults.
    """
    from optitact.pipeline import Pipeline

    plain = _plain(options)
    pipe = Pipeline(sensor, camera, **plain)
    return plain | {"radius": pipe.grids.radius, "grid_mm": pipe.grids.grid_mm}


def _g_design(s: np.ndarray) -> np.ndarray:
    return np.stack([np.ones_like(s), s, s**2, s**3], axis=-1)


def _f_ohka(t: np.ndarray, d: np.ndarray) -> np.ndarray:
    return d[0] * t + d[1] * t**3


def _shear_coupled(u: np.ndarray, fz: np.ndarray, p: np.ndarray) -> np.ndarray:
    return u * (fz / (p[0] + p[1] * np.sqrt(fz)))[..., None]


@dataclass(frozen=True, eq=False)
class Calibration:
    """Per-element calibration curves for one sensor, camera and pipeline.

    Attributes
    ----------
    model : {"ohka", "coupled"}
    sensor, camera : DomeSensor, FisheyeCamera
    pipeline_options : dict
        Options of :class:`optitact.Pipeline` the readings were made with.
    g : (E, 4) ndarray
        Normal-force coefficients on ``s = G / g_scale`` (N).
    g_scale : (E,) ndarray
    f : (E, 2) ndarray
        Shear coefficients: ``(d1, d3)`` on ``t = u / u_scale`` (ohka) or
        ``(a, b)`` (coupled).
    u_scale : (E,) ndarray
    g_max : (E,) ndarray
        Largest fitted G per element; above it G is clamped.
    u_max : (E,) ndarray
        Largest fitted ``|u|`` per element (mm); beyond it u is clamped.
    gu : (E, 2) ndarray
        Coupled model: the brightness gradient across the element, ``Fz =
        g(G) + s (gu . u / u_scale)`` (zero for ohka).
    residuals : dict
        ``{"fx", "fy", "fz"}`` -> (E,) RMS fit residuals (N), and ``"n"``
        -> (E,) samples per element.
    provenance : dict
        Where the samples came from.
    intensity : IntensityScale
        The grey-level scale of the frames the readings came from (default
        8-bit, exposure 1, gain 1).
    """

    model: str
    sensor: DomeSensor
    camera: FisheyeCamera
    pipeline_options: dict
    g: np.ndarray
    g_scale: np.ndarray
    f: np.ndarray
    u_scale: np.ndarray
    g_max: np.ndarray
    u_max: np.ndarray
    gu: np.ndarray
    residuals: dict = field(default_factory=dict)
    provenance: dict = field(default_factory=dict)
    intensity: IntensityScale = field(default_factory=IntensityScale)

    def __post_init__(self) -> None:
        check_type(self.intensity, IntensityScale, "intensity")

    @property
    def fingerprint(self) -> str:
        """Hash of the sensor, camera, pipeline options and intensity scale (see :func:`fingerprint`)."""
        return fingerprint(self.sensor, self.camera, self.pipeline_options, self.intensity)

    def __repr__(self) -> str:
        cam = self.camera
        res = ", ".join(f"{k} {np.median(self.residuals[k]):.3g}/{np.max(self.residuals[k]):.3g}"
                        for k in ("fx", "fy", "fz") if np.size(self.residuals.get(k, [])))
        return (f"<Calibration {self.model!r}: {len(self.g)} elements, {cam.width}x{cam.height} frames, "
                f"{self.intensity}, fingerprint {self.fingerprint}; fit residuals (N, median/max): "
                f"{res or 'none recorded'}>")

    __str__ = __repr__

    # ------------------------------------------------------------------ fitting
    @classmethod
    def fit(cls, readings: Readings, forces, *, sensor: DomeSensor, camera: FisheyeCamera,
            pipeline_options: dict | None = None, model: str = "coupled",
            provenance: dict | None = None, intensity: IntensityScale | None = None) -> Calibration:
        """Fit the curves to readings and the true (measured) forces that made them.

        Parameters
        ----------
        readings : Readings
            Stack readings ``(T, E)`` (from :meth:`optitact.Pipeline.process`).
        forces : (T, E, 3) array_like
            Element-local forces (N) applied in each frame.
        sensor, camera : DomeSensor, FisheyeCamera
            What the frames came from.
        pipeline_options : dict, optional
            The pipeline options used for the readings (stored).
        model : {"ohka", "coupled"}
        provenance : dict, optional
            Stored as is (e.g. the set's path and seed).
        intensity : IntensityScale, optional
            The grey-level scale of the frames the readings came from
            (default: 8-bit, exposure 1, gain 1). State it for frames of
            another depth, e.g. ``IntensityScale(bits=12)``.

        Raises
        ------
        TypeError
            ``readings`` are not stack readings, or ``forces`` is not a real
            numeric array.
        InputError
            Unknown model; fewer than 8 usable samples for an element, fewer
            than 4 distinct G values (duplicate points), no spread (or a
            relative spread below ``MIN_RELATIVE_SPREAD``: ill-conditioned) in
            G, u or Fz, no shear at all, or non-finite data.
        ShapeError
            ``forces`` does not match the readings.
        """
        from scipy.optimize import least_squares, lsq_linear

        intensity = IntensityScale() if intensity is None else check_type(intensity, IntensityScale,
                                                                          "intensity")
        if model not in MODELS:
            raise InputError(f"model must be one of {MODELS}, got {model!r}")
        if not isinstance(readings, Readings) or not readings.is_stack:
            raise TypeError("readings must be stack Readings (T, E) from Pipeline.process(stack)")
        try:
            f = np.asarray(forces)
        except ValueError as exc:
            raise TypeError(f"forces must be an array (T, E, 3); could not make one ({exc})") from None
        if f.dtype.kind not in "iuf":
            raise TypeError(f"forces must be a real numeric array (N), got dtype {f.dtype}")
        f = f.astype(np.float64)
        t_n, n_el = readings.G.shape
        if f.shape != (t_n, n_el, 3):
            raise ShapeError(f"forces must have shape {(t_n, n_el, 3)} to match the readings, "
                             f"got {f.shape}")
        if not np.isfinite(f).all():
            raise InputError("forces must be finite")
        if n_el != sensor.n_elements:
            raise ShapeError(f"readings have {n_el} elements, the sensor {sensor.n_elements}")
        _check_readings(readings)
        g_c = np.zeros((n_el, _G_TERMS))
        gu = np.zeros((n_el, 2))
        f_c = np.zeros((n_el, 2))
        g_scale, u_scale = np.ones(n_el), np.ones(n_el)
        g_max, u_max = np.zeros(n_el), np.zeros(n_el)
        res = {"fx": np.zeros(n_el), "fy": np.zeros(n_el), "fz": np.zeros(n_el),
               "n": np.zeros(n_el, int)}
        for e in range(n_el):
            ok = readings.contact[:, e] & ~readings.saturated[:, e]
            G, u, fe = readings.G[ok, e], readings.u[ok, e], f[ok, e]
            if len(G) < 8:
                raise InputError(f"element {e}: {len(G)} usable samples (in contact, not "
                                 f"saturated); a fit needs at least 8")
            if np.ptp(G) <= 0 or np.ptp(u) <= 0:
                raise InputError(f"element {e}: the readings do not vary (constant G or u); "
                                 f"the loads must span a range")
            n_distinct = len(np.unique(G))
            if n_distinct < _G_TERMS:
                raise InputError(f"element {e}: {n_distinct} distinct G values (duplicate points); "
                                 f"the cubic g(G) needs at least {_G_TERMS}")
            _check_spread(G, f"element {e}: G")
            _check_spread(u, f"element {e}: u")
            _check_spread(fe[:, 2], f"element {e}: the normal forces Fz")
            if not np.any(fe[:, :2]):
                raise InputError(f"element {e}: no sample has shear (Fx = Fy = 0 throughout); the "
                                 f"shear curve needs loads with shear")
            g_scale[e] = G.max()
            s = G / g_scale[e]
            g_max[e] = G.max()
            radius = np.hypot(u[:, 0], u[:, 1])
            u_max[e] = radius.max()
            u_scale[e] = u_max[e]
            design = _g_design(s)
            if model == "coupled":  # + the brightness gradient across the element
                design = np.concatenate([design, s[:, None] * u / u_scale[e]], axis=1)
            lo = np.r_[np.zeros(_G_TERMS), np.full(design.shape[1] - _G_TERMS, -np.inf)]
            sol = lsq_linear(design, fe[:, 2], bounds=(lo, np.inf), method="bvls")
            # BVLS can return a bound-active coefficient a rounding error below 0 (-5.6e-17 seen).
            g_c[e] = np.maximum(sol.x[:_G_TERMS], 0.0)
            gu[e] = sol.x[_G_TERMS:] if model == "coupled" else 0.0
            fz_hat = np.maximum(design @ np.r_[g_c[e], sol.x[_G_TERMS:]], 0.0)
            if model == "ohka":
                tt = (u / u_scale[e]).reshape(-1)
                a = np.stack([tt, tt**3], axis=-1)
                f_c[e] = np.maximum(lsq_linear(a, fe[:, :2].reshape(-1), bounds=(0.0, np.inf), method="bvls").x,
                                    0.0)
                shear = _f_ohka(u / u_scale[e], f_c[e])
            else:
                fzp = np.maximum(fz_hat, 1e-9)

                def resid(p, u=u, fzp=fzp, target=fe[:, :2]):
                    return (_shear_coupled(u, fzp, p) - target).reshape(-1)

                # Start from the linear problem u Fz = F_t (a + b sqrt(Fz)) (exact on exact data),
                # then minimise the shear residuals themselves.
                ft = fe[:, :2].reshape(-1)
                lin = np.stack([ft, ft * np.repeat(np.sqrt(fzp), 2)], axis=-1)
                x0 = lsq_linear(lin, (u * fzp[:, None]).reshape(-1), bounds=([1e-6, 0.0], np.inf),
                                method="bvls").x
                h0 = max(sensor.lever_arm, 1e-3)
                scale = [max(x0[0], 1e-6), max(x0[1], 1e-3 * x0[0], 1e-6)] if x0[0] > 1e-6 else [h0, h0]
                sol2 = least_squares(resid, x0=x0, bounds=([1e-6, 0.0], [np.inf, np.inf]), x_scale=scale,
                                     ftol=1e-12, xtol=1e-12, gtol=1e-12)
                f_c[e] = sol2.x
                shear = _shear_coupled(u, fzp, sol2.x)
            res["fz"][e] = math.sqrt(np.mean((fz_hat - fe[:, 2]) ** 2))
            res["fx"][e] = math.sqrt(np.mean((shear[:, 0] - fe[:, 0]) ** 2))
            res["fy"][e] = math.sqrt(np.mean((shear[:, 1] - fe[:, 1]) ** 2))
            res["n"][e] = len(G)
        return cls(model, sensor, camera, _resolved(sensor, camera, pipeline_options or {}),
                   g_c, g_scale, f_c,
                   u_scale, g_max, u_max, gu, res, dict(provenance or {}), intensity)

    # ------------------------------------------------------------------ applying
    def pipeline(self, *, baseline=None, method: str = "fast", bits: int | None = None,
                 exposure: float | None = None, gain: float | None = None):
        """The :class:`optitact.Pipeline` these curves expect (same sensor, camera, options, scale).

        Parameters
        ----------
        baseline : array_like, optional
            No-load frame(s), see :class:`optitact.Pipeline`.
        method : {"fast", "reference"}
        bits : int, optional
            Bit depth of the frames (e.g. 16, or 12 for 12-bit data in
            ``uint16`` files). Default: the calibration's; then integer
            frames must be of the dtype that holds it (``uint8`` for 8 bits),
            and ``uint16`` frames for an 8-bit calibration are refused until
            ``bits`` says what they hold. Frames of another depth are mapped
            onto the calibration's exactly (16-bit frames of an 8-bit
            calibration are read as ``frame / 257``) or refused.
        exposure, gain : float, optional
            The frames' exposure and gain, in the units the calibration's
            ``intensity`` states; default the calibration's. Others are
            refused.

        Raises
        ------
        InputError
            Frames of a depth, exposure or gain that cannot be mapped onto
            the calibration's exactly; the message names both scales.
        """
        from optitact.pipeline import Pipeline

        scale = self.intensity
        for name, value in (("exposure", exposure), ("gain", gain)):
            if value is not None and IntensityScale(**{name: value}).to_dict()[name] != getattr(scale, name):
                raise InputError(
                    f"the frames' {name} {value:g} is not the calibration's ({scale}): the camera's "
                    f"response at another {name} (offset, noise, saturation) is not known; record the "
                    f"frames at {name} {getattr(scale, name):g} or calibrate at {value:g}")
        return Pipeline(self.sensor, self.camera, baseline=baseline, method=method, bits=bits,
                        readings_bits=scale.bits,
                        **{k: v for k, v in self.pipeline_options.items() if k != "method"})

    def check(self, sensor: DomeSensor | None = None, camera: FisheyeCamera | None = None) -> None:
        """Raise CalibrationMismatchError unless ``sensor``/``camera`` are the calibration's."""
        if sensor is not None and sensor != self.sensor:
            raise CalibrationMismatchError(
                f"this calibration (fingerprint {self.fingerprint}) was made for another sensor")
        if camera is not None and camera != self.camera:
            raise CalibrationMismatchError(
                f"this calibration (fingerprint {self.fingerprint}) was made for a "
                f"{self.camera.width}x{self.camera.height} camera {self.camera.to_dict()}, "
                f"got {camera.to_dict()}")

    def forces(self, readings: Readings) -> tuple[np.ndarray, np.ndarray]:
        """Element-local forces from readings, and the clamp flags.

        Returns
        -------
        forces : (E, 3) or (T, E, 3) ndarray
            0 where there is no contact.
        clamped : (E,) or (T, E) bool
            The reading was outside the fitted range and was clamped to it.
        """
        if not isinstance(readings, Readings):
            raise TypeError(f"readings must be Readings, got {type(readings).__name__}")
        if readings.n_elements != len(self.g):
            raise ShapeError(f"readings have {readings.n_elements} elements, the calibration "
                             f"{len(self.g)}")
        _check_readings(readings)
        G = np.minimum(readings.G, self.g_max)
        radius = np.hypot(readings.u[..., 0], readings.u[..., 1])
        over_u = radius > self.u_max
        # Divide only where the centroid is clamped (radius > u_max >= 0): elsewhere a subnormal radius
        # would overflow the quotient that np.where then discards.
        scale = np.divide(np.broadcast_to(self.u_max, radius.shape), radius, out=np.ones_like(radius),
                          where=over_u)
        u = readings.u * scale[..., None]
        clamped = readings.contact & ((readings.G > self.g_max) | over_u)
        s = G / self.g_scale
        t = u / self.u_scale[:, None]
        fz = np.einsum("...ek,ek->...e", _g_design(s), self.g) + s * np.sum(t * self.gu, axis=-1)
        fz = np.maximum(fz, 0.0)
        if self.model == "ohka":
            shear = self.f[:, 0:1] * t + self.f[:, 1:2] * t**3
        else:
            fzp = np.maximum(fz, 0.0)
            shear = u * (fzp / (self.f[:, 0] + self.f[:, 1] * np.sqrt(fzp)))[..., None]
        out = np.concatenate([shear, fz[..., None]], axis=-1)
        out[~readings.contact] = 0.0
        return out, clamped

    def apply(self, readings: Readings):
        """A :class:`optitact.forces.ForceField` per frame (a list for stack readings)."""
        from optitact.forces import ForceField

        f, clamped = self.forces(readings)
        if readings.is_stack:
            return [ForceField(self.sensor, f[t], contact=readings.contact[t], clamped=clamped[t],
                               saturated=readings.saturated[t]) for t in range(len(f))]
        return ForceField(self.sensor, f, contact=readings.contact, clamped=clamped,
                          saturated=readings.saturated)

    # ------------------------------------------------------------------ files
    def to_dict(self) -> dict:
        """The JSON document (see :meth:`save`)."""
        from optitact import __version__

        return {
            "schema": SCHEMA, "schema_version": SCHEMA_VERSION, "library_version": __version__,
            "model": self.model, "fingerprint": self.fingerprint,
            "sensor": self.sensor.to_dict(), "camera": self.camera.to_dict(),
            "pipeline": dict(self.pipeline_options),
            "elements": {
                "g": self.g.tolist(), "g_scale": self.g_scale.tolist(), "f": self.f.tolist(),
                "u_scale": self.u_scale.tolist(), "g_max": self.g_max.tolist(),
                "u_max": self.u_max.tolist(), "gu": self.gu.tolist(),
            },
            "residuals_n": {k: np.asarray(v).tolist() for k, v in self.residuals.items()},
            "provenance": self.provenance,
            "intensity": self.intensity.to_dict(),
        }

    def save(self, path: str | os.PathLike) -> Path:
        """Write the calibration as JSON, atomically.

        The file holds the schema version, model, per-element parameters,
        fitted ranges, residuals, the frames' intensity scale, and the
        sensor, camera and pipeline with their fingerprint.

        Raises
        ------
        InputError
            A value is not finite (NaN or infinity are not JSON, and
            :meth:`load` refuses them); nothing is written.
        """
        try:
            text = json.dumps(self.to_dict(), indent=1, allow_nan=False)
        except ValueError as exc:
            raise InputError(f"cannot save this calibration to {path}: a value is not finite ({exc}); "
                             f"JSON holds finite numbers only") from None
        return atomic_write_text(path, text + "\n")

    @classmethod
    def from_dict(cls, d) -> Calibration:
        """Build from :meth:`to_dict` output, validating every field.

        Raises
        ------
        InputError
            Wrong schema or version, a missing or malformed field, parameters
            outside what a fit gives (negative g coefficients, non-positive
            scales or ranges, a coupled shear curve that divides by zero).
        CalibrationMismatchError
            The fingerprint does not match the sensor, camera and pipeline.
        """
        if not isinstance(d, dict):
            raise InputError(f"a calibration must be a JSON object, got {type(d).__name__}")
        if d.get("schema") != SCHEMA:
            raise InputError(f"not an optitact calibration (schema {d.get('schema')!r})")
        version = d.get("schema_version")
        if isinstance(version, bool) or not isinstance(version, int) or version != SCHEMA_VERSION:
            raise InputError(f"calibration schema version {d.get('schema_version')!r} is not "
                             f"supported (this optitact reads {SCHEMA_VERSION})")
        for key in ("model", "sensor", "camera", "pipeline", "elements", "fingerprint"):
            if key not in d:
                raise InputError(f"calibration is missing {key!r}")
        model = d["model"]
        if not isinstance(model, str) or model not in MODELS:
            raise InputError(f"calibration model must be one of {MODELS}, got {model!r}")
        if not isinstance(d["fingerprint"], str):
            raise InputError(f"calibration 'fingerprint' must be a string, got {d['fingerprint']!r}")
        try:
            sensor = DomeSensor.from_dict(d["sensor"])
        except (TypeError, ValueError, ArithmeticError) as exc:
            raise InputError(f"calibration 'sensor' is not a valid sensor: {exc}") from None
        try:
            camera = FisheyeCamera.from_dict(d["camera"])
        except (TypeError, ValueError, ArithmeticError) as exc:
            raise InputError(f"calibration 'camera' is not a valid camera: {exc}") from None
        if not isinstance(d["pipeline"], dict):
            raise InputError("calibration 'pipeline' must be an object of Pipeline options")
        check_keys(d["pipeline"], PIPELINE_KEYS, "calibration 'pipeline'", noun="option")
        for key in ("residuals_n", "provenance"):
            if not isinstance(d.get(key, {}), dict):
                raise InputError(f"calibration {key!r} must be an object, got "
                                 f"{type(d[key]).__name__}")
        residuals = {key: _numbers(value, f"calibration residuals_n[{key!r}]")
                     for key, value in d.get("residuals_n", {}).items()}
        try:
            intensity = IntensityScale.from_dict(d.get("intensity", {}))
        except (TypeError, ValueError) as exc:
            raise InputError(f"calibration 'intensity' is not a valid intensity scale: {exc}") from None
        n = sensor.n_elements
        el = d["elements"]
        if not isinstance(el, dict):
            raise InputError("calibration 'elements' must be an object")

        def arr(name, shape):
            if name not in el:
                raise InputError(f"calibration elements are missing {name!r}")
            a = _numbers(el[name], f"calibration elements[{name!r}]")
            if a.shape != shape:
                raise InputError(f"calibration elements[{name!r}] must have shape {shape}, "
                                 f"got {a.shape}")
            a.flags.writeable = False
            return a

        cal = cls(model, sensor, camera, dict(d["pipeline"]), arr("g", (n, _G_TERMS)),
                  arr("g_scale", (n,)), arr("f", (n, 2)), arr("u_scale", (n,)),
                  arr("g_max", (n,)), arr("u_max", (n,)), arr("gu", (n, 2)),
                  residuals, dict(d.get("provenance", {})), intensity)
        if np.any(cal.g_scale <= 0) or np.any(cal.u_scale <= 0):
            raise InputError("calibration scales must be > 0")
        if np.any(cal.g_max <= 0) or np.any(cal.u_max <= 0):
            raise InputError("calibration ranges g_max and u_max must be > 0")
        if np.any(cal.g < 0):
            raise InputError("calibration g coefficients must be >= 0 (g increases with G)")
        if model == "coupled" and (np.any(cal.f[:, 0] <= 0) or np.any(cal.f[:, 1] < 0)):
            raise InputError("coupled calibration shear parameters must have a > 0 and b >= 0")
        if model == "ohka" and np.any(cal.f < 0):
            raise InputError("ohka calibration shear coefficients must be >= 0")
        with np.errstate(all="ignore"):  # the curves must stay finite over the fitted range
            s_top, t_top = cal.g_max / cal.g_scale, cal.u_max / cal.u_scale
            fz_top = _g_design(s_top) @ np.ones(_G_TERMS) * np.abs(cal.g).max(axis=1) \
                + s_top * t_top * np.abs(cal.gu).sum(axis=1)
            shear_top = (cal.u_max * fz_top / cal.f[:, 0] if model == "coupled"
                         else cal.f[:, 0] * t_top + cal.f[:, 1] * t_top**3)
        if not (np.isfinite(fz_top).all() and np.isfinite(shear_top).all()):
            raise InputError("calibration curves overflow float64 within their fitted range (scales, "
                             "ranges or coefficients out of proportion)")
        try:
            cal.pipeline()  # the pipeline options must be valid
        except (TypeError, ValueError, ArithmeticError) as exc:
            raise InputError(f"calibration 'pipeline' options are not valid: {exc}") from None
        if cal.fingerprint != d["fingerprint"]:
            raise CalibrationMismatchError(
                f"calibration fingerprint {d['fingerprint']!r} does not match its own sensor, "
                f"camera and pipeline ({cal.fingerprint}); the file was edited or is corrupt")
        return cal

    @classmethod
    def load(cls, path: str | os.PathLike, *, sensor: DomeSensor | None = None,
             camera: FisheyeCamera | None = None) -> Calibration:
        """Read a calibration JSON file (never executes anything from it).

        Raises
        ------
        FileNotFoundError
            Nothing at ``path``.
        InputError
            ``path`` is a folder or not a regular file (a FIFO, a device),
            oversized, not JSON, wrong schema or version, malformed fields.
        CalibrationMismatchError
            ``sensor``/``camera`` given and not the calibration's.
        """
        path = Path(path)
        if not path.exists():
            raise FileNotFoundError(f"calibration file not found: {path}")
        if path.is_dir():
            raise InputError(f"{path} is a folder, expected a calibration JSON file")
        if not path.is_file():
            raise InputError(f"{path} is not a regular file (a FIFO, socket or device?), expected a "
                             f"calibration JSON file")
        size = path.stat().st_size
        if size > MAX_FILE_BYTES:
            raise InputError(f"{path}: {size} bytes is too large for a calibration "
                             f"(at most {MAX_FILE_BYTES})")
        with path.open("rb") as fh:
            data = fh.read(MAX_FILE_BYTES + 1)  # the file may have grown since stat()
        if len(data) > MAX_FILE_BYTES:
            raise InputError(f"{path} is too large for a calibration (more than {MAX_FILE_BYTES} bytes)")
        try:
            d = json.loads(data.decode("utf-8"), parse_constant=_refuse_constant)
        except (UnicodeDecodeError, ValueError, RecursionError) as exc:
            # JSONDecodeError and numbers too long to convert are ValueErrors; absurd nesting
            # exhausts the parser's recursion
            raise InputError(f"{path} is not a JSON calibration ({type(exc).__name__}: "
                             f"{str(exc)[:200]})") from None
        cal = cls.from_dict(d)
        cal.check(sensor, camera)
        return cal


def _numbers(value, what: str) -> np.ndarray:
    """A nested list of JSON numbers as a float64 array; InputError naming ``what`` otherwise.

    Strings ("0.99"), booleans, nulls and objects are refused (NumPy would
    convert the first two), and so are values that are not finite in float64
    (1e309 parses as infinity; integers beyond float64 overflow).
    """
    stack = [value]
    while stack:
        item = stack.pop()
        if isinstance(item, list):
            stack.extend(item)
        elif isinstance(item, bool) or not isinstance(item, (int, float)):
            raise InputError(f"{what} must hold numbers, got {item!r} ({type(item).__name__})")
    try:
        a = np.array(value, dtype=np.float64)
    except (TypeError, ValueError, ArithmeticError):  # ragged lists; ints beyond float64 overflow
        raise InputError(f"{what} must be a regular array of numbers within float64") from None
    if not np.isfinite(a).all():
        raise InputError(f"{what} must be finite, got {a[~np.isfinite(a)].flat[0]} (JSON numbers beyond "
                         f"float64, such as 1e309, read as infinity)")
    return a


def _refuse_constant(name: str):
    raise ValueError(f"{name} is not valid JSON (calibration numbers must be finite)")


def _check_spread(x: np.ndarray, what: str) -> None:
    """InputError unless ``x`` spans a range wider than ``MIN_RELATIVE_SPREAD`` of its magnitude."""
    spread, scale = float(np.ptp(x)), float(np.max(np.abs(x)))
    if not spread > MIN_RELATIVE_SPREAD * scale:
        raise InputError(f"{what} spans {spread:.3g} around a magnitude of {scale:.3g} (relative "
                         f"{spread / scale if scale else 0.0:.3g}); a fit needs a relative spread "
                         f"above {MIN_RELATIVE_SPREAD:g} (an ill-conditioned range)")


def _check_readings(readings: Readings) -> None:
    """InputError for non-finite readings or a negative G."""
    for name in ("G", "u"):
        arr = np.asarray(getattr(readings, name))
        if arr.dtype.kind not in "iuf":
            raise TypeError(f"readings.{name} must be real numbers, got dtype {arr.dtype}")
        if not np.isfinite(arr).all():
            raise InputError(f"readings.{name} must be finite, got {arr[~np.isfinite(arr)][0]}")
    if np.any(np.asarray(readings.G) < 0):
        raise InputError(f"readings.G must be >= 0, got {np.min(readings.G)}")


def fit(calibration_set, *, model: str = "coupled", partial: bool = False) -> Calibration:
    """Fit a calibration to a :class:`~optitact.calib.CalibrationSet` (or its path).

    Parameters
    ----------
    calibration_set : CalibrationSet or path-like
    model : {"coupled", "ohka"}
        The curve model (see :meth:`Calibration.fit`).
    partial : bool
        Fit the finished frames of a set that is not complete (a run that was
        killed or is still going). Without it such a set is refused: a fit on
        part of a design covers part of its force range.

    Raises
    ------
    InputError
        The set has no finished frame, or is incomplete and ``partial`` is false
        (the message says how many frames are done).
    """
    from .sets import CalibrationSet

    cs = calibration_set if isinstance(calibration_set, CalibrationSet) \
        else CalibrationSet(calibration_set)
    done = cs.done
    n_done, n = int(done.sum()), len(cs)
    if not done.any():
        raise InputError(f"{cs.path} has no finished frames yet (0 of {n}); run its generate command")
    if n_done < n and not partial:
        raise InputError(f"{cs.path} is incomplete: {n_done} of {n} frames done; run its generate command "
                         f"again to finish it, or fit the {n_done} done frames with partial=True "
                         f"(--partial)")
    return Calibration.fit(cs.readings(), cs.forces(), sensor=cs.sensor, camera=cs.camera,
                           pipeline_options=cs.attrs.get("pipeline", {}), model=model,
                           provenance={"set": str(cs.path), "frames": n_done, "frames_in_set": n,
                                       "seed": cs.attrs["seed"], "spp": cs.attrs["spp"],
                                       "design": cs.attrs["design"]},
                           intensity=IntensityScale(bits=cs.ccd.bits))
