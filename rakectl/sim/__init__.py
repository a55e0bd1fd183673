"""Offline work against the emulated hardware: scenarios, simulation, the safety campaign, the demo.

This package, :mod:`rakectl.bench` and :mod:`rakectl.cli` are the only ones
that may import :mod:`drivers`.
"""
