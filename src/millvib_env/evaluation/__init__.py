"""Measuring controllers: episodes on held-out plants (`evaluate`), the benchmark and its room to learn
(`benchmark`), sweeps over the plant's parameters (`sweep`) and the statistics of both (`stats`)."""
