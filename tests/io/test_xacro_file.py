"""xacro in (calib.io.urdf.xacro_file, calib.io.urdf.packages): a description package written by the
test (a xacro with macros, a block parameter, arguments, includes, a YAML parameter file and
package:// and file:// meshes) expands without ROS into the URDF written out by hand, and
calibrates to the same numbers; packages are found through --package, the xacro's own package,
ROS_PACKAGE_PATH and the ament index; mesh paths are kept as written; a UR description that
reads ur_description's default_kinematics.yaml gets the calibrated file beside the calibrated URDF,
which the xacro expands back into the calibrated robot; bad input gets one line, exit 2, nothing
written."""
from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

import calib
from calib.cli.main import main
from calib.errors import ParameterError, URDFError
from calib.io.urdf.packages import RosPackages
from calib.io.urdf.xacro_file import XacroText, expand_xacro

from conftest import ROOT
from ur_template import published_file, published_kinematics, xacro_urdf

# (found, not imported: the tests check that calib never imports xacro into this process)
pytestmark = pytest.mark.skipif(importlib.util.find_spec("xacro") is None,
                                reason="the ros extra (pip install 'calib[ros]') is not installed")

#: The arm: (joint, parent, child, xyz, axis, lower, upper); j3's z is the argument upper_len.
ARM = (("j1", "base_link", "link1", "0 0 0.4", "0 0 1"), ("j2", "link1", "link2", "0.1 0 0.1", "0 1 0"),
       ("j3", "link2", "link3", "0 0 UPPER", "0 1 0"), ("j4", "link3", "link4", "0.3 0 0.05", "1 0 0"),
       ("j5", "link4", "link5", "0.1 0 0", "0 1 0"), ("j6", "link5", "link6", "0.08 0 0", "1 0 0"))
LIMITS = {"j1": 2.9, "j2": 2.0, "j3": 2.5, "j4": 3.1, "j5": 2.1, "j6": 3.1}


def _write(path, text: str):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(textwrap.dedent(text).lstrip())
    return path


def _package(folder, name: str):
    _write(folder / "package.xml", f'<?xml version="1.0"?>\n<package format="3"><name>{name}</name>'
                                   f'<version>1.0.0</version></package>\n')
    return folder


@pytest.fixture
def arm(tmp_path):
    """The description package (ws/src/arm_description) and the meshes' package (ws/src/arm_meshes)."""
    desc = _package(tmp_path / "ws" / "src" / "arm_description", "arm_description")
    meshes = _package(tmp_path / "ws" / "src" / "arm_meshes", "arm_meshes")
    for j in ("base",) + tuple(LIMITS):
        _write(desc / "meshes" / f"{j}.stl", "solid x\nendsolid x\n")
        _write(meshes / "collision" / f"{j}.stl", "solid x\nendsolid x\n")
    _write(desc / "config" / "limits.yaml", "".join(f"{j}: {v}\n" for j, v in LIMITS.items()))
    _write(desc / "urdf" / "arm_macro.xacro", """
        <?xml version="1.0"?>
        <robot xmlns:xacro="http://www.ros.org/wiki/xacro">
          <xacro:property name="limits" value="${xacro.load_yaml('$(find arm_description)/config/limits.yaml')}"/>
          <xacro:macro name="revolute" params="prefix name parent child xyz axis">
            <link name="${prefix}${child}">
              <visual><geometry><mesh filename="package://arm_description/meshes/${name}.stl"/></geometry></visual>
              <collision><geometry><mesh filename="package://arm_meshes/collision/${name}.stl"/></geometry></collision>
            </link>
            <joint name="${prefix}${name}" type="revolute">
              <parent link="${prefix}${parent}"/><child link="${prefix}${child}"/>
              <origin xyz="${xyz}" rpy="0 0 0"/><axis xyz="${axis}"/>
              <limit lower="${-limits[name]}" upper="${limits[name]}" effort="100" velocity="${pi / 2}"/>
            </joint>
          </xacro:macro>
          <xacro:macro name="fixed_frame" params="prefix name parent *origin">
            <link name="${prefix}${name}"/>
            <joint name="${prefix}${parent}-${name}" type="fixed">
              <parent link="${prefix}${parent}"/><child link="${prefix}${name}"/>
              <xacro:insert_block name="origin"/>
            </joint>
          </xacro:macro>
        </robot>
        """)
    calls = "\n".join(f'    <xacro:revolute prefix="$(arg prefix)" name="{j}" parent="{p}" child="{c}" '
                      f'xyz="{xyz.replace("UPPER", "$(arg upper_len)")}" axis="{axis}"/>'
                      for j, p, c, xyz, axis in ARM)
    _write(desc / "urdf" / "arm.urdf.xacro", f"""
        <?xml version="1.0"?>
        <robot name="arm" xmlns:xacro="http://www.ros.org/wiki/xacro">
          <xacro:arg name="prefix" default=""/>
          <xacro:arg name="upper_len" default="0.45"/>
          <xacro:include filename="$(find arm_description)/urdf/arm_macro.xacro"/>
          <link name="$(arg prefix)base_link">
            <visual><geometry><mesh filename="file://$(find arm_description)/meshes/base.stl"/></geometry></visual>
          </link>
        {calls}
          <xacro:fixed_frame prefix="$(arg prefix)" name="tool0" parent="link6">
            <origin xyz="0.02 0 0" rpy="0 ${{pi / 2}} 0"/>
          </xacro:fixed_frame>
        </robot>
        """)
    return desc, meshes


