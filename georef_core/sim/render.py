"""Ray-cast rendering of the textured site and JPEG + EXIF writing.

The truth surface is sampled on a regular grid of site coordinates (``mesh_step_m``), every node is
mapped rigorously to the local ENU frame (project CRS -> geodetic -> ECEF -> ENU) and the grid is
triangulated (two triangles per cell). Rays are cast with Open3D's Embree-based
``RaycastingScene``: one ray per pixel, through the *undistorted* direction of the pixel centre, from
the camera centre at the exposure instant (global shutter). The hit's barycentric coordinates give
its site coordinates, where the mip-mapped texture (sun shading baked in) is sampled. A mild optical
blur, vignetting, an exposure gain jitter and sensor noise are applied before JPEG encoding.
"""

from __future__ import annotations

import datetime as _dt
import math
from dataclasses import dataclass
from fractions import Fraction

import numpy as np

from .camera import CameraModel


def _import_open3d():
    try:
        import open3d as o3d  # noqa: F401
        import open3d.core as o3c  # noqa: F401
    except ImportError as exc:  # pragma: no cover - depends on the machine
        raise ImportError(
            "georef_core.sim rendering needs open3d (pip install open3d-cpu); on Debian it also needs "
            "the system library libusb-1.0-0 (apt-get install -y libusb-1.0-0)") from exc
    return o3d, o3c


@dataclass
class RenderOptions:
    mesh_step_m: float = 0.2  # spacing of the height-field triangulation
    blur_sigma_px: float = 0.0  # extra optical blur (Gaussian); the mip-mapped texture is already band-limited
    vignetting: float = 0.12  # relative darkening at the image corners
    gain_jitter: float = 0.03  # RMS of the per-image exposure gain
    noise_dn: float = 1.2  # RMS sensor noise in 8-bit units
    # stronger radiometry for orthophoto-mosaicking tests (default off: seeded scenes keep their pixels):
    # a per-image exposure gain drawn uniformly in 1 +- exposure_spread (its own seeded stream, on top of
    # gain_jitter), and a cos^4-like radial falloff 1 / (1 + k rho^2)^2 this much darker at the corners
    # (rho = distance to the principal point / half the image diagonal); truth in truth/radiometry.json
    exposure_spread: float = 0.0
    vignetting_cos4: float = 0.0
    jpeg_quality: int = 92
    background_rgb: tuple[int, int, int] = (120, 125, 130)  # rays that hit nothing
    threads: int = 0  # Open3D threads (0: all cores)


