"""Batch kinematics of a TM-MDH model: vectorised over poses, with a Pinocchio model beside it.

:class:`ChainKinematics` is the scratch workspace (Pinocchio's Model/Data split) of a
:class:`RobotModel`: it holds the joint placements of the chain (the MDH link transforms) for the
parameter values last set with :meth:`ChainKinematics.set_values`, and computes tool poses and the
identification Jacobian for a whole array of configurations at once, in numpy (a few stacked
3x3 products per joint, no per-pose Python loop). A Pinocchio model with the same placements is
built on first use of :attr:`ChainKinematics.model` (for callers that run Pinocchio's own
algorithms, and as the reference the tests compare with). A robot model itself stays immutable.

Structure of the chain of an n-joint robot (joints revolute or prismatic about z):

    placement of joint 1     = T_meas_base_ref . T(u) . Rot(z, theta_1) Trans(z, d_1)
    placement of joint i > 1 = Trans(x, a_{i-1}) Rot(x, alpha_{i-1}) [Rot(y, beta_{i-1})]
                               . Rot(z, theta_i) Trans(z, d_i)
    frame "flange" on joint n = Trans(x, a_n) Rot(x, alpha_n) [Rot(y, beta_n)]
    placement of the tool mount (an extra joint held at 0, carrying frame "tool")
                              = flange . T(v) . T_flange_tool_ref
    frame "base" on universe  = T_meas_base_ref . T(u)

With several targets (``robot.targets``) there is one tool mount and one frame ``tool`` per
target, each with its own T(v_k) . T_flange_tool_ref_k; ``targets`` (N,) indices choose each
row's frame, so a target's v columns of the Jacobian are nonzero on its rows only.

(Rot(z) and Trans(z) commute, so the joint motion about or along z may follow Trans(z, d_i).)
Each placement is a product of elementary screws, one per parameter, so the derivative of a
placement with respect to a parameter is a constant twist in the placement's own frame:
``X^-1 dX/dp = Ad(suffix)^-1 s`` with ``s`` the unit screw of the factor and ``suffix`` the
product of the factors after it. :attr:`ChainKinematics.placement_twists` stacks these twists.
A right perturbation ``X exp(xi)`` of the placement of frame F moves the tool (LOCAL_WORLD_ALIGNED,
Pinocchio's kinematic regressor) by ``dp = R_F xi_v + (R_F xi_w) x (p_tool - p_F)``,
``dw = R_F xi_w`` (:meth:`ChainKinematics.poses_and_jacobian`).
"""
from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import pinocchio as pin

from calib.memo import Memo
from calib.model.factors import placement_factors
from calib.model.periodic import periodic_term
from calib.model.robot import RobotModel
from calib.model.spatial import to_se3


_AXIS = {"x": 0, "y": 1, "z": 2}
_I4 = np.eye(4)
_I4.setflags(write=False)
#: Poses per chunk of the batch kinematics (bounds the scratch memory; a few MB per chunk): the
#: forward kinematics, and the Jacobian (smaller: its scratch is 36 values per pose and joint).
CHUNK = 2048
JACOBIAN_CHUNK = 256
#: Rows of configurations whose joint cosines and sines a kinematics object keeps (about 2 MB).
JOINT_TERM_MEMO_ROWS = 8192
#: (i, j) of the rotation block entries c, -s (at (i, j)), s (at (j, i)) about axis x, y, z.
_ROT_IJ = np.array([(1, 2), (2, 0), (0, 1)])