def _urdf_by_hand(desc, upper_len: str) -> str:
    """The URDF the xacro stands for, written out (as xacro writes ${pi / 2}: Python's repr)."""
    links = [f'<link name="base_link"><visual><geometry><mesh filename="file://{desc}/meshes/base.stl"/></geometry>'
             f'</visual></link>']
    for j, p, c, xyz, axis in ARM:
        links.append(f'<link name="{c}"><visual><geometry><mesh filename="package://arm_description/meshes/{j}.stl"/>'
                     f'</geometry></visual><collision><geometry><mesh filename="package://arm_meshes/collision/{j}.stl"/>'
                     f'</geometry></collision></link>'
                     f'<joint name="{j}" type="revolute"><parent link="{p}"/><child link="{c}"/>'
                     f'<origin xyz="{xyz.replace("UPPER", upper_len)}" rpy="0 0 0"/><axis xyz="{axis}"/>'
                     f'<limit lower="{-LIMITS[j]!r}" upper="{LIMITS[j]!r}" effort="100" velocity="{np.pi / 2!r}"/></joint>')
    links.append(f'<link name="tool0"/><joint name="link6-tool0" type="fixed"><parent link="link6"/><child link="tool0"/>'
                 f'<origin xyz="0.02 0 0" rpy="0 {np.pi / 2!r} 0"/></joint>')
    return '<?xml version="1.0"?>\n<robot name="arm">' + "".join(links) + "</robot>\n"


def _poses(robot, Q):
    return np.array([robot.T_meas_tool(q) for q in Q])


def test_a_xacro_expands_to_the_urdf_it_stands_for(arm, tmp_path):
    """expand_xacro (args, --package for the meshes' package, the xacro's own package found by
    walking up) -> load_robot: the hand-written URDF's joints, limits and tool poses (to 1e-15);
    every file read is listed; mesh paths are as the xacro wrote them."""
    desc, meshes = arm
    text = expand_xacro(desc / "urdf" / "arm.urdf.xacro", {"upper_len": "0.5"}, packages={"arm_meshes": meshes})
    assert isinstance(text, XacroText) and text.notes == () and text.args == (("upper_len", "0.5"),)
    assert [f.name for f in text.files] == ["arm_macro.xacro", "limits.yaml"]
    (tmp_path / "by_hand.urdf").write_text(_urdf_by_hand(desc, "0.5"))
    a, b = calib.load_robot(text), calib.load_robot(tmp_path / "by_hand.urdf")
    assert a.joint_names == b.joint_names == tuple(LIMITS) and a.tool_frame == b.tool_frame == "tool0"
    np.testing.assert_array_equal(a.upper, b.upper)
    Q = b.random_configurations(20, 1)
    np.testing.assert_allclose(_poses(a, Q), _poses(b, Q), atol=1e-15, rtol=0)
    assert 'filename="package://arm_meshes/collision/j3.stl"' in text.text
    assert f'filename="file://{desc}/meshes/base.stl"' in text.text
    assert text.kinematics_file() is None          # (limits.yaml is no kinematics file calib writes)


