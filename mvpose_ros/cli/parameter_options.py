"""Command-line options from a table of node parameters (core.parameters.Param), so that a tool
and a node take the same settings under the same names, defaults and descriptions: `--box-margin`
for `box_margin`; a flag `--no-<name>` for a parameter on by default (`--<name>` for one off)."""
from __future__ import annotations

import argparse
from typing import Any, Sequence

from mvpose_ros.core.parameters import Param


def option(name: str) -> str:
    """The option of a parameter: `--box-margin` for `box_margin`."""
    return '--' + name.replace('_', '-')


def add_parameter_options(parser: argparse.ArgumentParser, params: Sequence[Param]) -> None:
    """One option per parameter, its help the description and the default (% escaped for argparse)."""
    for p in params:
        text = p.description.replace('%', '%%')
        if isinstance(p.default, bool):
            flag = f'--no-{p.name.replace("_", "-")}' if p.default else option(p.name)
            parser.add_argument(flag, dest=p.name, action='store_false' if p.default else 'store_true',
                                help=f'{text} (default: {"on" if p.default else "off"}; this option turns it '
                                     f'{"off" if p.default else "on"})')
        elif isinstance(p.default, list):
            parser.add_argument(option(p.name), nargs='+', default=list(p.default),
                                help=f'{text} (default: {" ".join(p.default)})')
        else:
            parser.add_argument(option(p.name), type=type(p.default), default=p.default, choices=p.choices or None,
                                help=f'{text} (default: {p.default})')


def parameter_values(args: argparse.Namespace, params: Sequence[Param]) -> dict[str, Any]:
    """The parsed options of the parameters, by parameter name."""
    return {p.name: getattr(args, p.name) for p in params}
