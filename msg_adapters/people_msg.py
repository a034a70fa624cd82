"""Encodings B and C: 2D people of one camera (keypoints and quantised heatmaps, one record per
person) and per-3D-person bundles of views (one record per (person, camera)).

The association node matches keypoints only: it reads B as WirePersons (msg_to_wire_people), whose
heatmaps stay the quantised cells that came, and sends each matched view's record on into C as it
came (wire_bundles_to_msg), instead of decoding every map to float and encoding it again."""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Header

from msg_adapters.records import UINT16_MAX, UINT32_MAX, from_cloud, to_cloud
from mvpose_ros.core.geometry.body import NUM_INFERENCE_JOINTS
from mvpose_ros.core.heatmap import HeatmapStack, PersonHeatmap
from mvpose_ros.core.types import Person2D

J = NUM_INFERENCE_JOINTS  # 16 keypoints and maps per person
BUNDLE_KEYS = [('person', '<u4'), ('camera', '<u2')]
# Bounds of an input message (max_people_bytes): people one camera can show (MoveNet MultiPose
# finds at most 6, Shelf has 4, the crowd benchmark 20), and the finest heatmap cells the
# detectors write (their default stride; the Shelf graph uses 8 px).
MAX_PEOPLE = 64
MIN_STRIDE = 4.0  # pixels


def people_dtype(n_cells: int, keys: Sequence[tuple[str, str]] = ()) -> np.dtype:
    """Record dtype of encoding B (after keys, for C): per joint its map's grid (h, w), and room
    for n_cells heatmap cells, the most any record's 16 maps hold."""
    return np.dtype([*keys, ('keypoints', '<f4', (3 * J,)), ('origin', '<f4', (2 * J,)),
                     ('stride', '<f4'), ('grid', '<u2', (2 * J,)), ('heatmap', 'u1', (n_cells,))])


def max_people_bytes(width: int, height: int, keys: Sequence[tuple[str, str]] = ()) -> int:
    """The most data bytes an encoding B message of a width x height camera can honestly carry:
    MAX_PEOPLE records whose maps cover the whole image in MIN_STRIDE px cells (1032 x 776:
    52 MB); with BUNDLE_KEYS, that camera's share of an encoding C message. A larger message is
    refused before it is decoded (decoding quadruples it)."""
    cells = (int(np.ceil(height / MIN_STRIDE)) + 1) * (int(np.ceil(width / MIN_STRIDE)) + 1)
    return MAX_PEOPLE * people_dtype(J * cells, keys).itemsize


def max_bundles_bytes(sizes: Sequence[tuple[int, int]]) -> int:
    """The most data bytes an encoding C message of a rig whose cameras are (width, height) can
    honestly carry: every camera's views of MAX_PEOPLE people."""
    return sum(max_people_bytes(w, h, BUNDLE_KEYS) for w, h in sizes)


def quantise(maps: np.ndarray) -> np.ndarray:
    """Heatmap values in [0, 1] (clipped) -> uint8 steps of 1/255, the wire format."""
    q = np.multiply(maps, 255.0)
    np.clip(q, 0, 255, out=q)
    return np.rint(q, out=q).astype(np.uint8)


def _check_people(keypoints: np.ndarray, origin: np.ndarray, stride: np.ndarray,
                  label: str) -> None:
    """Raise ValueError for the first invalid person: keypoints (P, 16, 3) with a finite score,
    u, v finite or (where the score is 0) NaN; origin (P, 2 * 16) finite; stride (P,) finite > 0."""
    uv, score = keypoints[..., :2], keypoints[..., 2]
    checks = (
        (~np.isfinite(score), 'keypoint score is not finite'),
        (np.isinf(uv).any(axis=-1), 'keypoint u, v infinite'),
        (np.isnan(uv).any(axis=-1) & (score != 0), 'keypoint u, v NaN with score != 0'),
    )
    for mask, problem in checks:
        if mask.any():
            p, j = np.argwhere(mask)[0]
            raise ValueError(f'{label} {p} joint {j}: {problem} (u, v, score = '
                             f'{tuple(keypoints[p, j].tolist())})')
    bad = ~np.isfinite(origin).all(axis=-1)
    if bad.any():
        p = int(np.argmax(bad))
        raise ValueError(f'{label} {p} heatmap origin: not finite ({origin[p].tolist()})')
    bad = ~(np.isfinite(stride) & (stride > 0))
    if bad.any():
        p = int(np.argmax(bad))
        raise ValueError(f'{label} {p} heatmap stride: must be finite and > 0, got {stride[p]}')


