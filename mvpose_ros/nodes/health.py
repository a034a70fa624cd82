"""A node's /diagnostics: its `diagnostics.*` parameters (core.health.thresholds), live, and a
timer that publishes, every `diagnostics.period` s, the statuses the node's collect function
returns (core.health: inputs, node, residuals) and its links (core.health.links: the endpoints
its writers and readers have matched) as one DiagnosticArray; also at once when its links change
or a new reader of /diagnostics matches, so that a runner waiting for the links to match does not
wait for the period."""
from __future__ import annotations

import time
from dataclasses import replace
from typing import Any, Callable

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.qos import QoSProfile

from msg_adapters.diagnostics_msg import statuses_to_msg
from mvpose_ros import topics
from mvpose_ros.core.health.links import links_status
from mvpose_ros.core.health.status import Status
from mvpose_ros.core.health.thresholds import PREFIX, HealthThresholds, health_parameters
from mvpose_ros.nodes.runtime import declare, live_parameters

DIAGNOSTICS_QOS = QoSProfile(depth=10)  # reliable, volatile: as diagnostic_updater publishes
NOT_LINKS = (topics.DIAGNOSTICS, '/parameter_events')  # rclpy's and this class's own endpoints
LINKS_POLL_S = 0.2  # s between two looks at the links (a few C calls: negligible CPU)


class NodeHealth:
    """Declares the diagnostics parameters (with residual: the bp_solver's too) and publishes
    collect(now, thresholds) on a timer; now: time.monotonic() s."""

    def __init__(self, node: Node, collect: Callable[[float, HealthThresholds], list[Status]],
                 residual: bool = False) -> None:
        specs = health_parameters(residual)
        self.thresholds = HealthThresholds.from_params(declare(node, specs))
        self._node = node
        self._collect = collect
        self._publisher = node.create_publisher(DiagnosticArray, topics.DIAGNOSTICS, DIAGNOSTICS_QOS)
        self._shown: tuple[dict[str, str], int] | None = None  # links and diagnostics readers last published
        node.create_timer(self.thresholds.period, self._publish)
        node.create_timer(LINKS_POLL_S, self._poll_links)
        live_parameters(node, [s.name for s in specs if s.live], self._check, self._apply)

    def prefix(self) -> str:
        """The node's name in its statuses: fully qualified, so namespaced rigs stay apart."""
        return _prefix(self._node)

    def _check(self, changes: dict[str, Any]) -> str | None:
        t = self._updated(changes)
        if t.drop_warn > t.drop_error or t.latency_warn > t.latency_error:
            return (f'diagnostics: drop_warn ({t.drop_warn}) and latency_warn ({t.latency_warn}) must not exceed '
                    f'drop_error ({t.drop_error}) and latency_error ({t.latency_error})')
        return None

    def _apply(self, changes: dict[str, Any]) -> None:
        self.thresholds = self._updated(changes)

    def _updated(self, changes: dict[str, Any]) -> HealthThresholds:
        return replace(self.thresholds, **{k[len(PREFIX):]: v for k, v in changes.items()})

    def _poll_links(self) -> None:
        if (node_links(self._node).values, self._publisher.get_subscription_count()) != self._shown:
            self._publish()

    def _publish(self) -> None:
        links = node_links(self._node)
        self._shown = links.values, self._publisher.get_subscription_count()
        statuses = [*self._collect(time.monotonic(), self.thresholds), links]
        self._publisher.publish(statuses_to_msg(statuses, self._node.get_clock().now().to_msg()))


def node_links(node: Node) -> Status:
    """The node's links status (core.health.links): the readers each of its writers has matched
    and the writers each of its readers has matched, now."""
    return links_status(_prefix(node),
                        {p.topic_name: p.get_subscription_count() for p in node.publishers
                         if p.topic_name not in NOT_LINKS},
                        {s.topic_name: s.get_publisher_count() for s in node.subscriptions
                         if s.topic_name not in NOT_LINKS})


def _prefix(node: Node) -> str:
    return node.get_fully_qualified_name().lstrip('/')