def test_packages_on_ros_package_path_and_the_ament_index(arm, tmp_path):
    """RosPackages: ROS_PACKAGE_PATH crawled (rospkg), an AMENT_PREFIX_PATH prefix's resource
    index (marker file -> share/NAME), the first prefix winning, --package winning over both;
    the environment is read from the mapping given, never changed."""
    desc, meshes = arm
    prefix1, prefix2 = tmp_path / "install1", tmp_path / "install2"
    for prefix in (prefix1, prefix2):
        _write(prefix / "share" / "ament_index" / "resource_index" / "packages" / "arm_meshes", "")
        (prefix / "share" / "arm_meshes").mkdir(parents=True)
    env = {"ROS_PACKAGE_PATH": str(tmp_path / "ws" / "src"), "AMENT_PREFIX_PATH": f"{prefix1}{os.pathsep}{prefix2}"}
    before = dict(os.environ)
    table = RosPackages.from_options(environ=env).table()
    assert table["arm_description"] == desc and table["arm_meshes"] == meshes      # (ROS 1 over ROS 2)
    table = RosPackages.from_options(environ={"AMENT_PREFIX_PATH": env["AMENT_PREFIX_PATH"]}).table()
    assert table == {"arm_meshes": prefix1 / "share" / "arm_meshes"}
    given = RosPackages.from_options({"arm_meshes": tmp_path}, environ=env).table()
    assert given["arm_meshes"] == tmp_path.resolve()
    assert dict(os.environ) == before
    text = expand_xacro(desc / "urdf" / "arm.urdf.xacro", packages=RosPackages.from_options(environ=env))
    assert calib.load_robot(text).n_joints == 6
    with pytest.raises(ParameterError, match="no such folder"):
        RosPackages.from_options(["arm_meshes=/nonexistent/folder"])


@pytest.mark.slow
def test_calibrate_a_xacro_as_its_urdf(arm, tmp_path, capsys):
    """calib calibrate ROBOT.urdf.xacro --xacro-arg --package: the calibrated model of the
    hand-written URDF's calibration (tool poses to 1e-12 m) and parameters (1e-12); the calibrated
    URDF keeps the package:// and file:// mesh paths as written; evaluate, identifiability and
    select-poses take the xacro too."""
    desc, meshes = arm
    (tmp_path / "by_hand.urdf").write_text(_urdf_by_hand(desc, "0.5"))
    nominal = calib.load_robot(tmp_path / "by_hand.urdf")
    true = calib.apply_deviations(nominal, calib.random_deviations(nominal, 1e-3, rng=np.random.default_rng(2)))
    meas = calib.simulate_measurements(true, nominal.random_configurations(40, 3), rng=np.random.default_rng(4))
    calib.write_measurements(tmp_path / "meas.csv", meas)
    xacro = [str(desc / "urdf" / "arm.urdf.xacro"), "--xacro-arg", "upper_len:=0.5", "--package", f"arm_meshes={meshes}"]
    code = main(["calibrate", xacro[0], str(tmp_path / "meas.csv"), *xacro[1:], "-o", str(tmp_path / "x.urdf"),
                 "--report", str(tmp_path / "x.json")])
    assert code == 0, capsys.readouterr().err
    assert main(["calibrate", str(tmp_path / "by_hand.urdf"), str(tmp_path / "meas.csv"), "-o", str(tmp_path / "u.urdf"),
                 "--report", str(tmp_path / "u.json")]) == 0
    capsys.readouterr()
    a, b = calib.load_robot(tmp_path / "x.urdf"), calib.load_robot(tmp_path / "u.urdf")
    Q = nominal.random_configurations(20, 5)
    np.testing.assert_allclose(_poses(a, Q), _poses(b, Q), atol=1e-12, rtol=0)
    pa, pb = (json.loads((tmp_path / f"{n}.json").read_text())["parameters"] for n in "xu")
    assert [p["name"] for p in pa] == [p["name"] for p in pb]
    np.testing.assert_allclose([p["identified"] for p in pa], [p["identified"] for p in pb], atol=1e-12, rtol=0)
    written = (tmp_path / "x.urdf").read_text()
    assert 'filename="package://arm_description/meshes/j2.stl"' in written
    assert 'filename="package://arm_meshes/collision/j6.stl"' in written
    assert f'filename="file://{desc}/meshes/base.stl"' in written
    assert not (tmp_path / "x.kinematics.yaml").exists()
    for command in (["evaluate", xacro[0], str(tmp_path / "meas.csv"), *xacro[1:]], ["identifiability", *xacro],
                    ["select-poses", *xacro, "-n", "8", "-o", str(tmp_path / "poses.csv")]):
        assert main(command) == 0, (command, capsys.readouterr().err)
    capsys.readouterr()


