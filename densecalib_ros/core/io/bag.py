"""Offline rosbag2 reading and writing (sqlite3 and mcap) with the pure-Python `rosbags` package,
no ROS runtime.

Image topics may be sensor_msgs/msg/Image (any encoding in core.io.image_encoding.RAW_ENCODINGS:
rgb8, bgr8, mono8, mono16, Bayer, YUV 4:2:2, ...) or sensor_msgs/msg/CompressedImage (jpeg,
png). Frame sets are formed by approximate-time synchronisation of the header stamps (core.io.sync,
the same logic the node uses), in the bag's message order. Only the selected frame sets are
decoded (two passes), so memory stays bounded by what is returned.
"""
from __future__ import annotations

import logging
import os
import re
from itertools import islice
from pathlib import Path
from typing import Iterator, Optional

import numpy as np

from ..errors import DamagedBagError, InputError
from .bag_storage import StorageDamage, storage_files, storage_messages
from .image_encoding import decode_compressed, decode_raw
from .sync import ApproximateTimeSynchronizer, evenly_spaced

log = logging.getLogger(__name__)

IMAGE_TYPE = "sensor_msgs/msg/Image"
COMPRESSED_TYPE = "sensor_msgs/msg/CompressedImage"
IMAGE_TYPES = (IMAGE_TYPE, COMPRESSED_TYPE)
REPAIR_HINT = ("If the bag is whole where it was recorded, copy it again; for other tools, "
               "`mcap recover BAG.mcap -o whole.mcap` (mcap's CLI) or `sqlite3 BAG.db3 .recover "
               "| sqlite3 whole.db3` keeps its readable part, and `ros2 bag reindex` writes its "
               "metadata.yaml.")
# Trailing topic components that name the image stream rather than the camera.
_STREAM_SUFFIXES = {"image_raw", "image_rect", "image_rect_color", "image_color", "image_mono",
                    "image", "compressed", "raw"}


def camera_names_from_topics(topics: list[str]) -> list[str]:
    """Camera names from image topics: the namespace without the image-stream suffixes, joined by
    '_' (/stereo/left/image_raw -> stereo_left, /cam0/image_raw/compressed -> cam0).
    Falls back to the whole topic when that leaves nothing or names collide."""
    def name(topic: str, strip: bool) -> str:
        parts = [p for p in topic.strip("/").split("/") if p]
        while strip and len(parts) > 1 and parts[-1] in _STREAM_SUFFIXES:
            parts.pop()
        return re.sub(r"[^A-Za-z0-9_]", "_", "_".join(parts)) or "camera"

    names = [name(t, True) for t in topics]
    if len(set(names)) < len(names):
        names = [name(t, False) for t in topics]
    if len(set(names)) < len(names):
        raise InputError(f"Topics {topics} do not give distinct camera names: list each topic "
                         "once.")
    return names


def stamp_ns(header) -> int:
    """std_msgs/Header stamp in nanoseconds."""
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def decode_image_message(msgtype: str, msg) -> np.ndarray:
    """A deserialised Image/CompressedImage (rosbags or rclpy object) -> uint8 RGB (H, W, 3) or
    gray (H, W)."""
    if msgtype.endswith("CompressedImage"):
        return decode_compressed(msg.format, msg.data)
    return decode_raw(msg.encoding, int(msg.height), int(msg.width), int(msg.step), msg.data,
                      bool(msg.is_bigendian))


def _open(bag_path: str | os.PathLike):
    from rosbags.rosbag2 import Reader

    path = Path(bag_path)
    if not path.exists():
        raise InputError(f"Bag {path} does not exist: give a rosbag2 folder (metadata.yaml + "
                         ".db3/.mcap) or a .mcap/.db3 file.")
    try:
        reader = Reader(path)
        reader.open()
    except Exception as exc:  # rosbags raises several unrelated types for unreadable bags
        raise InputError(f"Cannot open bag {path}: {exc}") from exc
    return reader


def _typestore():
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


def _image_connections(reader, topics: list[str]):
    by_topic = {}
    for conn in reader.connections:
        by_topic.setdefault(conn.topic, []).append(conn)
    available = sorted(t for t, cs in by_topic.items() if cs[0].msgtype in IMAGE_TYPES)
    conns = []
    for topic in topics:
        if topic not in by_topic:
            raise InputError(f"Topic {topic} is not in bag {reader.path}; its image topics are: "
                             f"{', '.join(available) or 'none'}.")
        if by_topic[topic][0].msgtype not in IMAGE_TYPES:
            raise InputError(f"Topic {topic} in bag {reader.path} has type "
                             f"{by_topic[topic][0].msgtype}, not an image; image topics: "
                             f"{', '.join(available) or 'none'}.")
        conns.extend(by_topic[topic])
    return conns