class _FactorTable:
    """The factors of several placements as arrays, padded with identities to equal length,
    so that their products and twists are computed for all placements at once."""

    def __init__(self, placements, n_params: int):
        self.n_placements = P = len(placements)
        self.n_factors = F = max(len(f) for f in placements)
        self.n_params = n_params
        self.base = np.tile(np.eye(4), (P, F, 1, 1))
        rot, trans = [], []   # (placement, factor, axis, param)
        for k, factors in enumerate(placements):
            for j, f in enumerate(factors):
                if f.kind == "const":
                    self.base[k, j] = f.const
                else:
                    (trans if f.kind[0] == "t" else rot).append((k, j, _AXIS[f.kind[1]], f.param))
        self.rot = np.array(rot, int).reshape(-1, 4)
        self.trans = np.array(trans, int).reshape(-1, 4)
        self.rot_i, self.rot_j = _ROT_IJ[self.rot[:, 2]].T
        # e_k x p = skew(e_k) p for the axis e_k of each rotation factor: one entry +-1 per row
        # of skew(e_k) (the axis's row zero), so component i is sign_i * p[col_i] (a gather)
        skew_k, m = np.zeros((len(self.rot), 3, 3)), np.arange(len(self.rot))
        skew_k[m, self.rot_j, self.rot_i], skew_k[m, self.rot_i, self.rot_j] = 1.0, -1.0
        self._cross_at, self._cross_sign = (m[:, None], np.abs(skew_k).argmax(axis=2)), skew_k.sum(axis=2)
        # a parameter appears once per placement (the flange's a_n, alpha_n, beta_n appear in the
        # tool placement of every target, each with its own twist rows)
        pairs = np.concatenate([self.rot[:, [0, 3]], self.trans[:, [0, 3]]])
        if len(set(map(tuple, pairs.tolist()))) != len(pairs):   # (np.unique(axis=0) imports numpy.ma)
            raise ValueError("a parameter appears in two factors of one placement")
        # flat positions in (P, F, 4, 4) of the entries the parameters set: c, c, -s, s of each
        # rotation factor, then the offset of each translation factor (one scatter per set)
        k, j, _, _ = self.rot.T
        at = lambda kk, jj, a, b: ((kk * F + jj) * 4 + a) * 4 + b    # noqa: E731
        self._flat = np.concatenate([at(k, j, self.rot_i, self.rot_i), at(k, j, self.rot_j, self.rot_j),
                                     at(k, j, self.rot_i, self.rot_j), at(k, j, self.rot_j, self.rot_i),
                                     at(self.trans[:, 0], self.trans[:, 1], self.trans[:, 2], 3)])
        self._entry_params = np.concatenate([self.rot[:, 3], self.trans[:, 3]])
        # (placement, parameter) -> row of the factor twists (translation factors, then rotation)
        self.factor_row = {(int(kk), int(pp)): r for r, (kk, pp) in
                           enumerate(np.concatenate([self.trans[:, [0, 3]], self.rot[:, [0, 3]]]).tolist())}
        # flat positions in the suffix products (P, F + 1, 4, 4) of what the twists read: the
        # axis row of the suffix's rotation for a translation factor; the whole suffix for a rotation
        k, j, axis, _ = self.trans.T
        self._trans_rows = (((k * (F + 1) + j + 1) * 4 + axis) * 4)[:, None] + np.arange(3)
        k, j, _, _ = self.rot.T
        self._rot_suffix = k * (F + 1) + j + 1
        self._rot_axis = self.rot[:, 2]

    def elementary(self, values: np.ndarray) -> np.ndarray:
        """(P, F, 4, 4) factor matrices at parameter ``values``."""
        E = self.base.copy()
        v = values[self._entry_params]
        nr = len(self.rot)
        c, s = np.cos(v[:nr]), np.sin(v[:nr])
        E.reshape(-1)[self._flat] = np.concatenate((c, c, -s, s, v[nr:]))
        return E

    def products(self, values: np.ndarray, twists: bool = True):
        """Products of the placements' factors (P, 4, 4), the factor matrices (P, F, 4, 4) and,
        with ``twists``, the local twist of each parameter, (6 P, n_params) (rows 6k..6k+5 for
        placement k)."""
        M, E, ftw = self.factor_products(values, twists)
        if ftw is None:
            return M, E, None
        tw = np.zeros((self.n_placements, 6, self.n_params))
        rows = np.array(list(self.factor_row.values()), int)
        kp = np.array(list(self.factor_row.keys()), int).reshape(-1, 2)
        tw[kp[:, 0], :, kp[:, 1]] = ftw[rows]
        return M, E, tw.reshape(6 * self.n_placements, self.n_params)

    def factor_products(self, values: np.ndarray, twists: bool = True):
        """Products of the placements' factors (P, 4, 4), the factor matrices (P, F, 4, 4) and,
        with ``twists``, the local twist (6,) of each factor with a parameter, one row per
        (placement, parameter) of :attr:`factor_row` (the dense :meth:`products` scattered)."""
        E = self.elementary(np.asarray(values, float))
        P, F = self.n_placements, self.n_factors
        if not twists:
            M = E[:, 0]
            for j in range(1, F):
                M = M @ E[:, j]
            return M, E, None
        # the twist of a factor's parameter is Ad(suffix)^-1 s, suffix = product of the factors
        # after it: (R[k], 0) for a translation along axis k and (R^T (e_k x p), R[k]) for a
        # rotation about it, with (R, p) the suffix
        suffix = np.empty((P, F + 1, 4, 4))
        suffix[:, F] = _I4
        for j in range(F - 1, -1, -1):
            np.matmul(E[:, j], suffix[:, j + 1], out=suffix[:, j])
        nt = len(self.trans)
        ftw = np.zeros((nt + len(self.rot), 6))
        ftw[:nt, :3] = suffix.reshape(-1)[self._trans_rows]
        S = suffix.reshape(-1, 4, 4)[self._rot_suffix]
        R, p = S[:, :3, :3], S[:, :3, 3]
        e_x_p = p[self._cross_at] * self._cross_sign
        ftw[nt:, :3] = np.einsum("mji,mj->mi", R, e_x_p)
        ftw[nt:, 3:] = R[np.arange(len(self.rot)), self._rot_axis]
        return suffix[:, 0], E, ftw