def _refused(capsys, argv, outputs, want: str) -> str:
    code = main([str(a) for a in argv])
    _, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and want in lines[0], err
    assert not any(p.exists() for p in outputs)
    return lines[0]


def test_bad_xacros_are_refused_in_one_line(arm, tmp_path, capsys):
    """A xacro that does not expand (an undefined property, malformed XML), an unknown package in
    $(find) or in a mesh path, a malformed --xacro-arg or --package, --xacro-arg for a URDF: exit
    2, one line naming the file and what is wrong, nothing written."""
    desc, meshes = arm
    csv = tmp_path / "meas.csv"
    csv.write_text("j1_deg,x_mm,y_mm,z_mm\n0,0,0,0\n")
    out = tmp_path / "out.urdf"
    main_xacro = desc / "urdf" / "arm.urdf.xacro"
    good = ["--package", f"arm_meshes={meshes}"]

    def calibrate(robot, *extra):
        return ["calibrate", robot, csv, "-o", out, *extra]

    bad = _write(desc / "urdf" / "bad.urdf.xacro", """
        <robot name="bad" xmlns:xacro="http://www.ros.org/wiki/xacro">
          <xacro:include filename="$(find arm_description)/urdf/arm_macro.xacro"/>
          <link name="${no_such_property}"/>
        </robot>""")
    line = _refused(capsys, calibrate(bad, *good), [out], "xacro cannot expand it")
    assert line.startswith(f"calib: error: {bad}: ") and "no_such_property" in line
    broken = _write(desc / "urdf" / "broken.urdf.xacro", "<robot name='x'><link name='a'></robot>")
    _refused(capsys, calibrate(broken), [out], f"{broken}: xacro cannot expand it")
    nowhere = _write(desc / "urdf" / "nowhere.urdf.xacro", """
        <robot name="n" xmlns:xacro="http://www.ros.org/wiki/xacro">
          <xacro:include filename="$(find nowhere_description)/urdf/x.xacro"/>
        </robot>""")
    line = _refused(capsys, calibrate(nowhere), [out], "unknown package 'nowhere_description'")
    assert "--package nowhere_description=DIR" in line and line.startswith(f"calib: error: {nowhere}: ")
    line = _refused(capsys, calibrate(main_xacro), [out], "unknown package 'arm_meshes' (the mesh "
                                                          "package://arm_meshes/collision/j1.stl of link 'link1')")
    _refused(capsys, calibrate(main_xacro, *good, "--xacro-arg", "upper_len=0.5"), [out], "expected NAME:=VALUE")
    _refused(capsys, calibrate(main_xacro, "--package", "arm_meshes"), [out], "expected NAME=DIR")
    _refused(capsys, calibrate(tmp_path / "x.urdf", "--xacro-arg", "a:=1"), [out],
             "--xacro-arg expand a robot given as a xacro")
    with pytest.raises(URDFError, match="is a xacro: expand it first"):
        calib.load_robot(main_xacro)


def test_expanding_leaves_the_process_alone(arm):
    """xacro runs in a child process: after an expansion this process has not imported xacro, and
    PyYAML's SafeLoader has not gained xacro's unit tags (!degrees, ...)."""
    desc, meshes = arm
    before = set(yaml.SafeLoader.yaml_constructors)
    expand_xacro(desc / "urdf" / "arm.urdf.xacro", packages={"arm_meshes": meshes})
    assert "xacro" not in sys.modules
    assert set(yaml.SafeLoader.yaml_constructors) == before


def test_without_the_ros_extra_the_error_names_it(arm, tmp_path):
    """Without xacro importable, calibrate of a xacro says which extra to install (exit 2)."""
    desc, meshes = arm
    _write(tmp_path / "shadow" / "xacro" / "__init__.py", "raise ImportError('no xacro here')\n")
    env = dict(os.environ, PYTHONPATH=f"{tmp_path / 'shadow'}{os.pathsep}{ROOT}")
    run = subprocess.run([sys.executable, "-m", "calib", "identifiability", str(desc / "urdf" / "arm.urdf.xacro"),
                          "--package", f"arm_meshes={meshes}"], capture_output=True, text=True, env=env, cwd=tmp_path)
    assert run.returncode == 2, run.stderr
    assert "needs the optional 'ros' dependencies" in run.stderr and "pip install 'calib[ros]'" in run.stderr
    assert len(run.stderr.strip().splitlines()) == 1


