"""Open3D baseline: recovers a synthetic rigid transform; clear errors for empty clouds."""

import open3d as o3d
import pytest
import torch

from vistask.objects import Open3DRegistration
from vistask.se3 import apply, random_poses
from vistask.vision import pose_error


def _asymmetric_surface(n: int, seed: int) -> torch.Tensor:
    """(n, 3) points on three boxes' faces of different sizes (no symmetry)."""
    g = torch.Generator().manual_seed(seed)
    boxes = [
        ((0.0, 0.0, 0.0), (0.10, 0.06, 0.04)),
        ((0.06, 0.0, 0.04), (0.03, 0.03, 0.07)),
        ((-0.03, 0.04, 0.02), (0.02, 0.05, 0.03)),
    ]
    parts = []
    for centre, size in boxes:
        u = torch.rand(n // len(boxes), 3, generator=g) - 0.5
        axis = torch.randint(0, 3, (len(u),), generator=g)
        u[torch.arange(len(u)), axis] = torch.sign(u[torch.arange(len(u)), axis]) * 0.5
        parts.append(torch.tensor(centre) + u * torch.tensor(size))
    return torch.cat(parts)


@pytest.mark.parametrize("seed", [0, 1])
def test_open3d_recovers_a_rigid_transform(seed: int) -> None:
    source = _asymmetric_surface(3000, seed)
    pose = random_poses(1, 0.2, generator=torch.Generator().manual_seed(seed))[0]
    target = apply(pose, source) + 0.0005 * torch.randn(source.shape)
    threads = o3d.utility.get_max_threads()
    result = Open3DRegistration(voxel=0.004).register(source, target, seed=seed)
    t_err, r_err = pose_error(result.pose, pose)
    assert t_err < 0.005 and r_err < 3.0
    assert result.fitness > 0.8
    assert o3d.utility.get_max_threads() == threads  # one-thread RANSAC gives Open3D back


def test_views_with_normals_towards_the_camera_and_colours_register() -> None:
    """Clouds as the dense baseline builds them from views: normals turned to the camera,
    colours; coloured ICP ends the refinement."""
    from vistask.objects.registration import view_cloud

    source = _asymmetric_surface(6000, 2)
    colours = torch.where(
        source[:, 2:] > 0.03, torch.tensor([0.2, 0.4, 0.9]), torch.tensor([0.9, 0.5, 0.1])
    )
    pose = random_poses(1, 0.2, generator=torch.Generator().manual_seed(2))[0]
    eye = torch.tensor([0.4, 0.3, 0.5])
    src = view_cloud(source, colours, eye, 0.004)
    tgt = view_cloud(apply(pose, source), colours, apply(pose, eye[None])[0], 0.004)
    towards = ((eye - src[0]) * src[1]).sum(-1)
    assert (towards >= 0).all() and torch.allclose(src[1].norm(dim=-1), torch.ones(len(src[1])))
    result = Open3DRegistration(voxel=0.004).register(
        src[0], tgt[0], src[1], tgt[1], 0, src[2], tgt[2]
    )
    t_err, r_err = pose_error(result.pose, pose)
    assert t_err < 0.005 and r_err < 3.0


def test_empty_point_clouds_are_clear_errors() -> None:
    points = _asymmetric_surface(300, 0)
    register = Open3DRegistration().register
    with pytest.raises(ValueError, match="empty point cloud"):
        register(points, torch.zeros(0, 3))
    with pytest.raises(ValueError, match="empty point cloud"):
        register(torch.zeros(0, 3), points)
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        register(points[:, :2], points)
    with pytest.raises(ValueError, match=r"confidence must be in \(0, 1\), got 1.0"):
        Open3DRegistration(confidence=1.0)
    with pytest.raises(ValueError, match="voxel must be positive"):
        Open3DRegistration(voxel=0.0)
