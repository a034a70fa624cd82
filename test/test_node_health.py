"""A node's /diagnostics and its parameters through rclpy's parameter service, as `ros2 param
set` uses it: a live change applied (and seen in the next diagnostics), a read-only one refused
with its reason, an out-of-range one refused."""
from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from sensor_msgs.msg import PointCloud2

from msg_adapters.diagnostics_msg import msg_to_statuses
from mvpose_ros.core.health.status import Level
from mvpose_ros.nodes.health import DIAGNOSTICS_QOS
from mvpose_ros.nodes.runtime import DATA_QOS
from ros_harness import matched, probe, spin_until, start_node, stop


def _set(node, executor, client, name: str, value: ParameterValue):
    """The result of setting one parameter. A request sent before the node's service has matched
    this client's endpoints is lost without a reply (discovery is per endpoint), so it is sent
    again until one comes: setting a parameter twice is setting it once."""
    request = SetParameters.Request(parameters=[Parameter(name=name, value=value)])
    for _ in range(6):
        future = client.call_async(request)
        if spin_until(executor, future.done, 5.0):
            return future.result().results[0]
        client.remove_pending_request(future)
    raise AssertionError(f'no reply to setting {name}')


def test_bp_solver_publishes_diagnostics_and_takes_live_parameters(domain, tmp_path):
    log = tmp_path / 'bp.log'
    with probe(domain, 'health_probe') as (node, executor):
        arrays: list[DiagnosticArray] = []
        node.create_subscription(DiagnosticArray, '/diagnostics', arrays.append, DIAGNOSTICS_QOS)
        client = node.create_client(SetParameters, '/bp_solver/set_parameters')
        proc = start_node('bp_solver', domain, log, '-p', 'window:=6', '-p', 'lag:=3',
                          '-p', 'diagnostics.stale_error:=0.5', '-p', 'diagnostics.period:=0.2')
        try:
            def bundles_input(level: Level) -> bool:
                return any(s.name == 'bp_solver: input bundles' and s.level == level
                           for a in arrays for s in msg_to_statuses(a))

            # no input for more than stale_error: WARN (every input of the node is silent)
            assert spin_until(executor, lambda: bundles_input(Level.WARN), 20.0), log.read_text()
            names = {s.name for s in msg_to_statuses(arrays[-1])}
            assert {'bp_solver: node', *(f'bp_solver: camera cam{c} reprojection' for c in range(5))} <= names
            assert client.wait_for_service(10.0)

            refused = _set(node, executor, client, 'window',
                           ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=8))
            assert not refused.successful and 'read-only' in refused.reason
            out_of_range = _set(node, executor, client, 'diagnostics.drop_warn',
                                ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=2.0))
            assert not out_of_range.successful and 'out of range' in out_of_range.reason
            applied = _set(node, executor, client, 'diagnostics.stale_error',
                           ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=1000.0))
            assert applied.successful, applied.reason
            arrays.clear()
            assert spin_until(executor, lambda: bundles_input(Level.OK), 10.0), log.read_text()  # applied live
            for name, value in (('collision_width', 0.2), ('max_gap', 0.5)):  # the stage's, via StageConfig
                stage = _set(node, executor, client, name,
                             ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=value))
                assert stage.successful, stage.reason
        finally:
            stop(proc)
    text = log.read_text()
    assert 'parameters changed: diagnostics.stale_error = 1000.0' in text
    assert 'parameters changed: collision_width = 0.2' in text and 'parameters changed: max_gap = 0.5' in text


