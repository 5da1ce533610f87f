"""Standard errors of readings and forces (optitact.pipeline.uncertainty, Calibration.stderr), checked against
Monte Carlo spreads through the CCD model, independent finite differences and coverage on ideal data."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from optitact.calib.crosstalk import CrossTalk
from optitact.calib.shipped import default_calibration
from optitact.forces import ForceField

from optitact.errors import InputError, ShapeError
from optitact.optics.camera import FisheyeCamera
from optitact.optics.ccd import CCD
from optitact.optics.sensor import DomeSensor
from optitact.pipeline.frame_pipeline import Pipeline
from optitact.pipeline.readings import Readings
from optitact.pipeline.uncertainty import PixelNoise, ReadingErrors, coverage, reading_errors
from optitact.studies.noise_sweep import _SpotModel, nominal_energy


@pytest.fixture(scope="module")
def spot():
    """A Gaussian spot on element 0 of a small camera, with the CCD's exact read noise."""
    sensor, camera, ccd = DomeSensor.default(), FisheyeCamera(width=160, height=120), CCD()
    return _SpotModel.build(sensor, camera, ccd, 0), ccd


@pytest.fixture(scope="module")
def cal():
    return default_calibration()


def _readings(cal, seed, n=None):
    """Readings inside every element's fitted range (contact everywhere but element 5)."""
    rng = np.random.default_rng(seed)
    lead = () if n is None else (n,)
    E = len(cal.g)
    G = cal.g_max * rng.uniform(0.25, 0.6, lead + (E,))
    u = rng.normal(0.0, 0.3, lead + (E, 2)) * cal.u_max[:, None]
    c = np.ones(lead + (E,), bool)
    c[..., 5] = False
    G[..., 5] = 0.0
    u[..., 5, :] = 0.0
    return Readings(G, u, c, np.zeros(lead + (E,), bool))


def _cov(readings, rel_g=0.01, su=0.004, rho=0.3):
    """A covariance of (G, ux, uy) per element with a G-u correlation."""
    G = np.asarray(readings.G)
    cov = np.zeros(G.shape + (3, 3))
    sg = rel_g * G
    cov[..., 0, 0] = sg**2
    cov[..., 1, 1] = su**2
    cov[..., 2, 2] = (0.7 * su) ** 2
    cov[..., 0, 1] = cov[..., 1, 0] = rho * sg * su
    return cov


# ----------------------------------------------------------------------------- reading noise
@pytest.mark.parametrize("factor", [1.0, 2.0])
def test_predicted_spread_of_G_and_u_matches_the_monte_carlo_spread_of_analytic_spots(spot, factor):
    model, ccd = spot
    rad = model.radiance(nominal_energy(model.sensor) * factor, 0.5, (0.2, -0.1))
    frames = np.concatenate(list(model.frames(rad, 400, seed=7)))
    pipe = model.pipe
    r = pipe.process(frames)
    assert r.contact[:, 0].all()
    # the CCD's dark noise in DN (read noise and rounding), an independent truth from the CCD model
    read = math.sqrt(float(ccd.variance_dn(np.zeros((1, 1)))[0, 0]))
    err = reading_errors(pipe, frames, PixelNoise(ccd.dn_per_electron, read), readings=r)
    predicted = np.array([err.G_se[:, 0].mean(), *err.u_se[:, 0].mean(axis=0)])
    empirical = np.array([r.G[:, 0].std(ddof=1), *r.u[:, 0].std(axis=0, ddof=1)])
    # 400 frames: the sample spread is good to 3.5 % (1 sigma); the threshold's crossings add a little to G.
    # (At a quarter of the nominal signal the linearisation is off: G's spread 10 % above it, u's 20-30 %
    # below, as faint pixels cross the threshold; see optitact.pipeline.uncertainty.)
    np.testing.assert_allclose(predicted, empirical, rtol=0.12, atol=0)


def test_reading_errors_of_one_frame_are_one_row_of_the_stack(spot):
    model, ccd = spot
    rad = model.radiance(nominal_energy(model.sensor), 0.5, (0.0, 0.0))
    frames = next(model.frames(rad, 3, seed=1))
    noise = PixelNoise.from_ccd(ccd)
    stack = reading_errors(model.pipe, frames, noise)
    one = reading_errors(model.pipe, frames[1], noise)
    np.testing.assert_allclose(one.cov, stack.cov[1], rtol=1e-12, atol=0)
    assert one.cov.shape == (41, 3, 3) and np.all(one.cov[1:] == 0)   # only element 0 is lit


