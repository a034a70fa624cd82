"""Scenarios made from a recorded scene: a synthetic camera ring, crowds of shifted copies, frames dropped upstream."""