def _chain(matrices: np.ndarray) -> np.ndarray:
    """Product of a sequence of 4x4 matrices (k, 4, 4), left to right."""
    out = matrices[0]
    for m in matrices[1:]:
        out = out @ m
    return out


@dataclass(frozen=True, eq=False, repr=False)     # (internal; array fields: nothing compares or prints them)
class _Structure:
    """What a ChainKinematics needs that depends only on the robot's structure and reference
    frames, not on its parameter values (shared by every workspace of the same robot)."""

    factors: tuple
    table: _FactorTable
    params_of: list          # per placement: indices of its parameters
    prismatic: np.ndarray
    plans: dict              # the Jacobian's column plans (see ChainKinematics._column_plan)


#: The chain structures of the last 32 models' structures and reference frames.
STRUCTURES = Memo("chain structures", 32, lru=True)


def _structure(robot: RobotModel) -> _Structure:
    refs = robot.T_flange_target_refs if robot.T_flange_target_refs is not None else robot.T_flange_tool_ref
    key = (robot.names, tuple((j.name, j.kind) for j in robot.joints),
           robot.T_meas_base_ref.tobytes(), np.ascontiguousarray(refs).tobytes())
    st = STRUCTURES.get(key)
    if st is not None:
        return st
    factors = placement_factors(robot)
    params_of = [np.array(sorted({f.param for f in fs if f.param is not None}), int) for fs in factors]
    placed = set(np.concatenate(params_of).tolist())
    geometric = [k for k, p in enumerate(robot.parameters) if p.group not in ("compliance", "periodic")]
    if not set(geometric) <= placed:      # joint terms (compliance, periodic) act through the joints instead
        raise ValueError("a parameter belongs to no placement")
    prismatic = robot.prismatic
    prismatic.setflags(write=False)
    st = _Structure(factors, _FactorTable(factors, robot.n_params), params_of, prismatic, {})
    return STRUCTURES.put(key, st)


