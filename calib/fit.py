"""The fitted calibration: curves g (normal) and f (shear) per element, applied to readings, saved as JSON.

:class:`Calibration` holds one sensor's curves: :meth:`Calibration.fit` fits
them to readings and known forces (element by element, see
:mod:`optitact.calib.curves` for the models ``"ohka"`` and ``"coupled"`` and
why), :meth:`Calibration.apply` turns readings into force fields, and
:meth:`Calibration.save` / :meth:`Calibration.load` keep it as a JSON document
(validated by :mod:`optitact.calib.document`). :func:`fit` fits one to a
synthetic calibration set.

Intensity scale
---------------
G is in the grey levels of the frames the curves were fitted on, so a
calibration records their :class:`~optitact.optics.ccd.IntensityScale`: the bit
depth (``intensity.bits``; the set's CCD when fitted from a calibration set,
8 for files written before the field existed) and the exposure and gain the
user states (default 1). :meth:`Calibration.pipeline` maps frames of another
depth exactly (16-bit frames that widen 8-bit ones, x 257) or refuses them,
and refuses another exposure or gain.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from optitact._validate import check_type
from optitact.optics.camera import Camera
from optitact.optics.ccd import IntensityScale
from optitact.errors import InputError, ShapeError
from optitact.io.files import atomic_write_text
from optitact.pipeline.readings import Readings
from optitact.optics.sensor import DomeSensor

from optitact.calib import propagation
from optitact.calib.crosstalk import CrossTalk, fit_crosstalk
from optitact.calib.curves import (FZ_FLOOR, G_TERMS, MODELS, fit_element, grey_for_force, normal_force,
                                   zero_shear_centroid)
from optitact.calib.document import STACK_NOISE_UNNAMED
from optitact.calib.document import (SCHEMA, SCHEMA_VERSION, CalibrationMismatchError, fingerprint,
                                     from_document, read_document, resolved_options)
from optitact.calib.error_model import ErrorModel, validate

__all__ = ["Calibration", "fit", "MAX_SHAPE", "SHAPE_REF_N", "TRANSFER_TOLERANCE"]

#: A transferred calibration's error per element beyond its own (1 sigma, a fraction of the force): the
#: curves were fitted to other elements. Moulded rubber elements differ in stiffness from moulding to
#: moulding (a spread of +-10 % in the modulus, 6 % rms), and a registration leaves 2 % rms of their
#: brightness (docs/results/realism.md); together about 6 %.
TRANSFER_TOLERANCE = 0.06

#: The normal force (N) at which an element's shape exponent leaves its forces unchanged.
SHAPE_REF_N = 0.5
#: Largest magnitude of a shape parameter (a factor e^0.5 = 1.65 and an exponent of 0.5): beyond it the
#: element is not the one the curves describe.
MAX_SHAPE = 0.5



@dataclass(frozen=True, eq=False)
class Calibration:
    """Per-element calibration curves for one sensor, camera and pipeline.

    Attributes
    ----------
    model : {"ohka", "coupled"}
    sensor, camera : DomeSensor, Camera (any model, e.g. FisheyeCamera)
    pipeline_options : dict
        Options of :class:`optitact.pipeline.frame_pipeline.Pipeline` the readings were made with.
    g : (E, 4) ndarray
        Normal-force coefficients on ``s = G / g_scale`` (N).
    g_scale : (E,) ndarray
    f : (E, 2) ndarray
        Shear coefficients: ``(d1, d3)`` on ``t = u / u_scale`` (ohka) or
        ``(a, b)`` (coupled).
    u_scale : (E,) ndarray
    g_max : (E,) ndarray
        Largest fitted G per element; above it the normal curve goes on along
        its tangent up to :data:`EXTRAPOLATE` beyond, then holds (flagged
        ``clamped``).
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
    crosstalk : CrossTalk or None
        The coupling between elements of the joint inversion
        (:mod:`optitact.calib.crosstalk`); None: every element on its own.
    u0 : (E, 2, 2) ndarray or None
        Coupled model: the grey-value centroid at zero shear, ``u0[e, 0] +
        u0[e, 1] / sqrt(Fz)`` (mm, see :func:`~optitact.calib.curves.zero_shear_centroid`):
        the rim light makes the cones nearer the rim brighter, so an unsheared
        element's centroid sits off its centre; the shear curve reads ``u -
        u0(Fz)``. None: zero (calibrations made before it existed).
    error_model : ErrorModel or None
        The calibration's error measured on independent data (:meth:`validated`,
        or the held-out presses of a press fit); :meth:`stderr` adds it instead
        of the fit residuals. None: not measured.
    shape : (E, 3) ndarray or None
        Each element's own departure from the curves' shape
        (:mod:`optitact.calib.element_shapes`): ``(log_scale, exponent,
        log_shear)``, the element's forces ``F`` times ``exp(log_scale +
        exponent l)``, ``l = log(Fz / SHAPE_REF_N)``, and its shear times
        ``exp(log_shear)`` as well (an element whose rubber is stiffer, softer
        or more nonlinear than the curves'). None: the curves as they are.
    """

    model: str
    sensor: DomeSensor
    camera: Camera
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
    crosstalk: CrossTalk | None = None
    u0: np.ndarray | None = None
    error_model: ErrorModel | None = None
    shape: np.ndarray | None = None

    def __post_init__(self) -> None:
        check_type(self.intensity, IntensityScale, "intensity")
        if self.shape is not None:
            a = np.array(self.shape, dtype=np.float64)
            if a.shape != (len(self.g), 3):
                raise ShapeError(f"shape must have shape {(len(self.g), 3)} (log_scale, exponent, log_shear "
                                 f"per element), got {a.shape}")
            if not (np.isfinite(a).all() and np.all(np.abs(a) <= MAX_SHAPE)):
                raise InputError(f"shape must be finite, each value within +-{MAX_SHAPE:g} (log scales and an "
                                 f"exponent of the force), got values up to {np.nanmax(np.abs(a)):.3g}")
            a.flags.writeable = False
            object.__setattr__(self, "shape", a)
        if self.error_model is not None:
            check_type(self.error_model, ErrorModel, "error_model")
        if self.u0 is not None and np.shape(self.u0) != (len(self.g), 2, 2):
            raise ShapeError(f"u0 must have shape {(len(self.g), 2, 2)}, got {np.shape(self.u0)}")
        if self.crosstalk is not None:
            check_type(self.crosstalk, CrossTalk, "crosstalk")

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
    def fit(cls, readings: Readings, forces, *, sensor: DomeSensor, camera: Camera,
            pipeline_options: dict | None = None, model: str = "coupled",
            provenance: dict | None = None, intensity: IntensityScale | None = None,
            joint: bool = False) -> Calibration:
        """Fit the curves to readings and the true (measured) forces that made them.

        Parameters
        ----------
        readings : Readings
            Stack readings ``(T, E)`` (from :meth:`optitact.pipeline.frame_pipeline.Pipeline.process`).
        forces : (T, E, 3) array_like
            Element-local forces (N) applied in each frame.
        sensor, camera : DomeSensor, Camera (any model, e.g. FisheyeCamera)
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
        joint : bool
            Also fit the cross-talk between elements (the joint inversion of
            :mod:`optitact.calib.crosstalk`), alternating with the curves; the
            readings must vary what the neighbours carry (a ``blend`` design).
            Its provenance records the fit's ``rms_log_before/after``.

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
        if not isinstance(joint, (bool, np.bool_)):
            raise TypeError(f"joint must be True or False, got {type(joint).__name__}")
        if joint:
            def curves(G):
                return cls.fit(Readings(G, readings.u, readings.contact, readings.saturated), f, sensor=sensor,
                               camera=camera, pipeline_options=pipeline_options, model=model,
                               provenance=provenance, intensity=intensity)

            ct, cal, info = fit_crosstalk(readings, f, sensor, curves, grey_for_force)
            return replace(cal, crosstalk=ct, provenance={**cal.provenance, "crosstalk_fit": info})
        g_c = np.zeros((n_el, G_TERMS))
        gu = np.zeros((n_el, 2))
        u0 = np.zeros((n_el, 2, 2))
        f_c = np.zeros((n_el, 2))
        g_scale, u_scale = np.ones(n_el), np.ones(n_el)
        g_max, u_max = np.zeros(n_el), np.zeros(n_el)
        res = {"fx": np.zeros(n_el), "fy": np.zeros(n_el), "fz": np.zeros(n_el),
               "n": np.zeros(n_el, int)}
        for e in range(n_el):
            ok = readings.contact[:, e] & ~readings.saturated[:, e]
            c = fit_element(readings.G[ok, e], readings.u[ok, e], f[ok, e], model=model,
                            lever_arm=sensor.lever_arm, e=e)
            g_c[e], gu[e], f_c[e], u0[e] = c.g, c.gu, c.f, c.u0
            g_scale[e], u_scale[e], g_max[e], u_max[e] = c.g_scale, c.u_scale, c.g_max, c.u_max
            res["fx"][e], res["fy"][e], res["fz"][e], res["n"][e] = c.rms_fx, c.rms_fy, c.rms_fz, c.n
        # the readings' stack-noise rule named (the Pipeline's default where the options do not say)
        options = {"stack_noise": "pooled"} | resolved_options(sensor, camera, pipeline_options or {})
        return cls(model, sensor, camera, options,
                   g_c, g_scale, f_c,
                   u_scale, g_max, u_max, gu, res, dict(provenance or {}), intensity,
                   u0=u0 if np.any(u0) else None)

    # ------------------------------------------------------------------ applying
    def pipeline(self, *, baseline=None, method: str = "fast", bits: int | None = None,
                 exposure: float | None = None, gain: float | None = None):
        """The :class:`~optitact.pipeline.frame_pipeline.Pipeline` these curves expect.

        Parameters
        ----------
        baseline : array_like, optional
            No-load frame(s), see :class:`optitact.pipeline.frame_pipeline.Pipeline`.
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
        from optitact.pipeline.frame_pipeline import Pipeline

        scale = self.intensity
        for name, value in (("exposure", exposure), ("gain", gain)):
            if value is not None and IntensityScale(**{name: value}).to_dict()[name] != getattr(scale, name):
                raise InputError(
                    f"the frames' {name} {value:g} is not the calibration's ({scale}): the camera's "
                    f"response at another {name} (offset, noise, saturation) is not known; record the "
                    f"frames at {name} {getattr(scale, name):g} or calibrate at {value:g}")
        return Pipeline(self.sensor, self.camera, baseline=baseline, method=method, bits=bits,
                        readings_bits=scale.bits, **self.reading_options)

    @property
    def reading_options(self) -> dict:
        """The pipeline options that read frames as these curves expect (all but ``method``).

        A calibration that names no ``stack_noise`` was fitted on readings made before the option
        existed: it reads with :data:`~optitact.calib.document.STACK_NOISE_UNNAMED`.
        """
        options = {k: v for k, v in self.pipeline_options.items() if k != "method"}
        options.setdefault("stack_noise", STACK_NOISE_UNNAMED)
        return options

    def check(self, sensor: DomeSensor | None = None, camera: Camera | None = None) -> None:
        """Raise CalibrationMismatchError unless ``sensor``/``camera`` are the calibration's."""
        if sensor is not None and sensor != self.sensor:
            raise CalibrationMismatchError(
                f"this calibration (fingerprint {self.fingerprint}) was made for another sensor")
        if camera is not None and camera != self.camera:
            raise CalibrationMismatchError(
                f"this calibration (fingerprint {self.fingerprint}) was made for a "
                f"{self.camera.width}x{self.camera.height} camera {self.camera.to_dict()}, "
                f"got {camera.to_dict()}")

    def transferred(self, sensor: DomeSensor, camera: Camera, *,
                    tolerance: float = TRANSFER_TOLERANCE) -> Calibration:
        """The same curves for another (e.g. a registered) sensor and camera of the same element layout.

        G is dewarped onto the dome (grey level x mm^2), so the curves carry
        over to another camera to first order; an element's gain relative to
        this calibration's sensor (``sensor.gains / self.sensor.gains``, see
        :attr:`DomeSensor.element_gain`) is folded into its G scale:
        ``g_scale`` and ``g_max`` times ``k``, i.e. ``Fz = g_self(G / k, u)``.
        The pipeline options (mm on the dome) and intensity scale are kept;
        the fingerprint becomes the new sensor's and camera's, and the
        provenance records ``{"transferred_from": <this fingerprint>}``.

        The curves were fitted to other elements than the new sensor's, so
        their error there is larger than their own: a measured
        :attr:`error_model` gains ``tolerance`` of the force per element
        (relative to Fz for Fz, to the shear for Fx and Fy), added in
        quadrature, so that ``process --stderr`` stays honest before any
        press is made (:data:`TRANSFER_TOLERANCE`). A calibration fitted to
        the sensor's own presses then measures its error anew.

        Parameters
        ----------
        sensor : DomeSensor
            Same ring counts and cones per element as this calibration's.
        camera : Camera
            Any model (e.g. a registered :class:`optitact.optics.camera_models.OpenCVFisheyeCamera`).
        tolerance : float
            The elements' relative error beyond the curves' own (1 sigma, default
            :data:`TRANSFER_TOLERANCE`); 0 keeps the error model as it is.

        Returns
        -------
        Calibration

        Raises
        ------
        CalibrationMismatchError
            Another element layout (ring counts, cones per element), or
            pipeline options that do not build a pipeline for the new sensor
            and camera.

        Examples
        --------
        >>> from optitact.calib.shipped import default_calibration
        >>> cal = default_calibration()
        >>> built = DomeSensor(element_gain=[1.2] + [1.0] * 40)
        >>> moved = cal.transferred(built, cal.camera)
        >>> float(moved.g_scale[0] / cal.g_scale[0]), moved.provenance["transferred_from"] == cal.fingerprint
        (1.2, True)
        """
        check_type(sensor, DomeSensor, "sensor")
        check_type(camera, Camera, "camera")
        old = self.sensor
        for name in ("ring_counts", "n_cones"):
            if getattr(sensor, name) != getattr(old, name):
                raise CalibrationMismatchError(
                    f"cannot transfer this calibration (fingerprint {self.fingerprint}): its sensor has "
                    f"{name} {getattr(old, name)}, the new one {getattr(sensor, name)}; the curves are per "
                    f"element, so the element layout must be the same")
        try:
            options = resolved_options(sensor, camera, self.pipeline_options)
        except (InputError, TypeError) as exc:
            raise CalibrationMismatchError(
                f"cannot transfer this calibration (fingerprint {self.fingerprint}): its pipeline options "
                f"{self.pipeline_options} do not carry over to the new sensor and camera ({exc})") from None
        k = sensor.gains / old.gains
        tolerance = float(tolerance)
        if not (np.isfinite(tolerance) and 0.0 <= tolerance < 1.0):
            raise InputError(f"tolerance must be a fraction in [0, 1), got {tolerance!r}")
        model = self.error_model
        if model is not None and tolerance > 0 and (sensor != old or camera != self.camera):
            tol = np.array([0.0, 0.0, tolerance])
            model = replace(model, relative=np.hypot(model.relative, tol),
                            shear=np.hypot(model.shear, tolerance - tol),
                            source=f"{model.source}; transferred to another sensor: + "
                                   f"{100 * tolerance:g} % per element")
        return replace(self, sensor=sensor, camera=camera, pipeline_options=options,
                       g_scale=self.g_scale * k, g_max=self.g_max * k, error_model=model,
                       provenance={"transferred_from": self.fingerprint, "source_provenance": self.provenance,
                                   "transfer_tolerance": tolerance})

    def forces(self, readings: Readings) -> tuple[np.ndarray, np.ndarray]:
        """Element-local forces from readings, and the clamp flags.

        Returns
        -------
        forces : (E, 3) or (T, E, 3) ndarray
            0 where there is no contact.
        clamped : (E,) or (T, E) bool
            The reading was outside the fitted range: G above ``g_max`` (the
            normal curve's tangent continued up to :data:`EXTRAPOLATE`
            beyond it, then held) or ``|u|`` beyond ``u_max`` (clamped to it).
        """
        self.check_readings(readings)
        G = readings.G
        if self.crosstalk is not None:  # every element's G as it would read alone, then the curves
            G = self.crosstalk.solve(self.sensor, G, readings.contact, self.normal_curve(readings.u))
        out, clamped = self.per_element_forces(G, readings.u)
        out[~readings.contact] = 0.0
        return out, clamped & readings.contact

    # ------------------------------------------------------------------ the curves, element by element
    def check_readings(self, readings: Readings) -> None:
        """Refuse readings these curves cannot be applied to.

        Parameters
        ----------
        readings : Readings
            Single-frame ``(E,)`` or stack ``(T, E)`` readings.

        Raises
        ------
        TypeError
            ``readings`` is not a :class:`~optitact.pipeline.readings.Readings`.
        ShapeError
            Another number of elements than the calibration's.
        InputError
            Readings that are not finite.
        """
        if not isinstance(readings, Readings):
            raise TypeError(f"readings must be Readings, got {type(readings).__name__}")
        if readings.n_elements != len(self.g):
            raise ShapeError(f"readings have {readings.n_elements} elements, the calibration "
                             f"{len(self.g)}")
        _check_readings(readings)

    def per_element_forces(self, G, u) -> tuple[np.ndarray, np.ndarray]:
        """Every element's own curves at ``(G, u)``: forces and clamp flags, with no cross-talk or contact.

        :meth:`forces` is this at the readings' G (the cross-talk undone
        first, when the calibration has one), zeroed where there is no
        contact; the propagation of errors differentiates it.

        Parameters
        ----------
        G : (..., E) array_like
            Grey-value integrals of the elements (as each would read alone).
        u : (..., E, 2) array_like
            Their centroid shifts, mm.

        Returns
        -------
        forces : (..., E, 3) ndarray
            Element-local forces, N.
        clamped : (..., E) bool ndarray
            G above ``g_max`` or ``|u|`` beyond ``u_max`` (see :meth:`forces`).
        """
        u, over_u = self.clamped_shift(u)
        clamped = (G > self.g_max) | over_u
        t = u / self.u_scale[:, None]
        fz = normal_force(self.g, self.g_scale, self.g_max, G, np.sum(t * self.gu, axis=-1))
        warp = self.shape_factor(fz)
        if self.model == "ohka":
            shear = self.f[:, 0:1] * t + self.f[:, 1:2] * t**3
        else:
            if self.u0 is not None:
                u = u - zero_shear_centroid(self.u0, fz)
            shear = u * (fz / (self.f[:, 0] + self.f[:, 1] * np.sqrt(fz)))[..., None]
        if warp is not None:
            shear = shear * (warp * np.exp(self.shape[:, 2]))[..., None]
            fz = fz * warp
        return np.concatenate([shear, fz[..., None]], axis=-1), clamped

    def shape_factor(self, fz) -> np.ndarray | None:
        """What each element's forces are times for its own :attr:`shape`, at curve forces ``fz`` (..., E).

        ``exp(log_scale + exponent l)``, ``l = log(max(Fz, FZ_FLOOR) / SHAPE_REF_N)`` (None without a
        shape).
        """
        if self.shape is None:
            return None
        ell = np.log(np.maximum(fz, FZ_FLOOR) / SHAPE_REF_N)
        return np.exp(self.shape[:, 0] + self.shape[:, 1] * ell)
    def normal_curve(self, u):
        """Every element's normal curve ``G -> Fz`` on its own, at centroid shifts ``u``.

        The joint inversion's inner step
        (:meth:`optitact.calib.crosstalk.CrossTalk.solve`): with the shifts
        held, Fz depends on G alone.

        Parameters
        ----------
        u : (..., E, 2) array_like
            Centroid shifts, mm (clamped to the fitted range, see :meth:`clamped_shift`).

        Returns
        -------
        callable
            ``G (..., E) -> Fz (..., E)`` (N), the Fz of :meth:`per_element_forces`.
        """
        q = np.sum(self.clamped_shift(u)[0] / self.u_scale[:, None] * self.gu, axis=-1)
        if self.shape is None:
            return lambda G: normal_force(self.g, self.g_scale, self.g_max, G, q)

        def curve(G):
            fz = normal_force(self.g, self.g_scale, self.g_max, G, q)
            return fz * self.shape_factor(fz)

        return curve

    def clamped_shift(self, u) -> tuple[np.ndarray, np.ndarray]:
        """Centroid shifts held to the fitted range ``|u| <= u_max``, as the curves read them.

        Parameters
        ----------
        u : (..., E, 2) array_like
            Centroid shifts, mm.

        Returns
        -------
        shift : (..., E, 2) ndarray
            ``u``, scaled back onto ``|u| = u_max`` where it is beyond it (its direction kept).
        beyond : (..., E) bool ndarray
            Where it was.
        """
        radius = np.hypot(u[..., 0], u[..., 1])
        over = radius > self.u_max
        # Divide only where the centroid is clamped (radius > u_max >= 0): elsewhere a subnormal radius
        # would overflow the quotient that np.where then discards.
        scale = np.divide(np.broadcast_to(self.u_max, radius.shape), radius, out=np.ones_like(radius),
                          where=over)
        return u * scale[..., None], over

    # ------------------------------------------------------------------ uncertainty
    def jacobian(self, readings: Readings) -> np.ndarray:
        """d(forces)/d(readings), (..., E, 3, E, 3): see :func:`optitact.calib.propagation.jacobian`."""
        return propagation.jacobian(self, readings)

    def model_error(self) -> np.ndarray:
        """The curves' own error per element and axis, (E, 3) N (:func:`.propagation.model_error`)."""
        return propagation.model_error(self)

    def stderr(self, readings: Readings, errors=None, *, model_error: bool = True, forces=None) -> np.ndarray:
        """Standard errors of :meth:`forces`, (E, 3) or (T, E, 3) N (:func:`.propagation.stderr`).

        ``errors``: the readings' covariance (:func:`~optitact.pipeline.uncertainty.reading_errors`); None gives
        the model error alone. ``model_error``: add it in quadrature (default). ``forces``: :meth:`forces`'
        estimates of these readings if already made.

        Examples
        --------
        >>> from optitact.calib.shipped import default_calibration
        >>> se = default_calibration().stderr(Readings.empty(41))
        >>> se.shape, bool((se > 0).all())
        ((41, 3), True)
        """
        return propagation.stderr(self, readings, errors, with_model_error=model_error, forces=forces)

    def validated(self, readings: Readings, forces, errors=None, *, source: str = "") -> Calibration:
        """A copy with its error measured on independent readings of known forces.

        See :func:`optitact.calib.error_model.validate`.
        """
        return validate(self, readings, forces, errors, source=source)

    def apply(self, readings: Readings, errors=None):
        """A :class:`optitact.forces.ForceField` per frame (a list for stack readings).

        Each carries ``stderr`` (:meth:`stderr`: the readings' ``errors``
        propagated, when given, plus the calibration's model error).
        """
        from optitact.forces import ForceField

        f, clamped = self.forces(readings)
        se = self.stderr(readings, errors, forces=f)
        if readings.is_stack:
            return [ForceField(self.sensor, f[t], contact=readings.contact[t], clamped=clamped[t],
                               saturated=readings.saturated[t], stderr=se[t]) for t in range(len(f))]
        return ForceField(self.sensor, f, contact=readings.contact, clamped=clamped,
                          saturated=readings.saturated, stderr=se)

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
                "u0": None if self.u0 is None else np.asarray(self.u0).tolist(),
                "shape": None if self.shape is None else self.shape.tolist(),
            },
            "residuals_n": {k: np.asarray(v).tolist() for k, v in self.residuals.items()},
            "provenance": self.provenance,
            "intensity": self.intensity.to_dict(),
            **({} if self.crosstalk is None else {"crosstalk": self.crosstalk.to_dict()}),
            **({} if self.error_model is None else {"error_model": self.error_model.to_dict()}),
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

        Warns
        -----
        OptitactWarning
            A coupled calibration of schema version 1 without ``u0``: it
            loads as that version, its shear curves taking ``u0 = 0``.
        """
        return from_document(cls, d)

    @classmethod
    def load(cls, path: str | os.PathLike, *, sensor: DomeSensor | None = None,
             camera: Camera | None = None) -> Calibration:
        """Read a calibration JSON file (never executes anything from it).

        A file of an older schema version loads as that version; where that
        version lacks what the current one holds (schema version 1 without
        the zero-shear centroid ``u0``) an :class:`~optitact.errors.OptitactWarning`
        names the file and what the calibration goes without.

        Raises
        ------
        FileNotFoundError
            Nothing at ``path``.
        InputError
            Not a calibration file that :func:`~optitact.calib.document.read_document`
            reads (a folder, not a regular file, oversized, not JSON), or a
            document :meth:`from_dict` refuses (wrong schema or version,
            malformed fields, a field its schema version requires missing);
            the message starts with ``path``.
        CalibrationMismatchError
            ``sensor``/``camera`` given and not the calibration's.
        """
        d = read_document(path)
        try:
            cal = from_document(cls, d, source=path)
            cal.check(sensor, camera)
        except InputError as exc:
            raise type(exc)(f"{path}: {exc}") from None
        return cal


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


def fit(calibration_set, *, model: str = "coupled", partial: bool = False, joint: bool = False) -> Calibration:
    """Fit a calibration to a :class:`~optitact.calib.sets.CalibrationSet` (or its path).

    Parameters
    ----------
    calibration_set : CalibrationSet or path-like
    model : {"coupled", "ohka"}
        The curve model (see :meth:`Calibration.fit`).
    partial : bool
        Fit the finished frames of a set that is not complete (a run that was
        killed or is still going). Without it such a set is refused: a fit on
        part of a design covers part of its force range.
    joint : bool
        Also fit the cross-talk between elements (see :meth:`Calibration.fit`).

    Raises
    ------
    InputError
        The set has no finished frame, or is incomplete and ``partial`` is false
        (the message says how many frames are done).
    """
    from optitact.calib.sets import CalibrationSet

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
                           pipeline_options={"stack_noise": STACK_NOISE_UNNAMED} | cs.attrs.get("pipeline", {}),
                           model=model,
                           provenance={"set": str(cs.path), "frames": n_done, "frames_in_set": n,
                                       "seed": cs.attrs["seed"], "spp": cs.attrs["spp"],
                                       "design": cs.attrs["design"],
                                       "render_mode": cs.attrs.get("render_mode", "full")},
                           intensity=IntensityScale(bits=cs.ccd.bits), joint=joint)
