"""The URDF's collision geometry (calib.io.urdf.collision): meshes named package://NAME/... found
in the folders above the URDF, a clear error for a missing mesh or a URDF without collision
geometry."""
from __future__ import annotations

import shutil

import pytest

import calib
from calib.io.urdf.collision import collision_geometry, package_dirs_for

from conftest import BUNDLED_URDF, erd_urdf
from plan_check import kr16_urdf


@pytest.mark.parametrize("name, shapes", [("ur10", 8), ("panda", 17)])
def test_example_robot_data_meshes_are_found_above_the_urdf(name, shapes):
    robot = calib.load_robot(erd_urdf(name))
    geom = collision_geometry(robot)
    assert geom.ngeoms == shapes
    assert all(g.parentJoint < robot.source.model.njoints for g in geom.geometryObjects)


def test_the_kr16_meshes_in_the_vendor_folder():
    """ROS-Industrial kuka_experimental's kr16_2.urdf (e78bbd1) names
    package://kuka_kr16_support/meshes/kr16_2/collision/*.stl: 7 links, each one mesh."""
    robot = calib.load_robot(kr16_urdf())
    geom = collision_geometry(robot)
    assert [g.name for g in geom.geometryObjects] == ["base_link_0"] + [f"link_{i}_0" for i in range(1, 7)]


def test_a_urdf_without_collision_geometry_is_refused():
    robot = calib.load_robot(BUNDLED_URDF)
    with pytest.raises(calib.URDFError, match="has no collision geometry"):
        collision_geometry(robot)


def test_a_missing_mesh_names_it_and_where_it_was_looked_for(tmp_path):
    src = kr16_urdf()
    pkg = tmp_path / "kuka_kr16_support"
    (pkg / "urdf").mkdir(parents=True)
    shutil.copy(src, pkg / "urdf" / "kr16_2.urdf")         # (its meshes left behind)
    robot = calib.load_robot(pkg / "urdf" / "kr16_2.urdf")
    with pytest.raises(calib.URDFError, match=r"base_link\.stl could not be found.*--package-dir") as info:
        collision_geometry(robot)
    assert "\n" not in str(info.value)
    # the package folder given: found
    assert collision_geometry(robot, [str(src.parents[2])]).ngeoms == 7


def test_package_dirs_come_from_the_folders_above_the_urdf(tmp_path):
    (tmp_path / "share" / "mypkg" / "urdf").mkdir(parents=True)
    urdf = tmp_path / "share" / "mypkg" / "urdf" / "r.urdf"
    dirs = package_dirs_for(urdf, '<mesh filename="package://mypkg/meshes/a.stl"/>', given=["/given"])
    assert dirs[0] == "/given" and str(tmp_path / "share") in dirs


def test_a_package_dir_that_is_no_folder():
    robot = calib.load_robot(erd_urdf("ur5"))
    with pytest.raises(calib.ParameterError, match="no such folder"):
        collision_geometry(robot, ["/no/such/folder"])