def _people_records(people: Sequence[Person2D], keys: Sequence[tuple[str, str]],
                    label: str) -> np.ndarray:
    """Records (P,) of B's fields (keys left zero), each map cut to its evidence
    (HeatmapStack.trimmed: the same look-ups and draws) and each record's maps one after another,
    zero-padded to the largest record; errors name the offending entry as f'{label} {index}'."""
    for p, person in enumerate(people):
        kp = np.shape(person.keypoints)
        if kp != (J, 3):
            raise ValueError(f'{label} {p} keypoints: expected ({J}, 3), got {kp}')
        shape = person.heatmap.shape
        if len(shape) != J or shape.min() < 1 or shape.max() > UINT16_MAX:
            raise ValueError(f'{label} {p} heatmap grids: expected {J} of h x w with 1 <= h, w <= '
                             f'{UINT16_MAX}, got {shape.tolist()}')
    n = len(people)
    keypoints = np.array([p.keypoints for p in people], dtype=np.float32).reshape(n, J, 3)
    origin = np.array([p.heatmap.origin for p in people], dtype=np.float32).reshape(n, 2 * J)
    stride = np.array([p.heatmap.stride for p in people], dtype=np.float32)
    _check_people(keypoints, origin, stride, label)
    if not n:
        return np.zeros(0, dtype=people_dtype(0, keys))
    stack = HeatmapStack.of([p.heatmap for p in people])
    if not np.isfinite(stack.values).all():
        bad = next(p for p, person in enumerate(people) if not np.isfinite(person.heatmap.cells).all())
        raise ValueError(f'{label} {bad} heatmap maps: non-finite values')
    # cut to the evidence that is sent: a cell below half a quantisation step goes as 0, and a map
    # cut by its float values would keep such rows, which a decoded map then loses when encoded again
    quantised = quantise(stack.values.astype(np.float32, copy=False))
    stack = HeatmapStack(quantised.astype(np.float32), stack.start, stack.shape, stack.origin, stack.stride).trimmed()
    with np.errstate(over='ignore'):  # an origin moved beyond float32 is named below
        origin = stack.origin.astype(np.float32).reshape(n, 2 * J)
    beyond = ~np.isfinite(origin).all(axis=1)
    if beyond.any():
        p = int(np.argmax(beyond))
        raise ValueError(f'{label} {p} heatmap origin: beyond float32 once its maps are cut to their evidence')
    cells = stack.values.astype(np.uint8)
    sizes = (stack.shape[..., 0] * stack.shape[..., 1]).sum(axis=1)
    n_cells = int(sizes.max())
    if n_cells > UINT32_MAX:
        raise ValueError(f'heatmap cells of one record: {n_cells} exceeds the PointField count range')
    records = np.zeros(n, dtype=people_dtype(n_cells, keys))
    records['keypoints'] = keypoints.reshape(n, 3 * J)
    records['origin'] = origin
    records['stride'] = stride
    records['grid'] = stack.shape.reshape(n, 2 * J)
    heat = records['heatmap']
    for p, first in enumerate(stack.start[:, 0]):
        heat[p, :sizes[p]] = cells[first:first + sizes[p]]
    return records