def iter_image_messages(bag_path: str | os.PathLike, topics: list[str]
                        ) -> Iterator[tuple[int, int, int, str, object]]:
    """Yield (topic index, header stamp ns, bag log time ns, msgtype, deserialised message) for the
    image messages of `topics`, in bag order (used by the node's replay). mcap files, and a bag
    rosbags cannot open (cut short: no footer, a page count past its end), are read record by
    record (core.io.bag_storage); damage raises DamagedBagError after the messages before it."""
    if not topics:
        raise InputError("No image topics given: list the bag's image topics, one per camera.")
    store = _typestore()
    files = storage_files(bag_path)
    reader = None
    try:
        reader = _open(bag_path)
    except InputError as exc:
        if files is None:
            raise
        log.info("%s; reading its storage files record by record", exc)
    try:
        if reader is not None and not (files and any(p.suffix == ".mcap" for p in files)):
            conns = _image_connections(reader, topics)
            source = ((c.topic, c.msgtype, t, raw)
                      for c, t, raw in reader.messages(connections=conns))
        else:
            if reader is not None:
                _image_connections(reader, topics)
            source = (m for path in files for m in storage_messages(path))
        yield from _deserialised(source, bag_path, topics, store)
    finally:
        if reader is not None:
            reader.close()


def _deserialised(source, bag_path, topics: list[str], store):
    """iter_image_messages' messages of the (topic, msgtype, log time, raw) in `source`."""
    index = {t: i for i, t in enumerate(topics)}
    read = 0
    while True:
        try:
            topic, msgtype, log_time_ns, raw = next(source)
            if topic not in index:
                continue
            if msgtype not in IMAGE_TYPES:
                raise InputError(f"Topic {topic} in bag {bag_path} has type {msgtype}, not an "
                                 "image.")
            msg = store.deserialize_cdr(raw, msgtype)
            stamp = stamp_ns(msg.header)
        except (StopIteration, InputError) as exc:
            if isinstance(exc, InputError):
                raise
            return
        except Exception as exc:  # storage (apsw, mcap, ours) and CDR raise types of their own
            why = str(exc) if isinstance(exc, StorageDamage) else f"{type(exc).__name__}: {exc}"
            raise DamagedBagError(f"Bag {bag_path} is damaged ({why}); {read} image messages "
                                  "of the topics were read before it", read) from exc
        read += 1
        yield index[topic], stamp, int(log_time_ns), msgtype, msg


CAMERA_INFO_TYPE = "sensor_msgs/msg/CameraInfo"


def topic_namespace(image_topic: str) -> str:
    """The namespace of an image topic, where its camera's CameraInfo and set_camera_info live
    (image_transport's convention): /rig/cam0/image_raw[/compressed] -> /rig/cam0."""
    parts = image_topic.rstrip("/").split("/")
    if parts[-1] == "compressed":
        parts = parts[:-1]
    return "/".join(parts[:-1])


def camera_info_topic(image_topic: str) -> str:
    """The CameraInfo topic beside an image topic: /rig/cam0/image_raw -> /rig/cam0/camera_info."""
    return f"{topic_namespace(image_topic)}/camera_info"


def read_camera_infos(bag_path: str | os.PathLike, image_topics: list[str]) -> list[dict]:
    """Per image topic, the first message on its camera_info_topic as a camera_info YAML dict
    (core.method.known_intrinsics.intrinsics_from_camera_info reads it). InputError when a topic is
    missing from the bag or carries no message."""
    store = _typestore()
    reader = _open(bag_path)
    try:
        by_topic = {c.topic: c for c in reader.connections if c.msgtype == CAMERA_INFO_TYPE}
        wanted = [camera_info_topic(t) for t in image_topics]
        missing = [t for t in wanted if t not in by_topic]
        if missing:
            raise InputError(f"Bag {reader.path} has no CameraInfo topic {', '.join(missing)} "
                             f"(its CameraInfo topics: {', '.join(sorted(by_topic)) or 'none'}): "
                             "give the intrinsics as files with --intrinsics instead.")
        first: dict[str, dict] = {}
        for conn, _, raw in reader.messages(connections=[by_topic[t] for t in wanted]):
            if conn.topic not in first:
                msg = store.deserialize_cdr(raw, conn.msgtype)
                first[conn.topic] = {
                    "image_width": int(msg.width), "image_height": int(msg.height),
                    "camera_matrix": {"data": [float(v) for v in msg.k]},
                    "distortion_model": str(msg.distortion_model),
                    "distortion_coefficients": {"data": [float(v) for v in msg.d]}}
            if len(first) == len(wanted):
                break
    finally:
        reader.close()
    empty = [t for t in wanted if t not in first]
    if empty:
        raise InputError(f"No message on {', '.join(empty)} in bag {bag_path}.")
    return [first[t] for t in wanted]


