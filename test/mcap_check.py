"""Reading a recording back with an independent reader: the `mcap` package and its ROS 2 decoder
(mcap-ros2-support), which decode each message from the definition embedded in the file."""
from __future__ import annotations

from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import Header

from msg_adapters.skeleton_msg import Skeletons, msg_to_skeletons


def mcap_file(folder: Path) -> Path:
    """The one .mcap file of a rosbag2 recording folder."""
    files = sorted(Path(folder).glob('*.mcap'))
    assert len(files) == 1, files
    return files[0]


def decoded_messages(folder: Path) -> list[tuple[str, str, bytes, object]]:
    """(topic, schema name, CDR bytes, decoded message) of every message, in log-time order."""
    with open(mcap_file(folder), 'rb') as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        return [(channel.topic, schema.name, bytes(message.data), decoded)
                for schema, channel, message, decoded in reader.iter_decoded_messages(log_time_order=True)]


def decoded_skeletons(cloud) -> tuple[int, Skeletons]:
    """(stamp ns, skeletons) of a PointCloud2 as the mcap decoder gives it, through our decoder."""
    header = Header(frame_id=cloud.header.frame_id)
    header.stamp.sec, header.stamp.nanosec = cloud.header.stamp.sec, cloud.header.stamp.nanosec
    msg = PointCloud2(header=header, height=cloud.height, width=cloud.width, is_bigendian=cloud.is_bigendian,
                      point_step=cloud.point_step, row_step=cloud.row_step, data=bytes(cloud.data),
                      is_dense=cloud.is_dense,
                      fields=[PointField(name=f.name, offset=f.offset, datatype=f.datatype, count=f.count)
                              for f in cloud.fields])
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec, msg_to_skeletons(msg)


def same_people(a: Skeletons, b: Skeletons) -> bool:
    """Same ids, and joints and confidence equal to float32 precision (the encoding's)."""
    return (np.array_equal(a.ids, b.ids) and np.allclose(a.joints, b.joints, atol=1e-6)
            and np.allclose(a.confidence, b.confidence, atol=1e-6))