def test_the_conversion_gain_is_estimated_from_a_noload_and_a_pressed_stack(spot):
    model, ccd = spot
    rad = model.radiance(8 * nominal_energy(model.sensor), 1.0, (0.0, 0.0))
    pressed = np.concatenate(list(model.frames(rad, 200, seed=3)))[:, slice(*model.window[:2]),
                                                                   slice(*model.window[2:])]
    noload = np.concatenate(list(model.frames(np.zeros_like(rad), 200, seed=4)))[
        :, slice(*model.window[:2]), slice(*model.window[2:])]
    est = PixelNoise.estimate(noload, pressed)
    assert est.dn_per_electron == pytest.approx(ccd.dn_per_electron, rel=0.1)
    # the line's intercept: rounding to grey levels, 1/12 on a lit pixel whose noise spans several levels
    assert est.lit_variance == pytest.approx(1 / 12, abs=0.03)
    # dark pixels at an integer offset with 0.13 DN of read noise mostly round to the offset itself
    assert 0 <= est.read_sigma <= math.sqrt(float(ccd.variance_dn(np.zeros((1, 1)))[0, 0]))
    with pytest.raises(InputError, match="min_signal"):
        PixelNoise.estimate(noload, noload)
    with pytest.raises(ShapeError, match="noload"):
        PixelNoise.estimate(noload[0], pressed)


def test_reading_errors_refuse_a_filter_and_a_wrong_noise(spot):
    model, _ = spot
    frame = np.zeros(model.camera.shape, np.uint8)
    with pytest.raises(InputError, match="filter"):
        reading_errors(model.pipe.replace(filter="gaussian"), frame, PixelNoise(0.01))
    with pytest.raises(TypeError, match="PixelNoise"):
        reading_errors(model.pipe, frame, 0.01)
    with pytest.raises(InputError, match="dn_per_electron"):
        PixelNoise(-1.0)


# ----------------------------------------------------------------------------- propagation
def _fd_jacobian(cal, r, step):
    """dF/d(G, ux, uy) of each element by central differences of cal.forces, one input at a time."""
    E = len(cal.g)
    jac = np.zeros((E, 3, E, 3))
    for j in range(E):
        if not r.contact[j]:
            continue
        for b, h in enumerate((step * cal.g_scale[j], step * cal.u_scale[j], step * cal.u_scale[j])):
            plus, minus = (np.array(r.G), np.array(r.u)), (np.array(r.G), np.array(r.u))
            if b == 0:
                plus[0][j] += h
                minus[0][j] -= h
            else:
                plus[1][j, b - 1] += h
                minus[1][j, b - 1] -= h
            fp = cal.forces(Readings(*plus, r.contact, r.saturated))[0]
            fm = cal.forces(Readings(*minus, r.contact, r.saturated))[0]
            jac[:, :, j, b] = (fp - fm) / (2 * h)
    return jac


@pytest.mark.parametrize("coupling", [None, "crosstalk"])
def test_force_errors_are_the_jacobian_times_the_reading_covariance(cal, coupling):
    if coupling:
        k = np.zeros((len(cal.sensor.ring_counts), len(cal.sensor.ring_counts) + 1))
        k[:, :-1], k[:, -1] = 0.01, 0.05
        cal = replace(cal, crosstalk=CrossTalk(k))
    r = _readings(cal, 3)
    cov = _cov(r)
    jac = _fd_jacobian(cal, r, 3e-3)   # another step than the library's (1e-4), and through cal.forces
    expect = np.sqrt(np.einsum("eajb,jbc,eajc->ea", jac, cov, jac))
    got = cal.stderr(r, ReadingErrors(cov), model_error=False)
    np.testing.assert_allclose(got, expect, rtol=1e-4, atol=1e-9)
    np.testing.assert_allclose(cal.jacobian(r), jac, rtol=1e-4, atol=1e-7)
    assert np.all(got[5] == 0)   # no contact: no reading noise
    if coupling:   # neighbours matter: the joint inversion spreads one element's noise to others
        assert np.abs(jac[0, 2, 1:, 0]).max() > 1e-3 * np.abs(jac[0, 2, 0, 0])