def read_frame_sets(bag_path: str | os.PathLike, topics: list[str], slop_s: float = 0.02,
                    max_frame_sets: Optional[int] = None, stride: int = 1,
                    return_stamps: bool = False,
                    stamp_offsets_s: Optional[list[float]] = None) -> tuple:
    """Synchronised frame sets of a bag's image topics; stamp_offsets_s[c]: how far topic c's
    stamping clock runs ahead of the others' (s), taken off its stamps before synchronising.

    Returns (frame_sets, camera_names): frame_sets[t][c] is camera c's image of set t, uint8 RGB
    (H, W, 3) or gray (H, W); camera c is topics[c], named by camera_names_from_topics. Sets are in
    stamp order; every `stride`-th set is kept, then at most `max_frame_sets` evenly spaced ones.
    With return_stamps, a third value: stamps_ns[t][c], the header stamp of each image used.
    """
    if stride < 1:
        raise InputError(f"stride must be >= 1, got {stride}.")
    if max_frame_sets is not None and max_frame_sets < 1:
        raise InputError(f"max_frame_sets must be >= 1, got {max_frame_sets}.")
    if len(set(topics)) != len(topics):
        raise InputError(f"Topics must be distinct, got {topics}.")
    names = camera_names_from_topics(topics)
    # Pass 1: stamps only; the payload is the message's key (topic index, position in topic).
    sync = ApproximateTimeSynchronizer(len(topics), slop_s, queue_size=1000)
    counts = [0] * len(topics)
    sets = []
    offsets_ns = [int(round(o * 1e9)) for o in (stamp_offsets_s or [0.0] * len(topics))]
    readable = None  # image messages before a damaged part of the bag (None: all read)
    try:
        for topic_index, stamp, _, _, _ in iter_image_messages(bag_path, topics):
            sets.extend(sync.add(topic_index, stamp - offsets_ns[topic_index],
                                 counts[topic_index]))
            counts[topic_index] += 1
    except DamagedBagError as damage:
        if not sets:
            raise InputError(f"{damage}; no whole frame set before it. Record the rig again, "
                             "or copy the bag from where it was recorded.") from damage
        readable = damage.messages_read
        log.warning("%s. Calibrating from the %d frame sets before it. %s", damage, len(sets),
                    REPAIR_HINT)
    if not sets:
        raise InputError(f"No synchronised frame sets in {bag_path} for topics {topics} with "
                         f"slop {slop_s} s (messages per topic: {counts}); check the topics' "
                         "header stamps, raise the slop, or give the cameras' clock offsets "
                         "(--time-offset NAME=S, or auto).")
    sets.sort(key=lambda s: s.stamp_ns)
    sets = sets[::stride]
    sets = evenly_spaced(sets, max_frame_sets)
    # Pass 2: decode only the selected messages.
    wanted = {(c, pos): t for t, s in enumerate(sets) for c, pos in enumerate(s.items)}
    frame_sets: list[list[Optional[np.ndarray]]] = [[None] * len(topics) for _ in sets]
    seen = [0] * len(topics)
    for topic_index, _, _, msgtype, msg in islice(iter_image_messages(bag_path, topics),
                                                  readable):
        t = wanted.get((topic_index, seen[topic_index]))
        seen[topic_index] += 1
        if t is not None:
            try:
                frame_sets[t][topic_index] = decode_image_message(msgtype, msg)
            except InputError as exc:  # which camera, and where in the bag
                stamp = int(sets[t].stamps_ns[topic_index]) + offsets_ns[topic_index]
                raise InputError(f"Camera {names[topic_index]} ({topics[topic_index]}), frame "
                                 f"set {t} (header stamp {stamp} ns) of {bag_path}: {exc} Check "
                                 "that camera's driver or recording.") from None
    if return_stamps:  # the header stamps as recorded
        return frame_sets, names, [[int(t) + o for t, o in zip(s.stamps_ns, offsets_ns)]
                                   for s in sets]
    return frame_sets, names


