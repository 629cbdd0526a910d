"""Benchmark of reading a ROS bag into measurements (issue 41: a 100,000-message bag read in at most
10 s, memory bounded: streamed, not loaded whole).

Writes, with rosbags' own writers (tests/rosbag_writer.py), a campaign of a 6-joint robot holding
each pose 2 s and moving 1 s between them, joint states at 500 Hz and the tracker's PoseStamped at
100 Hz: 100,000 messages (about 167 s), as a ROS 1 .bag, a ROS 2 sqlite3 bag and a ROS 2 MCAP
bag, and a 200,000-message MCAP bag. Each is read by :func:`calib.io.bag.reader.read_bag` in a
fresh process, which prints the wall time of the first read (rosbags' imports and its decoders'
generation included) and the peak of the memory Python and numpy allocate during a second read
(tracemalloc: rosbags' buffers, calib's arrays).
The target: at most 10 s for 100,000 messages; the memory of the read below the bag's size and
growing with the numbers kept (16 bytes a sample and 8 per value), not with the bag.

Run: python scripts/bench_bag.py
"""
from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

import _bench  # noqa: F401  (one BLAS thread)

ROOT = Path(__file__).resolve().parents[1]
URDF = ROOT / "robots" / "brtirus0707a" / "brtirus0707a.urdf"

_READ = r"""
import json, sys, time, tracemalloc
import calib
from calib.io.bag.reader import BagOptions, read_bag
robot = calib.load_robot(sys.argv[1])
options = BagOptions(pose="/tracker/pose")
t = time.perf_counter()
m = read_bag(sys.argv[2], robot, options)                  # (the first read in the process: all counted)
wall = time.perf_counter() - t
tracemalloc.start()                                        # (again, for the memory of the read alone)
read_bag(sys.argv[2], robot, options)
peak = tracemalloc.get_traced_memory()[1]
tracemalloc.stop()
print(json.dumps({"rows": m.n_poses, "wall_s": wall, "traced_peak_mb": peak / 2**20}))
"""


def _write(folder: Path, fmt: str, n_messages: int) -> Path:
    sys.path.insert(0, str(ROOT / "tests"))
    import calib
    from rosbag_writer import bag_path, campaign, campaign_messages, typestore, write_bag

    robot = calib.load_robot(URDF)
    seconds = n_messages / 600.0                       # 500 + 100 messages a second
    Q = robot.random_configurations(int(seconds // 3) + 1, 0)
    joints, poses = campaign(robot, Q, hz_joints=500.0, hz_pose=100.0)
    ts = typestore(fmt)
    messages = campaign_messages(ts, robot, joints, poses)[:n_messages]
    return write_bag(bag_path(folder, fmt, f"bench{n_messages}"), fmt, messages, ts)


def _size(path: Path) -> float:
    files = [path] if path.is_file() else list(path.iterdir())
    return sum(f.stat().st_size for f in files) / 2**20


def main() -> int:
    print(_bench.machine())
    print(f"{'bag':<28} {'messages':>9} {'size MB':>8} {'rows':>5} {'read s':>7} {'peak memory MB':>15}")
    worst = 0.0
    with tempfile.TemporaryDirectory() as tmp:
        for fmt, n in (("ros1", 100_000), ("sqlite3", 100_000), ("mcap", 100_000), ("mcap", 200_000)):
            bag = _write(Path(tmp), fmt, n)
            out = subprocess.run([sys.executable, "-c", _READ, str(URDF), str(bag)], capture_output=True, text=True,
                                 check=True)
            r = json.loads(out.stdout.strip().splitlines()[-1])
            if n == 100_000:
                worst = max(worst, r["wall_s"])
            print(f"{fmt + ' (' + bag.name + ')':<28} {n:>9,} {_size(bag):>8.1f} {r['rows']:>5} {r['wall_s']:>7.2f} "
                  f"{r['traced_peak_mb']:>15.1f}")
    print(f"slowest read of 100,000 messages: {worst:.2f} s (target: at most 10 s) -> "
          f"{'met' if worst <= 10 else 'NOT met'}")
    return 0 if worst <= 10 else 1


if __name__ == "__main__":
    sys.exit(main())