def test_model_error_adds_in_quadrature_and_stacks_work(cal):
    r = _readings(cal, 4, n=3)
    cov = _cov(r)
    noise = cal.stderr(r, ReadingErrors(cov), model_error=False)
    # the shipped calibration's error measured on validation frames, at each estimated Fz and shear
    est = cal.forces(r)[0]
    em = cal.error_model
    measured = em.sigma(est[..., 2], np.hypot(est[..., 0], est[..., 1]))
    assert em.shear.any() and np.any(measured != em.sigma(est[..., 2]))
    if em.element_scale is not None:  # a scale per ring of elements
        measured = measured * em.element_scale
    np.testing.assert_allclose(cal.stderr(r, ReadingErrors(cov)) ** 2, noise**2 + measured**2, rtol=1e-12)
    fitted = replace(cal, error_model=None)  # without one: the fit residuals
    both = fitted.stderr(r, ReadingErrors(cov))
    m = fitted.model_error()
    np.testing.assert_allclose(both**2, noise**2 + m**2, rtol=1e-12)
    assert m.shape == (41, 3) and np.all(m >= np.stack([cal.residuals[k] for k in ("fx", "fy", "fz")], -1))
    one = cal.stderr(r[1], ReadingErrors(cov[1]), model_error=False)
    np.testing.assert_allclose(one, noise[1], rtol=1e-12)
    with pytest.raises(ShapeError, match="errors.cov"):
        cal.stderr(r, ReadingErrors(cov[0]))


def test_coverage_of_ideal_readings_with_noise_of_the_predicted_size_is_ninety_percent(cal):
    rng = np.random.default_rng(11)
    r = _readings(cal, 5, n=150)
    cov = _cov(r, rel_g=0.004, su=0.002)
    noisy_G = r.G + 0.0
    noisy_u = r.u + 0.0
    draw = np.einsum("...ij,...j->...i", np.linalg.cholesky(cov + 1e-30 * np.eye(3)),
                     rng.standard_normal(cov.shape[:-1]))
    noisy_G = np.where(r.contact, r.G + draw[..., 0], 0.0)
    noisy_u = np.where(r.contact[..., None], r.u + draw[..., 1:], 0.0)
    noisy = Readings(noisy_G, noisy_u, r.contact, r.saturated)
    truth = cal.forces(r)[0]
    est = cal.forces(noisy)[0]
    se = cal.stderr(noisy, ReadingErrors(cov), model_error=False)
    cover = coverage(est, truth, se, where=r.contact)
    assert np.all((cover >= 0.88) & (cover <= 0.92)), cover


def test_coverage_checks_its_input():
    with pytest.raises(ShapeError, match="same shape"):
        coverage(np.zeros((2, 3)), np.zeros((2, 3)), np.zeros((3, 3)))
    assert np.isnan(coverage(np.zeros((2, 3)), np.zeros((2, 3)), np.ones((2, 3)), where=[False, False])).all()


def test_coverage_spread_is_that_of_the_frames():
    """Elements that share their frame's fate spread as T frames do; independent ones as T x E samples."""
    from optitact.pipeline.uncertainty import coverage_spread

    rng = np.random.default_rng(4)
    t_n, e_n = 400, 41
    se = np.ones((t_n, e_n, 3))
    # each frame's elements all inside (p = 0.9) or all outside its interval
    shared = np.where(rng.random((t_n, 1, 1)) < 0.9, 0.0, 5.0) * np.ones((t_n, e_n, 3))
    sd = coverage_spread(shared, np.zeros_like(shared), se, seed=1)
    assert np.all(np.abs(sd / np.sqrt(0.09 / t_n) - 1.0) < 0.2), sd
    independent = np.where(rng.random((t_n, e_n, 3)) < 0.9, 0.0, 5.0)
    sd = coverage_spread(independent, np.zeros_like(independent), se, seed=1)
    assert np.all(np.abs(sd / np.sqrt(0.09 / (t_n * e_n)) - 1.0) < 0.2), sd
    again = coverage_spread(independent, np.zeros_like(independent), se, seed=1)
    assert np.array_equal(sd, again)  # seeded
    where = np.zeros((t_n, e_n), bool)
    where[0] = True  # one frame counted: no spread to tell
    assert np.isnan(coverage_spread(independent, np.zeros_like(independent), se, where=where)).all()
    with pytest.raises(ShapeError, match="T, E, 3"):
        coverage_spread(np.zeros((5, 3)), np.zeros((5, 3)), np.ones((5, 3)))
    with pytest.raises(ShapeError, match="where"):
        coverage_spread(independent, np.zeros_like(independent), se, where=np.ones(3, bool))



