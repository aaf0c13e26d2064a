"""The two imagers of a D405 rendered as images: what a stereo matcher matches (`simulate --matcher sgbm`).

A D405 matches its left imager (the depth reference, which also gives colour) against its right one, 18 mm
along the camera's +x, with the same intrinsics (a rectified pair). Each imager is rendered with the scene's
own ray casting (`Scene.render_exact`: the props analytic, the robot's sampled surface refined per pixel), at
`supersample` rays a pixel side around the robot (its box and a margin; one ray a pixel elsewhere), box-averaged so
silhouettes land at sub-pixel positions, then:

- shading under one point light near the camera (`light_offset`, in the left imager's optical frame, the same
  light for both imagers): Lambert plus a Blinn-Phong specular term, strong on the metal robot (a highlight the
  two imagers see at different places on the tube), faint on the props; surfaces inside a notch in shadow;
- a faint texture bound to the material: a solid noise (a sum of cosines of random direction and wavelength) of
  the robot's tube coordinates (x, y across the tube, arc length along it) and of the props' base-frame
  coordinates, so both imagers see the same texture on the same material point;
- lens blur (a Gaussian of `blur_sigma` px) and, per frame, sensor noise (`sensor_noise` 8-bit levels).

Public API:
    ImagerModel(...)                                   # the parameters above
    right_imager(camera, baseline) -> CameraPose       # the right imager's pose
    render_pair(scene, camera, model) -> (left, right)  # clean (H, W, 3) float radiance, 8-bit scale
    sensor_image(clean, sigma, rng) -> (H, W, 3) uint8  # one frame's exposure
"""

from __future__ import annotations

import dataclasses
from dataclasses import asdict, dataclass

import numpy as np
from scipy.ndimage import gaussian_filter

from ntcr_recon.core.robot.surface import PART_OUTER_WALL
from ntcr_recon.sim.camera import MAX_IMAGE_PIXELS, MAX_IMAGE_SIDE, CameraPose, D405Intrinsics
from ntcr_recon.sim.scene import (
    COLOR_BACKDROP,
    COLOR_CAMERA_BODY,
    COLOR_POST,
    COLOR_ROBOT,
    COLOR_TABLE,
    INSIDE_NOTCH_SHADE,
    LABEL_BACKDROP,
    LABEL_CAMERA_BODY,
    LABEL_POST,
    LABEL_ROBOT,
    LABEL_TABLE,
    ExactFrame,
    Scene,
)

TEXTURE_SEED = 61  # the texture's cosines: fixed, so a material point looks the same in every scene and frame
TEXTURE_WAVES = 24
SUPERSAMPLE_MARGIN = 12  # px around the robot's box also supersampled (its blur, what it hides from the other imager)
# label -> (base colour, texture scale: the props' texture is coarser, they stand farther)
_PROP_COLORS = {LABEL_POST: (COLOR_POST, 2.0), LABEL_TABLE: (COLOR_TABLE, 4.0), LABEL_BACKDROP: (COLOR_BACKDROP, 6.0),
                LABEL_CAMERA_BODY: (COLOR_CAMERA_BODY, 2.0)}


