"""Experiments: training protocols, comparisons, benchmarks and their pictures.

They import the algorithms, environments and agents; nothing in the library imports them
(only ``scripts/`` and the tests do).
"""
