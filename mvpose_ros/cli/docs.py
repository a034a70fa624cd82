"""mvpose-docs: the generated documentation pages. `mvpose-docs nodes` writes docs/nodes.md (the
node reference, mvpose_ros.nodes.reference); `--check` only says whether it is up to date."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit code (1: --check found the page stale)."""
    parser = argparse.ArgumentParser(prog='mvpose-docs', description=__doc__)
    parser.add_argument('page', choices=['nodes'], help='the page to generate: nodes (docs/nodes.md; the data root as '
                                                        'for every node: $MVPOSE_DATA_ROOT or ../shared)')
    parser.add_argument('--output', type=Path, help='where to write it (default: docs/nodes.md of this checkout)')
    parser.add_argument('--check', action='store_true', help='write nothing; exit 1 and print the difference when '
                                                             'the page is not what the nodes declare')
    args = parser.parse_args(argv)
    from mvpose_ros.nodes.reference import default_page_path, page, stale_lines
    path = args.output or default_page_path()
    fresh = page()
    if args.check:
        current = path.read_text(encoding='utf-8') if path.is_file() else ''
        diff = stale_lines(current, fresh)
        print('\n'.join(diff) if diff else f'{path}: up to date')
        return 1 if diff else 0
    path.write_text(fresh, encoding='utf-8')
    print(f'{path}: written')
    return 0


if __name__ == '__main__':
    sys.exit(main())
