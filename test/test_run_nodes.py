"""run_nodes with nodes of both executor kinds in one process (a composed process with bp_solver):
each kind spins, the single-threaded one in a thread of its own, and an error in either ends the
process with it."""
from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

from ros_harness import ros_env

# Node `talker` (events executor) publishes; node `listener` (single-threaded executor, with the
# message info the events executor cannot give) finishes the process with code 7 once it heard
# three messages, or, with RAISE, raises in its callback.
SCRIPT = textwrap.dedent('''
    import os, sys
    from rclpy.node import Node
    from rclpy.task import Future
    from std_msgs.msg import String
    from mvpose_ros.nodes.runtime import run_nodes

    class Talker(Node):
        def __init__(self):
            super().__init__('talker')
            pub = self.create_publisher(String, 'chat', 10)
            self.create_timer(0.05, lambda: pub.publish(String(data='hi')))

    class Listener(Node):
        def __init__(self):
            super().__init__('listener')
            self.finished = Future()
            self.heard = 0
            self.create_subscription(String, 'chat', self.on_chat, 10)

        def on_chat(self, msg, info):
            assert info['received_timestamp'] > 0
            if os.environ.get('RAISE'):
                raise RuntimeError('listener failed')
            self.heard += 1
            if self.heard == 3:
                self.finished.set_result(7)

    run_nodes([Talker, Listener], ['prog'], [True, False])
''')


@pytest.mark.parametrize('fail, code, said', [('', 7, ''), ('1', 1, 'listener failed')])
def test_both_executor_kinds_spin_in_one_process(domain, fail, code, said):
    env = ros_env(domain, RAISE=fail)
    done = subprocess.run([sys.executable, '-c', SCRIPT], env=env, capture_output=True, text=True, timeout=60)
    assert done.returncode == code, done.stderr
    assert said in done.stderr
