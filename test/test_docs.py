"""The README and docs/: every relative link reaches a file of the checkout, and every link to a
heading reaches a heading of that file (GitHub's anchors), so moving a section cannot leave a
reader at a dead link; docs/nodes.md is what the nodes declare today; the README's test command is
.ci/run's."""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from mvpose_ros.core.defaults import DATA_ROOT_ENV, data_root

REPO = Path(__file__).resolve().parents[1]
PAGES = [REPO / 'README.md', *sorted((REPO / 'docs').glob('*.md'))]
_LINK = re.compile(r'\]\(([^)\s]+)\)')


def anchor(heading: str) -> str:
    """GitHub's anchor of a markdown heading's text: lower case, spaces to dashes, punctuation
    other than dashes and underscores dropped."""
    return re.sub(r'[^\w\- ]', '', heading.strip().lower()).replace(' ', '-')


def anchors(page: Path) -> set[str]:
    text = re.sub(r'^(    |\t).*$', '', page.read_text(encoding='utf-8'), flags=re.M)  # not code blocks
    return {anchor(m.group(1)) for m in re.finditer(r'^#+ (.+)$', text, flags=re.M)}


def test_anchor_is_githubs():
    assert anchor('Results on Shelf (real OpenPose BODY25 detections, frames 300..600, actors 1-3)') == \
        'results-on-shelf-real-openpose-body25-detections-frames-300600-actors-1-3'
    assert anchor('Latency or accuracy: the lag dial') == 'latency-or-accuracy-the-lag-dial'


@pytest.mark.parametrize('page', PAGES, ids=lambda p: p.name)
def test_relative_links_reach_a_file_and_its_heading(page):
    broken = []
    for target in _LINK.findall(page.read_text(encoding='utf-8')):
        if re.match(r'[a-z]+://', target):
            continue
        path, _, fragment = target.partition('#')
        linked = (page.parent / path).resolve() if path else page
        if not linked.exists():
            broken.append(f'{target}: no file {linked}')
        elif fragment and linked.suffix == '.md' and fragment not in anchors(linked):
            broken.append(f'{target}: no heading #{fragment} in {linked.name}')
    assert not broken, broken


def test_node_reference_is_what_the_nodes_declare(domain, tmp_path):
    """docs/nodes.md is `mvpose-docs nodes`'s output today: a parameter, topic or QoS changed in a
    node without regenerating the page fails here, with the difference."""
    env = {**os.environ, 'ROS_DOMAIN_ID': str(domain), 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
           DATA_ROOT_ENV: str(data_root())}  # as this process finds it (../shared beside the checkout)
    done = subprocess.run([sys.executable, '-m', 'mvpose_ros.cli.docs', 'nodes', '--check',
                           '--output', str(REPO / 'docs' / 'nodes.md')],
                          env=env, cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, (f'`mvpose-docs nodes --check` failed (a stale page: run `mvpose-docs nodes`)\n'
                                  f'{done.stdout}{done.stderr[-2000:]}')


def test_readme_test_command_is_what_ci_runs():
    """The README's test command is .ci/run's, verbatim, and the set-up command beside it installs
    from the same requirements file."""
    ci = [line for line in (REPO / '.ci' / 'run').read_text().splitlines()
          if line and not line.startswith(('#', 'set ', 'cd '))]
    readme = (REPO / 'README.md').read_text(encoding='utf-8').splitlines()
    assert ci and f'    {ci[-1]}' in readme, f'.ci/run runs {ci[-1]!r}; the README does not show it as a command'
    setup = '    python3 -m venv .venv && .venv/bin/pip install -r requirements.txt .'
    assert any(line.startswith(setup) for line in readme), 'no set-up command in the README'
