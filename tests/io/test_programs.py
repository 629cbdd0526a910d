"""Robot program files: each vendor's reader on lines of published files (sources below), corrected
copies that keep everything but the numbers, new joint programs read back to the same joints, and
bad input as one line naming the file and line.

Published lines read here:

* KUKA KRL: ros-industrial/kuka_experimental ``kuka_kss_hw_interface/krl/KSS_86/Program/ROS/
  ros_krlptp.dat`` (commit 1c70c6a) and RoboDK's KUKA post processors' data-list lines
  (ros-industrial-attic/robodk_postprocessors, ``KUKA_KRC4_DAT.py``);
* ABB RAPID: ABB's YuMi demonstration module ``DanceR`` and OrebroUniversity/yumi
  ``yumi_hw/rapid/EGM/TRobMain.mod``;
* URScript: RoboDK's ``Universal_Robots_SCRIPT.py`` (``movej([%.6f, ...],accel_radss,...)``,
  ``movel(p[...],accel_mss,...)``) and Polyscope's ``global Waypoint_1_p=p[...]``;
* FANUC: a controller-exported ``.LS`` ``/POS`` entry (``UF : 1, UT : 3, CONFIG : 'N U T, 0, 0,
  0'``) and RoboDK's ``Fanuc_R30iA.py`` joint-position example.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calib import MeasurementFormatError, load_robot
from calib.io.programs import corrected_program, joint_program_texts, read_program, write_joint_program

from conftest import erd_urdf

KRL_DAT = """&ACCESS RVP
&REL 74
&PARAM DISKPATH = KRC:\\R1\\Program\\ROS
DEFDAT  ROS_KRLPTP PUBLIC
INT movesQueued=0
REAL moveTime=0.200000
E6AXIS nextMove={A1 -156.919830,A2 -103.435272,A3 29.4374046,A4 2.74812388,A5 -45.1240845,A6 10.6140194,E1 0.0,E2 0.0,E3 0.0,E4 0.0,E5 0.0,E6 0.0}
; DECL E6POS XP9={X 1.0,Y 2.0,Z 3.0,A 0.0,B 0.0,C 0.0,S 2,T 2} (a comment: not a target)
DECL E6POS XP1={X 27.0236969,Y 1220.23962,Z 669.846619,A -90.0563354,B 53.4202652,C -178.565933,S 2,T 35,E1 0.0,E2 0.0,E3 0.0,E4 0.0,E5 0.0,E6 0.0}
DECL FDAT FP1={TOOL_NO 1,BASE_NO 0,IPO_FRAME #BASE,POINT2[] " ",TQ_STATE FALSE}
DECL PDAT ROS_Pdat={VEL 50.0000,ACC 50.0000,APO_DIST 20.0000,GEAR_JERK 100.000,EXAX_IGN 0}
ENDDAT
"""
RAPID_MOD = """MODULE DanceR
  ! CONST jointtarget jX:=[[1,2,3,4,5,6],[9E9,9E9,9E9,9E9,9E9,9E9]]; (a comment)
  PERS robtarget pHelix_R:=[[547.59,-9.12,341.68],[0.0201017,-0.0484601,-0.70938,-0.702871],[1,-1,-1,1],[-175.428,9E+09,9E+09,9E+09,9E+09,9E+09]];
  CONST jointtarget jpDance10:=[[20.000007956,-99.999986846,30.000014495,0,40.000015912,0],[-79.999977182,9E9,9E9,9E9,9E9,9E9]];
  PROC main()
    MoveAbsJ jpDance10\\ID:=10,vDance,z20,tHandDance\\WObj:=wobj0;
    joint_position_home := [[0, -130, 30, 0, 40, 0], [135, 9E9, 9E9, 9E9, 9E9, 9E9]];
    MoveAbsJ joint_position_home, speed, fine, tool0;
  ENDPROC
ENDMODULE
"""
URSCRIPT = """def prog():
  global Waypoint_1_p=p[.4391, -.1849, .2770, 2.2, -2.2, 0]
  global Waypoint_1_q=[0.1, -1.2, 1.3, -1.6, -1.5, 0.2]
  # movej([1,2,3,4,5,6]) (a comment)
  movej([0.000000, -1.570796, 1.570796, -1.570796, -1.570796, 0.000000],accel_radss,speed_rads,0,0)
  movel(p[0.400000, -0.100000, 0.300000, 2.221441, -2.221441, 0.000000],accel_mss,speed_ms,0,0)
end
"""
FANUC_LS = """/PROG  TEST
/MN
   1:J P[1] 100% FINE    ;
   2:L P[2:"Work pos"] 1000mm/sec CNT50    ;
/POS
P[1]{
   GP1:
    UF : 1, UT : 1,
    J1=    0.000 deg,    J2=    -40.966 deg,    J3=    43.328 deg,
    J4=    0.000 deg,    J5=    -84.792 deg,    J6=    180.000 deg
};
P[2:"Work pos"]{
   GP1:
\tUF : 0, UT : 3,\t\tCONFIG : 'N U T, 0, 0, 0',
\tX =  -258.768  mm,\tY =   397.980  mm,\tZ =  1033.305  mm,
\tW =    89.999 deg,\tP =      .002 deg,\tR =     2.111 deg
};
/END
"""


@pytest.fixture(scope="module")
def six():
    """A six-axis arm for the formats (the joints' count and units are what they depend on)."""
    return load_robot(erd_urdf("ur5"), tool_frame="tool0")


def _write(tmp_path, name, text):
    path = tmp_path / name
    path.write_bytes(text.encode("utf-8"))
    return path


def test_krl_data_list_as_published(tmp_path, six):
    prog = read_program(_write(tmp_path, "p.dat", KRL_DAT), six)
    assert [(t.name, t.line, t.kind) for t in prog.targets] == [("nextMove", 7, "joints"), ("XP1", 9, "pose")]
    np.testing.assert_allclose(np.degrees(prog.targets[0].q),
                               [-156.919830, -103.435272, 29.4374046, 2.74812388, -45.1240845, 10.6140194], atol=1e-12)
    t = prog.targets[1]
    assert t.configuration == (2, 35)
    np.testing.assert_allclose(t.T[:3, 3], [0.0270236969, 1.22023962, 0.669846619], atol=1e-15)
    # KUKA's A, B, C: R = Rz(A) Ry(B) Rx(C)
    a, b, c = np.radians([-90.0563354, 53.4202652, -178.565933])
    Rz = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
    Ry = np.array([[math.cos(b), 0, math.sin(b)], [0, 1, 0], [-math.sin(b), 0, math.cos(b)]])
    Rx = np.array([[1, 0, 0], [0, math.cos(c), -math.sin(c)], [0, math.sin(c), math.cos(c)]])
    np.testing.assert_allclose(t.T[:3, :3], Rz @ Ry @ Rx, atol=1e-14)
    assert t.refused == ""
    based = KRL_DAT.replace("BASE_NO 0", "BASE_NO 2")
    assert "BASE_NO 2" in read_program(_write(tmp_path, "b.dat", based), six).targets[1].refused


def test_rapid_module_as_published(tmp_path, six):
    prog = read_program(_write(tmp_path, "p.mod", RAPID_MOD), six)
    assert [(t.name, t.line, t.kind) for t in prog.targets] == [
        ("pHelix_R", 3, "pose"), ("jpDance10", 4, "joints"), ("joint_position_home", 7, "joints")]
    t = prog.targets[0]
    w = np.array([0.0201017, -0.0484601, -0.70938, -0.702871])
    np.testing.assert_allclose(t.T[:3, :3], Rotation.from_quat(np.r_[w[1:], w[0]]).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(t.T[:3, 3], [0.54759, -0.00912, 0.34168], atol=1e-15)
    assert t.configuration == (1, -1, -1, 1) and t.refused == ""
    np.testing.assert_allclose(np.degrees(prog.targets[2].q), [0, -130, 30, 0, 40, 0], atol=1e-12)
    wobj = RAPID_MOD.replace("\\WObj:=wobj0", "\\WObj:=table")
    assert "work object table" in read_program(_write(tmp_path, "w.mod", wobj), six).targets[0].refused


def test_urscript_as_published(tmp_path, six):
    prog = read_program(_write(tmp_path, "p.script", URSCRIPT), six)
    assert [(t.name, t.kind) for t in prog.targets] == [
        ("Waypoint_1_p", "pose"), ("Waypoint_1_q", "joints"), ("line 5 movej", "joints"), ("line 6 movel", "pose")]
    np.testing.assert_allclose(prog.targets[2].q, [0, -1.570796, 1.570796, -1.570796, -1.570796, 0], atol=0)
    np.testing.assert_allclose(prog.targets[3].T[:3, :3], Rotation.from_rotvec([2.221441, -2.221441, 0]).as_matrix(),
                               atol=1e-15)
    tcp = URSCRIPT.replace("  # movej", "  set_tcp(p[0, 0, 0.1, 0, 0, 0])\n  # movej")
    assert "set_tcp at line 4" in read_program(_write(tmp_path, "t.script", tcp), six).targets[0].refused


def test_fanuc_ls_as_published(tmp_path, six):
    path = _write(tmp_path, "p.ls", FANUC_LS)
    with pytest.raises(MeasurementFormatError, match=r"P\[1\]: joint positions need the J2/J3 interaction") as info:
        read_program(path, six)
    assert info.value.row == 6
    prog = read_program(path, six, options={"j23_factor": 1.0})
    j = prog.targets[0]
    # ROS-Industrial's linkage_transform: J3_urdf = J3 + J23_factor * J2
    np.testing.assert_allclose(np.degrees(j.q), [0, -40.966, 43.328 - 40.966, 0, -84.792, 180], atol=1e-12)
    t = prog.targets[1]
    assert t.name == "P[2]" and t.configuration == ("N", "U", "T", 0, 0, 0)
    # W, P, R: R = Rz(R) Ry(P) Rx(W)
    np.testing.assert_allclose(t.T[:3, :3], Rotation.from_euler("xyz", [89.999, 0.002, 2.111], degrees=True).as_matrix(),
                               atol=1e-14)
    uf = FANUC_LS.replace("UF : 0, UT : 3", "UF : 4, UT : 3")
    assert "user frame UF 4" in read_program(_write(tmp_path, "u.ls", uf), six, options={"j23_factor": 0}).targets[1].refused


@pytest.mark.parametrize("name,text,options", [("p.dat", KRL_DAT, {}), ("p.mod", RAPID_MOD, {}),
                                               ("p.script", URSCRIPT, {}), ("p.ls", FANUC_LS, {"j23_factor": 1.0})])
def test_corrected_copy_keeps_all_but_the_numbers_and_reads_back(tmp_path, six, name, text, options):
    """New joints and poses written into each program: every line without a target is byte for
    byte the same, and the copy reads back to the values written (to the digits each format
    keeps: KRL nine significant, RAPID 9 / 6 decimals, URScript 1e-9, FANUC 1e-3 mm / deg)."""
    prog = read_program(_write(tmp_path, name, text), six, options=options)
    rng = np.random.default_rng(0)
    N = len(prog.targets)
    q = np.array([t.q + 0.01 * rng.standard_normal(6) if t.kind == "joints" else np.full(6, np.nan)
                  for t in prog.targets])
    T = np.full((N, 4, 4), np.nan)
    for k, t in enumerate(prog.targets):
        if t.kind == "pose":
            T[k] = t.T.copy()
            T[k][:3, :3] = Rotation.from_rotvec(0.01 * rng.standard_normal(3)).as_matrix() @ t.T[:3, :3]
            T[k][:3, 3] += 0.002 * rng.standard_normal(3)
    out = corrected_program(prog, six, q=q, T=T, options=options)
    path = _write(tmp_path, "out" + Path(name).suffix, out)
    back = read_program(path, six, options=options)
    lines_in, lines_out = text.splitlines(keepends=True), out.splitlines(keepends=True)
    assert len(lines_in) == len(lines_out)
    target_lines = {t.line for t in prog.targets} | {ln for t in prog.targets for ln in range(t.line, t.line + 5)}
    for k, (a, b) in enumerate(zip(lines_in, lines_out)):
        if k + 1 not in target_lines:
            assert a == b
    tol_q = {"p.dat": 1e-7, "p.mod": 1e-9, "p.script": 1e-9, "p.ls": 2e-5}[name]
    tol_p = {"p.dat": 1e-8, "p.mod": 1e-9, "p.script": 1e-9, "p.ls": 1e-6}[name]
    for k, (a, b) in enumerate(zip(prog.targets, back.targets)):
        assert (a.name, a.kind) == (b.name, b.kind)
        if a.kind == "joints":
            assert np.abs(b.q - q[k]).max() < tol_q
        else:
            assert np.abs(b.T[:3, 3] - T[k][:3, 3]).max() < tol_p
            assert np.abs(b.T[:3, :3] - T[k][:3, :3]).max() < tol_q


@pytest.mark.parametrize("vendor,name", [("kuka", "plan.src"), ("abb", "plan.mod"), ("ur", "plan.script"),
                                         ("fanuc", "plan.ls")])
def test_new_joint_programs_read_back_to_the_same_joints(tmp_path, six, vendor, name):
    q = six.random_configurations(5, 1)
    options = {"j23_factor": -1.0} if vendor == "fanuc" else None
    files = write_joint_program(vendor, tmp_path / name, six, q, names=[f"M{k}" for k in range(5)], options=options)
    program = files[-1] if vendor != "kuka" else tmp_path / "plan.dat"
    assert program.exists() and all(f.exists() for f in files)
    back = read_program(program, six, options=options)
    assert [t.kind for t in back.targets] == ["joints"] * 5
    got = np.array([t.q for t in back.targets])
    # (FANUC: 0.001 deg a value, J3 carrying J2's rounding too through the J2/J3 interaction: 1.8e-5 rad)
    tol = {"kuka": 1e-7, "abb": 1e-9, "ur": 1e-9, "fanuc": 2e-5}[vendor]
    assert np.abs(got - q).max() < tol
    if vendor == "kuka":
        src = (tmp_path / "plan.src").read_text()
        assert src.startswith("DEF plan()") and src.count("PTP XM") == 5 and src.rstrip().endswith("END")
    texts = joint_program_texts(vendor, tmp_path / name, six, q, names=[f"M{k}" for k in range(5)], options=options)
    assert {p: (tmp_path / p.name).read_text() for p in texts} == texts


@pytest.mark.parametrize("name,text,fragment,line", [
    ("s.dat", "DECL E6POS XP1={X 1.0,Y 2.0,Z 3.0,A 0.0,B 0.0,C 0.0,S 2}\n", "S without T", 1),
    ("n.dat", "DECL E6AXIS X1={A1 1.0,A2 2.0,A3 x,A4 0.0,A5 0.0,A6 0.0}\n", "A3 'x' is not a number; expected", 1),
    ("o.dat", "\nDECL E6AXIS X1={A1 1.0,A2 2.0\n", "no closing '}'", 2),
    ("q.mod", "MODULE M\n  CONST robtarget p1:=[[1,2,3],[1,1,0,0],[0,0,0,0],[9E9,9E9,9E9,9E9,9E9,9E9]];\nENDMODULE\n",
     "has norm 1.41421; expected a unit quaternion", 2),
    ("v.script", "def p():\n  global Waypoint_1_q=p[.1, .2, .3, 0, 0, 0]\nend\n", "a pose in a variable named _q", 2),
    ("c.ls", FANUC_LS.replace("'N U T, 0, 0, 0'", "'N X T, 0, 0, 0'"), "expected 'F|N U|D T|B, t1, t4, t6'", 14),
    ("e.mod", "MODULE M\nENDMODULE\n", "holds no target calib reads", None),
])
def test_bad_programs_are_one_line_naming_the_file_and_line(tmp_path, six, name, text, fragment, line):
    with pytest.raises(MeasurementFormatError, match=fragment) as info:
        read_program(_write(tmp_path, name, text), six, options={"j23_factor": 0.0} if name.endswith(".ls") else None)
    assert info.value.row == line and str(tmp_path / name) in str(info.value)
    assert "\n" not in str(info.value)
