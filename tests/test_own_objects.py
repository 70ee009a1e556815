"""A user's own MJCF object: models robosuite reads as the file means are accepted, the others
are refused naming the file and the reason, before any scene is built."""

from pathlib import Path

import pytest

from vistask.envs.objects import check_same_object, distinct_object_specs, object_spec

SITES = """<site name="bottom_site" pos="0 0 -0.02"/><site name="top_site" pos="0 0 0.02"/>
<site name="horizontal_radius_site" pos="0.03 0.02 0"/>"""


def mjcf(folder: Path, geoms: str, name: str = "block", head: str = "", body: str = "") -> Path:
    """A file in robosuite's object layout holding ``geoms`` (``head`` before the worldbody,
    ``body`` inside the object's body)."""
    path = folder / f"{name}.xml"
    path.write_text(
        f'<mujoco model="{name}">{head}<worldbody><body><body name="object">{geoms}{body}'
        f"</body>{SITES}</body></worldbody></mujoco>"
    )
    return path


BOX = '<geom type="box" size="0.03 0.02 0.02" group="0" density="300"/>'


@pytest.mark.parametrize(
    ("geoms", "head", "body", "reason"),
    [
        ('<geom type="box" size="30 20 20" group="0"/>', "", "", "60.00 m across"),
        (
            '<geom type="box" size="0.03 0.02 0.02" group="0" contype="0" conaffinity="0"/>',
            "",
            "",
            "none of its geoms collides",
        ),
        (
            '<geom type="box" size="0.03 0.02 0.02" pos="0.3 0.2 0" group="0"/>',
            "",
            "",
            "origin lies outside its geoms",
        ),
        ('<geom type="box" size="0.03 0.02 0.02"/>', "", "", "has group None"),
        ('<geom type="box" size="0.03 0.02 0.02" group="3"/>', "", "", "has group '3'"),
        ('<geom type="box" size="0.03 0.02 0.02" group="1"/>', "", "", 'no geom of group "0"'),
        (BOX, '<compiler angle="degree"/>', "", "radians"),
        (BOX, '<compiler meshdir="meshes"/>', "", "meshdir"),
        (BOX, "", '<joint type="free"/>', "free joint"),
        (BOX, "", "<freejoint/>", "free joint"),
        ('<geom type="box" size="0.03 0.02" group="0"/>', "", "", "MuJoCo cannot compile it"),
    ],
)
def test_an_mjcf_object_robosuite_would_misread_is_refused_naming_file_and_reason(
    tmp_path, geoms, head, body, reason
):
    path = mjcf(tmp_path, geoms, head=head, body=body)
    with pytest.raises(ValueError, match=reason) as error:
        object_spec(path)
    assert str(path) in str(error.value)


def test_a_geom_group_from_a_default_class_and_an_upper_case_suffix_are_read(tmp_path):
    head = '<default><default class="part"><geom group="0" density="300"/></default></default>'
    path = mjcf(tmp_path, '<geom class="part" type="box" size="0.03 0.02 0.02"/>', head=head)
    upper = path.rename(tmp_path / "BLOCK.XML")
    assert object_spec(upper).symmetry.rotations.shape[0] == 8  # a box of three sizes


def test_two_files_of_one_name_are_refused(tmp_path):
    (tmp_path / "other").mkdir()
    first = mjcf(tmp_path, BOX)
    second = mjcf(tmp_path / "other", BOX.replace("0.03", "0.05"))
    assert list(distinct_object_specs("objects", [first, first])) == ["block"]
    with pytest.raises(ValueError, match=r"objects: .* other objects of one name, 'block'"):
        distinct_object_specs("objects", [first, second])


def test_a_run_folder_refuses_an_edited_file_of_the_object_it_learned(tmp_path):
    path = mjcf(tmp_path, BOX)
    check_same_object(tmp_path / "run" / "block", path)
    check_same_object(tmp_path / "run" / "block", path)  # the same file: resumed
    path.write_text(path.read_text().replace("0.03", "0.04"))
    with pytest.raises(ValueError, match="edited"):
        check_same_object(tmp_path / "run" / "block", path)


def test_a_box_turned_inside_its_body_has_the_four_symmetries_of_a_box(tmp_path):
    turned = '<geom type="box" size="0.05 0.015 0.02" euler="0 0 0.5" group="0" density="300"/>'
    assert object_spec(mjcf(tmp_path, turned)).symmetry.rotations.shape[0] == 4


@pytest.mark.parametrize("half", [0.005, 0.01])
def test_a_small_cube_has_the_24_rotations_of_a_cube(tmp_path, half):
    cube = f'<geom type="box" size="{half} {half} {half}" group="0" density="300"/>'
    assert object_spec(mjcf(tmp_path, cube)).symmetry.rotations.shape[0] == 24


def test_a_thin_square_prism_has_the_8_rotations_of_a_square_prism(tmp_path):
    prism = '<geom type="box" size="0.006 0.006 0.03" group="0" density="300"/>'
    assert object_spec(mjcf(tmp_path, prism)).symmetry.rotations.shape[0] == 8


def test_a_cube_turned_inside_its_body_has_the_24_rotations_of_a_cube(tmp_path):
    turned = '<geom type="box" size="0.02 0.02 0.02" euler="0.3 0 0.5" group="0" density="300"/>'
    assert object_spec(mjcf(tmp_path, turned)).symmetry.rotations.shape[0] == 24