class TerrainMesh:
    """Triangulated truth surface in local ENU, with a ray-casting scene."""

    def __init__(self, site, bounds: tuple[float, float, float, float], step: float):
        o3d, o3c = _import_open3d()
        xmin, ymin, xmax, ymax = bounds
        self.step = float(step)
        self.nx = int(math.ceil((xmax - xmin) / step)) + 1
        self.ny = int(math.ceil((ymax - ymin) / step)) + 1
        self.x0 = float(xmin)
        self.y0 = float(ymin)
        self.z = site.surface_grid(self.x0, self.y0, self.nx, self.ny, self.step)
        xs = self.x0 + np.arange(self.nx) * self.step
        ys = self.y0 + np.arange(self.ny) * self.step
        X, Y = np.meshgrid(xs, ys)
        self.vertices_enu = site.frame.site_to_enu(X.ravel(), Y.ravel(), self.z.ravel())
        idx = np.arange(self.nx * self.ny, dtype=np.int64).reshape(self.ny, self.nx)
        a = idx[:-1, :-1].ravel()
        b = idx[:-1, 1:].ravel()
        c = idx[1:, :-1].ravel()
        d = idx[1:, 1:].ravel()
        self.n_cells = a.size
        # triangle 0 of a cell: (i,j) (i,j+1) (i+1,j+1); triangle 1: (i,j) (i+1,j+1) (i+1,j)
        tris = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)]).astype(np.uint32)
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(o3c.Tensor(self.vertices_enu.astype(np.float32)), o3c.Tensor(tris))
        self._o3c = o3c

    def hits_to_site_xy(self, prim: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Site coordinates of ray hits from Open3D's primitive ids and barycentric (u, v)."""
        prim = prim.astype(np.int64)
        second = prim >= self.n_cells
        cell = np.where(second, prim - self.n_cells, prim)
        i = cell // (self.nx - 1)
        j = cell - i * (self.nx - 1)
        u = uv[:, 0].astype(np.float64)
        v = uv[:, 1].astype(np.float64)
        # point = (1-u-v) P0 + u P1 + v P2; offsets (dj, di) of P0, P1, P2: tri0 (0,0) (1,0) (1,1), tri1 (0,0) (1,1) (0,1)
        dj = np.where(second, u, u + v)
        di = np.where(second, u + v, v)
        return self.x0 + (j + dj) * self.step, self.y0 + (i + di) * self.step

    def cast(self, origins: np.ndarray, dirs: np.ndarray, threads: int = 0) -> dict:
        rays = np.empty((len(dirs), 6), dtype=np.float32)
        rays[:, :3] = origins
        rays[:, 3:] = dirs
        return self.cast_rays(rays, threads)

    def cast_rays(self, rays: np.ndarray, threads: int = 0) -> dict:
        """Cast (N, 6) float32 rays (origin, direction); returns t_hit, primitive_ids, primitive_uvs."""
        ans = self.scene.cast_rays(self._o3c.Tensor.from_numpy(rays), nthreads=threads)
        return {k: ans[k].numpy() for k in ("t_hit", "primitive_ids", "primitive_uvs")}

    def shadow_function(self, sun_enu: np.ndarray, threads: int = 0):
        """``f(x, y) -> visibility in [0, 1]`` of the sun, bilinear between mesh nodes."""
        v = self.vertices_enu
        n = len(v)
        rays = np.empty((n, 6), dtype=np.float32)
        rays[:, :3] = v + sun_enu[None, :] * 0.05 + np.array([0.0, 0.0, 0.02])
        rays[:, 3:] = sun_enu[None, :]
        occ = self.scene.test_occlusions(self._o3c.Tensor(rays), nthreads=threads).numpy()
        vis = (~occ.astype(bool)).astype(np.float32).reshape(self.ny, self.nx)
        x0, y0, s = self.x0, self.y0, self.step

        def f(x, y):
            from scipy.ndimage import map_coordinates

            x = np.asarray(x, dtype=float)
            y = np.asarray(y, dtype=float)
            coords = np.stack([((y - y0) / s).ravel(), ((x - x0) / s).ravel()])
            return map_coordinates(vis, coords, order=1, mode="nearest").reshape(x.shape)

        return f


class Renderer:
    """Renders images of a :class:`TerrainMesh` with a texture through a :class:`CameraModel`.

    Thread-safe: :meth:`render` keeps no state, so several images may be rendered at once."""

    def __init__(self, mesh: TerrainMesh, texture, camera: CameraModel, options: RenderOptions | None = None,
                 seed: int = 0):
        self.mesh = mesh
        self.texture = texture
        self.camera = camera
        self.options = options or RenderOptions()
        rc = camera.pixel_rays().reshape(-1, 3)
        self._ray_cols = [np.ascontiguousarray(rc[:, k], dtype=np.float32) for k in range(3)]
        u, v = np.meshgrid(np.arange(camera.width) - camera.cx, np.arange(camera.height) - camera.cy)
        rr = (u / (0.5 * camera.width)) ** 2 + (v / (0.5 * camera.width)) ** 2
        self.vignette = (1.0 - self.options.vignetting * np.clip(rr / 1.5625, 0, None)).astype(np.float32)
        if self.options.vignetting_cos4 > 0:
            rho2 = (u ** 2 + v ** 2) / (0.25 * (camera.width ** 2 + camera.height ** 2))
            self.vignette *= cos4_falloff(rho2, self.options.vignetting_cos4).astype(np.float32)
        n = camera.width * camera.height * 3
        bank_rng = np.random.default_rng(np.random.SeedSequence([int(seed), 404]))
        self._noise = (bank_rng.standard_normal(n + 65536, dtype=np.float32) * np.float32(self.options.noise_dn))

    def render(self, R_cam_to_enu: np.ndarray, centre_enu: np.ndarray, rng: np.random.Generator | None = None,
               band_rows: int = 160, velocity_enu_m_s=None, exposure_gain: float = 1.0,
               gain_out: list | None = None) -> np.ndarray:
        """uint8 RGB image (height, width, 3) of the site seen from a camera pose (local ENU).

        ``velocity_enu_m_s``: the camera's velocity, for a rolling-shutter camera (``camera.readout_s`` > 0):
        each row is seen from where the camera was at that row's exposure (``camera.row_time_s``).

        ``rng`` draws the exposure gain jitter and the sensor-noise offset; None: no noise. The image is
        processed in bands of rows (smaller temporaries: less memory traffic, no page-fault storms).
        ``exposure_gain`` multiplies the drawn gain; ``gain_out`` (a list) receives the total gain applied."""
        cam = self.camera
        o = self.options
        W, H = cam.width, cam.height
        R = np.asarray(R_cam_to_enu, dtype=np.float64)
        c32 = np.asarray(centre_enu, dtype=np.float32)
        rolling = cam.readout_s > 0 and velocity_enu_m_s is not None
        vel = np.asarray(velocity_enu_m_s, dtype=np.float64) if rolling else None
        gain = 1.0
        off = -1  # no sensor noise
        if rng is not None and o.gain_jitter > 0:
            gain = float(1.0 + o.gain_jitter * rng.standard_normal())
        gain *= float(exposure_gain)
        if gain_out is not None:
            gain_out.append(gain)
        if rng is not None and o.noise_dn > 0:
            off = int(rng.integers(0, 65536))
        blur = o.blur_sigma_px > 0
        fimg = np.empty((H, W, 3), dtype=np.float32) if blur else None
        out = np.empty((H, W, 3), dtype=np.uint8)
        # level of detail: one per image, from the distance along the optical axis at the centre pixel
        centre_ray = np.array([[*c32, *(R @ np.array([0.0, 0.0, 1.0]))]], dtype=np.float32)
        t_c = float(self.mesh.cast_rays(centre_ray, o.threads)["t_hit"][0])
        foot = (t_c if math.isfinite(t_c) else 1.0) / cam.fx
        dx, dy, dz = self._ray_cols
        for r0 in range(0, H, band_rows):
            r1 = min(H, r0 + band_rows)
            sl = slice(r0 * W, r1 * W)
            n = (r1 - r0) * W
            rays = np.empty((n, 6), dtype=np.float32)
            if rolling:  # one camera centre per row
                t_row = cam.row_time_s(np.arange(r0, r1))
                rays[:, :3] = np.repeat((c32[None] + t_row[:, None] * vel).astype(np.float32), W, axis=0)
            else:
                rays[:, :3] = c32
            tmp = np.empty(n, dtype=np.float32)
            for k in range(3):  # world direction = R @ camera direction, column by column (no BLAS)
                col = rays[:, 3 + k]
                np.multiply(dx[sl], np.float32(R[k, 0]), out=col)
                np.multiply(dy[sl], np.float32(R[k, 1]), out=tmp)
                col += tmp
                np.multiply(dz[sl], np.float32(R[k, 2]), out=tmp)
                col += tmp
            ans = self.mesh.cast_rays(rays, o.threads)
            del rays, tmp
            ok = np.isfinite(ans["t_hit"])
            if ok.all():
                x, y = self.mesh.hits_to_site_xy(ans["primitive_ids"], ans["primitive_uvs"])
                rgb = self.texture.sample(x, y, foot)
            else:
                rgb = np.empty((n, 3), dtype=np.float32)
                rgb[:] = np.asarray(o.background_rgb, dtype=np.float32)
                if ok.any():
                    x, y = self.mesh.hits_to_site_xy(ans["primitive_ids"][ok], ans["primitive_uvs"][ok])
                    rgb[ok] = self.texture.sample(x, y, foot)
            if blur:
                fimg[r0:r1] = rgb.reshape(r1 - r0, W, 3)
                continue
            out[r0:r1] = self._finish(rgb, r0, r1, gain, off)
        if blur:
            from scipy.ndimage import gaussian_filter

            fimg = gaussian_filter(fimg, sigma=(o.blur_sigma_px, o.blur_sigma_px, 0), mode="nearest")
            for r0 in range(0, H, band_rows):
                r1 = min(H, r0 + band_rows)
                out[r0:r1] = self._finish(fimg[r0:r1].reshape(-1, 3), r0, r1, gain, off)
        return out

    def _finish(self, rgb: np.ndarray, r0: int, r1: int, gain: float, off: int) -> np.ndarray:
        """Vignetting, gain, sensor noise and quantisation of rows r0:r1 given as (n, 3) float32."""
        W = self.camera.width
        rgb *= (self.vignette[r0:r1].reshape(-1, 1) * np.float32(gain))
        if self.options.noise_dn > 0 and off >= 0:
            rgb += self._noise[off + r0 * W * 3: off + r1 * W * 3].reshape(-1, 3)
        rgb += 0.5
        np.clip(rgb, 0, 255, out=rgb)
        return rgb.astype(np.uint8).reshape(r1 - r0, W, 3)


def cos4_falloff(rho2: np.ndarray, corner_loss: float) -> np.ndarray:
    """Radial falloff ``1 / (1 + k rho^2)^2`` (the cos^4 law of a lens whose corner ray is at atan(sqrt(k))),
    k chosen so that it is ``1 - corner_loss`` at rho = 1 (the image corners); ``rho2`` = rho^2."""
    k = 1.0 / math.sqrt(1.0 - float(corner_loss)) - 1.0
    return 1.0 / (1.0 + k * np.asarray(rho2, dtype=np.float64)) ** 2


def exposure_gains(seed: int, indices, spread: float) -> np.ndarray:
    """The simulator's extra per-image exposure gains, uniform in 1 +- ``spread`` (1 where spread is 0), one
    seeded stream per image index (independent of the rendering order)."""
    if spread <= 0:
        return np.ones(len(indices))
    return np.array([1.0 + spread * (2.0 * np.random.default_rng(np.random.SeedSequence([int(seed), 606, int(i)])).random()
                                     - 1.0) for i in indices])


# ---- JPEG + EXIF -------------------------------------------------------------------------------------
def _rational(x: float, den: int = 10000) -> tuple[int, int]:
    f = Fraction(x).limit_denominator(den)
    return f.numerator, f.denominator


def _dms(deg: float) -> tuple:
    deg = abs(deg)
    d = int(deg)
    m_float = (deg - d) * 60
    m = int(m_float)
    s = (m_float - m) * 60
    return ((d, 1), (m, 1), (int(round(s * 10000)), 10000))


def exif_bytes(camera: CameraModel, exposure_utc: _dt.datetime, gps_lat_lon_h: tuple[float, float, float] | None = None,
               exposure_time_s: float = 1 / 1000, software: str = "georef_core.sim") -> bytes:
    """EXIF block: times (UTC, with sub-seconds), focal length, focal-plane resolution, 35 mm focal, GPS."""
    import piexif

    stamp = exposure_utc.strftime("%Y:%m:%d %H:%M:%S").encode()
    sub = f"{exposure_utc.microsecond // 1000:03d}".encode()
    px_per_cm = 10.0 / camera.pixel_size_mm
    zeroth = {
        piexif.ImageIFD.Make: camera.make.encode(),
        piexif.ImageIFD.Model: camera.model.encode(),
        piexif.ImageIFD.Software: software.encode(),
        piexif.ImageIFD.DateTime: stamp,
        piexif.ImageIFD.Orientation: 1,
    }
    exif = {
        piexif.ExifIFD.DateTimeOriginal: stamp,
        piexif.ExifIFD.DateTimeDigitized: stamp,
        piexif.ExifIFD.SubSecTimeOriginal: sub,
        piexif.ExifIFD.SubSecTimeDigitized: sub,
        piexif.ExifIFD.FocalLength: _rational(camera.focal_mm),
        piexif.ExifIFD.FocalLengthIn35mmFilm: int(round(camera.focal_35mm_equiv)),
        piexif.ExifIFD.FocalPlaneXResolution: _rational(px_per_cm, 1000),
        piexif.ExifIFD.FocalPlaneYResolution: _rational(px_per_cm, 1000),
        piexif.ExifIFD.FocalPlaneResolutionUnit: 3,  # centimetres
        piexif.ExifIFD.PixelXDimension: camera.width,
        piexif.ExifIFD.PixelYDimension: camera.height,
        piexif.ExifIFD.ExposureTime: _rational(exposure_time_s, 100000),
        piexif.ExifIFD.FNumber: (28, 10),
        piexif.ExifIFD.ISOSpeedRatings: 100,
    }
    offset_tag = getattr(piexif.ExifIFD, "OffsetTimeOriginal", None)
    if offset_tag is not None:
        exif[offset_tag] = b"+00:00"
    gps = {}
    if gps_lat_lon_h is not None:
        lat, lon, h = gps_lat_lon_h
        gps = {
            piexif.GPSIFD.GPSVersionID: (2, 3, 0, 0),
            piexif.GPSIFD.GPSLatitudeRef: b"N" if lat >= 0 else b"S",
            piexif.GPSIFD.GPSLatitude: _dms(lat),
            piexif.GPSIFD.GPSLongitudeRef: b"E" if lon >= 0 else b"W",
            piexif.GPSIFD.GPSLongitude: _dms(lon),
            piexif.GPSIFD.GPSAltitudeRef: 0 if h >= 0 else 1,
            piexif.GPSIFD.GPSAltitude: _rational(abs(h), 1000),
            piexif.GPSIFD.GPSMapDatum: b"WGS-84",
        }
    return piexif.dump({"0th": zeroth, "Exif": exif, "GPS": gps, "1st": {}, "thumbnail": None})


def write_jpeg(path, image: np.ndarray, exif: bytes, quality: int = 92) -> None:
    from PIL import Image

    Image.fromarray(image).save(path, format="JPEG", quality=int(quality), exif=exif, subsampling=0, optimize=False)