def test_error_ratio_is_one_for_honest_errors_of_any_tails_where_coverage_is_not_ninety_percent():
    """Laplace errors with the right standard errors: ratio 1, but 0.92 of them inside 1.645 of them."""
    from optitact.pipeline.uncertainty import error_ratio

    rng = np.random.default_rng(6)
    n = 200_000
    se = rng.uniform(0.5, 2.0, (n, 3))
    normal = rng.normal(0.0, se)
    laplace = rng.laplace(0.0, se / np.sqrt(2.0))  # variance 2 b^2 = se^2
    np.testing.assert_allclose(error_ratio(normal, np.zeros_like(normal), se), 1.0, atol=0.01)
    np.testing.assert_allclose(error_ratio(laplace, np.zeros_like(laplace), se), 1.0, atol=0.01)
    np.testing.assert_allclose(coverage(normal, np.zeros_like(normal), se), 0.9, atol=0.003)
    inside = 1.0 - np.exp(-1.6448536269514722 * np.sqrt(2.0))  # P(|x| < 1.645 sd) of a Laplace
    np.testing.assert_allclose(coverage(laplace, np.zeros_like(laplace), se), inside, atol=0.003)
    assert inside > 0.9
    # too narrow and too wide: the ratio says by how much
    np.testing.assert_allclose(error_ratio(normal, np.zeros_like(normal), se / 2), 2.0, rtol=0.01)
    where = np.zeros(n, bool)
    assert np.isnan(error_ratio(normal, np.zeros_like(normal), se, where=where)).all()
    with pytest.raises(InputError, match="> 0"):
        error_ratio(normal, np.zeros_like(normal), np.zeros_like(se))
    with pytest.raises(ShapeError, match="same shape"):
        error_ratio(normal, np.zeros_like(normal), se[:5])

# ----------------------------------------------------------------------------- where users see it
def test_force_field_carries_the_errors_to_its_table_csv_and_plot(cal, tmp_path):
    pytest.importorskip("matplotlib")
    r = _readings(cal, 6)
    ff = cal.apply(r, ReadingErrors(_cov(r)))
    assert ff.stderr.shape == (41, 3) and not ff.stderr.flags.writeable
    table = ff.as_dict()
    assert list(table)[-3:] == ["fx_se", "fy_se", "fz_se"]
    path = ff.to_csv(tmp_path / "f.csv")
    header = path.read_text().splitlines()[0].split(",")
    assert header == ["element", "fx", "fy", "fz", "fx_global", "fy_global", "fz_global", "contact",
                      "clamped", "saturated", "fx_se", "fy_se", "fz_se"]
    back = ForceField.from_csv(path, cal.sensor)
    np.testing.assert_array_equal(back.stderr, ff.stderr)
    fig = ff.plot(np.zeros(cal.camera.shape), cal.camera)
    gids = {p.get_gid() for p in fig.axes[0].patches}
    assert {f"shear-ci-{i}" for i in np.flatnonzero(r.contact)} <= gids
    plain = ForceField(cal.sensor, ff.local)
    assert plain.stderr is None and "fx_se" not in plain.as_dict()
    with pytest.raises(ShapeError, match="stderr"):
        ForceField(cal.sensor, ff.local, stderr=np.zeros((41, 2)))
    with pytest.raises(InputError, match="stderr"):
        ForceField(cal.sensor, ff.local, stderr=-np.ones((41, 3)))


def test_a_frame_read_end_to_end_gets_errors_from_its_pixels(spot, cal):
    model, ccd = spot
    pipe = Pipeline(model.sensor, model.camera)
    rad = model.radiance(nominal_energy(model.sensor), 0.5, (0.1, 0.0))
    frame = next(model.frames(rad, 1, seed=2))[0]
    err = reading_errors(pipe, frame, PixelNoise.from_ccd(ccd))
    assert err.G_se[0] > 0 and np.all(err.u_se[0] > 0)
    assert err.G_se[0] < 0.1 * pipe.process(frame).G[0]


