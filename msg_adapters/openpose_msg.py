"""Encoding A: one camera's raw OpenPose BODY25 output (joint candidates and every PAF matrix
entry) as PointCloud2 records, one per candidate and one per affinity."""
from __future__ import annotations

import numpy as np
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Header

from msg_adapters.people_msg import MAX_PEOPLE
from msg_adapters.records import UINT16_MAX, from_cloud, to_cloud
from mvpose_ros.core.detection.openpose import BODY25_NUM_JOINTS, BODY25_PAF_PAIRS, OpenPoseFrame

OPENPOSE_DTYPE = np.dtype([
    ('kind', 'u1'), ('part', 'u1'), ('a', '<u2'), ('b', '<u2'),
    ('u', '<f4'), ('v', '<f4'), ('score', '<f4'),
])
KIND_CANDIDATE = 0
KIND_AFFINITY = 1
MAX_CANDIDATES = UINT16_MAX + 1  # candidate indices are UINT16
# An input message's bound (max_openpose_bytes): candidates of one joint type in one image, twice
# the people a camera can show (people_msg.MAX_PEOPLE; OpenPose also proposes stray candidates).
MAX_INPUT_CANDIDATES = 2 * MAX_PEOPLE
_PAIRS = np.array(BODY25_PAF_PAIRS)  # (26, 2)
_NUM_LIMBS = len(BODY25_PAF_PAIRS)


def max_openpose_bytes() -> int:
    """The most data bytes an encoding A message of one image can honestly carry:
    MAX_INPUT_CANDIDATES of every joint type and every PAF entry between them (7.7 MB)."""
    c = MAX_INPUT_CANDIDATES
    return (BODY25_NUM_JOINTS * c + _NUM_LIMBS * c * c) * OPENPOSE_DTYPE.itemsize


