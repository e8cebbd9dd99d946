"""Opening a bag with ``rosbags`` (ROS 1 .bag, ROS 2 folder, .mcap, .db3) and reading message times
from its index (ROS 1 index records, MCAP message indexes, sqlite3 timestamps) without reading messages.

Times are nanoseconds of the bag's record clock.
"""

from __future__ import annotations

import re
import struct
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from device.sources.bag.errors import BagError, BagNotFound

BAG_SUFFIXES = (".bag", ".mcap", ".db3")


def is_bag_path(path: str | Path) -> bool:
    """True when ``path`` looks like a bag: a .bag/.mcap/.db3 file or a ROS 2 bag folder."""
    p = Path(path)
    return (p.is_file() and p.suffix.lower() in BAG_SUFFIXES) or (p.is_dir() and (p / "metadata.yaml").is_file())


def _storage_name(path: Path) -> str:
    if path.suffix.lower() == ".bag":
        return "ROS 1 bag"
    if path.suffix.lower() == ".mcap":
        return "ROS 2 MCAP"
    if path.suffix.lower() == ".db3":
        return "ROS 2 sqlite3"
    text = (path / "metadata.yaml").read_text(errors="replace") if (path / "metadata.yaml").is_file() else ""
    m = re.search(r"storage_identifier:\s*(\S+)", text)
    return f"ROS 2 {m.group(1) if m else 'bag'} folder"


def _open_reader(path: Path) -> Any:
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    if not path.exists():
        raise BagNotFound(f"{path} does not exist; give a ROS 1 .bag, a ROS 2 bag folder or a .mcap/.db3 file")
    if path.is_dir() and not (path / "metadata.yaml").is_file():
        found = sorted(p for p in path.iterdir() if p.suffix.lower() in (".mcap", ".db3"))
        if len(found) != 1:
            raise BagNotFound(f"{path} has no metadata.yaml and {len(found)} .mcap/.db3 files; give the bag file itself (bag:{path}/NAME.mcap)")
        path = found[0]
    elif path.is_file() and path.suffix.lower() not in BAG_SUFFIXES:
        raise BagNotFound(f"{path} is not a bag: use a .bag (ROS 1), .mcap or .db3 (ROS 2) file or a ROS 2 bag folder")
    # ROS 1 bags always embed their message definitions; ROS 2 sqlite3 bags before Iron may not.
    store = None if path.suffix.lower() == ".bag" else get_typestore(Stores.ROS2_HUMBLE)
    reader = AnyReader([path], default_typestore=store)
    try:
        reader.open()
    except Exception as exc:  # rosbags raises its own ReaderError/AnyReaderError and struct/OS errors on damage
        raise BagError(f"{path} cannot be opened as a bag ({type(exc).__name__}: {exc}); check it is complete (ROS 1: rosbag reindex)") from exc
    return reader


def _mcap_index_times(storage: Any, channel_ids: set[int]) -> list[int] | None:
    """Log times of the channels' messages from an MCAP file's MessageIndex records (no chunk is read);
    None when a chunk has no message index (the writer left them out)."""
    bio = storage.bio
    out: list[int] = []
    if any(not chunk.message_index_offsets for chunk in storage.chunks):
        return None
    for chunk in storage.chunks:
        for cid, offset in chunk.message_index_offsets.items():
            if cid not in channel_ids:
                continue
            bio.seek(offset)
            head = bio.read(9)
            if len(head) != 9 or head[0] != 0x07:
                raise BagError(f"{storage.path}: the MCAP message index at byte {offset} is damaged; re-index the file (mcap recover)")
            (length,) = struct.unpack("<Q", head[1:])
            rec = bio.read(length)
            (nbytes,) = struct.unpack_from("<I", rec, 2)
            pairs = np.frombuffer(rec, dtype="<u8", count=nbytes // 8, offset=6)
            out.extend(int(t) for t in pairs[0::2])
    return out


def topic_times(connections: Sequence[Any]) -> tuple[np.ndarray, bool]:
    """Sorted record times (ns) of all messages of these connections, from the bag's index; and whether
    only the index was read (False: an unindexed MCAP had to be scanned)."""
    from rosbags.rosbag1 import Reader as Reader1
    from rosbags.rosbag2.reader import DirectoryReader
    from rosbags.rosbag2.storage_mcap import McapReader
    from rosbags.rosbag2.storage_sqlite3 import Sqlite3Reader

    times: list[int] = []
    indexed = True
    for conn in connections:
        owner = conn.owner
        if isinstance(owner, Reader1):
            times.extend(e.time for e in owner.indexes[conn.id])
            continue
        storages = owner.storages if isinstance(owner, DirectoryReader) else [owner]
        for st in storages:
            ids = {c.id for c in st.connections if c.topic == conn.topic and c.msgtype == conn.msgtype}
            if not ids:
                continue
            found = None
            if isinstance(st, Sqlite3Reader) and st.dbconn is not None:
                marks = ",".join("?" for _ in ids)
                found = [int(r[0]) for r in st.dbconn.execute(f"SELECT timestamp FROM messages WHERE topic_id IN ({marks})", tuple(ids))]
            elif isinstance(st, McapReader) and st.chunks:
                found = _mcap_index_times(st, ids)
            if found is None:  # an MCAP without message indexes: read it through once
                indexed = False
                found = [ts for _, ts, _ in st.messages([c for c in st.connections if c.id in ids])]
            times.extend(found)
    return np.sort(np.asarray(times, dtype=np.int64)), indexed