# ---------------------------------------------------------------------- the UR case
def _ur_description(folder):
    """A ur_description package as the test writes it: urdf/ur_macro.xacro with the lines
    tests/ur_template.py quotes from Universal_Robots_ROS2_Description 2.4.5 (the kinematics read
    by xacro.load_yaml as urdf/inc/ur_common.xacro reads them), and urdf/ur.urdf.xacro with the
    arguments ur_type and kinematics_params (default: config/<ur_type>/default_kinematics.yaml)."""
    desc = _package(folder / "ur_description", "ur_description")
    _write(desc / "meshes" / "ur5e" / "visual" / "base.dae", "<COLLADA/>\n")
    segments = ("shoulder", "upper_arm", "forearm", "wrist_1", "wrist_2", "wrist_3")
    joints = ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint",
              "wrist_3_joint")
    links = ("base_link_inertia", "shoulder_link", "upper_arm_link", "forearm_link", "wrist_1_link", "wrist_2_link",
             "wrist_3_link")
    body = "\n".join(
        f'    <link name="${{tf_prefix}}{links[k + 1]}"/>\n'
        f'    <joint name="${{tf_prefix}}{j}" type="revolute">\n'
        f'      <parent link="${{tf_prefix}}{links[k]}" />\n      <child link="${{tf_prefix}}{links[k + 1]}" />\n'
        f'      <origin xyz="${{sec_kinematics[\'{s}\'][\'x\']}} ${{sec_kinematics[\'{s}\'][\'y\']}} '
        f'${{sec_kinematics[\'{s}\'][\'z\']}}" rpy="${{sec_kinematics[\'{s}\'][\'roll\']}} '
        f'${{sec_kinematics[\'{s}\'][\'pitch\']}} ${{sec_kinematics[\'{s}\'][\'yaw\']}}" />\n'
        f'      <axis xyz="0 0 1" />\n'
        f'      <limit lower="${{-2 * pi}}" upper="${{2 * pi}}" effort="150" velocity="3.14"/>\n    </joint>'
        for k, (s, j) in enumerate(zip(segments, joints)))
    _write(desc / "urdf" / "ur_macro.xacro", f"""
        <?xml version="1.0"?>
        <robot xmlns:xacro="http://wiki.ros.org/xacro">
          <xacro:macro name="ur_robot" params="tf_prefix ur_type kinematics_parameters_file">
            <xacro:property name="sec_kinematics" value="${{xacro.load_yaml(kinematics_parameters_file)['kinematics']}}"/>
            <link name="${{tf_prefix}}base_link"/>
            <link name="${{tf_prefix}}base_link_inertia">
              <visual><geometry><mesh filename="package://ur_description/meshes/${{ur_type}}/visual/base.dae"/></geometry></visual>
            </link>
            <joint name="${{tf_prefix}}base_link-base_link_inertia" type="fixed">
              <parent link="${{tf_prefix}}base_link" />
              <child link="${{tf_prefix}}base_link_inertia" />
              <origin xyz="0 0 0" rpy="0 0 ${{pi}}" />
            </joint>
        {textwrap.indent(body, "    ")}
            <link name="${{tf_prefix}}base"/>
            <joint name="${{tf_prefix}}base_link-base_fixed_joint" type="fixed">
              <origin xyz="0 0 0" rpy="0 0 ${{pi}}"/>
              <parent link="${{tf_prefix}}base_link"/>
              <child link="${{tf_prefix}}base"/>
            </joint>
            <link name="${{tf_prefix}}flange"/>
            <joint name="${{tf_prefix}}wrist_3-flange" type="fixed">
              <parent link="${{tf_prefix}}wrist_3_link" />
              <child link="${{tf_prefix}}flange" />
              <origin xyz="0 0 0" rpy="0 ${{-pi/2.0}} ${{-pi/2.0}}" />
            </joint>
            <link name="${{tf_prefix}}tool0"/>
            <joint name="${{tf_prefix}}flange-tool0" type="fixed">
              <origin xyz="0 0 0" rpy="${{pi/2.0}} 0 ${{pi/2.0}}"/>
              <parent link="${{tf_prefix}}flange"/>
              <child link="${{tf_prefix}}tool0"/>
            </joint>
          </xacro:macro>
        </robot>
        """)
    _write(desc / "urdf" / "ur.urdf.xacro", """
        <?xml version="1.0"?>
        <robot xmlns:xacro="http://wiki.ros.org/xacro" name="ur">
          <xacro:include filename="$(find ur_description)/urdf/ur_macro.xacro"/>
          <xacro:arg name="ur_type" default="ur5e"/>
          <xacro:arg name="tf_prefix" default=""/>
          <xacro:arg name="kinematics_params" default="$(find ur_description)/config/$(arg ur_type)/default_kinematics.yaml"/>
          <xacro:ur_robot tf_prefix="$(arg tf_prefix)" ur_type="$(arg ur_type)"
                          kinematics_parameters_file="$(arg kinematics_params)"/>
        </robot>
        """)
    return desc


