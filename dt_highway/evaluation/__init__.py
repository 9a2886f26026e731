"""Every harness that scores something against the simulator's ground truth: the twin's tags,
the target-identification benchmark, the learned detector's AP, frames exported with their
truth, and driver/policy evaluation.

Outside this package the simulator's truth is read only where the design says so: by the
world itself, by the sensor models that turn it into measurements (the GNSS uplink, the
renderer, the simulated detector), by :mod:`dt_highway.env.senses` (what a person at the wheel
sees: where the cars are and which one a marker sits on), by the trial logs (cut-ins with
the cutting driver's true type, for the report) and by the learned detector's training data
(labels). Drivers, the twin's verdict, the fusion and the overlay never read it.
"""
