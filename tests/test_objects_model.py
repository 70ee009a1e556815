"""Object models: appearance classes, a stable feature hierarchy, potentials, persistence."""

import pytest
import torch

from vistask.objects import ObjectModel, appearance_descriptors
from vistask.objects.synthetic import synthetic_object
from vistask.saving import save_state
from vistask.se3 import SE3KDE, random_poses
from vistask.vision import Patches


@pytest.fixture(scope="module")
def model() -> ObjectModel:
    return ObjectModel.learn(synthetic_object(), "chair", n_classes=6, seed=3)


def _spread(points: torch.Tensor) -> float:
    return float(((points - points.mean(0)) ** 2).sum(1).mean().sqrt())


def test_same_seed_gives_the_same_hierarchy(model: ObjectModel) -> None:
    again = ObjectModel.learn(synthetic_object(), "chair", n_classes=6, seed=3)
    assert again.structure() == model.structure()
    torch.testing.assert_close(again.centres, model.centres)
    assert torch.equal(again.labels, model.labels)


def test_hierarchy_is_a_binary_tree_over_the_appearance_classes(model: ObjectModel) -> None:
    # The synthetic object has four colour pairs: k-means finds them, one primitive each.
    assert model.n_classes == 4
    assert len(model.features) == 2 * model.n_classes - 1
    assert model.features[model.root].parent is None
    covered: list[int] = []

    def walk(i: int) -> None:
        f = model.features[i]
        if f.is_primitive:
            covered.append(f.appearance)
            assert len(f.potential) == int((model.labels == f.appearance).sum())
        else:
            assert len(f.children) == 2
            assert all(model.features[c].parent == i for c in f.children)
            for c in f.children:
                walk(c)

    walk(model.root)
    assert sorted(covered) == list(range(model.n_classes))
    # Each class is one colour pair of the synthetic object: the classes recover them.
    for k in range(model.n_classes):
        colors = model.patches.colors[model.labels == k].reshape(-1, 6)
        assert (colors - colors[0]).abs().max() < 1e-6


def test_potentials_are_concentrated(model: ObjectModel) -> None:
    whole = _spread(model.patches.positions)
    # Meta-features pair the most compact features first: the first meta-feature's child
    # poses (its potentials' particles) spread much less than the whole object.
    first = model.features[model.n_classes]
    child_positions = torch.cat([model.features[c].potential.points[:, :3] for c in first.children])
    assert float(child_positions.norm(dim=1).pow(2).mean().sqrt()) < 0.8 * whole
    for f in model.features:
        if f.potential is not None and not f.is_primitive:
            assert len(f.potential) == 1  # a meta-feature has one instance in the object


def test_classify_rejects_foreign_appearance(model: ObjectModel) -> None:
    own = model.classify(model.patches.colors)
    assert torch.equal(own, model.labels)
    grey = torch.full((3, 2, 3), 0.5)
    assert (model.classify(grey) == -1).all()


def test_too_few_patches_and_missing_normals_are_clear_errors() -> None:
    obj = synthetic_object()
    with pytest.raises(ValueError, match="too few patches"):
        ObjectModel.learn(obj.select(torch.arange(3)), "tiny")
    with pytest.raises(ValueError, match="normals"):
        ObjectModel.learn(Patches(obj.positions, obj.directions, obj.colors), "flat")
    with pytest.raises(ValueError, match="n_classes must be >= 1, got 0"):
        ObjectModel.learn(obj, "chair", n_classes=0)
    with pytest.raises(ValueError, match="meta_sigma_t must be positive"):
        ObjectModel.learn(obj, "chair", meta_sigma_t=0.0)


def test_save_load_round_trip_keeps_the_grasp_density(model: ObjectModel, tmp_path) -> None:
    grasps = SE3KDE(random_poses(5, 0.05), sigma_t=0.01, sigma_r=0.2)
    model.grasp_density = grasps
    try:
        model.save(tmp_path / "m.pt")
        back = ObjectModel.load(tmp_path / "m.pt")
    finally:
        model.grasp_density = None
    assert back.structure() == model.structure()
    assert back.params == model.params
    for a, b in zip(back.features, model.features, strict=True):
        assert (a.children, a.parent, a.appearance) == (b.children, b.parent, b.appearance)
        if b.potential is not None:
            torch.testing.assert_close(a.potential.points, b.potential.points)
            assert (a.potential.sigma_t, a.potential.sigma_r) == (
                b.potential.sigma_t,
                b.potential.sigma_r,
            )
    assert back.grasp_density is not None
    x = random_poses(4, 0.05)
    torch.testing.assert_close(back.grasp_density(x), grasps(x))
    torch.testing.assert_close(back.classify(model.patches.colors), model.labels)


@pytest.mark.parametrize("gain", [(0.5, 0.5, 0.5), (1.3, 1.3, 1.3), (0.6, 0.5, 0.7)])
def test_a_dimmer_brighter_or_tinted_lamp_keeps_the_nearest_appearance_class(
    model: ObjectModel, gain: tuple[float, float, float]
) -> None:
    # Other light scales each channel of both sides of a patch alike: the descriptors move
    # far less than the raw colours, and each patch stays nearest its own class.
    colors = model.patches.colors
    relit = (colors * torch.tensor(gain)).clamp(0, 1)
    before, after = appearance_descriptors(colors), appearance_descriptors(relit)
    assert torch.equal(torch.cdist(after, model.centres).argmin(dim=1), model.labels)
    moved = (after - before).norm(dim=1).max()
    assert moved < 0.5 * (relit - colors).reshape(-1, 6).norm(dim=1).max()


def test_a_model_of_other_appearance_descriptors_is_refused(model: ObjectModel, tmp_path) -> None:
    state = model.state_dict()
    state["params"] = {k: v for k, v in state["params"].items() if k != "appearance"}
    save_state(tmp_path / "old.pt", "ObjectModel", state)
    with pytest.raises(ValueError, match="learn it again"):
        ObjectModel.load(tmp_path / "old.pt")