def _grids(records: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each record's map shapes (P, 16, 2) h, w and its number of heatmap cells (P,), of records
    (P,) of B's fields."""
    grid = records['grid'].reshape(len(records), J, 2).astype(np.int64)
    return grid, (grid[..., 0] * grid[..., 1]).sum(axis=1)


def _records_from_msg(msg: PointCloud2, keys: Sequence[tuple[str, str]]) -> np.ndarray:
    """Decode B's layout (after keys) with the heatmap count the message declares, then check
    every record's grids against it."""
    slot = len(keys) + 4  # the heatmap field's position; its name is checked by from_cloud
    n_cells = msg.fields[slot].count if len(msg.fields) > slot else 0
    if n_cells > len(msg.data):  # also keeps a corrupt count from sizing a huge dtype
        raise ValueError(f'people heatmap count {n_cells}: more than the {len(msg.data)} data bytes')
    records = from_cloud(msg, people_dtype(n_cells, keys))
    if len(records) == 0:
        if n_cells != 0:
            raise ValueError(f'people heatmap count: expected 0 with no records, got {n_cells}')
        return records
    grid, sizes = _grids(records)
    empty = (grid < 1).any(axis=2)
    if empty.any():
        i, j = np.argwhere(empty)[0]
        raise ValueError(f'people record {i} joint {j}: grid {tuple(grid[i, j].tolist())}, needs h, w >= 1')
    over = sizes > n_cells
    if over.any():
        i = int(np.argmax(over))
        raise ValueError(f'people record {i}: its grids hold {sizes[i]} cells, more than the heatmap count '
                         f'{n_cells}')
    with np.errstate(invalid='ignore', over='ignore'):  # non-finite origins and strides are named later
        corner = (records['origin'].astype(np.float64).reshape(-1, J, 2)
                  + records['stride'].astype(np.float64)[:, None, None] * (grid[..., ::-1] - 1))
        beyond = np.abs(corner).max(axis=2) > np.finfo(np.float32).max
    if beyond.any():
        i, j = np.argwhere(beyond)[0]
        raise ValueError(f'people record {i} joint {j}: its map reaches pixel {tuple(corner[i, j].tolist())}, '
                         f'beyond float32')
    return records


def _keypoints_of(records: np.ndarray) -> np.ndarray:
    """(P, 16, 3) float64 keypoints of records (P,) of B's fields, after checking the records'
    keypoints, origins and strides."""
    keypoints = records['keypoints'].reshape(len(records), J, 3)
    _check_people(keypoints, records['origin'], records['stride'], 'record')
    return keypoints.astype(np.float64)


def _people_from_records(records: np.ndarray) -> list[Person2D]:
    """Person2D (track_id -1) of each record (P,) of B's fields, values validated."""
    n = len(records)
    keypoints = _keypoints_of(records)
    if n == 0:
        return []
    grid, sizes = _grids(records)
    cells = np.divide(records['heatmap'], np.float32(255), dtype=np.float32)
    origin = records['origin'].astype(np.float64).reshape(n, J, 2)
    return [Person2D(keypoints=keypoints[p],
                     heatmap=PersonHeatmap.from_cells(cells[p, :sizes[p]], grid[p], origin[p],
                                                      float(records['stride'][p])))
            for p in range(n)]


def people_to_msg(people: Sequence[Person2D], header: Header) -> PointCloud2:
    """Encoding B: one record per person (none = an empty message, 'nobody')."""
    return to_cloud(_people_records(people, (), 'person'), header)


def msg_to_people(msg: PointCloud2) -> list[Person2D]:
    """Decode encoding B; maps come back on their own grids, as float32 / 255."""
    return _people_from_records(_records_from_msg(msg, ()))


@dataclass(eq=False)
class WirePerson:
    """A 2D person of an encoding B message with its keypoints decoded (core.types.Keypoints2D, as
    association needs) and its heatmaps left as they came: row `row` of its message's records."""

    keypoints: np.ndarray  # (16, 3) float64
    records: np.ndarray  # (P,) the message's records, B's fields, shared by its people
    row: int
    track_id: int = -1


def msg_to_wire_people(msg: PointCloud2) -> list[WirePerson]:
    """Decode encoding B as msg_to_people does, every field checked alike, but without its maps:
    each person's heatmap cells stay in the records, for wire_bundles_to_msg."""
    records = _records_from_msg(msg, ())
    keypoints = _keypoints_of(records)
    return [WirePerson(keypoints[p], records, p) for p in range(len(records))]


def _is_int(x: object) -> bool:
    return isinstance(x, (int, np.integer)) and not isinstance(x, bool)


def _views_in_order(bundles: Sequence[tuple[int, dict[int, object]]]) -> tuple[list[int], list[int], list]:
    """Encoding C's rows of bundles: person ids, cameras and views, sorted by person id then
    camera; person ids must be distinct, each bundle must hold at least one view."""
    for person_id, views in bundles:
        if not _is_int(person_id) or not 0 <= person_id <= UINT32_MAX:
            raise ValueError(f'bundle person id {person_id!r}: not an integer in UINT32')
        if not views:
            raise ValueError(f'bundle of person {person_id}: no views')
        for camera in views:
            if not _is_int(camera) or not 0 <= camera <= UINT16_MAX:
                raise ValueError(f'bundle of person {person_id}: camera {camera!r} not an '
                                 f'integer in UINT16')
    ids, cameras, people = [], [], []
    for person_id, views in sorted(bundles, key=lambda bundle: bundle[0]):
        if ids and ids[-1] == person_id:
            raise ValueError(f'bundle person id {person_id}: given twice')
        for camera, person in sorted(views.items()):
            ids.append(person_id)
            cameras.append(camera)
            people.append(person)
    return ids, cameras, people


def bundles_to_msg(bundles: Sequence[tuple[int, dict[int, Person2D]]],
                   header: Header) -> PointCloud2:
    """Encoding C: one record per (person id, camera), sorted by person id then camera. Person
    ids must be distinct, each bundle must hold at least one view."""
    ids, cameras, people = _views_in_order(bundles)
    records = _people_records(people, BUNDLE_KEYS, 'bundle view')
    records['person'] = ids
    records['camera'] = cameras
    return to_cloud(records, header)


def wire_bundles_to_msg(bundles: Sequence[tuple[int, dict[int, WirePerson]]],
                        header: Header) -> PointCloud2:
    """Encoding C as bundles_to_msg, each view's record copied from the B message it came in.
    Decoded, it gives the maps bundles_to_msg would give of those people (the same look-ups and
    draws: the detector's trimmed, quantised cells, not cut again)."""
    ids, cameras, people = _views_in_order(bundles)
    n = len(people)
    sources: dict[int, tuple[np.ndarray, list[int], list[int]]] = {}  # records' id -> records, rows out, rows in
    for i, person in enumerate(people):
        _, out_rows, in_rows = sources.setdefault(id(person.records), (person.records, [], []))
        out_rows.append(i)
        in_rows.append(person.row)
    sizes = np.zeros(n, dtype=np.int64)
    for records, out_rows, in_rows in sources.values():
        sizes[out_rows] = _grids(records[in_rows])[1]
    out = np.zeros(n, dtype=people_dtype(int(sizes.max(initial=0)), BUNDLE_KEYS))
    width = out['heatmap'].shape[1]
    for records, out_rows, in_rows in sources.values():
        for name in ('keypoints', 'origin', 'stride', 'grid'):
            out[name][out_rows] = records[name][in_rows]
        cells = min(width, records['heatmap'].shape[1])
        out['heatmap'][out_rows, :cells] = records['heatmap'][in_rows, :cells]
    out['person'] = ids
    out['camera'] = cameras
    return to_cloud(out, header)


def msg_to_bundles(msg: PointCloud2) -> list[tuple[int, dict[int, Person2D]]]:
    """Decode encoding C (records in any order) into (person id, {camera: Person2D}) in
    increasing person id; a (person, camera) pair given twice is an error."""
    records = _records_from_msg(msg, BUNDLE_KEYS)
    records = records[np.lexsort((records['camera'], records['person']))]
    person, camera = records['person'], records['camera']
    repeated = (np.diff(person) == 0) & (np.diff(camera) == 0)
    if repeated.any():
        i = int(np.argmax(repeated))
        raise ValueError(f'bundles: person {person[i]} camera {camera[i]} given twice')
    people = _people_from_records(records)
    ids, starts = np.unique(person, return_index=True)
    ends = np.append(starts[1:], len(records))
    return [(int(pid), {int(c): p for c, p in zip(camera[s:e], people[s:e])})
            for pid, s, e in zip(ids, starts, ends)]
