"""Mitsuba scene of the optical tactile sensor: acrylic shell, rim light, contact patches, camera.

Convention
----------
Global ``(x, y, z)`` in mm as in :mod:`optitact.optics.sensor`; the film is indexed
``(row, col)`` like the closed-form camera (:mod:`optitact.optics.camera`). Any
camera model renders: :class:`FisheyeCamera` through its closed-form
equidistant plugin, the others (:mod:`optitact.optics.camera_models`, with their
distortion and pose) through a table of their pixel corners' rays
(:func:`optitact.render.rays.corner_rays`).

The geometry is built as numpy triangle meshes (cached per sensor) and handed
to Mitsuba in memory; nothing is written to disk.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from functools import lru_cache

import numpy as np

from optitact._validate import integer, positive
from optitact.optics.camera import Camera, FisheyeCamera
from optitact.optics.contact import Contacts
from optitact.errors import InputError
from optitact.optics.sensor import DomeSensor

from optitact.render.rays import corner_rays

__all__ = ["RenderSettings", "shell_mesh", "patch_polygons", "patch_mesh", "build_scene"]


@dataclass(frozen=True)
class RenderSettings:
    """Physical and numerical settings of the reference renderer.

    Parameters
    ----------
    max_depth : int
        Longest light path (segments), default 40: guided light reaches a
        patch after many total internal reflections. Russian roulette is off
        (``rr_depth = max_depth``), so no path is cut short at random.
    rim_radiance : float
        Radiance of the rim light source (arbitrary units; the CCD exposure
        maps it to digital numbers), default 1.
    rubber_reflectance : float
        Diffuse albedo of the rubber where it touches the acrylic, default 0.8.
    patch_inset : float
        Depth of a patch below the outer surface (mm), default 0.02: the patch
        lies inside the acrylic, clear of the tessellated outer surface.
    n_polar, n_azimuth : int
        Tessellation of each hemisphere (rings from apex to rim, segments
        around), default 96 x 384 (surface sag < 0.001 mm).
    patch_segments : int
        Polygon sides of a patch disc, default 24 (area kept exact).
    """

    max_depth: int = 40
    rim_radiance: float = 1.0
    rubber_reflectance: float = 0.8
    patch_inset: float = 0.02
    n_polar: int = 96
    n_azimuth: int = 384
    patch_segments: int = 24

    def __post_init__(self) -> None:
        integer(self.max_depth, "max_depth", minimum=3)
        positive(self.rim_radiance, "rim_radiance")
        positive(self.rubber_reflectance, "rubber_reflectance")
        if self.rubber_reflectance > 1.0:
            raise InputError(f"rubber_reflectance must be <= 1, got {self.rubber_reflectance}")
        positive(self.patch_inset, "patch_inset")
        integer(self.n_polar, "n_polar", minimum=4)
        integer(self.n_azimuth, "n_azimuth", minimum=8)
        integer(self.patch_segments, "patch_segments", minimum=6)

    def to_dict(self) -> dict:
        """Return the settings as a JSON-friendly dict."""
        return asdict(self)


def _orient(v: np.ndarray, f: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Flip triangles whose winding disagrees with their vertex normals."""
    e = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    flip = (e * n[f].sum(axis=1)).sum(axis=1) < 0
    f = f.copy()
    f[flip] = f[flip][:, ::-1]
    return f


def _hemisphere(radius: float, n_polar: int, n_az: int, outward: bool):
    theta = np.linspace(0.0, np.pi / 2, n_polar + 1)[1:]
    phi = 2.0 * np.pi * np.arange(n_az) / n_az
    th, ph = np.meshgrid(theta, phi, indexing="ij")
    dirs = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=-1)
    dirs[-1, :, 2] = 0.0  # the rim ring lies exactly in the base plane
    dirs = np.concatenate([[[0.0, 0.0, 1.0]], dirs.reshape(-1, 3)])
    v = radius * dirs
    idx = 1 + np.arange(n_polar * n_az).reshape(n_polar, n_az)
    nxt = np.roll(idx, -1, axis=1)
    faces = [np.stack([np.zeros(n_az, int), idx[0], nxt[0]], axis=1)]
    a, b, c, d = idx[:-1], nxt[:-1], idx[1:], nxt[1:]
    faces += [np.stack([a, c, d], axis=-1).reshape(-1, 3), np.stack([a, d, b], axis=-1).reshape(-1, 3)]
    f = np.concatenate(faces)
    n = dirs if outward else -dirs
    return v, _orient(v, f, n), n


