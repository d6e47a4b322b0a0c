"""Capture model (thesis Sec. 5.4): calibrated pinhole cameras, point lights, dataset folders.

Camera convention (OpenCV): world-to-camera ``x_c = R x_w + t``, image x to the right, y down,
intrinsics ``K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` in pixels, pixel (i, j) covers
[j, j + 1) x [i, i + 1). Units: mm. Point lights: position and RGB radiant intensity; irradiance at
distance r is I / r^2.

Dataset folder::

    capture.json                    cameras, lights, image/mask file names, units
    images/cam{c}_light{l}.exr      linear RGB images (H, W, 3)
    masks/cam{c}.exr                valid-pixel masks (H, W, 1), 1 = use
    scene.json                      (optional) the scene model, e.g. the synthetic ground truth
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass

import numpy as np

from ..errors import MissingFileError, UserError
from ..exr_io import read_exr, write_exr
from ..json_io import save_json
from ..json_schema import check as check_schema

MAX_SIDE = 16384  # pixels a side of a camera image (teeth synth makes at most as many)
FORMAT = "material_structures.teeth.capture/1"


@dataclass
class Camera:
    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    width: int
    height: int
    name: str = "camera"

    def __post_init__(self) -> None:
        self.K = np.asarray(self.K, dtype=np.float64).reshape(3, 3)
        self.R = np.asarray(self.R, dtype=np.float64).reshape(3, 3)
        self.t = np.asarray(self.t, dtype=np.float64).reshape(3)
        self.width, self.height = int(self.width), int(self.height)

    @property
    def center(self) -> np.ndarray:
        return -self.R.T @ self.t

    def rays(self, px: np.ndarray, py: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World-space origins and unit directions through image points (px, py) (pixel units)."""
        fx, fy, cx, cy = self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2]
        dc = np.stack([(px - cx) / fx, (py - cy) / fy, np.ones_like(px)], axis=1)
        d = dc @ self.R  # R^T dc
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        return np.broadcast_to(self.center, d.shape).copy(), d

    def project(self, x: np.ndarray) -> np.ndarray:
        xc = x @ self.R.T + self.t
        uv = xc @ self.K.T
        return uv[:, :2] / uv[:, 2:3]

    @classmethod
    def look_at(cls, eye, target, up, fov_x_deg: float, width: int, height: int, name: str = "camera") -> Camera:
        eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
        z = target - eye
        z /= np.linalg.norm(z)
        x = np.cross(z, up)
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        R = np.stack([x, y, z])
        fx = 0.5 * width / np.tan(0.5 * np.radians(fov_x_deg))
        K = np.array([[fx, 0, 0.5 * width], [0, fx, 0.5 * height], [0, 0, 1.0]])
        return cls(K, R, -R @ eye, width, height, name)

    def to_dict(self) -> dict:
        return {"name": self.name, "K": self.K.tolist(), "R": self.R.tolist(), "t": self.t.tolist(),
                "width": self.width, "height": self.height}

    @classmethod
    def from_dict(cls, d: dict) -> Camera:
        return cls(d["K"], d["R"], d["t"], d["width"], d["height"], d.get("name", "camera"))


