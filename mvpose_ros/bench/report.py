"""What `mvpose-bench` prints and plots: the time per stage, frame rates, memory and PCP of
each run, the default row in detail, the two-process run and the profile; PNG plots of the
sweeps."""
from __future__ import annotations

import io
import pstats
import cProfile
from dataclasses import replace
from pathlib import Path
from typing import Iterable, Sequence, TextIO

from mvpose_ros.bench.runs import OTHER, SWEEPS, RunConfig
from mvpose_ros.core.evaluation.offline import GROUPING

# the core's timer keys, in pipeline order; any other key the timer has is printed after these
PREFERRED = (GROUPING, 'association', 'sampling', 'data term', 'factors', 'bp', 'decoding')
LABELS = {'association': 'tracking and matching', 'bp': 'BP'}

SHORT = {GROUPING: 'group+hm', 'association': 'trk+match', 'sampling': 'sampling', 'data term': 'data',
         'factors': 'factors', 'bp': 'BP', 'decoding': 'decode', OTHER: 'other'}


def stage_order(names: Iterable[str]) -> list[str]:
    """Stage names in pipeline order: the known ones first, then others, 'other' last."""
    names = list(dict.fromkeys(names))
    known = [n for n in PREFERRED if n in names]
    return known + [n for n in names if n not in PREFERRED and n != OTHER] + ([OTHER] if OTHER in names else [])


def stage_label(name: str, names: Sequence[str]) -> str:
    """The printed name of stage `name` among the stages `names` of a run."""
    if name == 'bp' and 'factors' not in names:
        return 'BP (with factors and decoding)'
    return LABELS.get(name, name)


def figures(result: dict) -> dict:
    """Per-frame milliseconds of each stage and the frame rates of one result."""
    n = max(result['frames'], 1)
    ms = {k: 1000.0 * v / n for k, v in result['stages_s'].items()}
    total = sum(result['stages_s'].values())
    after = total - result['stages_s'].get(GROUPING, 0.0)
    return {'ms': ms, 'total_ms': 1000.0 * total / n, 'from_2d_ms': 1000.0 * after / n,
            'fps': n / total if total > 0 else float('inf'), 'fps_from_2d': n / after if after > 0 else float('inf')}


def _mib(kib: float) -> float:
    return kib / 1024.0