class ChainKinematics:
    """Kinematics of a TM-MDH chain at given parameter values, batched over poses (scratch
    workspace).

    Use :meth:`set_values` to move to other parameter values; :attr:`values` are the values last
    set. What depends only on the robot's structure and reference frames is built once and
    shared between workspaces of the same robot; a build then costs one :meth:`set_values`.
    """

    def __init__(self, robot: RobotModel):
        st = _structure(robot)
        self.factors = st.factors
        self.n_joints = robot.n_joints
        self.n_params = robot.n_params
        self.prismatic = st.prismatic
        self.joint_names = robot.joint_names
        self._table = st.table
        self._params_of = st.params_of
        # how many of their placements' first factors make the flange and base frames
        self._flange_at = len(self.factors[self.n_joints]) - 7
        self._base_at = 7
        self._pin = None
        self._pin_values = None
        self._plans = st.plans      # (shared by the workspaces of this structure)
        self._joint_term_memo: OrderedDict = OrderedDict()
        self._last_walk = None
        self.compliance = None      # (calib.model.compliance loads for a model with compliance only)
        if robot.has_compliance:
            from calib.model.compliance import compliance_term
            self.compliance = compliance_term(robot)
        # the joint terms: deviations of the joint values before the chain (compliance, periodic)
        self.joint_terms = tuple(t for t in (self.compliance, periodic_term(robot)) if t is not None)
        self.n_targets = robot.n_targets
        self.set_values(robot.values)

    # ------------------------------------------------------------------ parameters
    def set_values(self, values: np.ndarray, twists: bool = True) -> None:
        """Move to parameter ``values`` ((n_params,) SI); with ``twists`` also compute the
        placement twists needed by the Jacobian (:attr:`placement_twists`)."""
        values = np.array(values, float)
        last = getattr(self, "values", None)
        if (last is not None and (not twists or self._factor_twists is not None)
                and np.array_equal(values, last)):
            return      # already there (an LM step's Jacobian after its trial residuals needs twists)
        M, E, ftw = self._table.factor_products(values, twists)
        self.placements = M          # (n + K, 4, 4): joint placements, then each target's tool mount
        self._rot_T = np.ascontiguousarray(M[:, :3, :3].transpose(0, 2, 1))   # (for _walk)
        self._trans = np.ascontiguousarray(M[:, :3, 3])
        self._factors = E            # (the flange and base placements are made when asked)
        for name in ("flange_placement", "base_placement"):
            self.__dict__.pop(name, None)
        self._factor_twists = ftw
        self._dense_twists = None
        self.values = values

    @cached_property
    def flange_placement(self) -> np.ndarray:
        """(4, 4) the flange frame relative to the last joint's frame at the current values."""
        return _chain(self._factors[self.n_joints, :self._flange_at])

    @cached_property
    def base_placement(self) -> np.ndarray:
        """(4, 4) T_meas_base at the current values."""
        return _chain(self._factors[0, :self._base_at])

    @property
    def placement_twists(self) -> np.ndarray | None:
        """The local twist of each parameter in each placement at the current values, (6 P,
        n_params) (rows 6k..6k+5 for placement k: the n joints, then each target's tool mount),
        or None when the last :meth:`set_values` did not compute them."""
        ftw = getattr(self, "_factor_twists", None)
        if ftw is None:
            return None
        if self._dense_twists is None:
            tab = self._table
            tw = np.zeros((tab.n_placements, 6, tab.n_params))
            for (k, p), r in tab.factor_row.items():
                tw[k, :, p] = ftw[r]
            self._dense_twists = tw.reshape(6 * tab.n_placements, tab.n_params)
        return self._dense_twists

    # ------------------------------------------------------------------ Pinocchio model
    def _pinocchio(self):
        if self._pin is None:
            model = pin.Model()
            model.name = "tm_mdh"
            parent = 0
            for name, prismatic in zip(self.joint_names, self.prismatic):
                jm = pin.JointModelPZ() if prismatic else pin.JointModelRZ()
                parent = model.addJoint(parent, jm, pin.SE3.Identity(), name)
            # The tool placement rides on an extra joint that is always at 0: Pinocchio's
            # regressor then covers the flange->tool parameters too.
            mount = model.addJoint(parent, pin.JointModelRZ(), pin.SE3.Identity(), "calib_tool_mount")
            ids = (model.addFrame(pin.Frame("base", 0, pin.SE3.Identity(), pin.FrameType.OP_FRAME)),
                   model.addFrame(pin.Frame("flange", parent, pin.SE3.Identity(), pin.FrameType.OP_FRAME)),
                   model.addFrame(pin.Frame("tool", mount, pin.SE3.Identity(), pin.FrameType.OP_FRAME)))
            self._pin = (model, model.createData(), ids)
        model = self._pin[0]
        if self._pin_values is not self.values:
            for k, M in enumerate(self.placements[:self.n_joints + 1]):   # the first target's tool
                model.jointPlacements[k + 1] = to_se3(M)
            model.frames[self._pin[2][1]].placement = to_se3(self.flange_placement)
            model.frames[self._pin[2][0]].placement = to_se3(self.base_placement)
            self._pin_values = self.values
        return self._pin

    @property
    def model(self) -> pin.Model:
        """A Pinocchio model of the chain at the current values: joints 1..n the robot's, joint
        n + 1 the tool mount (keep it at 0), frames "base", "flange", "tool"."""
        return self._pinocchio()[0]

    @property
    def data(self) -> pin.Data:
        """Scratch data of :attr:`model`."""
        return self._pinocchio()[1]

    @property
    def base_frame_id(self) -> int:
        return self._pinocchio()[2][0]

    @property
    def flange_frame_id(self) -> int:
        return self._pinocchio()[2][1]

    @property
    def tool_frame_id(self) -> int:
        return self._pinocchio()[2][2]

    # ------------------------------------------------------------------ batch kinematics
    # Inside, poses are held with the pose index last and the rotation's columns first:
    # Rt (3, 3, N), Rt[j, i, n] the (i, j) element of pose n's rotation, and p (3, N). A constant
    # placement then acts on all poses in one matrix product (R M: Rt <- M^T Rt over (3, 3 N)),
    # and a joint's motion mixes two contiguous column blocks.
    def _walk(self, Q: np.ndarray, frames: tuple | None = None):
        """Pose of the last joint's frame (after its motion) at configurations Q (N, n), as
        (Rt (3, 3, N), p (3, N)); with ``frames`` = (Rt_F (n + 1, 3, 3, N), p_F (n + 1, 3, N))
        also store the frame of each joint placement (before the joint's motion) in its first
        n entries."""
        terms = self._joint_terms(Q)
        rot_T, trans = self._rot_T, self._trans
        last = self._last_walk
        if frames is None and last is not None and last[0] is rot_T and last[1] is terms:
            return last[2], last[3]     # (the same values and configurations as the last walk)
        Qt, c2, s2 = terms
        N = Qt.shape[1]
        Rt = np.empty((3, 3, N))
        Rt[:] = rot_T[0, :, :, None]
        p = np.empty((3, N))
        p[:] = trans[0, :, None]
        if frames is not None:
            frames[1][0] = p
        for k in range(self.n_joints):
            if k:           # (with frames, each position summed where the frame is kept)
                flat = Rt.reshape(3, 3 * N)
                p = np.add(p, np.dot(trans[k], flat).reshape(3, N), out=None if frames is None else frames[1][k])
                Rt = np.dot(rot_T[k], flat).reshape(3, 3, N)
            if frames is not None:
                frames[0][k] = Rt
            if self.prismatic[k]:
                p = p + Qt[k] * Rt[2]
            else:
                mixed = Rt[1::-1] * s2[k]
                Rt[:2] *= c2[k]
                Rt[:2] += mixed
        if frames is None:
            for a in (Rt, p):
                a.setflags(write=False)
            self._last_walk = (rot_T, terms, Rt, p)
        return Rt, p

    def _joint_terms(self, Q: np.ndarray):
        """(Qt (n, N), c2, s2 (n, 2, 1, N)) of configurations Q (N, n) for :meth:`_walk`: the
        joint values and the cosines and sines that turn a rotation's first two columns,
        ``R Rz(q)``: column 0 <- c col0 + s col1, column 1 <- c col1 - s col0. Kept by content
        for the last JOINT_TERM_MEMO_ROWS rows: an LM run walks the same chunks of
        configurations at every evaluation (the 1,402 iiwa rows: six Jacobian chunks and one
        chunk of poses, 137 walks per calibration)."""
        Q = np.asarray(Q, float)
        key = (Q.shape, Q.tobytes())
        memo = self._joint_term_memo
        hit = memo.get(key)
        if hit is not None:
            memo.move_to_end(key)
            return hit
        Qt = np.ascontiguousarray(Q.T)
        cos_q, sin_q = np.cos(Qt), np.sin(Qt)
        terms = (Qt, np.stack((cos_q, cos_q), axis=1)[:, :, None], np.stack((sin_q, -sin_q), axis=1)[:, :, None])
        for a in terms:
            a.setflags(write=False)
        memo[key] = terms
        rows = sum(k[0][0] for k in memo)
        while rows > JOINT_TERM_MEMO_ROWS and len(memo) > 1:
            rows -= memo.popitem(last=False)[0][0][0]
        return terms

    @staticmethod
    def _attach(Rt: np.ndarray, p: np.ndarray, T: np.ndarray):
        """The pose (Rt (3, 3, N), p (3, N), see :meth:`_walk`) followed by the constant 4x4 T."""
        N = p.shape[1]
        flat = Rt.reshape(3, 3 * N)
        return (np.dot(np.ascontiguousarray(T[:3, :3].T), flat).reshape(3, 3, N),
                p + np.dot(T[:3, 3], flat).reshape(3, N))

    def effective(self, Q: np.ndarray) -> np.ndarray:
        """(N, n) joint values the chain takes at commanded Q (N, n): Q itself, or with the joint
        terms at the current values: compliance q + C tau(q) (:mod:`calib.model.compliance`),
        periodic errors (:mod:`calib.model.periodic`)."""
        Q = np.atleast_2d(np.asarray(Q, float))
        out = Q
        for term in self.joint_terms:
            out = out + term.offsets(Q, self.values)
        return out

    def frame_poses(self, Q: np.ndarray, frame: str = "tool",
                    targets: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Poses of a frame ("tool", "flange" or "base") in the meas frame for configurations Q.

        Q : (N, n) joint values, radians / metres; targets : (N,) int, each row's target index
        for the "tool" frame of a multi-target model (None: the first target). Returns
        (R (N, 3, 3), p (N, 3) metres). Computed in chunks of ``CHUNK`` poses: the memory beyond
        the outputs is bounded.
        """
        Q = self.effective(Q)
        N = len(Q)
        if frame == "base":
            T = self.base_placement
            return np.repeat(T[None, :3, :3], N, axis=0), np.repeat(T[None, :3, 3], N, axis=0)
        groups = self._target_groups(N, targets if frame == "tool" else None)
        if len(groups) == 1 and N <= CHUNK:
            # one chunk of one target: its arrays are the outputs (no scatter copies)
            t = groups[0][0]
            T = self.placements[self.n_joints + t] if frame == "tool" else self.flange_placement
            Rc, pc = self._attach(*self._walk(Q), T)
            return np.ascontiguousarray(Rc.transpose(2, 1, 0)), np.ascontiguousarray(pc.T)
        R, p = np.empty((N, 3, 3)), np.empty((N, 3))
        for t, rows in groups:
            T = self.placements[self.n_joints + t] if frame == "tool" else self.flange_placement
            Q_rows = Q[rows]
            R_rows, p_rows = np.empty((len(Q_rows), 3, 3)), np.empty((len(Q_rows), 3))
            for a in range(0, len(Q_rows), CHUNK):
                Rc, pc = self._attach(*self._walk(Q_rows[a:a + CHUNK]), T)
                R_rows[a:a + CHUNK] = Rc.transpose(2, 1, 0)
                p_rows[a:a + CHUNK] = pc.T
            R[rows], p[rows] = R_rows, p_rows
        return R, p

    def _target_groups(self, N: int, targets):
        """(target index, rows) pairs covering N rows: all rows with target 0 when ``targets``
        is None or the model has one tool frame."""
        if targets is None or self.n_targets == 1:
            return [(0, slice(None))]
        targets = np.asarray(targets, int)
        return [(int(t), np.flatnonzero(targets == t)) for t in np.unique(targets)]

    def poses_and_jacobian(self, Q: np.ndarray, columns: np.ndarray | None = None, *,
                           transposed: bool = False, targets: np.ndarray | None = None):
        """See :meth:`_poses_and_jacobian`; with joint terms (compliance, :mod:`calib.model.compliance`;
        periodic errors, :mod:`calib.model.periodic`) at the effective joint values, the column of a
        term's parameter being that of theta_i (d_i) times its factor (tau_i(q); sin q_i ...)."""
        Q = np.atleast_2d(np.asarray(Q, float))
        if not self.joint_terms:
            return self._poses_and_jacobian(Q, columns, transposed=transposed, targets=targets)
        cols = np.arange(self.n_params) if columns is None else np.asarray(columns, int)
        of = {int(c): (t, j) for t, term in enumerate(self.joint_terms) for j, c in enumerate(term.idx)}
        wanted = [(k, *of[int(c)]) for k, c in enumerate(cols) if int(c) in of]
        if not wanted:
            return self._poses_and_jacobian(self.effective(Q), cols, transposed=transposed, targets=targets)
        m = len(cols)
        ext = list(map(int, cols))            # each column once: add the missing theta_i / d_i
        ext += sorted({int(self.joint_terms[t].q_cols[j]) for _, t, j in wanted} - set(ext))
        at = {c: k for k, c in enumerate(ext)}
        # in the layout the chain computes (Jt (columns, 6, N)): no transposed copies
        R, p, Jt = self._poses_and_jacobian(self.effective(Q), np.array(ext, int), transposed=True,
                                            targets=targets)
        factors = [term.factors(Q) for term in self.joint_terms]
        for k, t, j in wanted:
            Jt[k] = Jt[at[int(self.joint_terms[t].q_cols[j])]] * factors[t][:, j]
        Jt = Jt[:m]
        return R, p, Jt if transposed else np.ascontiguousarray(Jt.transpose(2, 1, 0))

    def _poses_and_jacobian(self, Q: np.ndarray, columns: np.ndarray | None = None, *,
                            transposed: bool = False, targets: np.ndarray | None = None):
        """Tool poses and the identification Jacobian at configurations Q (N, n), rad / m.

        columns : parameter indices of the wanted Jacobian columns, in the wanted order (default
        all, in the order of the parameters).
        Returns (R (N, 3, 3), p (N, 3) metres, J (N, 6, m)): J[:, :3] the derivative of the tool
        position in the meas frame (metres per unit), J[:, 3:] the differential rotation of the
        tool in the meas frame (radians per unit), ``R(x + dx) = exp([J[:, 3:] dx]) R(x)``.
        With ``transposed`` J comes as Jt (m, 6, N), ``Jt[c, i, n] = J[n, i, c]``, the layout it
        is computed in: ``Jt.reshape(m, -1)`` is the transposed stacked Jacobian with its rows
        ordered component first (dx of every pose, then dy, ...), ready for ``Jt @ Jt.T``; pair
        it with residuals laid out (6, N).
        Computed in chunks of ``JACOBIAN_CHUNK`` poses: the memory beyond the outputs is bounded.

        A right perturbation ``exp(xi)`` of the placement of frame F (R_F, p_F) moves the tool by
        ``Ad xi`` about the tool point: ``Ad = [[R_F, [p_F - p_tool]x R_F], [0, R_F]]``.
        """
        if self._factor_twists is None:
            self.set_values(self.values)
        Q = np.atleast_2d(np.asarray(Q, float))
        N = len(Q)
        if N <= JACOBIAN_CHUNK and (targets is None or self.n_targets == 1):
            # one chunk of one target: its arrays are the outputs (no scatter copies)
            Rc, pc, Jc = self._jacobian_chunk(Q, self._column_plan(columns, 0), 0)
            return (np.ascontiguousarray(Rc.transpose(2, 1, 0)), np.ascontiguousarray(pc.T),
                    Jc if transposed else np.ascontiguousarray(Jc.transpose(2, 1, 0)))
        m = len(columns) if columns is not None else self.n_params
        R, p = np.empty((N, 3, 3)), np.empty((N, 3))
        J = np.empty((m, 6, N)) if transposed else np.empty((N, 6, m))
        for t, rows in self._target_groups(N, targets):
            plan = self._column_plan(columns, t)
            idx = np.arange(N)[rows]
            for a in range(0, len(idx), JACOBIAN_CHUNK):
                # (a slice when the rows are consecutive: cheaper to gather and scatter)
                at = slice(a, a + JACOBIAN_CHUNK) if isinstance(rows, slice) else idx[a:a + JACOBIAN_CHUNK]
                Rc, pc, Jc = self._jacobian_chunk(Q[at], plan, t)
                R[at] = Rc.transpose(2, 1, 0)
                p[at] = pc.T
                if transposed:
                    J[:, :, at] = Jc
                else:
                    J[at] = Jc.transpose(2, 1, 0)
        return R, p, J

    def _jacobian_chunk(self, Q, plan, target: int = 0):
        """Tool pose (Rt (3, 3, N), p (3, N), see :meth:`_walk`) and Jt (m, 6, N) of a chunk of
        poses.

        A parameter with twist (v, w) in a placement frame (R, p_F) moves the tool by
        (R v + D x R w, R w), D = p_F - p_tool. All placements at once: the twists, (P, 2 w, 3)
        padded to the widest placement w, times each frame's rotation, then the D x R w terms."""
        N = len(Q)
        P = self.n_joints + 1
        RtF, pF = np.empty((P, 3, 3, N)), np.empty((P, 3, N))
        Rt, p = self._attach(*self._walk(Q, (RtF, pF)), self.placements[self.n_joints + target])
        RtF[-1], pF[-1] = Rt, p
        D = (pF - p)[:, None]                                                # (P, 1, 3, N)
        slot, rows, out_col, width, m, turning, gather = plan
        TW = np.zeros((P * width, 6))
        TW[slot] = self._factor_twists[rows]
        # (R v, R w) of every slot: (R x)[i] = sum_j x[j] Rt[j, i]
        X = np.matmul(TW.reshape(P, 2 * width, 3), RtF.reshape(P, 3, 3 * N)).reshape(P, width, 6, N)
        # the D x R w terms, for the slots that turn (each placement's first ``turning``: a
        # translation's w is zero)
        Xt = X[:, :turning]
        Rw = Xt[:, :, 3:]
        Xt[:, :, 0] += D[:, :, 1] * Rw[:, :, 2] - D[:, :, 2] * Rw[:, :, 1]
        Xt[:, :, 1] += D[:, :, 2] * Rw[:, :, 0] - D[:, :, 0] * Rw[:, :, 2]
        Xt[:, :, 2] += D[:, :, 0] * Rw[:, :, 1] - D[:, :, 1] * Rw[:, :, 0]
        if gather is not None:      # (every column is a slot: one gather, no scatter of a copy)
            return Rt, p, X.reshape(P * width, 6, N)[gather]
        Jt = np.zeros((m, 6, N))    # (the columns of other targets' tool parameters: 0)
        Jt[out_col] = X.reshape(P * width, 6, N)[slot]
        return Rt, p, Jt

    def _column_plan(self, columns, target: int = 0):
        """Where each wanted parameter sits: (slot = placement * width + place in it, its row of
        the factor twists, output column, width = most wanted parameters of one placement, number
        of columns, turning = most wanted rotation parameters of one placement: a placement's
        come first, gather = the slot of each output column, or None when a column has none).
        The plans of the last few column sets are kept (an LM run asks for the same ones)."""
        columns = np.arange(self.n_params) if columns is None else np.asarray(columns, int)
        key = (columns.tobytes(), target)
        plan = self._plans.get(key)
        if plan is None:
            plan = self._plans[key] = self._make_plan(columns, target)
            if len(self._plans) > 8:
                self._plans.pop(next(iter(self._plans)))
        return plan

    def _make_plan(self, columns, target: int = 0):
        out_col = np.full(self.n_params, -1)
        out_col[columns] = np.arange(len(columns))
        used = list(range(self.n_joints)) + [self.n_joints + target]   # joints, this target's tool
        row_of = self._table.factor_row
        n_trans = len(self._table.trans)        # (the factor rows of translations come first)
        # each placement's wanted parameters, those of rotation factors first
        params = [sorted(self._params_of[k][out_col[self._params_of[k]] >= 0].tolist(),
                         key=lambda p, k=k: row_of[(k, p)] < n_trans) for k in used]
        width = max(1, max(len(ps) for ps in params))
        turning = max(sum(row_of[(k, p)] >= n_trans for p in ps) for k, ps in zip(used, params))
        slot = np.concatenate([k * width + np.arange(len(ps)) for k, ps in enumerate(params)])
        param = np.array([p for ps in params for p in ps], int)
        # each slot's row of the factor twists (its placement's factor of that parameter)
        rows = np.array([row_of[(k, p)] for k, ps in zip(used, params) for p in ps], int)
        gather = None
        if len(slot) == len(columns):
            # the slot of each output column (every column has one): Jt = X[gather]
            gather = np.empty(len(columns), int)
            gather[out_col[param]] = slot
        return slot, rows, out_col[param], width, len(columns), turning, gather
