"""Reading the values of a message in place when it is laid out as one rosbags has decoded
(:class:`Layouts`): the speed that reads 100,000 messages in a few seconds.

rosbags decodes each message into Python objects (some 50 us for a JointState); a recording
repeats the same layout message after message (the same frame_id, the same joint names, so the
same byte offsets), and only the stamp and the numbers change. So the first message of each
layout is decoded by rosbags and its numbers are looked for in its bytes: a layout is learned
when they are found exactly once, as little-endian float64 (ROS 1 serialization, or CDR with the
little-endian encapsulation), and the header stamp is where both serializations put it (bytes 4
to 12: ROS 1's ``seq`` or CDR's encapsulation header, then ``sec``, ``nsec``). A later message is
read in place only when its bytes from the frame_id up to the numbers are those of a learned
layout (the frame_id, the names, the lengths and the padding); any other goes to rosbags.
"""
from __future__ import annotations

import struct

import numpy as np

__all__ = ["Layouts", "STAMP"]

#: The header stamp: sec (int32 in CDR, uint32 in ROS 1; both below 2**31 until 2038) and nsec
#: (uint32), little-endian, at bytes 4 to 12 of the message.
STAMP = struct.Struct("<iI")
_PREFIX_FROM = 12
#: Layouts kept per topic (a topic mixing a few publishers' messages).
MAX_LAYOUTS = 8


class _Layout:
    __slots__ = ("prefix", "offset", "count", "extra")

    def __init__(self, prefix: bytes, offset: int, count: int, extra):
        self.prefix, self.offset, self.count, self.extra = prefix, offset, count, extra


class Layouts:
    """The learned layouts of one topic's messages; ``cdr``: ROS 2 messages (CDR, with its
    encapsulation header), else ROS 1's."""

    def __init__(self, cdr: bool):
        self.known: list[_Layout] = []
        self.cdr = cdr

    def read(self, raw) -> tuple[int, memoryview, object] | None:
        """(stamp ns, the bytes of the numbers, what was learned with the layout) of a message of
        a learned layout, else None."""
        view = memoryview(raw)
        for lay in self.known:
            end = lay.offset + 8 * lay.count
            if len(view) >= end and view[_PREFIX_FROM:lay.offset] == lay.prefix:
                sec, nsec = STAMP.unpack_from(view, 4)
                return sec * 1_000_000_000 + nsec, view[lay.offset:end], lay.extra
        return None

    def learn(self, raw, stamp_ns: int, values: np.ndarray, extra=None) -> None:
        """Learn the layout of ``raw``, whose header stamp is ``stamp_ns`` and whose run of float64
        numbers ``values`` (k,) rosbags decoded; ``extra`` is handed back with each message read
        in that layout. Nothing is learned when the stamp or the numbers are not found where and
        as the module docstring says, or when the topic has :data:`MAX_LAYOUTS` already."""
        raw = bytes(raw)
        values = np.asarray(values, dtype="<f8")
        if len(self.known) >= MAX_LAYOUTS or len(values) == 0 or len(raw) < _PREFIX_FROM:
            return
        if self.cdr and not raw[1] & 1:      # a big-endian CDR encapsulation (0x0000, 0x0002): not read in place
            return
        sec, nsec = STAMP.unpack_from(raw, 4)
        if sec * 1_000_000_000 + nsec != stamp_ns:
            return
        pattern = values.tobytes()
        offset = raw.find(pattern, _PREFIX_FROM)
        if offset < 0 or raw.find(pattern, offset + 1) >= 0:
            return
        self.known.append(_Layout(raw[_PREFIX_FROM:offset], offset, len(values), extra))