def print_tables(results: Sequence[dict], out: TextIO) -> None:
    """The tables of the runs, a row each: time per frame of each stage, then memory and PCP."""
    ok = [r for r in results if 'error' not in r]
    names = stage_order([k for r in ok for k in r['stages_s']])
    head = (f'{"run":24s} {"cams":>4s} {"people":>6s} {"M":>3s} {"win":>4s} '
            + ' '.join(f'{SHORT.get(n, n[:9]):>9s}' for n in names) + f' {"total":>8s} {"fps":>7s} {"fps 2D+":>7s}')
    print('Time per frame (ms) of each stage; fps = frames per second of the whole 3D stage (grouping and '
          'heatmaps onward); fps 2D+ = from 2D people on (tracking and matching onward)', file=out)
    print(head, file=out)
    print('-' * len(head), file=out)
    for r in results:
        c = r['config']
        win = str(c['settings']['window']) if c['settings']['window'] else 'all'
        if 'error' in r:
            print(f'{c["name"]:24s} failed: {r["error"]}', file=out)
            continue
        f = figures(r)
        cells = ' '.join(f'{f["ms"][n]:9.2f}' if n in f['ms'] else f'{"-":>9s}' for n in names)
        m = c['settings']['hypotheses']
        print(f'{c["name"]:24s} {r["cameras"]:4d} {r["people_3d"]:6.1f} {m:3d} {win:>4s} {cells} '
              f'{f["total_ms"]:8.2f} {f["fps"]:7.1f} {f["fps_from_2d"]:7.1f}', file=out)
    print('stages: ' + '; '.join(f'{SHORT.get(n, n)} = {stage_label(n, names)}' for n in names), file=out)
    notes = []
    same = [f'{r["config"]["name"]} = {r["same_run_as"]}' for r in ok if r.get('same_run_as')]
    if same:
        notes.append('measured once: ' + ', '.join(same))
    for r in ok:
        c = r['config']
        if r.get('same_run_as'):
            continue
        if r['people_3d'] == 0:
            notes.append(f'{c["name"]}: no 3D people (with {r["cameras"]} camera(s) no joint is seen twice); '
                         f'only grouping and association ran')
        if r['scene']:
            s = r['scene']
            notes.append(f'{c["name"]}: target {c["people"]:g} people: {s["copies"]} shifted copies of the scene '
                         f'(offsets {", ".join(f"({x:+.1f},{y:+.1f})" for x, y in s["offsets_m"][1:])} m), '
                         f'{r["people_3d"]:.1f} 3D people and {r["people_2d_per_camera"]:.1f} 2D people per camera '
                         f'per frame; grouping and heatmaps measured on the original detections only')
    if notes:
        print('notes:\n  ' + '\n  '.join(notes), file=out)

    print('\nMemory (MiB; each run its own process) and accuracy (PCP %, alpha 0.5, actors 1-3)', file=out)
    head = (f'{"run":24s} {"frames":>6s} {"2D/cam":>6s} {"3D":>5s} {"out":>5s} {"start":>6s} {"ready":>6s} '
            f'{"peak":>6s} {"stage":>6s} {"growth":>6s}   {"strict fw/aa":>13s} {"lenient fw/aa":>13s} {"MPJPE":>8s}')
    print(head, file=out)
    print('-' * len(head), file=out)
    for r in ok:
        c = r['config']
        p = r['pcp']
        acc = (f'{p["strict_frame_weighted"]:6.2f}/{p["strict_actor_avg"]:6.2f} '
               f'{p["lenient_frame_weighted"]:6.2f}/{p["lenient_actor_avg"]:6.2f} {p["mpjpe_mm"]:5.1f} mm') if p else ''
        stage = r['peak_stage_kib']
        stage_cells = (f'{_mib(stage):6.1f} {_mib(stage - r["rss_ready_kib"]):6.1f}' if stage is not None
                       else f'{"n/a":>6s} {"n/a":>6s}')
        print(f'{c["name"]:24s} {r["frames"]:6d} {r["people_2d_per_camera"]:6.1f} {r["people_3d"]:5.1f} '
              f'{r["people_out"]:5.1f} {_mib(r["rss_start_kib"]):6.1f} {_mib(r["rss_ready_kib"]):6.1f} '
              f'{_mib(r["peak_rss_kib"]):6.1f} {stage_cells}   {acc}', file=out)
    print('2D/cam, 3D, out: people per frame (2D per camera, associated, output). RSS: start = after imports; '
          'ready = every frame\'s 2D people held in memory (the bench holds the clip; the graph streams it); '
          'peak = the process maximum (ru_maxrss); stage = peak from tracking onward (peak reset at ready); '
          'growth = stage - ready', file=out)