@dataclass
class PointLight:
    position: np.ndarray
    intensity: np.ndarray

    def __post_init__(self) -> None:
        self.position = np.asarray(self.position, dtype=np.float64).reshape(3)
        self.intensity = np.asarray(self.intensity, dtype=np.float64).reshape(-1) * np.ones(3)

    def to_dict(self) -> dict:
        return {"position": self.position.tolist(), "intensity": self.intensity.tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> PointLight:
        return cls(d["position"], d["intensity"])


def default_rig(target=(0.0, 0.0, 5.0), width: int = 96, height: int = 64, n_lights: int = 54,
                n_cameras: int = 3, light_distance: float = 1000.0, camera_distance: float = 300.0,
                fov_x_deg: float = 5.0, intensity: float = 1.0e6) -> tuple[list[Camera], list[PointLight]]:
    """The thesis' rig: 54 point lights about 1 m away covering the frontal directions, 3 cameras.

    The mouth faces +y, z is up. Lights lie on a Fibonacci spiral over the frontal cap within 75
    degrees of +y; cameras sit left, centre and right (azimuth -30, 0, +30 deg) with long lenses.
    """
    target = np.asarray(target, dtype=np.float64)
    cams = []
    az = np.linspace(-30.0, 30.0, n_cameras) if n_cameras > 1 else np.zeros(1)
    names = ["left", "center", "right"] if n_cameras == 3 else [f"cam{i}" for i in range(n_cameras)]
    for a, name in zip(az, names, strict=True):
        r = np.radians(a)
        eye = target + camera_distance * np.array([np.sin(r), np.cos(r), 0.12])
        cams.append(Camera.look_at(eye, target, (0, 0, 1), fov_x_deg, width, height, name))
    lights = []
    golden = np.pi * (3.0 - np.sqrt(5.0))
    cos_max = np.cos(np.radians(75.0))
    for i in range(n_lights):
        cz = 1.0 - (i + 0.5) / n_lights * (1.0 - cos_max)  # cos of angle to +y
        s = np.sqrt(1.0 - cz * cz)
        ang = golden * i
        d = np.array([s * np.cos(ang), cz, s * np.sin(ang)])
        lights.append(PointLight(target + light_distance * d, np.full(3, intensity)))
    return cams, lights


@dataclass
class Capture:
    """Cameras, lights, images (n_cam, n_light, H, W, 3) and masks (n_cam, H, W) bool."""

    cameras: list[Camera]
    lights: list[PointLight]
    images: np.ndarray | None = None
    masks: np.ndarray | None = None

    def save(self, folder: str | os.PathLike, scene_dict: dict | None = None) -> None:
        folder = os.fspath(folder)
        os.makedirs(os.path.join(folder, "images"), exist_ok=True)
        os.makedirs(os.path.join(folder, "masks"), exist_ok=True)
        images, masks = {}, {}
        for c in range(len(self.cameras)):
            if self.masks is not None:
                masks[str(c)] = f"masks/cam{c}.exr"
                write_exr(os.path.join(folder, masks[str(c)]), self.masks[c].astype(np.float32)[:, :, None])
            if self.images is not None:
                for li in range(len(self.lights)):
                    rel = f"images/cam{c}_light{li}.exr"
                    images[f"{c},{li}"] = rel
                    write_exr(os.path.join(folder, rel), self.images[c, li])
        meta = {"format": FORMAT, "units": "mm", "cameras": [c.to_dict() for c in self.cameras],
                "lights": [li.to_dict() for li in self.lights], "images": images, "masks": masks}
        save_json(os.path.join(folder, "capture.json"), meta, indent=1)
        if scene_dict is not None:
            save_json(os.path.join(folder, "scene.json"), scene_dict)

    @classmethod
    def load(cls, folder: str | os.PathLike) -> Capture:
        """Read a capture folder, refusing what would be fitted as garbage: a missing or malformed
        capture.json, cameras or lights with non-finite or impossible values, images missing for some
        (camera, light), image or mask sizes that differ from their camera, non-finite or negative
        pixels. Every error names the file and the problem."""
        folder = os.fspath(folder)
        path = os.path.join(folder, "capture.json")
        if not os.path.isfile(path):
            raise MissingFileError(f"no capture.json in {folder!r}", path)
        try:
            with open(path) as f:
                meta = json.load(f)
        except (json.JSONDecodeError, UnicodeDecodeError) as e:
            raise UserError(f"{path}: not a JSON file ({e})") from None
        # core/schemas/capture.schema.json: the fields, their kinds, sizes and ranges; below what it cannot say
        check_schema(meta, "capture", path)
        cams = [Camera.from_dict(c) for c in meta["cameras"]]
        lights = [PointLight.from_dict(li) for li in meta["lights"]]
        for i, c in enumerate(cams):
            if not (np.isfinite(c.K).all() and np.isfinite(c.R).all() and np.isfinite(c.t).all()):
                raise UserError(f"{path}: camera {i} has a non-finite K, R or t")
            if not (c.K[0, 0] > 0 and c.K[1, 1] > 0):  # a zero focal length renders every pixel black
                raise UserError(f"{path}: camera {i} has a focal length (K[0][0], K[1][1]) that is not > 0")
            if np.abs(c.R @ c.R.T - np.eye(3)).max() > 1e-4 or np.linalg.det(c.R) < 0:
                raise UserError(f"{path}: camera {i}'s R is not a rotation (R R^T = I, det R = 1, to 1e-4)")
            if (c.width, c.height) != (cams[0].width, cams[0].height):
                raise UserError(f"{path}: camera {i} is {c.width} x {c.height}, camera 0 "
                                f"{cams[0].width} x {cams[0].height}; all cameras need one image size")
        for i, li in enumerate(lights):
            if not (np.isfinite(li.position).all() and np.isfinite(li.intensity).all()) or (li.intensity < 0).any():
                raise UserError(f"{path}: light {i} has a non-finite position or a negative or non-finite intensity")
        h, w = cams[0].height, cams[0].width
        images = None
        if meta.get("images"):
            images = np.zeros((len(cams), len(lights), h, w, 3), dtype=np.float32)
            seen = np.zeros((len(cams), len(lights)), dtype=bool)
            for key, rel in meta["images"].items():
                try:
                    c, li = (int(v) for v in key.split(","))
                except ValueError:
                    raise UserError(f"{path}: image key {key!r} is not 'camera,light'") from None
                if not (0 <= c < len(cams) and 0 <= li < len(lights)):
                    raise UserError(f"{path}: image {key!r} names a camera or light that does not exist")
                img = read_exr(os.path.join(folder, rel), channels=["R", "G", "B"])
                if img.shape[:2] != (h, w):
                    raise UserError(f"{rel}: image size {img.shape[:2]} does not match camera {c} ({h}, {w})")
                if not np.isfinite(img).all() or (img < 0).any():
                    raise UserError(f"{rel}: has non-finite or negative pixels")
                images[c, li] = img
                seen[c, li] = True
            if not seen.all():
                missing = [f"{c},{li}" for c, li in zip(*np.nonzero(~seen), strict=True)]
                raise UserError(f"{path}: no image for {len(missing)} (camera, light) pairs, e.g. "
                                f"{', '.join(missing[:4])}")
        masks = None
        if meta.get("masks"):
            masks = np.zeros((len(cams), h, w), dtype=bool)
            seen_m = np.zeros(len(cams), dtype=bool)
            for key, rel in meta["masks"].items():
                try:
                    c = int(key)
                except ValueError:
                    raise UserError(f"{path}: mask key {key!r} is not a camera index") from None
                if not 0 <= c < len(cams):
                    raise UserError(f"{path}: mask {key!r} names a camera that does not exist")
                m = read_exr(os.path.join(folder, rel))
                if m.shape[:2] != (h, w):
                    raise UserError(f"{rel}: mask size {m.shape[:2]} does not match camera {c} ({h}, {w})")
                masks[c] = m[:, :, 0] > 0.5
                seen_m[c] = True
            if not seen_m.all():
                raise UserError(f"{path}: no mask for cameras {np.flatnonzero(~seen_m).tolist()}")
        return cls(cams, lights, images, masks)


def split_camera(capture: Capture, camera: int) -> tuple[Capture, Capture]:
    """(the capture without camera ``camera``, the capture of that camera alone): a fit's training views and
    the view it holds out to check new viewpoints by."""
    n = len(capture.cameras)
    if not 0 <= camera < n:
        raise UserError(f"the held-out camera {camera} is not in the capture (its cameras are 0-{n - 1})")
    if n < 2:
        raise UserError("the capture has one camera: holding it out leaves the fit nothing to see")
    keep = [c for c in range(n) if c != camera]

    def part(ids: list[int]) -> Capture:
        return Capture([capture.cameras[c] for c in ids], capture.lights,
                       None if capture.images is None else capture.images[ids],
                       None if capture.masks is None else capture.masks[ids])

    return part(keep), part([camera])
