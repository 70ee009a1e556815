"""robosuite tabletop scenes: reproducibility, ground truth consistent with the images,
object-frame patch sets. Renders a handful of 128 x 128 images (EGL, CPU)."""

import numpy as np
import pytest
import roma
import torch

from vistask.envs.objects import DEFAULT_DISTRACTORS, object_spec
from vistask.envs.tabletop import (
    TABLE_TOP_Z,
    make_scene,
    object_patches,
    object_symmetry,
    tabletop_world,
)
from vistask.vision import pose_error

SIZE = 128


@pytest.fixture(scope="module")
def scene():
    return make_scene(
        11, target="hammer", n_distractors=3, cameras=("front", "top"), image_size=SIZE
    )


def test_scene_is_reproducible_from_its_seed(scene) -> None:
    again = make_scene(
        11, target="hammer", n_distractors=3, cameras=("front", "top"), image_size=SIZE
    )
    assert again.objects == scene.objects
    torch.testing.assert_close(again.poses, scene.poses, atol=1e-6, rtol=0)
    for name, view in scene.views.items():
        assert torch.equal(again.views[name].rgb, view.rgb)
        assert torch.equal(again.views[name].depth, view.depth)
        assert torch.equal(again.views[name].segmentation, view.segmentation)
    other = make_scene(12, target="hammer", n_distractors=3, cameras=("front",), image_size=SIZE)
    assert (other.poses[0] - scene.poses[0]).abs().max() > 1e-3


def test_a_scene_shows_its_own_lamp_whatever_was_drawn_before(scene) -> None:
    world = tabletop_world(["hammer", *DEFAULT_DISTRACTORS])

    def relit(seed: int):
        return world.generate(seed, "hammer", 3, ["front"], SIZE, relight=True).views["front"]

    first = relit(5)
    relit(6)  # another lamp
    assert torch.equal(relit(5).rgb, first.rgb)
    # And the default light comes back for the next scene that is not relit.
    again = make_scene(11, target="hammer", n_distractors=3, cameras=("front",), image_size=SIZE)
    assert torch.equal(again.views["front"].rgb, scene.views["front"].rgb)


def test_scene_contents(scene) -> None:
    assert scene.target == "hammer" and len(scene.objects) == 4 == len(set(scene.objects))
    assert scene.poses.shape == (4, 7) and scene.bounds.shape == (4, 2, 3)
    torch.testing.assert_close(scene.poses[:, 3:].norm(dim=-1), torch.ones(4))
    for view in scene.views.values():
        assert view.rgb.shape == (SIZE, SIZE, 3) and view.rgb.dtype == torch.uint8
        assert torch.isfinite(view.depth).all() and (view.depth > 0).all()
        assert set(view.segmentation.unique().tolist()) <= {-1, 0, 1, 2, 3}
        assert view.mask(0).sum() > 20  # the target is visible
    # Objects rest on the table: the lowest bounding-box corner touches the top.
    for pose, (lo, hi) in zip(scene.poses, scene.bounds, strict=True):
        corners = torch.stack(torch.meshgrid(*torch.stack([lo, hi], 1), indexing="ij"), -1).reshape(
            -1, 3
        )
        z = corners @ _rotmat(pose).T + pose[:3]
        assert abs(z[:, 2].min().item() - TABLE_TOP_Z) < 0.01


def _rotmat(pose: torch.Tensor) -> torch.Tensor:
    return roma.unitquat_to_rotmat(pose[3:])


def test_ground_truth_matches_the_pixels(scene) -> None:
    """Back-projected pixels of each object, moved into its frame by the ground-truth pose,
    fall inside its bounding box: checks extrinsics, intrinsics, depth, flips and labels."""
    for view in scene.views.values():
        for i in range(len(scene.objects)):
            if view.mask(i).sum() < 10:
                continue
            points, _ = view.point_cloud(view.mask(i))
            R = _rotmat(scene.poses[i])
            local = (points - scene.poses[i, :3]) @ R
            lo, hi = scene.bounds[i]
            inside = ((local >= lo - 0.002) & (local <= hi + 0.002)).all(-1)
            assert inside.all(), (view.camera.name, scene.objects[i], inside.float().mean())


def test_object_frame_patches_lie_in_the_bounding_box() -> None:
    patches = object_patches("milk", n_rotations=2, cameras=("front", "top"), image_size=SIZE)
    lo, hi = tabletop_world().bounds["milk"]
    assert len(patches) > 50 and patches.pixels is None
    inside = ((patches.positions >= lo - 0.003) & (patches.positions <= hi + 0.003)).all(-1)
    assert inside.float().mean() > 0.98
    torch.testing.assert_close(patches.directions.norm(dim=-1), torch.ones(len(patches)))
    # Patches from all four views contribute: both the top and the sides of the carton.
    assert (
        patches.positions[:, 2].max() > hi[2] - 0.02
        and patches.positions[:, 2].min() < lo[2] + 0.03
    )


def test_symmetries_and_pose_error_on_scene_poses(scene) -> None:
    assert object_symmetry("can").axis is not None
    specs = [object_spec(k) for k in DEFAULT_DISTRACTORS]
    assert sum(s.symmetry.axis is None and len(s.symmetry.rotations) == 1 for s in specs) >= 2
    t, r = pose_error(scene.poses, scene.poses, scene.symmetry(0))
    assert t.max() < 1e-6 and r.max() < 0.1


def test_clear_errors() -> None:
    with pytest.raises(ValueError, match="unknown object"):
        make_scene(0, target="teapot")
    with pytest.raises(ValueError, match="seed"):
        make_scene(-1)
    with pytest.raises(ValueError, match="n_distractors"):
        make_scene(0, n_distractors=5)
    with pytest.raises(ValueError, match="unknown camera"):
        make_scene(0, cameras=("nowhere",), image_size=16)
    with pytest.raises(ValueError, match="unknown object"):
        object_patches("teapot")


def test_cameras_agree_with_robosuite_camera_utils(scene) -> None:
    pytest.importorskip("h5py")  # robosuite.utils.camera_utils imports it
    from robosuite.utils import camera_utils

    world = tabletop_world()
    for name, view in scene.views.items():
        K = camera_utils.get_camera_intrinsic_matrix(world.sim, name, SIZE, SIZE)
        T = camera_utils.get_camera_extrinsic_matrix(world.sim, name)
        # Ours puts pixel centres on integers: half a pixel off robosuite's principal point.
        np.testing.assert_allclose(view.camera.K.numpy(), K - [[0, 0, 0.5], [0, 0, 0.5], [0, 0, 0]])
        np.testing.assert_allclose(view.camera.cam_to_world.numpy(), T, atol=1e-9)


@pytest.mark.parametrize("kind", ["tests/data/hinged_lid.xml", "hinged_box"])
def test_objects_of_several_bodies_and_joints_are_arranged_and_segmented_whole(kind) -> None:
    # A lid on a hinge: its own joint comes before the free joint, and its geoms hang below
    # the root body. Both must belong to the object.
    scene = make_scene(2, target=kind, n_distractors=0, cameras=("top",), image_size=SIZE)
    lo, hi = scene.bounds[0]
    assert float(hi[2] - lo[2]) > 0.04  # base and lid (or hinged box and its lid) together
    assert float(scene.poses[0, 2]) > TABLE_TOP_Z  # resting on the table
    assert (scene.views["top"].segmentation == 0).sum() > 50