def print_default(result: dict, out: TextIO) -> None:
    """The default row in detail: every stage with its share, both frame rates, memory, PCP."""
    f = figures(result)
    names = stage_order(result['stages_s'])
    c = result['config']
    stage = c['settings']
    print(f'\n{c["name"]}: {result["frames"]} frames, {result["cameras"]} cameras, {result["people_3d"]:.2f} 3D people '
          f'per frame; window {stage["window"]}, lag {stage["lag"]}, M {stage["hypotheses"]}, '
          f'{stage["bp_hypotheses"]} in BP, heatmap cells {c["stride"]:g} px', file=out)
    for n in names:
        ms = f['ms'][n]
        print(f'  {stage_label(n, names):32s} {ms:8.2f} ms/frame {100 * ms / f["total_ms"]:5.1f} %', file=out)
    print(f'  {"whole 3D stage":32s} {f["total_ms"]:8.2f} ms/frame -> {f["fps"]:.1f} frames/s '
          f'(grouping and heatmaps onward, all stages)', file=out)
    print(f'  {"from 2D people":32s} {f["from_2d_ms"]:8.2f} ms/frame -> {f["fps_from_2d"]:.1f} frames/s '
          f'(tracking and matching onward)', file=out)
    stage = result['peak_stage_kib']
    print(f'  peak memory {_mib(result["peak_rss_kib"]):.1f} MiB '
          f'(RSS after imports {_mib(result["rss_start_kib"]):.1f}, '
          f'with the 2D people of every frame {_mib(result["rss_ready_kib"]):.1f}'
          + (f', peak from tracking onward {_mib(stage):.1f}: the stage grows by '
             f'{_mib(stage - result["rss_ready_kib"]):.1f})' if stage is not None else ')'), file=out)
    if result['pcp']:
        p = result['pcp']
        print(f'  PCP strict {p["strict_frame_weighted"]:.2f} frame-weighted / {p["strict_actor_avg"]:.2f} '
              f'actor-average'
              f' | lenient {p["lenient_frame_weighted"]:.2f} / {p["lenient_actor_avg"]:.2f} | MPJPE '
              f'{p["mpjpe_mm"]:.1f} mm', file=out)


def print_paced(results: Sequence[dict], out: TextIO) -> None:
    """Each paced row's time per frame from 2D people on (p50 / p95) beside the same run back to
    back: what a frame costs a node that waits for its next message, against a loop."""
    done = [(RunConfig.from_dict(r['config']), r) for r in results if 'error' not in r]
    loops = {config.key(): r for config, r in done if not config.pace}
    for config, r in done:
        loop = loops.get(replace(config, pace=0.0).key())
        if not config.pace or loop is None:
            continue
        paced, back = r['frame_ms'], loop['frame_ms']
        print(f'\nfed at {config.pace:g} Hz (sleeping between frames): from 2D people p50 / p95 {paced["p50"]:.2f} / '
              f'{paced["p95"]:.2f} ms per frame; back to back {back["p50"]:.2f} / {back["p95"]:.2f} ms '
              f'(x{paced["p50"] / back["p50"]:.2f} at the median)', file=out)


def print_crowds(results: Sequence[dict], out: TextIO) -> None:
    """A line per run of the people sweep: time from 2D people on per frame and per 3D person (the
    crowd scenes)."""
    rows = [r for r in results if r['config'].get('sweep') == 'people' and 'error' not in r and r['people_3d'] > 0]
    if rows:
        print('\ncrowd scenes (shifted copies of the Shelf scene), from 2D people on:', file=out)
    for r in rows:
        ms = figures(r)['from_2d_ms']
        print(f'  {r["config"]["name"]:12s} {r["people_3d"]:5.1f} 3D people per frame {ms:8.2f} ms/frame -> '
              f'{ms / r["people_3d"]:.2f} ms per person', file=out)


def _sweep_value(result: dict, sweep: str) -> float:
    stage = result['config']['settings']
    return {'cameras': result['cameras'], 'people': result['people_3d'], 'window': stage['window'] or result['frames'],
            'M': stage['hypotheses']}[sweep]


