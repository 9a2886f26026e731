"""Safety metrics at simulation frequency and the crash-safe trial logs they are written to."""