def _limb_layout(n: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per limb (26,): rows n_a, columns n_b and the start of its entries in the concatenation of
    all PAF matrices (row-major), for candidate counts n (25,)."""
    rows, cols = n[_PAIRS[:, 0]], n[_PAIRS[:, 1]]
    sizes = rows * cols
    return rows, cols, np.cumsum(sizes) - sizes


def openpose_to_msg(frame: OpenPoseFrame, header: Header) -> PointCloud2:
    """Encode a frame (candidates: 25 of (n_k, 3) u, v px, score; pafs: 26 of (n_a, n_b))."""
    if len(frame.candidates) != BODY25_NUM_JOINTS:
        raise ValueError(f'OpenPoseFrame candidates: expected {BODY25_NUM_JOINTS} joints, '
                         f'got {len(frame.candidates)}')
    if len(frame.pafs) != _NUM_LIMBS:
        raise ValueError(f'OpenPoseFrame pafs: expected {_NUM_LIMBS} limbs, got {len(frame.pafs)}')
    candidates = [np.asarray(c, dtype=np.float32) for c in frame.candidates]
    for j, c in enumerate(candidates):
        if c.ndim != 2 or c.shape[1] != 3:
            raise ValueError(f'OpenPoseFrame candidates of joint {j}: expected (n, 3), got {c.shape}')
        if len(c) > MAX_CANDIDATES:
            raise ValueError(f'OpenPoseFrame candidates of joint {j}: {len(c)} exceed the UINT16 '
                             f'index range ({MAX_CANDIDATES})')
        if not np.isfinite(c).all():
            raise ValueError(f'OpenPoseFrame candidates of joint {j}: non-finite u, v or score')
    n = np.array([len(c) for c in candidates])
    rows, cols, offsets = _limb_layout(n)
    pafs = [np.asarray(p, dtype=np.float32) for p in frame.pafs]
    for k, p in enumerate(pafs):
        if p.shape != (rows[k], cols[k]):
            raise ValueError(f'OpenPoseFrame paf {k} (joints {BODY25_PAF_PAIRS[k]}): expected shape '
                             f'({rows[k]}, {cols[k]}), got {p.shape}')
        if not np.isfinite(p).all():
            raise ValueError(f'OpenPoseFrame paf {k} (joints {BODY25_PAF_PAIRS[k]}): non-finite score')

    cand = np.concatenate(candidates)
    n_cand = len(cand)
    sizes = rows * cols
    paf_index = np.arange(sizes.sum()) - np.repeat(offsets, sizes)
    row, col = np.divmod(paf_index, np.repeat(cols, sizes))
    records = np.zeros(n_cand + len(paf_index), dtype=OPENPOSE_DTYPE)
    cands, affs = records[:n_cand], records[n_cand:]
    cands['kind'] = KIND_CANDIDATE
    cands['part'] = np.repeat(np.arange(BODY25_NUM_JOINTS), n)
    cands['a'] = np.arange(n_cand) - np.repeat(np.cumsum(n) - n, n)
    cands['u'], cands['v'], cands['score'] = cand.T
    affs['kind'] = KIND_AFFINITY
    affs['part'] = np.repeat(np.arange(_NUM_LIMBS), sizes)
    affs['a'], affs['b'] = row, col
    affs['u'] = affs['v'] = np.nan
    affs['score'] = np.concatenate([p.ravel() for p in pafs])
    return to_cloud(records, header)


def _first(mask: np.ndarray) -> int:
    return int(np.argmax(mask))


def msg_to_openpose(msg: PointCloud2) -> OpenPoseFrame:
    """Decode encoding A (records in any order) into an OpenPoseFrame (float64 arrays holding the
    float32 values). Raises ValueError on a bad layout, an unknown kind or part, a candidate index
    missing or given twice, a PAF entry out of range, missing or given twice, or a non-finite
    value where one is not allowed."""
    records = from_cloud(msg, OPENPOSE_DTYPE)
    kind = records['kind']
    bad = (kind != KIND_CANDIDATE) & (kind != KIND_AFFINITY)
    if bad.any():
        i = _first(bad)
        raise ValueError(f'openpose record {i}: kind value {kind[i]} is neither '
                         f'{KIND_CANDIDATE} (candidate) nor {KIND_AFFINITY} (affinity)')
    cand = records[kind == KIND_CANDIDATE]
    aff = records[kind == KIND_AFFINITY]

    checks = (
        (cand, cand['part'] >= BODY25_NUM_JOINTS, 'candidate part (joint) >= 25'),
        (cand, cand['b'] != 0, 'candidate b is not 0'),
        (cand, ~(np.isfinite(cand['u']) & np.isfinite(cand['v'])), 'candidate u, v not finite'),
        (cand, ~np.isfinite(cand['score']), 'candidate score not finite'),
        (aff, aff['part'] >= _NUM_LIMBS, f'affinity part (limb) >= {_NUM_LIMBS}'),
        (aff, ~(np.isnan(aff['u']) & np.isnan(aff['v'])), 'affinity u, v not NaN'),
        (aff, ~np.isfinite(aff['score']), 'affinity score not finite'),
    )
    for table, mask, problem in checks:
        if mask.any():
            r = table[_first(mask)]
            raise ValueError(f'openpose {problem}: part {r["part"]}, a {r["a"]}, b {r["b"]}, '
                             f'u {r["u"]}, v {r["v"]}, score {r["score"]}')

    # candidates: sorted by (joint, index), joint k's indices must read 0..n_k-1
    cand = cand[np.lexsort((cand['a'], cand['part']))]
    part = cand['part'].astype(np.intp)
    n = np.bincount(part, minlength=BODY25_NUM_JOINTS)
    starts = np.cumsum(n) - n
    wrong = cand['a'] != np.arange(len(cand)) - starts[part]
    if wrong.any():
        i = _first(wrong)
        repeated = i > 0 and part[i - 1] == part[i] and cand['a'][i - 1] == cand['a'][i]
        problem = (f'duplicated candidate index {cand["a"][i]}' if repeated
                   else f'missing candidate index {i - starts[part[i]]}')
        raise ValueError(f'openpose candidates of joint {part[i]}: {problem} '
                         f'(indices must be 0..n-1 each exactly once)')

    # affinities: each limb's n_a x n_b entries exactly once
    rows, cols, offsets = _limb_layout(n)
    limb = aff['part'].astype(np.intp)
    a, b = aff['a'].astype(np.intp), aff['b'].astype(np.intp)
    out = (a >= rows[limb]) | (b >= cols[limb])
    if out.any():
        i = _first(out)
        k = limb[i]
        raise ValueError(f'openpose PAF entry of limb {k} (joints {BODY25_PAF_PAIRS[k]}): '
                         f'({a[i]}, {b[i]}) outside its ({rows[k]}, {cols[k]}) candidates')
    flat = offsets[limb] + a * cols[limb] + b
    order = np.argsort(flat, kind='stable')
    repeated = np.diff(flat[order]) == 0
    if repeated.any():
        i = order[_first(repeated)]
        k = limb[i]
        raise ValueError(f'openpose PAF entry of limb {k} (joints {BODY25_PAF_PAIRS[k]}): '
                         f'({a[i]}, {b[i]}) given twice')
    missing = np.bincount(limb, minlength=_NUM_LIMBS) < rows * cols
    if missing.any():
        k = _first(missing)
        raise ValueError(f'openpose PAF of limb {k} (joints {BODY25_PAF_PAIRS[k]}): missing '
                         f'entries ({np.count_nonzero(limb == k)} of {rows[k] * cols[k]})')

    values = np.empty(len(flat))
    values[flat] = aff['score']
    uvs = np.column_stack([cand['u'], cand['v'], cand['score']]).astype(np.float64)
    return OpenPoseFrame(
        candidates=[uvs[s:s + c] for s, c in zip(starts, n)],
        pafs=[values[o:o + r * c].reshape(r, c) for o, r, c in zip(offsets, rows, cols)],
    )