def _annulus(r_in: float, r_out: float, z: float, n_az: int, normal_z: float):
    phi = 2.0 * np.pi * np.arange(n_az) / n_az
    ring = np.stack([np.cos(phi), np.sin(phi), np.zeros(n_az)], axis=-1)
    v = np.concatenate([r_in * ring, r_out * ring])
    v[:, 2] = z
    i = np.arange(n_az)
    j = np.roll(i, -1)
    f = np.concatenate([np.stack([i, j, n_az + i], axis=1), np.stack([j, n_az + j, n_az + i], axis=1)])
    n = np.tile([0.0, 0.0, normal_z], (2 * n_az, 1))
    return v, _orient(v, f, n), n


@lru_cache(maxsize=8)
def shell_mesh(r_in: float, r_out: float, n_polar: int, n_az: int, emitter_gap: float = 0.01):
    """Triangle meshes ``(vertices, faces, normals)`` of the shell and the rim light.

    Returns a dict with keys ``outer`` (normals outward), ``inner`` (normals
    towards the dome centre, i.e. out of the acrylic), ``rim`` (the base
    annulus of the shell, normal -z) and ``light`` (an annulus ``emitter_gap``
    mm below the rim, normal +z, facing the rim). Normals point out of the
    acrylic, as Mitsuba's dielectric expects (interior = acrylic).
    """
    return {
        "outer": _hemisphere(r_out, n_polar, n_az, outward=True),
        "inner": _hemisphere(r_in, n_polar, n_az, outward=False),
        "rim": _annulus(r_in, r_out, 0.0, n_az, -1.0),
        "light": _annulus(r_in, r_out, -emitter_gap, n_az, 1.0),
    }


