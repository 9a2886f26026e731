"""Every harness that scores something against the simulator's ground truth: the twin's tags,
the target-identification benchmark, the learned detector's AP, frames exported with their
truth, and driver/policy evaluation. Nothing outside this package (and the env's sensor
models) reads ground truth.
"""