def write_plots(results: Sequence[dict], output: Path) -> list[Path]:
    """One PNG per sweep run: time per frame of each stage and the total against the setting."""
    from mvpose_ros.core.drawing.plot import Series, line_plot
    titles = {'cameras': ('cameras', 'cameras (the first k of Shelf\'s 5)'),
              'people': ('people', '3D people per frame (scene copies; measured)'),
              'window': ('window', 'window length (frames; lag = window // 2)'),
              'M': ('M', 'M, hypotheses sampled per joint')}
    paths = []
    ok = [r for r in results if 'error' not in r]
    for sweep in SWEEPS:
        rows = [r for r in ok if r['config']['sweep'] == sweep]
        if len(rows) < 2:
            continue
        rows.sort(key=lambda r: _sweep_value(r, sweep))
        label, xlabel = titles[sweep]
        xs = [_sweep_value(r, sweep) for r in rows]
        figs = [figures(r) for r in rows]
        names = stage_order([k for r in rows for k in r['stages_s']])
        series = [Series(stage_label(n, names), xs, [f['ms'].get(n, float('nan')) for f in figs]) for n in names]
        series.append(Series('total', xs, [f['total_ms'] for f in figs], color=(0, 0, 0), thickness=3))
        if sweep == 'people':  # copies are made from the original scene's 2D people, not regrouped
            series[names.index(GROUPING)].name += ' (scene)' if GROUPING in names else ''
        if sweep in ('people', 'cameras'):
            ref = next((i for i, r in enumerate(rows) if r['people_3d'] > 0 and xs[i] > 0), None)
            if ref is not None:
                slope = figs[ref]['total_ms'] / xs[ref]
                series.append(Series(f'linear from {xs[ref]:.3g} {label}', [xs[ref], max(xs)],
                                     [figs[ref]['total_ms'], slope * max(xs)], color=(140, 140, 140), dashed=True))
        frames = rows[0]['frames']
        title = f'Time per frame against {label} (Shelf, {frames} frames; graph settings otherwise)'
        xticks = xs if sweep != 'people' else None
        paths.append(line_plot(output / f'time_vs_{sweep.lower()}.png', series, title=title, xlabel=xlabel,
                               ylabel='ms per frame', xticks=xticks))
    return paths


def print_two_processes(result: dict, out: TextIO) -> None:
    """The two-process run: each side's time per frame, the wall time per frame and its PCP."""
    front = ('grouping and heatmaps', 'association')
    ms = result['stages_ms']
    p = result['pcp']
    print(f"\n{result['config']['name']} on two processes (grouping, heatmaps and association | sampling onward, "
          f"frames streamed through a pipe; bench.pipelined):", file=out)
    print(f"  whole 3D stage {result['wall_ms']:.2f} ms/frame wall -> {result['fps']:.1f} frames/s "
          f"(runs: {', '.join(f'{w:.2f}' for w in result['walls_ms'])} ms/frame)", file=out)
    print(f"  process 1: {sum(ms.get(k, 0.0) for k in front):.2f} ms/frame ("
          + ', '.join(f'{k} {ms[k]:.2f}' for k in front if k in ms) + '); process 2: '
          f"{sum(v for k, v in ms.items() if k not in front):.2f} ms/frame ("
          + ', '.join(f'{k} {v:.2f}' for k, v in ms.items() if k not in front) + ')', file=out)
    print(f"  PCP strict {p['strict_frame_weighted']:.2f} / {p['strict_actor_avg']:.2f} | lenient "
          f"{p['lenient_frame_weighted']:.2f} / {p['lenient_actor_avg']:.2f} | MPJPE {p['mpjpe_mm']:.1f} mm "
          f"(the single-process run's: the same solver on the same input)", file=out)


def print_profile(result: dict, profile: cProfile.Profile, output: Path, out: TextIO) -> None:
    """Save a profiled run's profile and print its top 20 functions by own time."""
    output.mkdir(parents=True, exist_ok=True)
    path = output / 'profile_default.prof'
    profile.dump_stats(str(path))
    text = io.StringIO()
    pstats.Stats(profile, stream=text).strip_dirs().sort_stats('tottime').print_stats(20)
    lines = [line for line in text.getvalue().splitlines() if line.strip()]
    start = next((i for i, line in enumerate(lines) if 'function calls' in line), 0)
    f = figures(result)
    print(f'\nProfile of the default run ({result["frames"]} frames, grouping onward, reading files left out; '
          f'cProfile, top 20 functions by own time; full profile: {path}); under the profiler: '
          f'{f["total_ms"]:.2f} ms/frame', file=out)
    print('\n'.join(lines[start:]), file=out)
