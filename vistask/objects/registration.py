"""Baseline: Open3D global registration (FPFH features + RANSAC restarts and FGR) refined by
multi-scale point-to-plane ICP and coloured ICP.

The model's object-frame points are registered to the scene's points; the estimated
transform is the object pose. ``estimate_pose`` registers the model's patches to the scene's
patches, the points NBP sees; ``register`` takes any clouds (e.g. dense depth clouds).
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass

import numpy as np
import roma
import torch
from torch import Tensor

from vistask.checks import check_at_least, check_positive, checked
from vistask.objects.model import ObjectModel
from vistask.vision import Patches


@checked
@dataclass
class RegistrationResult:
    """Estimated pose (7,) of the source in the target's frame, with Open3D's scores."""

    pose: Tensor
    fitness: float
    inlier_rmse: float


MIN_ICP_POINTS = 50
"""Coarse ICP scales that leave fewer points than this are skipped."""


@contextlib.contextmanager
def _one_thread():
    """Open3D limited to one thread inside the block, its limit restored after."""
    import open3d as o3d

    previous = o3d.utility.get_max_threads()
    o3d.utility.set_max_threads(1)
    try:
        yield
    finally:
        o3d.utility.set_max_threads(previous)


def _cloud(points: Tensor, normals: Tensor | None, colors: Tensor | None, name: str, voxel: float):
    import open3d as o3d

    if points.dim() != 2 or points.shape[-1] != 3:
        raise ValueError(f"{name} points must have shape (N, 3), got {tuple(points.shape)}")
    if len(points) == 0:
        raise ValueError(f"empty point cloud: no {name} points to register")
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points.double().cpu().numpy()))
    if normals is not None:
        pcd.normals = o3d.utility.Vector3dVector(normals.double().cpu().numpy())
    if colors is not None:
        pcd.colors = o3d.utility.Vector3dVector(colors.double().clamp(0, 1).cpu().numpy())
    pcd = pcd.voxel_down_sample(voxel)
    if normals is None:
        pcd.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * voxel, max_nn=30))
    if len(pcd.points) < 3:
        raise ValueError(f"too few {name} points to register: {len(pcd.points)} after sampling")
    return pcd


def view_cloud(
    points: Tensor, colors: Tensor, viewpoint: Tensor, voxel: float
) -> tuple[Tensor, Tensor, Tensor]:
    """One view's cloud, down-sampled to ``voxel``, with normals estimated from the points
    and turned towards the camera at ``viewpoint`` (3,): outward from the surfaces it saw,
    as FPFH features need them on both clouds.

    Returns:
        (N, 3) points, (N, 3) unit normals and (N, 3) colours.
    """
    pcd = _cloud(points, None, colors, "view", voxel)
    pcd.orient_normals_towards_camera_location(viewpoint.double().cpu().numpy())
    as_tensor = lambda v: torch.from_numpy(np.asarray(v)).float()  # noqa: E731
    return as_tensor(pcd.points), as_tensor(pcd.normals), as_tensor(pcd.colors)


@checked
class Open3DRegistration:
    """The baseline pose estimator at full strength: FPFH features, global registration by
    several RANSAC runs and Fast Global Registration, each candidate refined by multi-scale
    point-to-plane ICP and then coloured ICP (when both clouds have colours), the best fit
    kept.

    ``Open3DRegistration().estimate_pose(model, patches)`` registers the model's patch
    positions to the scene's. Lengths are in metres. The arguments are kept as attributes
    of the same names.

    Args:
        voxel: down-sampling voxel; FPFH radius and match distances scale with it.
        feature_radius: FPFH radius in voxels.
        max_nn: FPFH neighbour cap.
        restarts: RANSAC runs with different seeds.
        ransac_iterations: iterations of each RANSAC run at most.
        confidence: RANSAC stopping confidence.
        fgr: add Fast Global Registration's estimate to the candidates.
        icp_scales: ICP from coarse to fine: correspondence distances and down-sampling
            voxels, in voxels.
        colored: finish with coloured ICP where both clouds have colours.
        mutual_filter: keep only mutual nearest FPFH matches.

    Raises:
        ValueError: voxel, feature_radius or a scale not positive, restarts or
            ransac_iterations below 1, or confidence outside (0, 1).
    """

    def __init__(
        self,
        voxel: float = 0.004,
        feature_radius: float = 10.0,
        max_nn: int = 100,
        restarts: int = 5,
        ransac_iterations: int = 100_000,
        confidence: float = 0.999,
        fgr: bool = True,
        icp_scales: tuple[float, ...] = (4.0, 2.0, 1.0),
        colored: bool = True,
        mutual_filter: bool = False,
    ) -> None:
        check_positive(voxel=voxel, feature_radius=feature_radius)
        if not icp_scales or min(icp_scales) <= 0:
            raise ValueError(f"icp_scales must be positive, got {icp_scales}")
        check_at_least(1, restarts=restarts, ransac_iterations=ransac_iterations)
        if not 0 < confidence < 1:
            raise ValueError(f"confidence must be in (0, 1), got {confidence}")
        self.voxel = voxel
        self.feature_radius = feature_radius
        self.max_nn = max_nn
        self.restarts = restarts
        self.ransac_iterations = ransac_iterations
        self.confidence = confidence
        self.fgr = fgr
        self.icp_scales = tuple(icp_scales)
        self.colored = colored
        self.mutual_filter = mutual_filter

    def register(
        self,
        source: Tensor,
        target: Tensor,
        source_normals: Tensor | None = None,
        target_normals: Tensor | None = None,
        seed: int = 0,
        source_colors: Tensor | None = None,
        target_colors: Tensor | None = None,
    ) -> RegistrationResult:
        """Register ``source`` to ``target``: global candidates, each refined, best kept.

        Args:
            source: (N, 3) points (e.g. an object model in its own frame).
            target: (M, 3) points (e.g. a scene in the world frame).
            source_normals, target_normals: (N, 3) / (M, 3) unit normals, or None to estimate.
            seed: seed of the first RANSAC run (run r uses seed + r). RANSAC runs on one
                thread, so that a seed gives the same pose in any process.
            source_colors, target_colors: (N, 3) / (M, 3) RGB in [0, 1], or None.

        Returns:
            the pose mapping source coordinates to target coordinates, with the fitness and
            inlier RMSE of the best candidate at the finest ICP distance.

        Raises:
            ValueError: empty or too small point clouds.
        """
        import open3d as o3d

        reg = o3d.pipelines.registration
        src = _cloud(source, source_normals, source_colors, "source", self.voxel)
        tgt = _cloud(target, target_normals, target_colors, "target", self.voxel)
        search = o3d.geometry.KDTreeSearchParamHybrid(
            radius=self.feature_radius * self.voxel, max_nn=self.max_nn
        )
        f_src = reg.compute_fpfh_feature(src, search)
        f_tgt = reg.compute_fpfh_feature(tgt, search)
        distance = 1.5 * self.voxel
        candidates = []
        # Open3D's parallel RANSAC may pick another sample from run to run whatever the
        # seed; on one thread a seed gives one result, in any process and on any machine.
        with _one_thread():
            for r in range(self.restarts):
                o3d.utility.random.seed((seed + r) % 2**31)  # Open3D takes a C int
                candidates.append(
                    reg.registration_ransac_based_on_feature_matching(
                        src,
                        tgt,
                        f_src,
                        f_tgt,
                        self.mutual_filter,
                        distance,
                        reg.TransformationEstimationPointToPoint(False),
                        3,
                        [
                            reg.CorrespondenceCheckerBasedOnEdgeLength(0.9),
                            reg.CorrespondenceCheckerBasedOnDistance(distance),
                        ],
                        reg.RANSACConvergenceCriteria(self.ransac_iterations, self.confidence),
                    ).transformation
                )
        if self.fgr:
            option = reg.FastGlobalRegistrationOption(maximum_correspondence_distance=distance)
            candidates.append(
                reg.registration_fgr_based_on_feature_matching(
                    src, tgt, f_src, f_tgt, option
                ).transformation
            )
        colored = self.colored and src.has_colors() and tgt.has_colors()
        best = None
        for T in candidates:
            T = self._refine(src, tgt, T, colored)
            fit = reg.evaluate_registration(src, tgt, distance, T)
            if best is None or (fit.fitness, -fit.inlier_rmse) > (
                best[1].fitness,
                -best[1].inlier_rmse,
            ):
                best = (T, fit)
        T, fit = best
        T = torch.from_numpy(np.asarray(T).copy())
        pose = torch.cat([T[:3, 3], roma.rotmat_to_unitquat(T[:3, :3])]).float()
        return RegistrationResult(pose, float(fit.fitness), float(fit.inlier_rmse))

    def _refine(self, src, tgt, T: np.ndarray, colored: bool) -> np.ndarray:
        """Multi-scale point-to-plane ICP from ``T``, then coloured ICP at the finest scale."""
        import open3d as o3d

        reg = o3d.pipelines.registration
        for scale in self.icp_scales:
            size = scale * self.voxel
            s, t = (
                (src, tgt)
                if scale <= 1
                else (src.voxel_down_sample(size), tgt.voxel_down_sample(size))
            )
            if min(len(s.points), len(t.points)) < MIN_ICP_POINTS:
                continue  # too coarse for this object: point-to-plane ICP would be degenerate
            T = reg.registration_icp(
                s, t, 1.5 * size, T, reg.TransformationEstimationPointToPlane()
            ).transformation
        if colored:
            # No correspondence within reach (a candidate far off) leaves T as it is.
            with contextlib.suppress(RuntimeError):
                T = reg.registration_colored_icp(
                    src,
                    tgt,
                    1.5 * self.voxel,
                    T,
                    reg.TransformationEstimationForColoredICP(),
                    reg.ICPConvergenceCriteria(max_iteration=30),
                ).transformation
        return T

    def estimate_pose(
        self, model: ObjectModel, patches: Patches, seed: int = 0
    ) -> RegistrationResult:
        """Register the model's patches to the scene's (positions, normals and the mean of
        the two side colours): the baseline on the points NBP sees.

        Args:
            model: object model (its object-frame patches are the source).
            patches: (M) world-frame scene patches.
            seed: RANSAC seed.
        """
        return self.register(
            model.patches.positions,
            patches.positions,
            model.patches.normals,
            patches.normals,
            seed,
            model.patches.colors.mean(1),
            patches.colors.mean(1),
        )
