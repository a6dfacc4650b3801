"""The receiver (BRIEF 3): the model (d, delta) and the measurement effects applied to it
(noise, pulses, display quantisation), assembled per receiver into epochs."""
