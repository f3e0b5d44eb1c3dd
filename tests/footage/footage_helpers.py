"""Small synthetic recordings for the footage tests: a 160x120 noise texture moving 2 px per frame,
written by PyAV, and tiny ROS 1 / ROS 2 bags written with rosbags' own writers."""

from __future__ import annotations

from fractions import Fraction

import cv2
import numpy as np
import yaml

W, H = 160, 120
CAMERA = {"model": "pinhole", "width": W, "height": H,
          "params": dict(fx=150.0, fy=150.0, cx=79.5, cy=59.5, k1=0.0, k2=0.0, p1=0.0, p2=0.0, k3=0.0)}


def texture_frames(n: int, step_px: int = 2, seed: int = 0) -> list[np.ndarray]:
    """n uint8 (H, W) views of one blurred noise texture, each `step_px` further to the right."""
    rng = np.random.default_rng(seed)
    tex = cv2.GaussianBlur(rng.integers(0, 256, (H, W + step_px * n), dtype=np.uint8), (0, 0), 1.0)
    tex = cv2.normalize(tex, None, 0, 255, cv2.NORM_MINMAX)
    return [np.ascontiguousarray(tex[:, step_px * i: step_px * i + W]) for i in range(n)]


def write_video(path, images, codec="libx264", rate=10, pts=None, options=None, container_options=None):
    """Encode grey uint8 images; `pts` (in 1/rate units) leaves gaps where frames were dropped."""
    import av

    with av.open(str(path), "w", options=container_options or {}) as out:
        stream = out.add_stream(codec, rate=rate, options=options or {})
        stream.width, stream.height = images[0].shape[1], images[0].shape[0]
        stream.pix_fmt = "yuvj420p" if codec == "mjpeg" else "yuv420p"
        stream.codec_context.time_base = Fraction(1, rate)
        for k, img in enumerate(images):
            frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(np.dstack([img] * 3)), format="rgb24")
            frame.pts = k if pts is None else pts[k]
            frame.time_base = Fraction(1, rate)
            for packet in stream.encode(frame):
                out.mux(packet)
        for packet in stream.encode():
            out.mux(packet)
    return path


def packets(path):
    """(pos, size, pts, keyframe) of every video packet in file order."""
    import av

    with av.open(str(path)) as c:
        return [(p.pos, p.size, p.pts, p.is_keyframe) for p in c.demux(video=0) if p.size]


def write_dataset(root, images: str, fps: float = 10.0, **keys):
    root.mkdir(parents=True, exist_ok=True)
    doc = {"format": "pipemap-dataset/2", "name": "footage", "images": images, "fps": fps, "camera": CAMERA,
           "pipe": {"radius_m": 0.1}}
    doc.update(keys)
    (root / "dataset.yaml").write_text(yaml.safe_dump(doc))
    return root


def image_message(typestore, img: np.ndarray, stamp_ns: int, compressed: bool, encoding: str = "mono8"):
    """A sensor_msgs Image (`encoding` mono8, rgb8 or bgr8) or CompressedImage (PNG) of `img`
    (img None: a CompressedImage whose data is garbage)."""
    types = typestore.types
    Header, Time = types["std_msgs/msg/Header"], types["builtin_interfaces/msg/Time"]
    stamp = Time(sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000)
    fields = {"stamp": stamp, "frame_id": "camera"}
    if "seq" in Header.__dataclass_fields__:
        fields["seq"] = 0
    header = Header(**fields)
    if compressed:
        if img is None:  # a message damaged on the way: not an image at all
            data = np.frombuffer(b"not an image", np.uint8)
        else:
            ok, data = cv2.imencode(".png", img)
            assert ok
        return "sensor_msgs/msg/CompressedImage", types["sensor_msgs/msg/CompressedImage"](
            header=header, format="png", data=data.reshape(-1))
    if encoding != "mono8":
        img = np.dstack([img] * 3)
    channels = 1 if img.ndim == 2 else 3
    return "sensor_msgs/msg/Image", types["sensor_msgs/msg/Image"](
        header=header, height=img.shape[0], width=img.shape[1], encoding=encoding, is_bigendian=0,
        step=img.shape[1] * channels, data=np.ascontiguousarray(img).reshape(-1))


def write_bag(path, images, stamps_ns, log_order=None, ros2: bool = False, compressed: bool = False,
              topic: str = "/camera/image_raw", encoding: str = "mono8", storage: str = "sqlite3", extra_topic=None):
    """Write `images` with header stamps `stamps_ns`, logged in `log_order` (default: stamp order);
    each message is logged 5 ms after its stamp, in that order."""
    from rosbags.typesys import Stores, get_typestore

    order = list(range(len(images))) if log_order is None else list(log_order)
    path.parent.mkdir(parents=True, exist_ok=True)
    if ros2:
        from rosbags.rosbag2 import StoragePlugin, Writer

        typestore = get_typestore(Stores.ROS2_HUMBLE)
        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        writer, serialize = Writer(path, version=9, storage_plugin=plugin), typestore.serialize_cdr
    else:
        from rosbags.rosbag1 import Writer

        typestore = get_typestore(Stores.ROS1_NOETIC)
        writer, serialize = Writer(path), typestore.serialize_ros1
    msgtype = "sensor_msgs/msg/CompressedImage" if compressed else "sensor_msgs/msg/Image"
    with writer:
        conn = writer.add_connection(topic, msgtype, typestore=typestore)
        other = writer.add_connection(extra_topic, "std_msgs/msg/String", typestore=typestore) if extra_topic else None
        t_log = int(stamps_ns[0])
        for k in order:
            t_log = max(t_log, int(stamps_ns[k])) + 5_000_000
            _, msg = image_message(typestore, images[k], int(stamps_ns[k]), compressed, encoding)
            writer.write(conn, t_log, serialize(msg, msgtype))
            if other is not None:
                text = typestore.types["std_msgs/msg/String"](data="hello")
                writer.write(other, t_log + 1, serialize(text, "std_msgs/msg/String"))
    return path
