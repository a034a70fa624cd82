"""A Foxglove WebSocket protocol client written from the protocol's specification with the plain
`websockets` package (no code of foxglove-sdk's): it reads the advertised channels, subscribes,
and decodes what comes, protobuf with the advertised FileDescriptorSet, ROS 2 CDR with the
advertised ros2msg definition (mcap-ros2-support's decoder)."""
from __future__ import annotations

import base64
import json
import struct
import time
from dataclasses import dataclass, field

from mcap.records import Schema
from mcap_ros2.decoder import DecoderFactory
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from foxglove_decode import decode

SUBPROTOCOLS = ['foxglove.sdk.v1', 'foxglove.websocket.v1']
MESSAGE_DATA = 0x01  # binary opcode of a message on a subscription


@dataclass
class Received:
    """A message on a subscription: the channel's topic, its log time (ns) and the decoded message."""

    topic: str
    log_time: int
    message: object


@dataclass
class Client:
    """One connection: the channels advertised (id -> the advertise entry) and this client's
    subscriptions (subscription id -> channel id)."""

    url: str
    channels: dict[int, dict] = field(default_factory=dict)
    subscriptions: dict[int, int] = field(default_factory=dict)
    server_info: dict = field(default_factory=dict)

    def __enter__(self) -> 'Client':
        self._connection = connect(self.url, subprotocols=SUBPROTOCOLS, open_timeout=10, max_size=None)
        self.ws = self._connection.__enter__()
        return self

    def __exit__(self, *exc) -> None:
        self._connection.__exit__(*exc)

    def _control(self, text: str) -> None:
        msg = json.loads(text)
        if msg.get('op') == 'serverInfo':
            self.server_info = msg
        elif msg.get('op') == 'advertise':
            self.channels.update({c['id']: c for c in msg['channels']})
        elif msg.get('op') == 'unadvertise':
            for channel in msg['channelIds']:
                self.channels.pop(channel, None)

    def wait_channels(self, topics: set[str], timeout: float = 10.0) -> dict[str, int]:
        """Topic -> channel id of `topics`, once all are advertised; TimeoutError otherwise."""
        deadline = time.monotonic() + timeout
        while not topics <= {c['topic'] for c in self.channels.values()}:
            if time.monotonic() > deadline:
                raise TimeoutError(f'not advertised: {topics - {c["topic"] for c in self.channels.values()}}')
            try:
                frame = self.ws.recv(timeout=0.2)
            except TimeoutError:
                continue
            if isinstance(frame, str):
                self._control(frame)
        return {c['topic']: i for i, c in self.channels.items() if c['topic'] in topics}

    def subscribe(self, channel_ids) -> None:
        """Subscribe to each of `channel_ids` (a subscription id of its own each)."""
        subs = []
        for channel in channel_ids:
            sub = len(self.subscriptions) + 1
            self.subscriptions[sub] = channel
            subs.append({'id': sub, 'channelId': channel})
        self.ws.send(json.dumps({'op': 'subscribe', 'subscriptions': subs}))

    def unsubscribe_all(self) -> None:
        self.ws.send(json.dumps({'op': 'unsubscribe', 'subscriptionIds': list(self.subscriptions)}))
        self.subscriptions.clear()

    def receive(self, until, timeout: float = 20.0, tick=None) -> list[Received]:
        """Decoded messages on this client's subscriptions until until(messages so far) or
        `timeout` s; the connection closing ends it too. tick(): called before every wait (a
        test's publisher sending its next message)."""
        got: list[Received] = []
        deadline = time.monotonic() + timeout
        while not until(got) and time.monotonic() < deadline:
            if tick is not None:
                tick()
            try:
                frame = self.ws.recv(timeout=0.05)
            except TimeoutError:
                continue
            except ConnectionClosed:
                break
            if isinstance(frame, str):
                self._control(frame)
            elif frame[0] == MESSAGE_DATA:
                sub, log_time = struct.unpack_from('<IQ', frame, 1)
                channel = self.channels[self.subscriptions[sub]]
                got.append(Received(channel['topic'], log_time, decode_payload(channel, frame[13:])))
        return got


_ros2 = DecoderFactory()


def decode_payload(channel: dict, data: bytes) -> object:
    """A message of an advertised channel, decoded by its schema alone."""
    if channel['encoding'] == 'protobuf':
        return decode(channel['schemaName'], base64.b64decode(channel['schema']), data)
    if channel['encoding'] == 'cdr' and channel.get('schemaEncoding') == 'ros2msg':
        schema = Schema(id=channel['id'], name=channel['schemaName'], encoding='ros2msg',
                        data=channel['schema'].encode())
        return _ros2.decoder_for('cdr', schema)(bytes(data))
    raise ValueError(f'{channel["topic"]}: no decoder for {channel["encoding"]}')
