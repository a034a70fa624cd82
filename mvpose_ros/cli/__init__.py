"""Command-line entry points: argument parsing only; the work is in bench, graph and the core."""
