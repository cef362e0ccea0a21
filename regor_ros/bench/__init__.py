"""The benchmark harness: the shared data sets' loaders, the peers, the benchmarks behind
``regor-bench`` and the gate's calibration (``regor-calibrate-gate``). Nothing a robot runs needs it."""