def patch_polygons(contacts: Contacts, *, radius: float, inset: float, segments: int):
    """The flat polygon of every touching cone, or None if nothing touches.

    Each polygon is a regular ``segments``-gon in the tangent plane at its
    patch centre, ``inset`` mm inside the outer surface, with circumradius
    scaled so that its area equals the contact area ``pi a^2``; its vertex
    ``j`` lies at angle ``2 pi j / segments`` from ``u`` towards ``w``.

    Returns
    -------
    tuple or None
        ``(mid, normal, u, w, circumradius, radius)``: polygon centres (m, 3),
        outward unit normals, in-plane unit axes, circumradii and contact radii
        (m,), for the touching cones in row-major ``(element, cone)`` order.
    """
    touching = contacts.radii > 0
    if not touching.any():
        return None
    centers = contacts.centers[touching]
    radii = contacts.radii[touching]
    normal = centers / np.linalg.norm(centers, axis=1, keepdims=True)
    helper = np.where(np.abs(normal[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    u = np.cross(helper, normal)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    w = np.cross(normal, u)
    k = segments
    circ = radii * math.sqrt(2.0 * math.pi / (k * math.sin(2.0 * math.pi / k)))
    return (radius - inset) * normal, normal, u, w, circ, radii


def patch_mesh(contacts: Contacts, *, radius: float, inset: float, segments: int):
    """One triangle mesh with the flat polygon (:func:`patch_polygons`) of each touching cone, or None."""
    poly = patch_polygons(contacts, radius=radius, inset=inset, segments=segments)
    if poly is None:
        return None
    mid, normal, u, w, circ, radii = poly
    k = segments
    ang = 2.0 * np.pi * np.arange(k) / k
    rim = (mid[:, None, :] + circ[:, None, None]
           * (np.cos(ang)[None, :, None] * u[:, None, :] + np.sin(ang)[None, :, None] * w[:, None, :]))
    m = len(radii)
    v = np.concatenate([mid[:, None, :], rim], axis=1).reshape(-1, 3)
    base = (k + 1) * np.arange(m)[:, None]
    i = np.arange(k)
    f = np.stack([np.broadcast_to(base, (m, k)), base + 1 + i, base + 1 + (i + 1) % k], axis=-1)
    f = f.reshape(-1, 3)
    n = np.repeat(-normal, k + 1, axis=0)  # faces towards the dome centre (the camera)
    return v, _orient(v, f, n), n


def _mi_mesh(mi, name: str, data, props) -> object:
    v, f, n = data
    mesh = mi.Mesh(name, len(v), len(f), props=props, has_vertex_normals=n is not None)
    params = mi.traverse(mesh)
    arrays = [("vertex_positions", v, np.float32), ("faces", f, np.uint32)]
    if n is not None:
        arrays.append(("vertex_normals", n, np.float32))
    for key, arr, dtype in arrays:
        params[key] = type(params[key])(np.ascontiguousarray(arr, dtype=dtype).ravel())
    params.update()
    return mesh


_SENSOR_REGISTERED: set = set()


def _patch_groups(sensor: DomeSensor, contacts: Contacts, settings_reflectance: float):
    """``(name, contacts, gain)`` per patch mesh: one mesh, or one per distinct element gain (as built).

    An element's gain (:attr:`DomeSensor.element_gain`) scales its rubber's
    reflectance, so its spots' brightness; the product must stay at most 1.
    """
    if not sensor.element_gain:
        yield "patches", contacts, 1.0
        return
    from dataclasses import replace

    gains = sensor.gains
    if settings_reflectance * gains.max() > 1.0:
        raise InputError(f"transport='path' scales the rubber's reflectance ({settings_reflectance:g}) by each "
                         f"element's gain; the largest gain {gains.max():.4g} makes it exceed 1 (at most "
                         f"{1.0 / settings_reflectance:.4g}): render with transport='two_stage' or lower "
                         f"rubber_reflectance")
    for i, g in enumerate(np.unique(gains[contacts.in_contact.any(axis=1)])):
        keep = (gains == g)[:, None]
        yield f"patches_{i}", replace(contacts, radii=np.where(keep, contacts.radii, 0.0)), float(g)


def register_fisheye(mi) -> str:
    """Register the sensor plugins for the active variant; return the full-frame fisheye one.

    ``optitact_fisheye`` is the closed-form equidistant fisheye of
    :class:`FisheyeCamera` and renders the film (or its crop window);
    ``optitact_fisheye_packed`` renders a list of image pixels packed into a
    small film: film pixel ``k`` (row-major) is image pixel ``(rows[k],
    cols[k])``, a sample keeps its sub-pixel position (so each listed pixel
    is integrated exactly as in a full frame), and film pixels past the list
    look away from the dome (they read 0). ``optitact_ray_table`` and
    ``optitact_ray_table_packed`` do the same for any other camera model
    from a table of corner rays (see :func:`~optitact.render.rays.corner_rays`). :func:`build_scene`
    sets the tables on the loaded sensor.
    """
    name = "optitact_fisheye"
    if mi.variant() in _SENSOR_REGISTERED:
        return name
    from optitact._optional import require

    dr = require("drjit", purpose="rendering")
    jit = dr.is_jit_v(mi.Float)

    class Lens(mi.Sensor):
        """A sensor whose rays carry no differentials."""

        def sample_ray_differential(self, time, wavelength_sample, position_sample,
                                    aperture_sample, active=True):
            ray, weight = self.sample_ray(time, wavelength_sample, position_sample,
                                          aperture_sample, active)
            return mi.RayDifferential3f(ray), weight

    class Fisheye(Lens):
        """Equidistant fisheye on the dome axis; same model as :class:`FisheyeCamera`."""

        def __init__(self, props):
            super().__init__(props)
            self.focal = float(props.get("focal_px"))
            self.cz = float(props.get("camera_z"))

        def image_position(self, position_sample):
            """Image film position (x = col + 0.5 at a pixel centre), image size, and validity."""
            film = self.film()
            p = (mi.ScalarVector2f(film.crop_offset())
                 + position_sample * mi.ScalarVector2f(film.crop_size()))
            return p.x, p.y, mi.ScalarVector2f(film.size()), None

        def sample_ray(self, time, wavelength_sample, position_sample, aperture_sample,
                       active=True):
            x, y, size, listed = self.image_position(position_sample)
            dx = x - 0.5 * size.x  # principal point at the image centre
            dy = y - 0.5 * size.y
            r = dr.sqrt(dx * dx + dy * dy)
            alpha = r / self.focal
            s = dr.select(r > 1e-12, dr.sin(alpha) / r, 0.0)
            d = mi.Vector3f(dx * s, dy * s, dr.cos(alpha))
            if listed is not None:
                d = dr.select(listed, d, mi.Vector3f(0.0, 0.0, -1.0))
            ray = mi.Ray3f(mi.Point3f(0.0, 0.0, self.cz), d, time, [])
            return ray, mi.Spectrum(1.0)

        def to_string(self):
            return f"Fisheye[focal_px={self.focal}, z={self.cz}]"

    class PackedFisheye(Fisheye):
        """The fisheye rendering only listed image pixels, packed into a small film."""

        def __init__(self, props):
            super().__init__(props)
            self.image_size = mi.ScalarVector2f(float(props.get("image_width")),
                                                float(props.get("image_height")))
            self.n_pixels = 0
            self.rows = mi.Float(0.0)
            self.cols = mi.Float(0.0)

        def image_position(self, position_sample):
            film = self.film()
            p = position_sample * mi.ScalarVector2f(film.size())
            fx, fy = dr.floor(p.x), dr.floor(p.y)
            k = mi.UInt32(fy) * mi.UInt32(int(film.size()[0])) + mi.UInt32(fx)
            listed = k < self.n_pixels
            k = dr.select(listed, k, 0)
            x = dr.gather(mi.Float, self.cols, k) + (p.x - fx)
            y = dr.gather(mi.Float, self.rows, k) + (p.y - fy)
            return x, y, self.image_size, listed

        def to_string(self):
            return f"PackedFisheye[focal_px={self.focal}, z={self.cz}, pixels={self.n_pixels}]"

    def gather3(table, index):
        if jit:
            return dr.gather(mi.Vector3f, table, index)
        return mi.Vector3f(*(float(v) for v in table[int(index)]))

    def gather1(table, index):
        return dr.gather(mi.Float, table, index) if jit else float(table[int(index)])

    def cell_of(q, size):
        """Cell ``(column, row)`` of a film position (clamped into the film) and the offsets in it."""
        jx = dr.clip(dr.floor(q.x), 0.0, size.x - 1.0)
        jy = dr.clip(dr.floor(q.y), 0.0, size.y - 1.0)
        return mi.UInt32(jx), mi.UInt32(jy), q.x - jx, q.y - jy

    class RayTable(Lens):
        """Any camera model: rays interpolated bilinearly between the pixel corners' rays.

        ``corners`` holds the unit dome-frame ray of every corner of the film's
        (crop window's) pixels, ``(h + 1) x (w + 1) x 3`` row-major, and
        ``valid`` 1 per pixel whose 4 corners have a ray (0: the pixel's
        samples miss with weight 0).
        """

        def __init__(self, props):
            super().__init__(props)
            self.origin = mi.Point3f(float(props.get("origin_x")), float(props.get("origin_y")),
                                     float(props.get("origin_z")))
            self.corners = mi.Float(0.0)
            self.valid = mi.Float(0.0)

        def cell(self, position_sample):
            """Pixel (table cell) index, its first corner's index, the corner row stride, offsets, listed."""
            size = mi.ScalarVector2f(self.film().crop_size())
            jx, jy, u, v = cell_of(position_sample * size, size)
            w = mi.UInt32(int(size.x))
            return jy * w + jx, jy * (w + 1) + jx, w + 1, u, v, None

        def sample_ray(self, time, wavelength_sample, position_sample, aperture_sample,
                       active=True):
            k, base, stride, u, v, listed = self.cell(position_sample)
            d00 = gather3(self.corners, base)
            d01 = gather3(self.corners, base + 1)
            d10 = gather3(self.corners, base + stride)
            d11 = gather3(self.corners, base + stride + 1)
            d = (d00 * (1.0 - u) + d01 * u) * (1.0 - v) + (d10 * (1.0 - u) + d11 * u) * v
            ok = gather1(self.valid, k) > 0.5
            if listed is not None:
                ok = ok & listed
            d = dr.select(ok, dr.normalize(d), mi.Vector3f(0.0, 0.0, -1.0))
            ray = mi.Ray3f(self.origin, d, time, [])
            return ray, mi.Spectrum(dr.select(ok, 1.0, 0.0))

        def to_string(self):
            return f"RayTable[origin={self.origin}]"

    class PackedRayTable(RayTable):
        """The ray table rendering only listed image pixels, packed into a small film.

        ``corners`` holds the 4 corner rays of each listed pixel (``n x 2 x 2
        x 3``), ``valid`` one flag per listed pixel.
        """

        def __init__(self, props):
            super().__init__(props)
            self.n_pixels = 0

        def cell(self, position_sample):
            size = mi.ScalarVector2f(self.film().size())
            jx, jy, u, v = cell_of(position_sample * size, size)
            k = jy * mi.UInt32(int(size.x)) + jx
            listed = k < self.n_pixels
            k = dr.select(listed, k, 0)
            return k, 4 * k, 2, u, v, listed

        def to_string(self):
            return f"PackedRayTable[origin={self.origin}, pixels={self.n_pixels}]"

    mi.register_sensor(name, lambda props: Fisheye(props))
    mi.register_sensor(PACKED_SENSOR, lambda props: PackedFisheye(props))
    mi.register_sensor(TABLE_SENSOR, lambda props: RayTable(props))
    mi.register_sensor(PACKED_TABLE_SENSOR, lambda props: PackedRayTable(props))
    _SENSOR_REGISTERED.add(mi.variant())
    return name


#: Width of the packed film that holds a pixel list (see :func:`build_scene`).
PACKED_WIDTH = 256
#: Name of the packed-pixel fisheye plugin (see :func:`register_fisheye`).
PACKED_SENSOR = "optitact_fisheye_packed"
#: Names of the ray-table plugins for any camera model, full film and packed pixels.
TABLE_SENSOR = "optitact_ray_table"
PACKED_TABLE_SENSOR = "optitact_ray_table_packed"


def build_scene(mi, sensor: DomeSensor, camera: Camera, contacts: Contacts,
                settings: RenderSettings, *, crop: tuple[int, int, int, int] | None = None,
                pixels: np.ndarray | None = None, instanced: bool = False):
    """Assemble the Mitsuba scene for one frame.

    Parameters
    ----------
    mi : module
        The mitsuba module with the variant already set.
    sensor, camera, contacts, settings
        What to render.
    crop : (row0, col0, height, width), optional
        Render only this window of the film.
    pixels : (n,) int array, optional
        Render only these flat pixel indices (``row * width + col``), packed
        row-major into a film ``PACKED_WIDTH`` wide (see
        :func:`register_fisheye`).

    The camera is any :class:`~optitact.optics.camera.Camera`: a
    :class:`FisheyeCamera` gets the closed-form equidistant plugin, another
    model the ray-table plugin, its rays starting at ``camera.position``
    and interpolated between the pixel corners' rays (:func:`~optitact.render.rays.corner_rays`,
    cached per camera and window; the table re-projects within 0.001 px).
    instanced : bool
        Put the shell (about 150,000 triangles at the default tessellation)
        in a shape group drawn by one instance. The scene then builds faster,
        but every ray pays a two-level traversal (slower tracing): worth
        it for light renders (a few thousand pixels, tens of samples), not
        for full frames at many samples. The geometry is the same; pixels
        differ only by floating-point rounding of the intersections.

    Notes
    -----
    Physics: an acrylic dielectric shell (``int_ior = n``, ``ext_ior = 1``)
    closed by its rim annulus; a Lambertian emitter just below the rim injects
    light, which the shell guides by total internal reflection. Where a cone
    touches, a diffuse rubber patch inside the outer surface scatters the
    guided light (frustrated TIR); the part scattered below the critical angle
    leaves through the inner surface towards the camera. Unloaded
    elements get no geometry.
    """
    shell = shell_mesh(sensor.inner_radius, sensor.outer_radius, settings.n_polar,
                       settings.n_azimuth)
    acrylic = mi.load_dict({"type": "dielectric", "int_ior": float(sensor.refractive_index),
                            "ext_ior": 1.0})
    shell_shapes = {}
    for name in ("outer", "inner", "rim"):
        props = mi.Properties()
        props["bsdf"] = acrylic
        shell_shapes[f"shell_{name}"] = _mi_mesh(mi, f"shell_{name}", shell[name], props)
    if instanced:
        objects = {"shell": {"type": "shapegroup", "id": "optitact_shell", **shell_shapes},
                   "shell_instance": {"type": "instance", "shell": {"type": "ref", "id": "optitact_shell"}}}
    else:
        objects = dict(shell_shapes)
    props = mi.Properties()
    props["bsdf"] = mi.load_dict({"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.0}})
    props["emitter"] = mi.load_dict({"type": "area", "radiance": {
        "type": "rgb", "value": float(settings.rim_radiance)}})
    objects["rim_light"] = _mi_mesh(mi, "rim_light", shell["light"], props)
    for name, part, gain in _patch_groups(sensor, contacts, settings.rubber_reflectance):
        patches = patch_mesh(part, radius=sensor.outer_radius, inset=settings.patch_inset,
                             segments=settings.patch_segments)
        if patches is None:
            continue
        props = mi.Properties()
        props["bsdf"] = mi.load_dict({"type": "twosided", "bsdf": {
            "type": "diffuse",
            "reflectance": {"type": "rgb", "value": float(settings.rubber_reflectance * gain)}}})
        v, f, _ = patches
        objects[name] = _mi_mesh(mi, name, (v, f, None), props)

    film = {"type": "hdrfilm", "width": camera.width, "height": camera.height,
            "pixel_format": "luminance", "rfilter": {"type": "box"}, "sample_border": False}
    fisheye = isinstance(camera, FisheyeCamera)
    register_fisheye(mi)
    if fisheye:
        lens = {"type": "optitact_fisheye" if pixels is None else PACKED_SENSOR,
                "focal_px": camera.focal_px, "camera_z": float(camera.z)}
    else:
        ox, oy, oz = (float(v) for v in camera.position)
        lens = {"type": TABLE_SENSOR if pixels is None else PACKED_TABLE_SENSOR,
                "origin_x": ox, "origin_y": oy, "origin_z": oz}
    if pixels is not None:
        n = len(pixels)
        film.update(width=min(n, PACKED_WIDTH), height=-(-n // PACKED_WIDTH))
        if fisheye:
            lens.update(image_width=camera.width, image_height=camera.height)
    if crop is not None:
        r0, c0, h, w = crop
        film.update(crop_offset_x=int(c0), crop_offset_y=int(r0), crop_width=int(w),
                    crop_height=int(h))
    scene = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": settings.max_depth,
                       "rr_depth": settings.max_depth},
        "camera": {**lens, "film": film, "sampler": {"type": "independent", "sample_count": 1}},
        **objects,
    }
    loaded = mi.load_dict(scene)
    lens_obj = loaded.sensors()[0]
    if pixels is not None and fisheye:
        rows, cols = np.divmod(np.asarray(pixels, dtype=np.int64), camera.width)
        lens_obj.rows = mi.Float(rows.astype(np.float32))
        lens_obj.cols = mi.Float(cols.astype(np.float32))
        lens_obj.n_pixels = len(rows)
    elif not fisheye:
        rays, valid = corner_rays(camera, crop=crop, pixels=pixels)
        if pixels is not None:
            lens_obj.n_pixels = len(pixels)
        _set_tables(mi, lens_obj, rays.reshape(-1, 3), valid.reshape(-1).astype(np.float32))
    return loaded


def _set_tables(mi, lens, rays: np.ndarray, valid: np.ndarray) -> None:
    """Hand the corner rays and pixel flags to a ray-table sensor (flat Dr.Jit arrays; numpy on scalar)."""
    import drjit as dr

    if dr.is_jit_v(mi.Float):
        lens.corners = mi.Float(np.ascontiguousarray(rays, np.float32).ravel())
        lens.valid = mi.Float(np.ascontiguousarray(valid, np.float32))
    else:
        lens.corners, lens.valid = rays, valid