def test_a_ur_xacro_gets_its_calibrated_kinematics_file(tmp_path, capsys):
    """ur.urdf.xacro with kinematics_params:= the published ur5e default_kinematics.yaml (read in
    place) expands to the URDF of tests/ur_template.py (1e-15); calibrate writes
    CALIBRATED.kinematics.yaml beside the URDF and says how to use it, and the xacro expanded with
    it, with the file's tool_in_tool0, is the calibrated robot (tool0 in base_link to 1e-9 m / rad
    at random configurations)."""
    desc = _ur_description(tmp_path / "src")
    published = published_file("ur5e", tmp_path)
    args = ["--xacro-arg", "ur_type:=ur5e", "--xacro-arg", f"kinematics_params:={published}"]
    xacro = desc / "urdf" / "ur.urdf.xacro"
    text = expand_xacro(xacro, dict(a.split(":=") for a in args[1::2]))
    assert text.kinematics_file() == published.resolve()
    (tmp_path / "template.urdf").write_text(xacro_urdf(published_kinematics("ur5e")))
    nominal, template = calib.load_robot(text), calib.load_robot(tmp_path / "template.urdf", tool_frame="tool0")
    Q = nominal.random_configurations(20, 1)
    assert nominal.tool_frame == "tool0" and nominal.base_frame == "base_link"
    np.testing.assert_allclose(_poses(nominal, Q), _poses(template, Q), atol=1e-15, rtol=0)
    true = calib.apply_deviations(nominal, calib.random_deviations(nominal, 0.5e-3, rng=np.random.default_rng(7)))
    calib.write_measurements(tmp_path / "meas.csv", calib.simulate_measurements(
        true, nominal.random_configurations(50, 2), rng=np.random.default_rng(8)))
    out = tmp_path / "cal.urdf"
    code = main(["calibrate", str(xacro), str(tmp_path / "meas.csv"), *args, "-o", str(out)])
    stdout, err = capsys.readouterr()
    assert code == 0, err
    kin = tmp_path / "cal.kinematics.yaml"
    assert f"wrote {out}, {kin}" in stdout
    assert f"--xacro-arg kinematics_params:={kin}" in stdout
    assert 'filename="package://ur_description/meshes/ur5e/visual/base.dae"' in out.read_text()
    assert "calib.tool_in_tool0 in the file the tool frame in tool0" in err       # (the export's note)
    calibrated = calib.load_robot(out)
    again = calib.load_robot(expand_xacro(xacro, {"ur_type": "ur5e", "kinematics_params": str(kin)}))
    # ur_description's tool0 is the flange on axis 6; the calibrated tool0's offset from it is the
    # file's calib.tool_in_tool0 (ignored by ur_description: the controller's TCP)
    tool = yaml.safe_load(kin.read_text())["calib"]["tool_in_tool0"]
    T_tool = np.eye(4)
    T_tool[:3, :3] = Rotation.from_euler("xyz", [tool["roll"], tool["pitch"], tool["yaw"]]).as_matrix()
    T_tool[:3, 3] = tool["x"], tool["y"], tool["z"]
    got, want = _poses(again, Q) @ T_tool, _poses(calibrated, Q)
    np.testing.assert_allclose(got[:, :3, 3], want[:, :3, 3], atol=1e-9, rtol=0)
    np.testing.assert_allclose(got[:, :3, :3], want[:, :3, :3], atol=1e-9, rtol=0)
    assert np.abs(_poses(calibrated, Q) - _poses(nominal, Q)).max() > 1e-4         # (it did move)


def test_calib_formats_lists_xacros(capsys):
    """calib formats says how xacros are expanded and where packages are found."""
    assert main(["formats"]) == 0
    out = capsys.readouterr().out
    assert "Robot descriptions as xacros" in out and "--xacro-arg NAME:=VALUE" in out and "AMENT_PREFIX_PATH" in out
    assert calib.expand_xacro is expand_xacro and calib.RosPackages is RosPackages