@dataclass(frozen=True)
class ImagerModel:
    """How the two imagers are rendered (see the module docstring)."""

    supersample: int = 2  # rays per pixel side (fewer when the image would exceed the renderer's limit)
    light_offset: tuple[float, float, float] = (0.009, -0.025, 0.0)  # m, left imager's optical frame
    ambient: float = 0.25  # share of the diffuse light that reaches every surface
    robot_specular: float = 110.0  # 8-bit levels at the highlight's peak (metal)
    robot_shininess: float = 60.0  # Blinn-Phong exponent
    props_specular: float = 8.0
    props_shininess: float = 10.0
    texture_contrast: float = 0.08  # standard deviation of the robot's albedo, relative
    props_texture_contrast: float = 0.15
    texture_wavelength: tuple[float, float] = (0.4e-3, 1.6e-3)  # m, the robot's (2-8 px at 90 mm; props: scaled)
    blur_sigma: float = 0.6  # px, the lens
    sensor_noise: float = 1.5  # 8-bit levels, per pixel and frame

    def validate(self) -> None:
        if not (isinstance(self.supersample, int) and 1 <= self.supersample <= 4):
            raise ValueError(f"supersample must be 1 to 4 rays a pixel side, got {self.supersample}")
        low, high = self.texture_wavelength
        if not 0 < low <= high:
            raise ValueError(f"texture wavelengths must be 0 < low <= high m, got {self.texture_wavelength}")
        for name in ("ambient", "robot_specular", "robot_shininess", "props_specular", "props_shininess",
                     "texture_contrast", "props_texture_contrast", "blur_sigma", "sensor_noise"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")

    def to_dict(self) -> dict:
        return asdict(self)


def right_imager(camera: CameraPose, baseline: float) -> CameraPose:
    """The right imager: `baseline` along the camera's +x, the same orientation (and name: the camera's own
    housing, behind both imagers, is not in its view)."""
    return CameraPose(camera.name, camera.rotation, camera.translation + camera.rotation[:, 0] * baseline)


def supersampled(intrinsics: D405Intrinsics, factor: int, rows: tuple[int, int],
                 columns: tuple[int, int]) -> tuple[D405Intrinsics, int]:
    """The intrinsics of `factor` x `factor` rays per pixel (sub-pixel centres) over the pixels rows[0]:rows[1],
    columns[0]:columns[1], the factor lowered until the image fits the renderer's limits."""
    height, width = rows[1] - rows[0], columns[1] - columns[0]
    while factor > 1 and (factor * max(width, height) > MAX_IMAGE_SIDE or factor**2 * width * height
                          > MAX_IMAGE_PIXELS):
        factor -= 1
    half = (factor - 1) / 2  # pixel u's sub-pixel k sits at u + (k + 0.5) / factor - 0.5
    fine = dataclasses.replace(intrinsics, width=width * factor, height=height * factor,
                               fx=intrinsics.fx * factor, fy=intrinsics.fy * factor,
                               cx=(intrinsics.cx - columns[0]) * factor + half,
                               cy=(intrinsics.cy - rows[0]) * factor + half)
    return fine, factor


def robot_box(label: np.ndarray, margin: int) -> tuple[tuple[int, int], tuple[int, int]] | None:
    """The rows and columns (start, stop) of the pixels that see the robot, `margin` px wider; None: none do."""
    rows, columns = np.nonzero(label == LABEL_ROBOT)
    if rows.size == 0:
        return None
    height, width = label.shape
    return ((max(int(rows.min()) - margin, 0), min(int(rows.max()) + margin + 1, height)),
            (max(int(columns.min()) - margin, 0), min(int(columns.max()) + margin + 1, width)))


def _fine_scene(scene: Scene, intrinsics: D405Intrinsics) -> Scene:
    """The scene seen with other intrinsics, sharing its sampled surface."""
    fine = Scene(scene.shape, scene.cameras, intrinsics, scene.props, scene.surface_spacing)
    fine.surface = scene.surface  # the cached sample (cached_property): sampled once per scene
    return fine


def solid_texture(points: np.ndarray, wavelength: tuple[float, float]) -> np.ndarray:
    """A zero-mean, unit-deviation solid noise of 3-D points (m): TEXTURE_WAVES cosines of random direction,
    log-uniform wavelength in `wavelength` and random phase (the same for every call)."""
    rng = np.random.default_rng(TEXTURE_SEED)
    directions = rng.normal(size=(TEXTURE_WAVES, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    lengths = np.exp(rng.uniform(np.log(wavelength[0]), np.log(wavelength[1]), TEXTURE_WAVES))
    phases = rng.uniform(0.0, 2 * np.pi, TEXTURE_WAVES)
    points = np.asarray(points, dtype=np.float32)  # enough: a phase of 1e4 rad is 1e-3 rad off
    total = np.zeros(len(points), dtype=np.float32)
    for direction, length, phase in zip(directions, lengths, phases, strict=True):
        total += np.cos(points @ (2 * np.pi * direction / length).astype(np.float32) + np.float32(phase))
    return total.astype(np.float64) * np.sqrt(2.0 / TEXTURE_WAVES)


def robot_material_points(scene: Scene, sample: np.ndarray, hits_base: np.ndarray) -> np.ndarray:
    """Tube coordinates (x, y across the tube in its cross-section's frame, arc length along it; m) of points on
    the robot's surface, from the surface sample each hit (its arc length and frame) and the hit itself."""
    s = scene.surface.s[sample]
    centre, frame = scene.shape.centerline(s)
    local = np.einsum("nji,nj->ni", frame, hits_base - centre)
    return np.column_stack([local[:, 0], local[:, 1], s + local[:, 2]])


def _albedo(scene: Scene, exact: ExactFrame, hits_base: np.ndarray, model: ImagerModel) -> np.ndarray:
    """(N, 3) base colour of each pixel's surface (8-bit scale) with its texture; 0 where nothing is hit."""
    label = exact.label.ravel()
    albedo = np.zeros((label.size, 3))
    robot = label == LABEL_ROBOT
    if robot.any():
        material = robot_material_points(scene, exact.robot_sample.ravel()[robot], hits_base[robot])
        texture = solid_texture(material, model.texture_wavelength)
        albedo[robot] = COLOR_ROBOT * (1.0 + model.texture_contrast * texture)[:, None]
    for which, (color, scale) in _PROP_COLORS.items():
        mask = label == which
        if mask.any():
            wavelength = (model.texture_wavelength[0] * scale, model.texture_wavelength[1] * scale)
            texture = solid_texture(hits_base[mask], wavelength)
            albedo[mask] = color * (1.0 + model.props_texture_contrast * texture)[:, None]
    return np.clip(albedo, 0.0, None)


def _shading(points_cam: np.ndarray, normal: np.ndarray, light_cam: np.ndarray, shininess: np.ndarray):
    """Per pixel: Lambert's cosine and the Blinn-Phong term of a point light (optical frame)."""
    to_light = light_cam - points_cam
    to_light /= np.linalg.norm(to_light, axis=1, keepdims=True)
    to_eye = -points_cam / np.linalg.norm(points_cam, axis=1, keepdims=True)
    halfway = to_light + to_eye
    halfway /= np.linalg.norm(halfway, axis=1, keepdims=True)
    lambert = np.clip(np.einsum("ij,ij->i", normal, to_light), 0.0, None)
    blinn = np.clip(np.einsum("ij,ij->i", normal, halfway), 0.0, None) ** shininess
    return lambert, blinn * (lambert > 0)


def radiance(scene: Scene, imager: CameraPose, exact: ExactFrame, light_base: np.ndarray,
             model: ImagerModel) -> np.ndarray:
    """(H, W, 3) radiance (8-bit scale, unclipped) of an exact rendering under the light (base frame)."""
    rays = scene.intrinsics.pixel_rays().reshape(-1, 3)
    depth = exact.depth.ravel()
    seen = np.isfinite(depth)
    points_cam = rays * np.where(seen, depth, 1.0)[:, None]
    albedo = _albedo(scene, exact, imager.to_base(points_cam), model)
    robot = exact.label.ravel() == LABEL_ROBOT
    shininess = np.where(robot, model.robot_shininess, model.props_shininess)
    lambert, blinn = _shading(points_cam, exact.normal.reshape(-1, 3), imager.to_camera(light_base), shininess)
    shade = np.where(robot & (exact.robot_part.ravel() != PART_OUTER_WALL), INSIDE_NOTCH_SHADE, 1.0)
    diffuse = albedo * ((model.ambient + (1.0 - model.ambient) * lambert) * shade)[:, None]
    specular = np.where(robot, model.robot_specular, model.props_specular) * blinn * shade
    color = (diffuse + specular[:, None]) * seen[:, None]
    return color.reshape(*exact.depth.shape, 3)


def render_imager(scene: Scene, imager: CameraPose, light_base: np.ndarray, model: ImagerModel) -> np.ndarray:
    """One imager's clean image: (H, W, 3) float, 8-bit scale, supersampled around the robot, box-averaged and
    blurred."""
    exact = scene.render_exact(imager)
    image = radiance(scene, imager, exact, light_base, model)
    box = robot_box(exact.label, SUPERSAMPLE_MARGIN) if model.supersample > 1 else None
    if box is not None:
        (r0, r1), (c0, c1) = box
        fine_intrinsics, factor = supersampled(scene.intrinsics, model.supersample, (r0, r1), (c0, c1))
        if factor > 1:
            fine = _fine_scene(scene, fine_intrinsics)
            detail = radiance(fine, imager, fine.render_exact(imager), light_base, model)
            image[r0:r1, c0:c1] = detail.reshape(r1 - r0, factor, c1 - c0, factor, 3).mean(axis=(1, 3))
    if model.blur_sigma > 0:
        image = gaussian_filter(image, sigma=(model.blur_sigma, model.blur_sigma, 0.0), mode="nearest")
    return image


def render_pair(scene: Scene, camera: CameraPose, model: ImagerModel) -> tuple[np.ndarray, np.ndarray]:
    """The camera's left (its own pose) and right imagers' clean images under one light near the camera."""
    model.validate()
    light = camera.to_base(np.asarray(model.light_offset, dtype=float))
    right = right_imager(camera, scene.intrinsics.baseline)
    return render_imager(scene, camera, light, model), render_imager(scene, right, light, model)


def sensor_image(clean: np.ndarray, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """One exposure of a clean image: Gaussian sensor noise of `sigma` levels, rounded and clipped to 8 bits."""
    noisy = clean + rng.normal(0.0, sigma, clean.shape) if sigma > 0 else clean
    return np.clip(np.rint(noisy), 0, 255).astype(np.uint8)
