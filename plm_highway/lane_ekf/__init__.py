"""Model-based latency compensation: the delay-compensated lane-coordinate EKF of Sensors 2025, 25, 6251."""
