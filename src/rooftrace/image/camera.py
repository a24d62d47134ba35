"""Camera models: a frame camera (collinearity) and an orthophoto (affine).

Conventions (the camera file, docs/image.md): M = R_kappa R_phi R_omega;
[u, v, w]^T = M [X - X0, Y - Y0, Z - Z0]^T; photo coordinates
x = x0 - f u / w, y = y0 - f v / w in mm (x right, y up), then Brown
distortion; pixel column C = (W - 1)/2 + x / ps, row L = (H - 1)/2 - y / ps,
pixel centres at integers.  Both models expose the same methods so that
stages do not care which one they get: ``project`` (object -> pixel),
``ray`` (pixel -> object-space ray), ``intersect_plane`` and
``registration_error`` (covariance propagation to pixels).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

__all__ = ["FrameCamera", "OrthoCamera", "rotation_matrix"]


def rotation_matrix(omega: float, phi: float, kappa: float) -> np.ndarray:
    """M = R_kappa R_phi R_omega for angles in radians (object -> image frame)."""
    co, so = np.cos(omega), np.sin(omega)
    cp, sp = np.cos(phi), np.sin(phi)
    ck, sk = np.cos(kappa), np.sin(kappa)
    r_omega = np.array([[1, 0, 0], [0, co, so], [0, -so, co]])
    r_phi = np.array([[cp, 0, -sp], [0, 1, 0], [sp, 0, cp]])
    r_kappa = np.array([[ck, sk, 0], [-sk, ck, 0], [0, 0, 1]])
    return r_kappa @ r_phi @ r_omega


@dataclass(frozen=True)
class FrameCamera:
    """A frame (central perspective) camera with interior and exterior orientation.

    Parameters
    ----------
    image_size : (int, int)
        Width W and height H in pixels.
    pixel_size_mm, focal_length_mm : float
        Pixel size and focal length (mm).
    principal_point_mm : (float, float)
        x0, y0 (mm).
    distortion : dict
        Brown coefficients k1, k2, k3 (mm^-2, mm^-4, mm^-6) and p1, p2 (mm^-1).
    exterior : ndarray of shape (6,)
        X0, Y0, Z0 (CRS units) and omega, phi, kappa (radians).
    exterior_covariance : ndarray of shape (6, 6) or None
        Order [X0, Y0, Z0, omega, phi, kappa], metres and radians.
    crs : pyproj.CRS or None
    """

    image_size: tuple[int, int]
    pixel_size_mm: float
    focal_length_mm: float
    exterior: np.ndarray
    principal_point_mm: tuple[float, float] = (0.0, 0.0)
    distortion: dict = field(default_factory=dict)
    exterior_covariance: np.ndarray | None = None
    crs: object = None

    kind = "frame"

    # ------------------------------------------------------------------ geometry
    @property
    def center(self) -> np.ndarray:
        return np.asarray(self.exterior[:3], float)

    @property
    def rotation(self) -> np.ndarray:
        return rotation_matrix(*np.asarray(self.exterior[3:6], float))

    def with_exterior(self, exterior: np.ndarray, covariance: np.ndarray | None = None) -> FrameCamera:
        """Copy with another exterior orientation (and covariance)."""
        cov = self.exterior_covariance if covariance is None else covariance
        return replace(self, exterior=np.asarray(exterior, float), exterior_covariance=cov)

    def _has_distortion(self) -> bool:
        return any(float(self.distortion.get(k, 0.0)) != 0.0 for k in ("k1", "k2", "k3", "p1", "p2"))

    def distort(self, xy: np.ndarray) -> np.ndarray:
        """Apply Brown radial/decentring distortion to ideal photo coordinates (mm)."""
        if not self._has_distortion():
            return xy
        d = self.distortion
        x0, y0 = self.principal_point_mm
        xb, yb = xy[:, 0] - x0, xy[:, 1] - y0
        r2 = xb * xb + yb * yb
        radial = d.get("k1", 0) * r2 + d.get("k2", 0) * r2**2 + d.get("k3", 0) * r2**3
        p1, p2 = d.get("p1", 0), d.get("p2", 0)
        dx = xb * radial + p1 * (r2 + 2 * xb * xb) + 2 * p2 * xb * yb
        dy = yb * radial + p2 * (r2 + 2 * yb * yb) + 2 * p1 * xb * yb
        return np.column_stack([xy[:, 0] + dx, xy[:, 1] + dy])

    def undistort(self, xy: np.ndarray, iterations: int = 20) -> np.ndarray:
        """Invert :meth:`distort` by fixed-point iteration (converges for mild distortion)."""
        if not self._has_distortion():
            return xy
        ideal = xy.copy()
        for _ in range(iterations):
            ideal = ideal + (xy - self.distort(ideal))
        return ideal

    def photo_to_pixel(self, xy: np.ndarray) -> np.ndarray:
        """Photo coordinates (mm, y up) -> pixel (column, row), centres at integers."""
        w, h = self.image_size
        ps = self.pixel_size_mm
        return np.column_stack([(w - 1) / 2 + xy[:, 0] / ps, (h - 1) / 2 - xy[:, 1] / ps])

    def pixel_to_photo(self, cr: np.ndarray) -> np.ndarray:
        """Pixel (column, row) -> photo coordinates (mm)."""
        cr = np.atleast_2d(np.asarray(cr, float))
        w, h = self.image_size
        ps = self.pixel_size_mm
        return np.column_stack([(cr[:, 0] - (w - 1) / 2) * ps, ((h - 1) / 2 - cr[:, 1]) * ps])

    def project(self, xyz: np.ndarray, exterior: np.ndarray | None = None) -> np.ndarray:
        """Object coordinates (N, 3) -> pixel (column, row) (N, 2) by the collinearity equations."""
        xyz = np.atleast_2d(np.asarray(xyz, float))
        eo = self.exterior if exterior is None else exterior
        m = rotation_matrix(*eo[3:6])
        uvw = (xyz - np.asarray(eo[:3], float)) @ m.T
        f = self.focal_length_mm
        x0, y0 = self.principal_point_mm
        with np.errstate(divide="ignore", invalid="ignore"):
            photo = np.column_stack([x0 - f * uvw[:, 0] / uvw[:, 2], y0 - f * uvw[:, 1] / uvw[:, 2]])
        return self.photo_to_pixel(self.distort(photo))

    def ray(self, cr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rays through pixels: origins (N, 3) (the projection centre) and unit directions (N, 3)."""
        photo = self.undistort(self.pixel_to_photo(cr))
        x0, y0 = self.principal_point_mm
        cam = np.column_stack([photo[:, 0] - x0, photo[:, 1] - y0, np.full(len(photo), -self.focal_length_mm)])
        d = cam @ self.rotation  # M^T applied to row vectors
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        return np.broadcast_to(self.center, d.shape).copy(), d

    def intersect_plane(self, cr: np.ndarray, plane: np.ndarray) -> np.ndarray:
        """Intersect pixel rays with the plane a X + b Y + c Z + d = 0; returns (N, 3)."""
        o, d = self.ray(cr)
        n = np.asarray(plane[:3], float)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = -(o @ n + plane[3]) / (d @ n)
        return o + t[:, None] * d

    # ------------------------------------------------------ error propagation
    def jacobians(self, xyz: np.ndarray, step: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
        """Partial derivatives of (column, row) w.r.t. the EO (N, 2, 6) and the point (N, 2, 3).

        Central differences; the steps are relative to 1 m and 1 microradian,
        far below any precision that matters, and exact enough for variance
        propagation.
        """
        xyz = np.atleast_2d(np.asarray(xyz, float))
        eo = np.asarray(self.exterior, float)
        j_eo = np.empty((len(xyz), 2, 6))
        for k in range(6):
            h = step * (1.0 if k >= 3 else 1e3)
            de = np.zeros(6)
            de[k] = h
            j_eo[:, :, k] = (self.project(xyz, eo + de) - self.project(xyz, eo - de)) / (2 * h)
        j_x = np.empty((len(xyz), 2, 3))
        for k in range(3):
            dx = np.zeros(3)
            dx[k] = 1e-3
            j_x[:, :, k] = (self.project(xyz + dx) - self.project(xyz - dx)) / 2e-3
        return j_eo, j_x

    def pixel_covariance(self, xyz: np.ndarray, sigma_xy: float = 0.48, sigma_z: float = 0.15) -> np.ndarray:
        """Covariance (N, 2, 2) of projected pixels from the EO covariance and the point precision.

        Defaults are Marcato & Dal Poz's LiDAR precisions: 0.48 m planimetric, 0.15 m altimetric.
        """
        j_eo, j_x = self.jacobians(xyz)
        sx = np.diag([sigma_xy**2, sigma_xy**2, sigma_z**2])
        cov = np.einsum("nik,kl,njl->nij", j_x, sx, j_x)
        if self.exterior_covariance is not None:
            ce = np.asarray(self.exterior_covariance, float)
            cov += np.einsum("nik,kl,njl->nij", j_eo, ce, j_eo)
        return cov

    def registration_error(self, xyz: np.ndarray, sigma_xy: float = 0.48, sigma_z: float = 0.15) -> np.ndarray:
        """Registration error e = sqrt(sigma_L^2 + sigma_C^2) in pixels for each point (Marcato & Dal Poz)."""
        cov = self.pixel_covariance(xyz, sigma_xy, sigma_z)
        return np.sqrt(cov[:, 0, 0] + cov[:, 1, 1])

    @property
    def ground_sample_distance(self) -> float:
        """Nadir ground sample distance (CRS units per pixel) at the ground below the camera."""
        return self.pixel_size_mm / self.focal_length_mm * float(self.exterior[2])


@dataclass(frozen=True)
class OrthoCamera:
    """An orthophoto used as a camera: its affine geotransform, no exterior orientation.

    ``transform`` is the GDAL/rasterio affine ``(a, b, c, d, e, f)`` mapping
    (column, row) of pixel *corners* to map coordinates: X = a C + b L + c,
    Y = d C + e L + f.  Pixel centres sit at integers, as for the frame
    camera, hence the half-pixel shifts.  A standard orthophoto leans tall
    roofs (relief displacement is not removed); Z is ignored.
    """

    image_size: tuple[int, int]
    transform: tuple[float, float, float, float, float, float]
    crs: object = None
    sigma_px: float = 0.0

    kind = "orthophoto"

    def _matrix(self) -> np.ndarray:
        a, b, c, d, e, f = self.transform
        return np.array([[a, b, c], [d, e, f], [0, 0, 1]], float)

    def project(self, xyz: np.ndarray) -> np.ndarray:
        xyz = np.atleast_2d(np.asarray(xyz, float))
        inv = np.linalg.inv(self._matrix())
        h = np.column_stack([xyz[:, 0], xyz[:, 1], np.ones(len(xyz))]) @ inv.T
        return h[:, :2] - 0.5

    def ray(self, cr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        cr = np.atleast_2d(np.asarray(cr, float))
        h = np.column_stack([cr[:, 0] + 0.5, cr[:, 1] + 0.5, np.ones(len(cr))]) @ self._matrix().T
        origin = np.column_stack([h[:, 0], h[:, 1], np.full(len(cr), 1e4)])
        return origin, np.tile([0.0, 0.0, -1.0], (len(cr), 1))

    def intersect_plane(self, cr: np.ndarray, plane: np.ndarray) -> np.ndarray:
        o, _ = self.ray(cr)
        a, b, c, d = plane
        with np.errstate(divide="ignore", invalid="ignore"):
            z = -(a * o[:, 0] + b * o[:, 1] + d) / c
        return np.column_stack([o[:, 0], o[:, 1], z])

    @property
    def ground_sample_distance(self) -> float:
        a, b, _, d, e, _ = self.transform
        return float(np.sqrt(abs(a * e - b * d)))

    def registration_error(self, xyz: np.ndarray, sigma_xy: float = 0.48, sigma_z: float = 0.15) -> np.ndarray:
        """Planimetric LiDAR precision in pixels, plus the orthophoto's own ``sigma_px``."""
        n = len(np.atleast_2d(xyz))
        s = sigma_xy / self.ground_sample_distance
        return np.full(n, np.sqrt(2 * s * s + self.sigma_px**2))
