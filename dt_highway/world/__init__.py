"""The simulated world: typed drivers and cut-ins on highway-env's road, with stable ids, and
the fast road, vehicle and observation that run highway-env's own models quicker.

Everything here is the simulator's ground truth: only the env, the sensor models and the
:mod:`dt_highway.evaluation` harnesses read it.
"""
