"""A picture of a plan (PNG, matplotlib's Agg canvas: no display, pyplot and the global backend
left alone): the robot at each pose (its joints' origins joined, grey), the measured points in
visiting order (coloured from first to last, the first few numbered) and the tool's path
between them along the joint moves, the instrument and its lines of sight, the cell's boxes, the
touch features, the floor. Two views of the base frame: in perspective and from above.
"""
from __future__ import annotations

import io

import numpy as np

from calib.model.kinematics import ChainKinematics

__all__ = ["plan_png", "DPI"]

DPI = 90
#: Configurations drawn per joint move of the tool's path.
PATH_SAMPLES = 12
#: Poses whose number is written beside their point.
NUMBERED = 12


def _joint_origins(robot, Q: np.ndarray) -> np.ndarray:
    """(N, n + 1, 3): the chain joints' origins and the tool point at Q (N, n), base frame."""
    import pinocchio as pin

    chain = robot.source
    model, data = chain.model, chain.model.createData()
    out = []
    for q in Q:
        pin.forwardKinematics(model, data, chain.configuration(q))
        pin.updateFramePlacements(model, data)
        oMb = data.oMf[chain.base_frame_id]
        pts = [oMb.actInv(data.oMi[j].translation) for j in chain.joint_ids]
        pts.append(oMb.actInv(data.oMf[chain.tool_frame_id].translation))
        out.append(pts)
    return np.array(out)


def _box_edges(lo: np.ndarray, hi: np.ndarray):
    c = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    for a in range(8):
        for b in range(a + 1, 8):
            if np.sum(c[a] != c[b]) == 1:
                yield c[[a, b]]


def plan_png(robot, model, cell, path: np.ndarray, measured: np.ndarray, title: str) -> bytes:
    """The picture (PNG bytes) of a plan for ``robot`` (the nominal model: its skeleton) whose
    measured points are ``model``'s tool points (the targets' model, or the probe's), with the
    program's configurations ``path`` (m, n) rad / m of which ``measured`` (m,) bool are
    poses; ``cell`` (:class:`calib.io.cell.Cell`) for the instrument, boxes and features."""
    from matplotlib import rc_context
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    import mpl_toolkits.mplot3d  # noqa: F401  (registers the 3d projection)

    path = np.asarray(path, float)
    poses = path[measured]
    kin = ChainKinematics(model)
    points = kin.frame_poses(poses)[1] * 1e3
    steps = [path[k] + (path[k + 1] - path[k]) * t for k in range(len(path) - 1)
             for t in np.linspace(0.0, 1.0, PATH_SAMPLES, endpoint=False)] + [path[-1]]
    trail = kin.frame_poses(np.array(steps))[1] * 1e3
    skeleton = _joint_origins(robot, poses) * 1e3
    fig = Figure(figsize=(13, 6.2))
    fig.subplots_adjust(left=0.02, right=0.98, top=0.88, bottom=0.08, wspace=0.15)
    ax3 = fig.add_subplot(1, 2, 1, projection="3d")
    ax2 = fig.add_subplot(1, 2, 2)
    colours = np.linspace(0.0, 1.0, len(points))
    for ax, dims in ((ax3, (0, 1, 2)), (ax2, (0, 1))):
        def draw(xyz, *args, **kw):
            ax.plot(*(xyz[:, d] for d in dims), *args, **kw)

        for s in skeleton:
            draw(s, color="0.6", lw=0.8, alpha=0.35)
        draw(trail, color="tab:blue", lw=0.7, alpha=0.6)
        ax.scatter(*(points[:, d] for d in dims), c=colours, cmap="viridis", s=22, zorder=5)
        for k in range(min(NUMBERED, len(points))):
            ax.text(*(points[k, d] for d in dims), f" {k + 1}", fontsize=7)
        inst = cell.instrument
        if inst is not None:
            p = inst.position * 1e3
            ax.scatter(*(p[[d]] for d in dims), marker="*", s=160, color="tab:red", zorder=6)
            for q in points:
                draw(np.vstack([p, q]), color="tab:red", lw=0.3, alpha=0.25)
        for box in cell.forbidden:
            for e in _box_edges(box.lower * 1e3, box.upper * 1e3):
                draw(e, color="tab:red", lw=1.0)
        if cell.workspace is not None:
            for e in _box_edges(cell.workspace.lower * 1e3, cell.workspace.upper * 1e3):
                draw(e, color="tab:green", lw=0.8, ls="--")
        for f in cell.features:
            c = f.position * 1e3
            if f.kind == "point":
                ax.scatter(*(c[[d]] for d in dims), marker="x", s=60, color="k", zorder=6)
            else:
                U = f.frame()[:, :2]
                h = np.array(f.size) * 1e3 / 2
                corners = np.array([c + U @ (h * np.array(s)) for s in ([-1, -1], [1, -1], [1, 1], [-1, 1], [-1, -1])])
                draw(corners, color="k", lw=1.0)
    ax3.set_xlabel("x mm")
    ax3.set_ylabel("y mm")
    ax3.set_zlabel("z mm")
    ax3.set_title("perspective", fontsize=9)
    drawn = np.concatenate([trail, skeleton.reshape(-1, 3)])
    span = np.maximum(drawn.max(axis=0) - drawn.min(axis=0), 1.0)
    ax3.set_box_aspect(span / span.max())
    if cell.floor:
        lim = np.abs(np.concatenate([trail[:, :2], skeleton[:, :, :2].reshape(-1, 2)])).max() * 1.1
        xx, yy = np.meshgrid(np.linspace(-lim, lim, 2), np.linspace(-lim, lim, 2))
        ax3.plot_surface(xx, yy, np.zeros_like(xx), color="0.85", alpha=0.3)
    ax2.set_aspect("equal", adjustable="datalim")
    ax2.set_xlabel("x mm")
    ax2.set_ylabel("y mm")
    ax2.set_title("from above (base frame)", fontsize=9)
    ax2.grid(alpha=0.3)
    fig.suptitle(title, fontsize=10)
    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    with rc_context({"text.hinting": "no_hinting"}):
        fig.savefig(buf, format="png", dpi=DPI)
    return buf.getvalue()