def test_the_photon_transfer_intercept_is_kept_as_the_lit_pixels_variance():
    """Noise of variance c + g * signal on lit pixels (float frames: no rounding): estimate returns both,
    and reading_errors counts c in every lit pixel (var G = sum a^2 (read^2 + c + g v), a direct sum)."""
    rng = np.random.default_rng(11)
    h, w, n = 40, 50, 400
    signal = np.tile(np.linspace(0.0, 150.0, w), (h, 1))
    c, g, read = 6.0, 0.5, 0.3
    noload = 10.0 + rng.normal(0.0, read, (n, h, w))
    pressed = 10.0 + signal + rng.normal(0.0, 1.0, (n, h, w)) * np.sqrt(read**2 + np.where(signal > 0, c, 0.0)
                                                                      + g * signal)
    est = PixelNoise.estimate(noload, pressed)
    assert est.dn_per_electron == pytest.approx(g, rel=0.05)
    assert est.lit_variance == pytest.approx(c, rel=0.1)
    assert est.read_sigma == pytest.approx(read * math.sqrt(1 + 1 / n), rel=0.05)
    assert PixelNoise(0.1).lit_variance == 0.0  # stated by hand: none unless given
    with pytest.raises(InputError, match="lit_variance"):
        PixelNoise(0.1, lit_variance=-1.0)


def test_reading_errors_add_the_lit_variance_to_every_lit_pixel(spot):
    model, ccd = spot
    rad = model.radiance(nominal_energy(model.sensor), 0.5, (0.1, 0.0))
    frame = next(model.frames(rad, 1, seed=5))[0]
    pipe = model.pipe
    without = reading_errors(pipe, frame, PixelNoise(ccd.dn_per_electron, 0.2))
    with_c = reading_errors(pipe, frame, PixelNoise(ccd.dn_per_electron, 0.2, lit_variance=3.0))
    # var G is sum a^2 sigma_p^2 over the lit pixels: c adds c * sum a^2 (the same pixels are lit)
    fold = pipe.region_weights
    g = frame.reshape(-1)[fold.pixel].astype(np.float64)
    lit = (g > pipe.lit_levels(frame.dtype)) & (fold.label == 0)
    added = 3.0 * np.sum(fold.weights[0][lit] ** 2) / pipe.dn_ratio**2
    assert with_c.cov[0, 0, 0] - without.cov[0, 0, 0] == pytest.approx(added, rel=1e-9)
    diag = [np.diagonal(e.cov[0], axis1=-2, axis2=-1) for e in (with_c, without)]
    assert np.all(diag[0] > diag[1])


def test_the_photon_transfer_exponent_is_measured_when_asked_and_used_by_reading_errors(spot):
    """Noise of variance g * signal^e (e = 0.75, as a path tracer's grows; float frames): exponent="fit"
    recovers (g, e) and no intercept, where a straight line would invent one; reading_errors then uses
    v^e in every lit pixel (var G = sum a^2 (read^2 + g v^e), a direct sum)."""
    rng = np.random.default_rng(5)
    h, w, n = 40, 60, 300
    signal = np.tile(np.geomspace(2.0, 200.0, w), (h, 1))
    g, e, read = 1.3, 0.75, 0.25
    noload = 5.0 + rng.normal(0.0, read, (n, h, w))
    pressed = 5.0 + signal + rng.normal(0.0, 1.0, (n, h, w)) * np.sqrt(read**2 + g * signal**e)
    fit = PixelNoise.estimate(noload, pressed, min_signal=1.0, exponent="fit")
    assert fit.exponent == pytest.approx(e, abs=0.03) and fit.dn_per_electron == pytest.approx(g, rel=0.1)
    assert fit.lit_variance < 0.3
    line = PixelNoise.estimate(noload, pressed, min_signal=1.0)
    assert line.exponent == 1.0 and line.lit_variance > 3.0  # a straight line through a bent curve
    with pytest.raises(InputError, match="exponent"):
        PixelNoise.estimate(noload, pressed, exponent="guess")
    with pytest.raises(InputError, match="exponent"):
        PixelNoise(1.0, exponent=2.5)

    model, ccd = spot
    rad = model.radiance(nominal_energy(model.sensor), 0.5, (0.1, 0.0))
    frame = next(model.frames(rad, 1, seed=6))[0]
    pipe = model.pipe
    err = reading_errors(pipe, frame, PixelNoise(0.05, 0.2, exponent=0.7))
    fold = pipe.region_weights
    v = frame.reshape(-1)[fold.pixel].astype(np.float64) - pipe.entry_baseline
    lit = (frame.reshape(-1)[fold.pixel] > pipe.lit_levels(frame.dtype)) & (fold.label == 0)
    direct = np.sum(fold.weights[0][lit] ** 2 * (0.2**2 + 0.05 * np.maximum(v[lit], 0.0) ** 0.7))
    assert err.cov[0, 0, 0] == pytest.approx(direct / pipe.dn_ratio**2, rel=1e-9)
