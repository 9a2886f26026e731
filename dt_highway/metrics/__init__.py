"""Safety metrics at simulation frequency, the crash-safe trial logs they are written to, the overlay's
metrics from those logs, and the paired statistics of a study (:mod:`dt_highway.metrics.stats`)."""
