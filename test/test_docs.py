"""The README and docs/: every relative link reaches a file of the checkout, and every link to a
heading reaches a heading of that file (GitHub's anchors), so moving a section cannot leave a
reader at a dead link."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

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
