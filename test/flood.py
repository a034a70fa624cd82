"""A foreign publisher flooding one image topic with junk, as its own process:

    python test/flood.py TOPIC FRAME_ID SECONDS [RATE]

Per second about RATE messages (default 1000), cycling through: random bytes, a PNG and a JPEG
whose headers declare 30000 x 30000, a message of 8 MB (beyond any camera's byte bound here), the
right frame_id on half of a 16 x 16 JPEG, and a wrong frame_id. Best effort, as a camera driver. Prints
`sent <n> in <s> s (<bytes> bytes)` at the end."""
from __future__ import annotations

import struct
import sys
import time
import zlib

import cv2
import numpy as np
import rclpy
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import CompressedImage
from std_msgs.msg import Header

BIG = 8 << 20  # bytes: more than max_image_bytes of a 1032 x 776 camera (7.4 MB)


def _chunk(kind: bytes, body: bytes) -> bytes:
    return struct.pack('>I', len(body)) + kind + body + struct.pack('>I', zlib.crc32(kind + body))


def junk(frame_id: str) -> list[tuple[str, str, bytes]]:
    """(frame_id, format, data) of every kind of junk sent, in turn."""
    png_bomb = (b'\x89PNG\r\n\x1a\n' + _chunk(b'IHDR', struct.pack('>IIBBBBB', 30000, 30000, 8, 2, 0, 0, 0))
                + _chunk(b'IDAT', zlib.compress(bytes(4000))) + _chunk(b'IEND', b''))
    jpeg = bytearray(cv2.imencode('.jpg', np.full((16, 16, 3), 90, np.uint8))[1].tobytes())
    sof = jpeg.index(b'\xff\xc0')
    jpeg_bomb = bytes(jpeg[:sof + 5]) + struct.pack('>HH', 30000, 30000) + bytes(jpeg[sof + 9:])
    rng = np.random.default_rng(0)
    return [(frame_id, 'jpeg', rng.integers(0, 256, 300, np.uint8).tobytes()),
            (frame_id, 'png', png_bomb), (frame_id, 'jpeg', jpeg_bomb),
            (frame_id, 'jpeg', b'\xff\xd8' + bytes(BIG)),
            (frame_id, 'jpeg', bytes(jpeg[:len(jpeg) // 2])),
            ('intruder', 'jpeg', bytes(jpeg))]


def main(argv: list[str]) -> None:
    topic, frame_id, seconds = argv[0], argv[1], float(argv[2])
    rate = float(argv[3]) if len(argv) > 3 else 1000.0
    rclpy.init()
    node = rclpy.create_node('flood')
    pub = node.create_publisher(CompressedImage, topic, qos_profile_sensor_data)
    kinds = junk(frame_id)
    # the 8 MB message once per cycle of 50 (about 20 a second at 1000/s), the small ones in between
    cycle = [kinds[3]] + [kinds[i % len(kinds)] for i in range(49) if i % len(kinds) != 3]
    msgs = [CompressedImage(header=Header(frame_id=f), format=fmt, data=data) for f, fmt, data in cycle]
    start = time.monotonic()
    sent = size = 0
    while time.monotonic() - start < seconds:
        msg = msgs[sent % len(msgs)]
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(time.time_ns(), 1_000_000_000)
        pub.publish(msg)
        sent += 1
        size += len(msg.data)
        ahead = start + sent / rate - time.monotonic()
        if ahead > 0:
            time.sleep(ahead)
    print(f'sent {sent} in {time.monotonic() - start:.1f} s ({size} bytes)', flush=True)
    node.destroy_node()
    rclpy.try_shutdown()


if __name__ == '__main__':
    main(sys.argv[1:])