def write_image_bag(bag_path: str | os.PathLike, frame_sets: list[list[np.ndarray]],
                    topics: list[str], stamps_ns: list[int], *, storage: str = "sqlite3",
                    encoding: str = "rgb8", frame_ids: Optional[list[str]] = None,
                    camera_infos: Optional[list[dict]] = None) -> None:
    """Write frame_sets[t][c] (uint8 RGB (H, W, 3) or gray (H, W)) as a rosbag2 bag: topic c gets
    one message per set, header stamp stamps_ns[t][c] (or stamps_ns[t] for all cameras), log time =
    header stamp. encoding: rgb8, bgr8, mono8, mono16, bayer_<pattern>8 (sensor_msgs/Image) or
    jpeg, png (CompressedImage). storage: sqlite3 or mcap. camera_infos: per camera a
    core.io.camera_info.ros_camera_info dict, written once per frame set on camera_info_topic. Used
    to make test bags and to export rigs."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    from .image_encoding import COMPRESSED_FORMATS, encode_compressed, encode_raw

    plugins = {"sqlite3": StoragePlugin.SQLITE3, "mcap": StoragePlugin.MCAP}
    if storage not in plugins:
        raise InputError(f"Unknown bag storage {storage!r}: use sqlite3 or mcap.")
    if len(stamps_ns) != len(frame_sets):
        raise InputError(f"{len(frame_sets)} frame sets but {len(stamps_ns)} stamps.")
    store = _typestore()
    t = store.types
    compressed = encoding in COMPRESSED_FORMATS
    msgtype = COMPRESSED_TYPE if compressed else IMAGE_TYPE
    frame_ids = frame_ids or [f"{n}_optical_frame" for n in camera_names_from_topics(topics)]
    messages = []
    for images, stamps in zip(frame_sets, stamps_ns):
        stamps = list(stamps) if np.ndim(stamps) else [stamps] * len(topics)
        for c, image in enumerate(images):
            sec, nsec = divmod(int(stamps[c]), 1_000_000_000)
            header = t["std_msgs/msg/Header"](
                stamp=t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec),
                frame_id=frame_ids[c])
            if compressed:
                data = np.frombuffer(encode_compressed(image, encoding), np.uint8)
                msg = t[COMPRESSED_TYPE](header=header, format=encoding, data=data)
            else:
                h, w, step, raw = encode_raw(image, encoding)
                msg = t[IMAGE_TYPE](header=header, height=h, width=w, encoding=encoding,
                                    is_bigendian=0, step=step, data=np.frombuffer(raw, np.uint8))
            messages.append((int(stamps[c]), c, msg, msgtype))
            if camera_infos:
                info = camera_infos[c]
                messages.append((int(stamps[c]), len(topics) + c, t[CAMERA_INFO_TYPE](
                    header=header, height=int(info["image_height"]),
                    width=int(info["image_width"]), distortion_model=info["distortion_model"],
                    d=np.array(info["distortion_coefficients"]["data"], np.float64),
                    k=np.array(info["camera_matrix"]["data"], np.float64),
                    r=np.array(info["rectification_matrix"]["data"], np.float64),
                    p=np.array(info["projection_matrix"]["data"], np.float64),
                    binning_x=0, binning_y=0,
                    roi=t["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0,
                                                              width=0, do_rectify=False)),
                    CAMERA_INFO_TYPE))
    messages.sort(key=lambda m: (m[0], m[1]))
    with Writer(Path(bag_path), version=9, storage_plugin=plugins[storage]) as writer:
        conns = [writer.add_connection(topic, msgtype, typestore=store) for topic in topics]
        if camera_infos:
            conns += [writer.add_connection(camera_info_topic(topic), CAMERA_INFO_TYPE,
                                            typestore=store) for topic in topics]
        for log_ns, c, msg, kind in messages:
            writer.write(conns[c], log_ns, store.serialize_cdr(msg, kind))


def clock_topics(topics: list[str], image_topic: str) -> list[str]:
    """The topics of `topics` that an image topic's camera stamps by its clock: the image topic,
    its other transports (image_raw/compressed, ...) and its CameraInfo (image_transport's
    naming)."""
    base = image_topic.rstrip("/")
    if base.endswith("/compressed"):
        base = base[:-len("/compressed")]
    info = camera_info_topic(image_topic)
    mine = [t for t in topics if t == base or t.startswith(base + "/") or t == info]
    return sorted(mine, key=lambda t: (t == info, t))  # the images first


def recorded_topics(bag_path: str | os.PathLike) -> list[str]:
    """Every topic recorded in a bag."""
    reader = _open(bag_path)
    try:
        return sorted({c.topic for c in reader.connections})
    finally:
        reader.close()


def _bag_storage(path: Path) -> str:
    return "mcap" if path.suffix == ".mcap" or any(path.glob("*.mcap")) else "sqlite3"


def restamp_bag(src: str | os.PathLike, dst: str | os.PathLike, offsets_ns: dict[str, int],
                note: str = "") -> dict[str, int]:
    """Copy bag `src` into the new rosbag2 folder `dst` (same storage and compression) with the
    header stamps of each topic in offsets_ns moved back by its offset [ns] (stamp - offset: the
    camera's clock ran that far ahead), so that downstream tools synchronising on stamps see the
    cameras on one clock. Every other topic, and every message's log time (the recorder's
    clock), is copied as recorded. `note` goes into the bag's metadata (custom_data). Returns
    the messages restamped per topic. dst must not exist (a bag is never overwritten); a failed
    copy leaves no dst behind."""
    import shutil

    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer

    dst = Path(dst)
    if dst.exists():
        raise InputError(f"{dst} exists already: give a new folder for the restamped bag (a bag "
                         "is never overwritten).")
    store = _typestore()
    reader = _open(src)
    counts = {topic: 0 for topic in offsets_ns}
    try:
        recorded = {c.topic for c in reader.connections}
        missing = sorted(set(offsets_ns) - recorded)
        if missing:
            raise InputError(f"Topic(s) {', '.join(missing)} are not in bag {src}.")
        for conn in reader.connections:
            if conn.topic in offsets_ns and conn.msgtype not in store.types:
                raise InputError(f"Cannot restamp {conn.topic}: its type {conn.msgtype} is not a "
                                 "standard ROS 2 message type.")
            first_field = store.get_msgdef(conn.msgtype).fields[0] \
                if conn.topic in offsets_ns else None
            if first_field and (first_field[0], first_field[1][-1]) != (
                    "header", "std_msgs/msg/Header"):
                raise InputError(f"Cannot restamp {conn.topic}: {conn.msgtype} has no header "
                                 "as its first field.")
        writer = Writer(dst, version=9, storage_plugin=StoragePlugin[
            _bag_storage(Path(src)).upper()])
        mode = str(reader.compression_mode or "").lower()
        if mode in ("file", "message"):
            writer.set_compression(CompressionMode[mode.upper()], CompressionFormat.ZSTD)
        writer.open()
        try:
            out_conns = {}
            for conn in reader.connections:
                if not conn.msgdef.data and conn.msgtype not in store.types:
                    raise InputError(f"Cannot copy {conn.topic}: the bag does not define its "
                                     f"type {conn.msgtype} (an old bag format).")
                definition = (dict(msgdef=conn.msgdef.data, rihs01=conn.digest)
                              if conn.msgdef.data else dict(typestore=store))
                out_conns[conn.id] = writer.add_connection(
                    conn.topic, conn.msgtype, serialization_format=conn.ext.serialization_format,
                    offered_qos_profiles=conn.ext.offered_qos_profiles, **definition)
            if note:
                writer.set_custom_data("densecalib", note)
            for conn, log_ns, raw in reader.messages():
                offset = offsets_ns.get(conn.topic)
                if offset is not None:
                    msg = store.deserialize_cdr(raw, conn.msgtype)
                    stamp = stamp_ns(msg.header) - int(offset)
                    if stamp < 0:
                        raise InputError(f"{conn.topic}: a stamp of {stamp_ns(msg.header)} ns "
                                         f"less the offset {offset} ns is negative: is the "
                                         "offset's sign right (positive = the camera's clock "
                                         "runs ahead)?")
                    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp,
                                                                            1_000_000_000)
                    raw = store.serialize_cdr(msg, conn.msgtype)
                    counts[conn.topic] += 1
                writer.write(out_conns[conn.id], log_ns, raw)
        finally:
            writer.close()
    except BaseException:
        shutil.rmtree(dst, ignore_errors=True)
        raise
    finally:
        reader.close()
    return counts
