"""The flat-world depth source: no network, no prior, only the camera's calibration.

Every pixel ray is intersected with the ground plane ``z = g`` of the ego frame; rays that meet it
farther than ``far`` metres (along the optical axis), or never (at or above the horizon), get
``far``: the scene is modelled as a flat road closed by a fronto-parallel "wall" at ``far``. The
result is already metric (``1 / depth``), so the radar scale recovery only has to correct the camera
height (its scale) and the pitch (its shift: a small pitch error moves the horizon, which adds a
constant to the ground's inverse depth, ``1/z = (alpha + dpitch) / h``). It is the right depth
for the road and wrong everywhere else (cars, rails, trees and buildings take the depth of the
ground or of the wall behind them): a last resort that lets a scene without a depth prior and
without Depth-Anything-V2 weights be prepared at all.

Ground height ``g`` in the ego frame (``DepthConfig.flat_world_ground_z``, None = estimated):

* from ``lidar/`` when the scene has it: the most populated 5 cm height bin of the lower half of
  the points in a patch ahead of the ego (the road dominates it), median over a few frames. This
  covers converters whose ego origin is a sensor (View-of-Delft's ego frame is its radar's);
* else 0: the scene format's ego frame follows nuScenes, whose body frame is "the center of the
  rear axle projected onto the ground" (nuscenes-devkit issues #161, #691); aiMotive's body frame
  also sits on the ground (camera 1.25 m, radar 0.37 m above it; the lane width measured in the
  sample's images agrees with a camera about 1.1-1.25 m up), and so do the synthetic scenes.

The radar points' heights are not used: a conventional automotive radar's elevation is too coarse
(the aiMotive sample's targets lie 1-3 m *below* the road at 50-100 m: about -1 deg of bias and
1 deg of noise), ground returns are rare and multipath ghosts sit below the road.
"""

from __future__ import annotations

import math

import numpy as np

from radar4dgs.depth.geometry import pixel_grid, pixel_rays

# Lidar patch used to find the ground (ego frame, m): ahead of the bumper, about one road wide.
GROUND_PATCH_X = (3.0, 30.0)
GROUND_PATCH_Y = 6.0
GROUND_BIN = 0.05  # m
GROUND_MIN_POINTS = 50
GROUND_FRAMES = 8  # frames (evenly spread) read for the lidar estimate
# Below this camera height above the estimated ground the geometry is not a road scene (m).
MIN_CAMERA_HEIGHT = 0.1


def flat_world_depth(K: np.ndarray, cam_to_ego: np.ndarray, width: int, height: int, ground_z: float = 0.0,
                     far: float = 80.0) -> np.ndarray:
    """(H, W) float64 z-depth (m, along the optical axis) of the ground plane ``z = ground_z`` of the
    ego frame seen by a camera with intrinsics ``K`` (3, 3) and pose ``cam_to_ego`` (4, 4, OpenCV
    camera axes), capped at ``far`` (rays at or above the horizon get ``far``)."""
    v, u = pixel_grid(width, height)
    rays = pixel_rays(np.asarray(K, dtype=np.float64), u, v)  # camera z = 1, so the ray parameter is z-depth
    rotation, centre = np.asarray(cam_to_ego, dtype=np.float64)[:3, :3], np.asarray(cam_to_ego)[:3, 3]
    camera_height = float(centre[2] - ground_z)
    if not camera_height > MIN_CAMERA_HEIGHT:
        raise ValueError(f"flat-world depth: the camera is {camera_height:.2f} m above the ground plane "
                         f"z = {ground_z:.2f} of the ego frame; set DepthConfig.flat_world_ground_z "
                         "(--config.depth.flat-world-ground-z) to the road's height in the ego frame")
    down = -(rays @ rotation[2])  # metres the ray descends per metre of z-depth
    with np.errstate(divide="ignore"):
        depth = np.where(down > 0, camera_height / np.where(down > 0, down, 1.0), np.inf)
    return np.minimum(depth, far)


def lidar_ground_z(points: np.ndarray) -> float:
    """Ground height (m) in the ego frame from one lidar scan (N, >= 3) in the ego frame, NaN when
    the patch ahead of the ego holds too few points."""
    points = np.asarray(points, dtype=np.float64)
    x, y, z = points[:, 0], points[:, 1], points[:, 2]
    z = z[(x >= GROUND_PATCH_X[0]) & (x <= GROUND_PATCH_X[1]) & (np.abs(y) <= GROUND_PATCH_Y) & np.isfinite(z)]
    if len(z) < GROUND_MIN_POINTS:
        return math.nan
    # The road is the densest height band in the lower half: cars, kerbs and walls sit above it,
    # the odd multipath or noise point below it is too sparse to win.
    lower = np.sort(z)[: len(z) // 2 + 1]
    lo, hi = lower[0], lower[-1]
    bins = max(1, int(math.ceil((hi - lo) / GROUND_BIN)))
    counts, edges = np.histogram(lower, bins=bins, range=(lo, lo + bins * GROUND_BIN))
    k = int(np.argmax(counts))
    centre = 0.5 * (edges[k] + edges[k + 1])
    near = lower[np.abs(lower - centre) <= 2 * GROUND_BIN]
    return float(np.median(near))


def estimate_ground_z(scene) -> tuple[float, str]:
    """Ground height in the ego frame (m) and where it came from (see the module docstring)."""
    if scene.has("lidar"):
        picks = np.unique(np.linspace(0, len(scene) - 1, min(GROUND_FRAMES, len(scene))).round().astype(int))
        heights = [lidar_ground_z(scene.load_optional("lidar", int(i))) for i in picks]
        heights = [h for h in heights if math.isfinite(h)]
        if heights:
            return float(np.median(heights)), f"lidar ({len(heights)} frames)"
    return 0.0, "ego origin (scene format: on the ground)"


class FlatWorldDepth:
    """The flat-world source of a scene: the same relative inverse depth for every frame (it
    depends on the calibration only).

    Attributes:
        depth: (H, W) float64 capped ground depth (m).
        wall: (H, W) bool, the pixels at the cap (no ground within ``far``).
        inverse: (H, W) float32 relative inverse depth ``1 / depth`` (larger = closer).
        ground_z, ground_source: the ground plane used and where it came from.
        camera_height: the camera's height above that plane (m).
        far: the cap (m).
    """

    kind = "inverse-depth"

    def __init__(self, scene, far: float = 80.0, ground_z: float | None = None):
        camera = scene.camera
        if ground_z is None:
            ground_z, source = estimate_ground_z(scene)
        else:
            source = "config"
        self.ground_z, self.ground_source, self.far = float(ground_z), source, float(far)
        self.camera_height = float(np.asarray(camera.cam_to_ego)[2, 3] - self.ground_z)
        self.depth = flat_world_depth(camera.K, camera.cam_to_ego, camera.width, camera.height, self.ground_z, far)
        self.inverse = (1.0 / self.depth).astype(np.float32)
        self.wall = self.depth >= self.far

    def __call__(self, image: np.ndarray | None = None) -> np.ndarray:
        """(H, W) float32 relative inverse depth (a copy; ``image`` is ignored)."""
        return self.inverse.copy()

    def describe(self) -> dict:
        """The geometry used, for the depth summary."""
        return {"ground_z": self.ground_z, "ground_source": self.ground_source,
                "camera_height": round(self.camera_height, 4), "far": self.far,
                "wall_fraction": round(float(self.wall.mean()), 4)}