def test_association_takes_its_stage_and_sync_parameters_live_and_refuses_a_bad_one(domain, tmp_path):
    log = tmp_path / 'association.log'
    with probe(domain, 'association_probe') as (node, executor):
        arrays: list[DiagnosticArray] = []
        node.create_subscription(DiagnosticArray, '/diagnostics', arrays.append, DIAGNOSTICS_QOS)
        client = node.create_client(SetParameters, '/association/set_parameters')
        proc = start_node('association', domain, log, '-p', 'diagnostics.period:=0.2')
        try:
            # its service exists from the node's construction; it answers once the node spins,
            # which its first diagnostics show (under load, seconds later)
            assert spin_until(executor, lambda: any(s.name.startswith('association: ')
                                                    for a in arrays for s in msg_to_statuses(a)), 60.0), \
                log.read_text()
            assert client.wait_for_service(20.0), log.read_text()
            double = ParameterType.PARAMETER_DOUBLE
            for name, value in (('track_iou', 0.4), ('max_skew', 0.03)):
                applied = _set(node, executor, client, name, ParameterValue(type=double, double_value=value))
                assert applied.successful, applied.reason
            refused = _set(node, executor, client, 'single_view_people',
                           ParameterValue(type=ParameterType.PARAMETER_STRING, string_value='yes'))
            assert not refused.successful
        finally:
            stop(proc)
    text = log.read_text()
    assert 'parameters changed: track_iou = 0.4' in text and 'parameters changed: max_skew = 0.03' in text


def test_a_node_reports_on_diagnostics_the_endpoints_its_writers_and_readers_have_matched(domain, tmp_path):
    """bp_solver's links: none matched while nobody reads or writes its topics, then the probe's
    skeletons reader and bundles writer, as each end sees the other."""
    log = tmp_path / 'bp.log'
    with probe(domain, 'links_probe') as (node, executor):
        arrays: list[DiagnosticArray] = []
        node.create_subscription(DiagnosticArray, '/diagnostics', arrays.append, DIAGNOSTICS_QOS)
        proc = start_node('bp_solver', domain, log, '-p', 'diagnostics.period:=0.2')
        try:
            def links() -> dict[str, str]:
                found = [s for a in arrays[-1:] for s in msg_to_statuses(a) if s.name == 'bp_solver: links']
                return found[0].values if found else {}

            assert spin_until(executor, lambda: bool(links()), 20.0), log.read_text()
            counts = (links()['matched readers of /skeletons'], links()['matched writers of /people/bundles'])
            assert counts == ('0', '0')
            reader = node.create_subscription(PointCloud2, '/skeletons', lambda _: None, DATA_QOS)
            writer = node.create_publisher(PointCloud2, '/people/bundles', DATA_QOS)
            assert spin_until(executor, lambda: matched([reader, writer]), 20.0)
            assert spin_until(executor, lambda: (links().get('matched readers of /skeletons'),
                                                 links().get('matched writers of /people/bundles')) == ('1', '1'),
                              20.0), links()
            assert not any('/diagnostics' in key or '/parameter_events' in key for key in links())
        finally:
            stop(proc)


def test_a_change_of_a_nodes_links_is_published_at_once_not_after_the_period(domain, tmp_path):
    """With diagnostics.period 60 s, the probe's skeletons reader matching shows on /diagnostics
    long before the next periodic message (the wait below is a bound for failures only): a runner
    waiting for the links does not wait for the period. The probe's diagnostics reader has matched
    bp_solver's writer first, so nothing published after that can be lost on the way."""
    log = tmp_path / 'bp.log'
    with probe(domain, 'links_probe') as (node, executor):
        arrays: list[DiagnosticArray] = []
        diagnostics = node.create_subscription(DiagnosticArray, '/diagnostics', arrays.append, DIAGNOSTICS_QOS)
        proc = start_node('bp_solver', domain, log, '-p', 'diagnostics.period:=60.0')
        try:
            assert spin_until(executor, lambda: matched([diagnostics]), 20.0), log.read_text()
            reader = node.create_subscription(PointCloud2, '/skeletons', lambda _: None, DATA_QOS)
            assert spin_until(executor, lambda: matched([reader]), 20.0)
            assert spin_until(executor, lambda: any(
                s.name == 'bp_solver: links' and s.values.get('matched readers of /skeletons') == '1'
                for a in arrays for s in msg_to_statuses(a)), 20.0), log.read_text()
        finally:
            stop(proc)
